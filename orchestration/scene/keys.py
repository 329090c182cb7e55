"""Dotted scene keys at the edges: ``--set key=value`` items, values read as TOML reads them, and
the error every bad key or value raises.

A scene is read into typed records (:mod:`orchestration.scene.records`) once; the dotted keys
(``plant.n_modes``, ``controller.cutoff``...) are how scene files, ``--set``, sweep axes and SSP
annotations name the records' fields. Every error is a :class:`ConfigError` (a ``ValueError``)
whose one-line message names the key and what is allowed.
"""
from __future__ import annotations

import json
import math

import tomllib

__all__ = ["ConfigError", "FMU_FLAVOURS", "parse_value", "toml_value", "parse_override",
           "check_known"]

#: The FMUs a scene runs on (``master.fmus``): compiled C (FMI 2.0), or pythonfmu.
FMU_FLAVOURS = ("native", "python")


class ConfigError(ValueError):
    """A bad key or value in a scene or a ``--set`` override (the message is one line)."""


def parse_value(text: str):
    """Read a value as TOML does (``4`` -> int, ``0.5`` -> float, ``true`` -> bool, ``inf``);
    anything else is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
        return text.strip()


def toml_value(value) -> str:
    """A scene value as a TOML value: the inverse of :func:`parse_value`."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} into an SSP annotation")


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
            import difflib                  # only for an unknown key's message

            close = difflib.get_close_matches(key, list(known), n=1) if isinstance(key, str) \
                else []
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ConfigError(f"unknown key {key!r}{hint} (known keys: "
                              f"{', '.join(sorted(known))})")
