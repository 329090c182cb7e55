"""Studies of the closed loop: linear analysis, filter design, stability of the coupling, model fidelity, mode fits and the monolithic reference."""
