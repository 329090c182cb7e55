"""Dotted configuration keys (``plant.n_modes``, ``controller.cutoff``...) shared by the command
line's ``--set key=value`` overrides and the scene files.

A configuration is a flat ``dict`` from dotted key to value. ``plant.*`` keys are the fields of
:class:`~plant_fmu.params.PlantParams` plus the plant FMU's solver settings, ``controller.*`` keys
the fields of :class:`~controller_fmu.pd_lowpass.ControllerParams`. Every error is a
:class:`ConfigError` (a ``ValueError``) whose one-line message names the key and what is allowed.
"""
from __future__ import annotations

import dataclasses
import difflib
import tomllib

from controller_fmu.pd_lowpass import ControllerParams
from plant_fmu.params import PlantParams

__all__ = ["ConfigError", "PLANT_KEYS", "CONTROLLER_KEYS", "FIDELITIES", "parse_value",
           "parse_override", "apply_overrides", "plant_params", "controller_params",
           "default_config", "check_known"]

#: Model fidelities of the plant.
FIDELITIES = ("nonlinear", "linear")


class ConfigError(ValueError):
    """A bad key or value in a scene or a ``--set`` override (the message is one line)."""


def _fields(cls) -> dict:
    return {f.name: f.default for f in dataclasses.fields(cls)}


#: plant.* keys with their defaults: the physical parameters and the FMU's solver settings.
PLANT_KEYS = {**_fields(PlantParams), "fidelity": "nonlinear"}
#: controller.* keys with their defaults.
CONTROLLER_KEYS = _fields(ControllerParams)


def default_config() -> dict:
    cfg = {f"plant.{k}": v for k, v in PLANT_KEYS.items()}
    cfg.update({f"controller.{k}": v for k, v in CONTROLLER_KEYS.items()})
    return cfg


def parse_value(text: str):
    """Read a value as TOML does (``4`` -> int, ``0.5`` -> float, ``true`` -> bool, ``inf``);
    anything else is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def parse_override(item: str) -> tuple[str, object]:
    """``"plant.n_modes=4"`` -> ``("plant.n_modes", 4)``."""
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key or not value.strip():
        raise ConfigError(f"--set expects key=value, got {item!r}")
    return key, parse_value(value)


def check_known(keys, known) -> None:
    """Raise naming the first key of ``keys`` that is not in ``known``, with the closest match."""
    for key in keys:
        if key not in known:
            close = difflib.get_close_matches(key, list(known), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown key {key!r}{hint} (known keys: {', '.join(sorted(known))})")


def apply_overrides(config: dict, overrides, known=None) -> dict:
    """A copy of ``config`` with ``--set`` items (strings ``key=value``) applied."""
    out = dict(config)
    pairs = [parse_override(o) for o in overrides]
    check_known([k for k, _ in pairs], out if known is None else known)
    out.update(pairs)
    return out


def _section(config: dict, prefix: str, names) -> dict:
    return {k[len(prefix):]: v for k, v in config.items()
            if k.startswith(prefix) and k[len(prefix):] in names}


def plant_params(config: dict) -> PlantParams:
    """The validated :class:`PlantParams` of a configuration."""
    try:
        return PlantParams(**_section(config, "plant.", _fields(PlantParams)))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"plant.{exc}") from None


def controller_params(config: dict) -> ControllerParams:
    """The validated :class:`ControllerParams` of a configuration."""
    try:
        return ControllerParams(**_section(config, "controller.", CONTROLLER_KEYS))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"controller.{exc}") from None


def fidelity(config: dict) -> str:
    value = config.get("plant.fidelity", "nonlinear")
    if value not in FIDELITIES:
        raise ConfigError(f"plant.fidelity = {value!r} is not allowed; allowed: "
                          f"{', '.join(FIDELITIES)}")
    return value
