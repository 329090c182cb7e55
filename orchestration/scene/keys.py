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

__all__ = ["ConfigError", "ConfigTypeError", "FMU_FLAVOURS", "parse_value", "toml_value",
           "parse_override", "check_known", "config_error", "unknown_key"]

#: The FMUs a scene runs on (``master.fmus``): compiled C (FMI 2.0), or pythonfmu.
FMU_FLAVOURS = ("native", "python")


class ConfigError(ValueError):
    """A bad key or value in a scene or a ``--set`` override (the message is one line).

    ``str(error)`` speaks Python; :attr:`cli` is the same message as the command line words it
    (``flexpend keys`` where Python says ``orchestration.scene_keys()``; an override named
    ``--set``): both are made by the same code, from the same parts."""

    def __init__(self, message: str = "", *, cli: str | None = None):
        super().__init__(message)
        self.cli = message if cli is None else cli

    def prefixed(self, prefix: str, cli_prefix: str | None = None, cls=None) -> "ConfigError":
        """This error with ``prefix`` before its message (``cli_prefix`` before its CLI form;
        default the same), as ``cls`` (default: its own class, or its TypeError kind)."""
        cli_prefix = prefix if cli_prefix is None else cli_prefix
        cls = cls or type(self)
        if isinstance(self, TypeError):
            cls = type_kind(cls)
        return cls(f"{prefix}{self}", cli=f"{cli_prefix}{self.cli}")


class ConfigTypeError(ConfigError, TypeError):
    """A scene key given a value of the wrong type (a string for a number...): a
    :class:`ConfigError` that is also a ``TypeError``."""


_TYPE_KINDS: dict = {ConfigError: ConfigTypeError}


def type_kind(cls):
    """The TypeError kind of the ConfigError class ``cls`` (made once per class)."""
    if issubclass(cls, TypeError):
        return cls
    if cls not in _TYPE_KINDS:
        _TYPE_KINDS[cls] = type(f"{cls.__name__[:-5]}TypeError", (cls, ConfigTypeError),
                                {"__module__": cls.__module__,
                                 "__doc__": f"A {cls.__name__} that is also a TypeError."})
    return _TYPE_KINDS[cls]


def config_error(exc: Exception, prefix: str = "") -> ConfigError:
    """A model's TypeError or ValueError (``fmu_common.checks``) as a ConfigError, its message
    behind ``prefix``: a :class:`ConfigTypeError` for a TypeError."""
    if isinstance(exc, ConfigError):
        return exc.prefixed(prefix)
    cls = ConfigTypeError if isinstance(exc, TypeError) else ConfigError
    return cls(f"{prefix}{exc}")


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


#: Where the scene keys are listed, by who reads the message.
KEYS_LISTED = {"python": "orchestration.scene_keys() lists the scene keys",
               "cli": "flexpend keys lists the scene keys"}
_DESIGN = "orchestration.studies.design.DESIGN_DEFAULTS lists the design keys"
#: Where the ``design.*`` keys are listed.
DESIGN_LISTED = {"python": _DESIGN, "cli": _DESIGN}


def unknown_key(key, known, what: str = "key", listed: dict | None = KEYS_LISTED
                ) -> ConfigError:
    """The error of a key not in ``known``: one line with the closest match (difflib), and
    where the keys are listed (``listed``: by reader; None: the keys themselves, when few).
    ``str()`` speaks Python, ``.cli`` the command line."""
    import difflib                  # only for an unknown key's message

    close = difflib.get_close_matches(key, list(known), n=1) if isinstance(key, str) else []
    hint = f"; did you mean {close[0]!r}?" if close else ""
    text = repr(key)
    shown_key = text if len(text) <= 60 else f"{text[:48]}... ({len(text)} characters)"

    def message(where: str) -> str:
        return f"unknown {what} {shown_key}{hint} ({where})"

    if listed is None:
        every = "allowed: " + ", ".join(sorted(known))
        return ConfigError(message(every))
    return ConfigError(message(listed["python"]), cli=message(listed["cli"]))


def check_known(keys, known, what: str = "key", listed: dict | None = KEYS_LISTED) -> None:
    """Raise :func:`unknown_key` for the first key of ``keys`` that is not in ``known``."""
    for key in keys:
        if key not in known:
            raise unknown_key(key, known, what, listed)
