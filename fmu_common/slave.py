"""FMI plumbing shared by the pythonfmu slaves (``FlexiblePendulum`` and ``PDLowPass``).

Nothing here knows any physics. It registers parameters from a frozen dataclass (the start values
in ``modelDescription.xml`` are then the dataclass defaults), guards the "fixed" variability of
parameters, logs failures and (de)serialises FMU states.

pythonfmu 0.7.0 turns every Python exception into ``fmi2Fatal`` and destroys the Python instance;
Python code has no way to return ``fmi2Error``. The slaves therefore never raise: a failure is
logged with the status ``fmi2Error`` and a message that names its cause (the FMU's loader,
``fmu_common/loader``, turns a call during which an error was logged into
``fmi2Error``), and ``doStep`` returns ``fmi2Discard`` (``do_step`` returns False).

FMU states are dicts with a header (``format``, ``version``, ``model``); serialised, they are JSON.
A serialised state is checked in full when it is read (:meth:`SlaveBase._fmu_state_from_bytes`:
header, keys, types, sizes, finiteness, parameter ranges, by building the model it describes), and
a restore builds everything it needs before it changes the instance, so that a restore that fails
leaves the instance exactly as it was.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
from pythonfmu import (Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer,
                       Real, String)
from pythonfmu.enums import Fmi2Status

__all__ = ["SlaveBase", "Fmi2Status", "dumps_state", "loads_state", "StateError",
           "STATE_FORMAT", "STATE_VERSION", "check_finite"]

#: Relative tolerance on the communication point of ``doStep`` against the slave's own time.
TIME_RTOL = 1e-9
#: The header of every FMU state.
STATE_FORMAT = "flexpend-fmu-state"
STATE_VERSION = 1


class StateError(ValueError):
    """An FMU state that this FMU cannot restore (the message says why)."""


def check_finite(name: str, value, length=None) -> list | float:
    """``value`` as a finite float (or, with ``length``, a list of that many); else StateError."""
    if length is not None:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise StateError(f"{name} must be a list of {length} numbers")
        return [check_finite(f"{name}[{i}]", v) for i, v in enumerate(value)]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise StateError(f"{name} = {value!r} is not a finite number")
    return float(value)

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
    """A pythonfmu slave whose variables come from a table (:mod:`fmu_common.variables`).

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
        """Register the variables of ``table`` (:mod:`fmu_common.variables`), in its order, each
        at its position in the table as its value reference: parameters are fixed and kept in
        ``self._par``, inputs are attributes of the slave, outputs are read through
        ``output_getter(name)``. The native FMUs' Model-Exchange variables (``me_only``) and
        ``time`` are left out (these FMUs are co-simulation FMI 2.0 only); a variable after them
        keeps its position (pythonfmu's ``register_variable`` numbers in registration order,
        so the variables are put at their references here, with its defaults: an input's
        getter and setter read and write the slave's attribute)."""
        from fmu_common.variables import python_entries

        for index, v in python_entries(table):
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
                          description=v.description,
                          getter=lambda n=v.name: getattr(self, n),
                          setter=lambda value, n=v.name: setattr(self, n, value))
            else:
                var = cls(v.name, causality=Fmi2Causality.output,
                          variability=Fmi2Variability.continuous, initial=Fmi2Initial.calculated,
                          description=v.description, getter=output_getter(v.name))
            if index in self.vars:  # pragma: no cover - a table's positions are distinct
                raise RuntimeError(f"{v.name}: value reference {index} is taken")
            var.value_reference = index
            self.vars[index] = var

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
            self._guarded("setReal", lambda v: super(SlaveBase, self).set_real(v, values), vrs,
                          None)

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

    def _state_header(self) -> dict:
        return {"format": STATE_FORMAT, "version": STATE_VERSION, "model": type(self).__name__}

    @staticmethod
    def _fmu_state_to_bytes(state) -> bytes:
        return dumps_state(state)

    @classmethod
    def _fmu_state_from_bytes(cls, state: bytes):
        """The state in ``state`` (bytes), or ``{"invalid": reason}`` (which the loader turns into
        fmi2Error with the reason): every check that needs no instance is made here."""
        try:
            data = loads_state(state)
            cls._check_header(data)
            cls._check_state(data)
            return data
        except Exception as exc:  # noqa: BLE001 - an exception would be fmi2Fatal
            if isinstance(exc, StateError):
                return {"invalid": f"not a valid {cls.__name__} state: {exc}"}
            return {"invalid": f"not a valid {cls.__name__} state ({type(exc).__name__}: {exc})"}

    @classmethod
    def _check_header(cls, state):
        if not isinstance(state, dict):
            raise StateError(f"a state is a JSON object, not {type(state).__name__}")
        if state.get("format") != STATE_FORMAT:
            raise StateError(f"format {state.get('format')!r}, expected {STATE_FORMAT!r}")
        if state.get("version") != STATE_VERSION:
            raise StateError(f"version {state.get('version')!r}; this FMU reads version "
                             f"{STATE_VERSION}")
        if state.get("model") != cls.__name__:
            raise StateError(f"it is a state of the model {state.get('model')!r}, not of "
                             f"{cls.__name__}")

    @staticmethod
    def _check_keys(state: dict, keys):
        missing = sorted(set(keys) - set(state))
        extra = sorted(set(state) - set(keys))
        if missing or extra:
            raise StateError(f"keys missing {missing}, unknown {extra}")

    @classmethod
    def _check_state(cls, state):  # pragma: no cover - every slave defines it
        """Raise :class:`StateError` if ``state`` cannot be restored (no instance needed)."""
        raise NotImplementedError

    def _restore_failed(self, exc) -> None:
        """Log why a restore failed (the instance was not changed)."""
        why = str(exc) if isinstance(exc, StateError) else f"{type(exc).__name__}: {exc}"
        self.log(f"the FMU state could not be restored: {why}; the instance is unchanged",
                 Fmi2Status.error)

    # ------------------------------------------------------------------ never raise
    def terminate(self):
        self._terminated = True

    def _guarded(self, what, fun, vrs, default):
        try:
            return fun(vrs)
        except Exception as exc:  # noqa: BLE001 - an exception would be fmi2Fatal
            self.log(f"{what}: {type(exc).__name__}: {exc}", Fmi2Status.error)
            return [default] * len(vrs)

    def get_integer(self, vrs):
        return self._guarded("getInteger", super().get_integer, vrs, 0)

    def get_boolean(self, vrs):
        return self._guarded("getBoolean", super().get_boolean, vrs, False)

    def get_string(self, vrs):
        return self._guarded("getString", super().get_string, vrs, "")

    def set_integer(self, vrs, values):
        self._guarded("setInteger", lambda v: super(SlaveBase, self).set_integer(v, values), vrs,
                      None)

    def set_boolean(self, vrs, values):
        self._guarded("setBoolean", lambda v: super(SlaveBase, self).set_boolean(v, values), vrs,
                      None)

    def set_string(self, vrs, values):
        self._guarded("setString", lambda v: super(SlaveBase, self).set_string(v, values), vrs,
                      None)

    def _step_size_error(self, step_size) -> str | None:
        """Why ``doStep`` cannot take ``step_size`` (or after fmi2Terminate), or None."""
        if self.__dict__.get("_terminated"):
            return "doStep after fmi2Terminate is not allowed"
        if not (isinstance(step_size, float) and math.isfinite(step_size) and step_size > 0):
            return f"the step size {step_size!r} is not positive and finite"
        return None


def finite_or_none(value) -> float | None:
    """``float(value)`` if it is a finite real, else None."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None
