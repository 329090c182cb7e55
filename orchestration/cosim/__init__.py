"""The co-simulation engine: the FMU slaves, the coupling, the Python loops and the compiled loop."""
