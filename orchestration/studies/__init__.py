"""Studies of the closed loop: linear analysis, filter design, stability of the coupling, model fidelity, mode fits, a run's summary and the monolithic reference."""
