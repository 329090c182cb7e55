"""Scenes: what to run, read once into typed records (the schema, TOML and SSP files)."""
