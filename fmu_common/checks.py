"""Validation of parameter values, shared by every model's parameter records: each check returns
the value in its canonical type or raises ``TypeError``/``ValueError`` with one line that names
the parameter and what is allowed."""
from __future__ import annotations

import dataclasses
import math

__all__ = ["check_real", "check_int", "check_bool", "check_choice", "replace_checked"]


def check_real(name: str, value, *, low=None, high=None, low_open=True, high_open=False,
               allow_inf=False) -> float:
    """Return ``value`` as a float, or raise naming ``name`` and the allowed range.

    ``low_open``/``high_open`` exclude the bounds; ``allow_inf`` admits ``+inf`` (an "off" value).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    lo = "-inf" if low is None else low
    hi = "inf" if high is None else high
    allowed = f"{'(' if low_open else '['}{lo}, {hi}{')' if high_open else ']'}"
    try:
        value = float(value)
    except OverflowError:         # an integer beyond the largest double
        raise ValueError(f"{name} = an integer of {len(str(abs(value)))} digits is out of range; "
                         f"allowed: {allowed}") from None
    ok = not math.isnan(value) and (math.isfinite(value) or (allow_inf and value == math.inf))
    if low is not None:
        ok = ok and (value > low if low_open else value >= low)
    if high is not None:
        ok = ok and (value < high if high_open else value <= high)
    if not ok:
        raise ValueError(f"{name} = {value!r} is out of range; allowed: {allowed}")
    return value


def check_int(name: str, value, *, low: int, high: int) -> int:
    """Return ``value`` as an int, or raise naming ``name`` and the allowed range."""
    if isinstance(value, bool):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if not low <= value <= high:
        shown = value if abs(value) < 10 ** 20 else f"an integer of {len(str(abs(value)))} digits"
        raise ValueError(f"{name} = {shown} is out of range; allowed: integers {low}..{high}")
    return value


def check_bool(name: str, value) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    raise TypeError(f"{name} must be a boolean (true or false), got {value!r}")


def check_choice(name: str, value, allowed) -> str:
    """Return ``value`` if it is one of the strings ``allowed``, or raise naming ``name`` and
    them."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: {', '.join(allowed)}")
    return value


def replace_checked(record, kind: str, changes: dict):
    """``dataclasses.replace`` that names unknown fields (``kind``: "plant", "controller")."""
    unknown = set(changes) - {f.name for f in dataclasses.fields(record)}
    if unknown:
        raise TypeError(f"unknown {kind} parameter(s): {', '.join(sorted(unknown))}")
    return dataclasses.replace(record, **changes)
