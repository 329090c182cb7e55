"""Validation of parameter values, shared by every model's parameter records: each check returns
the value in its canonical type or raises ``TypeError``/``ValueError`` with one line that names
the parameter and what is allowed.

A record's fields carry their own :class:`Param` (:func:`real`, :func:`integer`,
:func:`boolean`, :func:`choice`: a ``dataclasses.field`` with the unit, one line of meaning and
the rule), and the record's ``__post_init__`` checks them with :func:`check_fields`: the limits
that validation enforces are the ones a listing of the parameters prints (``flexpend keys``)."""
from __future__ import annotations

import dataclasses
import functools
import math
import sys

__all__ = ["check_real", "check_int", "check_bool", "check_choice", "replace_checked", "Param",
           "real", "integer", "boolean", "choice", "param_of", "check_fields", "shown",
           "number_text"]

#: The longest value a message quotes (longer ones are cut, their length said).
MAX_SHOWN = 40


def shown(value) -> str:
    """``repr(value)``, cut to about :data:`MAX_SHOWN` characters (a message stays one short
    line whatever the value: a 10 MB string, a deep list)."""
    try:
        text = repr(value)
    except RecursionError:
        text = f"<a {type(value).__name__}>"
    if len(text) <= MAX_SHOWN:
        return text
    return f"{text[:MAX_SHOWN - 12]}... ({len(text)} characters)"


def number_text(x) -> str:
    """A limit as a message quotes it: ``0.0``, ``0.1``, ``1e-15``, ``1e+06``, ``-1e+12``,
    ``inf`` (a float's ``repr`` when short, else 6 significant digits)."""
    if not isinstance(x, float):
        return str(x)
    text = repr(x)
    return text if len(text) <= 8 else f"{x:g}"


def check_real(name: str, value, *, low=None, high=None, low_open=True, high_open=False,
               allow_inf=False) -> float:
    """Return ``value`` as a float, or raise naming ``name`` and the allowed range.

    ``low_open``/``high_open`` exclude the bounds; ``allow_inf`` admits ``+inf`` (an "off" value).
    A range open at 0 (``(0.0, ...``: a step, an interval, a tolerance, a length) takes normal
    numbers only: a subnormal value (positive, below ``sys.float_info.min``, 2.2e-308) is 0 to
    every use of it (``1 / h`` overflows, ``t + h == t``) and is refused as 0 is.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a real number, got {shown(value)}")

    def allowed():
        lo = "-inf" if low is None else number_text(low)
        hi = "inf" if high is None else number_text(high)
        return f"{'(' if low_open else '['}{lo}, {hi}{')' if high_open else ']'}"
    try:
        value = float(value)
    except OverflowError:         # an integer beyond the largest double
        raise ValueError(f"{name} = an integer of {len(str(abs(value)))} digits is out of range; "
                         f"allowed: {allowed()}") from None
    ok = not math.isnan(value) and (math.isfinite(value) or (allow_inf and value == math.inf))
    if low is not None:
        ok = ok and (value > low if low_open else value >= low)
    if high is not None:
        ok = ok and (value < high if high_open else value <= high)
    if not ok:
        raise ValueError(f"{name} = {value!r} is out of range; allowed: {allowed()}")
    if low == 0 and low_open and value < sys.float_info.min:
        raise ValueError(f"{name} = {value!r} is out of range: a subnormal number, below the "
                         f"smallest normal double {sys.float_info.min!r}; allowed: {allowed()}")
    return value


def check_int(name: str, value, *, low: int, high: int) -> int:
    """Return ``value`` as an int, or raise naming ``name`` and the allowed range."""
    if isinstance(value, bool):
        raise TypeError(f"{name} must be an integer, got {shown(value)}")
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int):
        raise TypeError(f"{name} must be an integer, got {shown(value)}")
    if not low <= value <= high:
        text = value if abs(value) < 10 ** 20 else f"an integer of {len(str(abs(value)))} digits"
        raise ValueError(f"{name} = {text} is out of range; allowed: integers {low}..{high}")
    return value


def check_bool(name: str, value) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    raise TypeError(f"{name} must be a boolean (true or false), got {shown(value)}")


def check_choice(name: str, value, allowed) -> str:
    """Return ``value`` if it is one of the strings ``allowed``, or raise naming ``name`` and
    them."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} = {shown(value)} is not allowed; allowed: "
                         f"{', '.join(map(str, allowed))}")
    return value


def replace_checked(record, kind: str, changes: dict):
    """``dataclasses.replace`` that names unknown fields (``kind``: "plant", "controller")."""
    unknown = set(changes) - {f.name for f in dataclasses.fields(record)}
    if unknown:
        raise TypeError(f"unknown {kind} parameter(s): {', '.join(sorted(unknown))}")
    return dataclasses.replace(record, **changes)


