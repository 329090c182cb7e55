"""FMI plumbing shared by the two pythonfmu slaves (``FlexiblePendulum`` and ``PDLowPass``).

Nothing here knows any physics. It registers parameters from a frozen dataclass (the start values
in ``modelDescription.xml`` are then the dataclass defaults), guards the "fixed" variability of
parameters, logs failures and (de)serialises FMU states.

pythonfmu 0.7.0 turns every Python exception into ``fmi2Fatal`` and destroys the Python instance;
Python code has no way to return ``fmi2Error``. The slaves therefore never raise: a failure is
logged with the status ``fmi2Error`` and a message that names its cause, and ``doStep`` returns
``fmi2Discard`` (``do_step`` returns False) until a saved FMU state is restored.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
from pythonfmu import (Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer,
                       Real, String)
from pythonfmu.enums import Fmi2Status

__all__ = ["SlaveBase", "Fmi2Status", "dumps_state", "loads_state"]

#: Relative tolerance on the communication point of ``doStep`` against the slave's own time.
TIME_RTOL = 1e-9

_TYPES = {"Boolean": Boolean, "Integer": Integer, "Real": Real, "String": String}


def _encode(obj):
    if isinstance(obj, np.ndarray):
        return {"__ndarray__": obj.tolist(), "dtype": str(obj.dtype), "shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot serialise {type(obj).__name__} in an FMU state")


def _decode(d):
    if "__ndarray__" in d:
        return np.array(d["__ndarray__"], dtype=d["dtype"]).reshape(d["shape"])
    return d


def dumps_state(state) -> bytes:
    """JSON bytes of a state (numpy arrays tagged; floats written exactly by ``repr``)."""
    return json.dumps(state, default=_encode, allow_nan=True).encode("utf-8")


def loads_state(data: bytes):
    return json.loads(data.decode("utf-8"), object_hook=_decode)


class SlaveBase(Fmi2Slave):
    """A pythonfmu slave whose variables come from a table (:mod:`plant_fmu.interface`).

    Subclasses call :meth:`_register_table` in ``__init__`` and read ``self._par`` (a dict
    name -> value) when they initialise.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self._par: dict = {}
        self._par_snap: dict | None = None  # an unshared copy of _par, reused by FMU states
        self._initialized = False     # True after exitInitializationMode
        self._error: str | None = None  # why the slave cannot step (until a state is restored)

    # ------------------------------------------------------------------ variables
    def _register_table(self, table, output_getter):
        """Register the variables of ``table`` (:mod:`plant_fmu.interface`), in its order, so that
        a variable's value reference is its position in the table: parameters are fixed and
        kept in ``self._par``, inputs are attributes of the slave, outputs are read through
        ``output_getter(name)``."""
        for index, v in enumerate(table):
            cls = _TYPES[v.type]
            if v.causality == "parameter":
                self._par[v.name] = v.start
                var = cls(v.name, causality=Fmi2Causality.parameter,
                          variability=Fmi2Variability.fixed, description=v.description,
                          getter=lambda n=v.name: self._par[n],
                          setter=lambda value, n=v.name: self._set_parameter(n, value))
            elif v.causality == "input":
                setattr(self, v.name, v.start)
                var = cls(v.name, causality=Fmi2Causality.input,
                          variability=Fmi2Variability.continuous, start=v.start,
                          description=v.description)
            else:
                var = cls(v.name, causality=Fmi2Causality.output,
                          variability=Fmi2Variability.continuous, initial=Fmi2Initial.calculated,
                          description=v.description, getter=output_getter(v.name))
            self.register_variable(var)
            if var.value_reference != index:  # pragma: no cover - pythonfmu numbers in order
                raise RuntimeError(f"{v.name}: value reference {var.value_reference}, expected "
                                   f"{index} (the position in the table)")

    def set_real(self, vrs, values):
        """pythonfmu's ``set_real``, with a fast path for the real inputs (set every step): one
        ``setattr`` each instead of a type check and a setter closure."""
        names = self.__dict__.get("_real_inputs")
        if names is None:
            names = self._real_inputs = {
                vr: v.local_name for vr, v in self.vars.items()
                if v.causality == Fmi2Causality.input and isinstance(v, Real)}
        try:
            for vr, value in zip(vrs, values):
                setattr(self, names[vr], value)
        except KeyError:                 # not only real inputs: pythonfmu's checked path
            super().set_real(vrs, values)

    def _set_parameter(self, name, value):
        if self._initialized:
            self.log(f"parameter {name} is fixed: it can only be set before "
                     f"exitInitializationMode; the value {value!r} is ignored", Fmi2Status.error)
            return
        self._par[name] = value
        self._par_snap = None
        self._parameters_changed()

    def _parameters_changed(self):
        """Hook: a parameter was set before initialisation (drop what was derived from them)."""

    @staticmethod
    def dataclass_defaults(cls) -> dict:
        return {f.name: f.default for f in dataclasses.fields(cls)}

    # ------------------------------------------------------------------ failures
    def _refuse(self, message: str, status=Fmi2Status.error) -> bool:
        """Log ``message`` and return False (``doStep`` -> fmi2Discard)."""
        self.log(message, status)
        return False

    def _check_time(self, current_time: float, own_time: float) -> str | None:
        """None if ``current_time`` is the slave's own time, else the reason why not."""
        if abs(current_time - own_time) <= TIME_RTOL * max(1.0, abs(own_time)):
            return None
        return (f"doStep called at t = {current_time!r} but the FMU is at t = {own_time!r}; "
                f"restore a saved FMU state to step from another time")

    # ------------------------------------------------------------------ FMU state
    def _params_snapshot(self) -> dict:
        """The parameters as a dict that is never mutated (shared by the saved states)."""
        if self._par_snap is None:
            self._par_snap = dict(self._par)
        return self._par_snap

    def _same_params(self, params: dict) -> bool:
        return params is self._par_snap or params == self._par

    def _restore_params(self, params: dict):
        self._par = dict(params)
        self._par_snap = None

    @staticmethod
    def _fmu_state_to_bytes(state) -> bytes:
        return dumps_state(state)

    @staticmethod
    def _fmu_state_from_bytes(state: bytes):
        try:
            return loads_state(state)
        except Exception as exc:  # noqa: BLE001 - an exception would be fmi2Fatal
            return {"invalid": f"not a serialised FMU state ({type(exc).__name__}: {exc})"}

    @staticmethod
    def _check_state(state):
        """Raise if ``state`` is not a state of this kind of slave (caught by the caller)."""
        if not isinstance(state, dict) or "invalid" in state:
            raise ValueError(state.get("invalid") if isinstance(state, dict) else
                             f"not an FMU state: {type(state).__name__}")


def finite_or_none(value) -> float | None:
    """``float(value)`` if it is a finite real, else None."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None
