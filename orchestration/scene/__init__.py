"""Scenes: what to run, read once into typed records (:mod:`.records`), from TOML files, dicts and
``--set`` items (:mod:`.schema`) or SSP archives (:mod:`.ssp`); the dotted keys at the edges
(:mod:`.keys`) and the wiring (:mod:`.wiring`)."""