# ------------------------------------------------------------------ a record's parameters
@dataclasses.dataclass(frozen=True)
class Param:
    """What a record's field is and what it may be: ``kind`` (``"real"``, ``"int"``,
    ``"bool"``, ``"choice"``, or ``"other"``: checked by the record's own code), ``meaning``
    (one line), ``unit`` (SI, None for none), and the rule :func:`check_fields` enforces: the
    bounds ``low``/``high`` (open or closed; ``high_field``: the field whose value is the upper
    bound), ``allow_inf`` (``+inf`` admitted, an "off" value), ``choices``. ``note``: what
    is also required with other parameters (checked by the code that sees them together), said
    in the listing after the rule."""

    kind: str
    meaning: str
    unit: str | None = None
    low: float | None = None
    high: float | None = None
    low_open: bool = True
    high_open: bool = False
    allow_inf: bool = False
    choices: tuple = ()
    high_field: str | None = None
    note: str = ""

    def allowed(self, prefix: str = "") -> str:
        """The rule in words: ``(0, 1e+06]``, ``integers 0..2``, ``true or false``, ``one of
        a, b``; ``prefix`` before a field's name (``"plant."``)."""
        if self.kind == "real":
            lo = "-inf" if self.low is None else number_text(self.low)
            hi = ("inf" if self.high is None or self.allow_inf else number_text(self.high))
            text = (f"{'(' if self.low_open else '['}{lo}, {hi}"
                    f"{')' if self.high_open else ']'}")
            if self.allow_inf and self.high is None:
                text += " (inf: none)"
        elif self.kind == "int":
            hi = f"{prefix}{self.high_field}" if self.high_field else self.high
            text = f"integers {self.low}..{hi}"
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "choice":
            text = ", ".join(map(str, self.choices))
        else:
            text = ""
        return f"{text}; {self.note}" if text and self.note else text or self.note

    def check(self, name: str, value, high=None):
        """``value`` in its canonical type, or TypeError/ValueError naming ``name`` (``high``:
        the value of ``high_field``)."""
        if self.kind == "real":
            return check_real(name, value, low=self.low, high=self.high, low_open=self.low_open,
                              high_open=self.high_open, allow_inf=self.allow_inf)
        if self.kind == "int":
            return check_int(name, value, low=self.low,
                             high=self.high if self.high_field is None else high)
        if self.kind == "bool":
            return check_bool(name, value)
        if self.kind == "choice":
            return check_choice(name, value, self.choices)
        return value


def _field(default, param: Param):
    return dataclasses.field(default=default, metadata={"param": param})


def real(default, meaning, unit=None, *, low=None, high=None, low_open=True, high_open=False,
         allow_inf=False, note="", check=True):
    """A real field (``check=False``: its record checks it itself, the rule only listed)."""
    return _field(default, Param("real" if check else "other", meaning, unit, low, high,
                                 low_open, high_open, allow_inf, note=note))


def integer(default, meaning, unit=None, *, low, high=None, high_field=None, note=""):
    """An integer field from ``low`` to ``high`` (or to the value of the field ``high_field``)."""
    return _field(default, Param("int", meaning, unit, low, high, high_field=high_field,
                                 note=note))


def boolean(default, meaning, *, note=""):
    return _field(default, Param("bool", meaning, note=note))


def choice(default, meaning, choices, *, note=""):
    return _field(default, Param("choice", meaning, choices=tuple(choices), note=note))


def param_of(cls, name: str) -> Param | None:
    """The :class:`Param` of the field ``name`` of the dataclass ``cls`` (None: none)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            return f.metadata.get("param")
    return None


@functools.lru_cache(maxsize=None)
def _checked_params(cls) -> tuple:
    """``(name, Param)`` of the fields of ``cls`` that have one, those bounded by another field
    last (found once per class: a sweep checks 10,000 scenes)."""
    params = [(f.name, f.metadata["param"]) for f in dataclasses.fields(cls)
              if "param" in f.metadata]
    return tuple(sorted(params, key=lambda np_: np_[1].high_field is not None))


def check_fields(record, prefix: str = "") -> None:
    """Check every field of ``record`` (a frozen dataclass) that has a :class:`Param`, in
    field order (those bounded by another field after it), and store each in its canonical
    type; the first bad one raises TypeError/ValueError naming ``prefix + name``."""
    for name, p in _checked_params(type(record)):
        high = getattr(record, p.high_field) if p.high_field else None
        object.__setattr__(record, name, p.check(prefix + name, getattr(record, name), high))
