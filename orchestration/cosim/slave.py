"""One co-simulation FMU instance, on fmpy's ``FMU2Slave`` (or ``FMU3Slave``): typed start values,
fast real get/set on preallocated buffers, FMU state, guaranteed cleanup; every FMI status
above warning becomes one :class:`CoSimulationError` in one place (:meth:`Slave._call`).
"""
from __future__ import annotations

import functools
import os

import numpy as np
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2Integer, fmi2Real, fmi2True, fmi2ValueReference

from ..scene.fmu import library_path, model_description, unpack

__all__ = ["describe", "CoSimulationError", "RunInterrupted", "Slave"]


_STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
#: FMI 2.0 start values by type: fmpy's setter and the conversion (as :meth:`Slave._set_start`)
_FMI2_SETTERS = {"Real": ("setReal", float), "Integer": ("setInteger", int),
                 "Enumeration": ("setInteger", int), "Boolean": ("setBoolean", bool),
                 "String": ("setString", str)}


class CoSimulationError(RuntimeError):
    """An FMU call failed; the message names the FMU, the call, the status and the FMU's log.

    Raised by :meth:`Master.run`, it also carries what was computed before the failure:
    ``result`` (the output rows up to the last output point reached) and ``stats``."""

    def __init__(self, message, status=None, time=None):
        super().__init__(message)
        self.status = status
        self.time = time
        self.result = None
        self.stats = None


class RunInterrupted(Exception):
    """:meth:`Master.run` stopped because its ``stop`` callback asked it to (Ctrl-C); ``result``
    holds the output rows up to the last output point reached, ``time`` the time reached."""

    def __init__(self, time, result=None, stats=None):
        super().__init__(f"interrupted at t = {time:.6g}")
        self.time = time
        self.result = result
        self.stats = stats



def _samples(start_values) -> bool:
    """Whether start values set a sampled controller (``sample_period > 0``)."""
    return float((start_values or {}).get("sample_period", 0.0) or 0.0) > 0.0


def describe(path):
    """The FMU's model description (fmpy's ``read_model_description``), read once per file and
    content: every caller in a process (the wiring check, the slaves) shares it. Its archive and
    model identifiers are checked first (:func:`orchestration.scene.fmu.model_description`: an
    :class:`~orchestration.scene.fmu.FmuError`)."""
    st = os.stat(path)
    return _describe(os.fspath(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=64)
def _describe(path: str, mtime_ns: int, size: int):
    return model_description(path, validate=True)


class Slave:
    """One co-simulation FMU instance, with typed start values and fast real I/O."""

    def __init__(self, path, name: str, start_values: dict | None = None, log_level: int = 3,
                 unzipdir=None):
        self.name = name
        self.path = str(path)
        #: a sampled controller (a start value sample_period > 0): the master reads its output
        #: after setting its inputs to the sources' outputs at the same instant (Master)
        self.sampled = _samples(start_values)
        self.md = describe(self.path)
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.messages: list[str] = []
        self._log_level = log_level
        self._own_unzipdir = unzipdir is None      # extracted here: removed by close()
        self._unzipdir = unzipdir or unpack(self.path)
        self.fmu = None
        #: FMI 3.0 (fmpy's FMU3Slave) or 2.0 (FMU2Slave)
        self.fmi3 = self.md.fmiVersion.startswith("3")
        #: takes fmi2SetRealInputDerivatives (a native FMI 2.0 FMU, canInterpolateInputs)
        self.interpolates_inputs = (not self.fmi3 and self.md.coSimulation is not None
                                    and bool(self.md.coSimulation.canInterpolateInputs))
        try:
            interface = self._interface_description()
            library_path(self._unzipdir, self.md, interface.modelIdentifier, self.path)
            self.fmu = self._fmu_class()(guid=self.md.guid, unzipDirectory=self._unzipdir,
                                         modelIdentifier=interface.modelIdentifier,
                                         instanceName=name)
            self._instantiate()
        except BaseException:
            self.fmu = None
            self._remove_unzipdir()
            raise
        #: the highest time derivative of its outputs the FMU gives after a step (FMI's
        #: maxOutputDerivativeOrder; 0: none)
        cs = self.md.coSimulation
        self.output_derivative_order = int(getattr(cs, "maxOutputDerivativeOrder", 0) or 0) \
            if cs is not None else 0
        self._start_values = dict(start_values or {})
        inputs = {v.name for v in self.md.modelVariables if v.causality == "input"}
        #: True when an output may depend directly on an input (no dependencies declared
        #: counts as "all"): its outputs at t_k+1 then need the inputs at t_k+1.
        self.feedthrough = any(o.dependencies is None or
                               any(d.name in inputs for d in o.dependencies)
                               for o in self.md.outputs)

    # ------------------------------------------------------------------ plumbing
    #: the FMI interface this class instantiates (``fmi2CoSimulation``; a subclass may take the
    #: FMU's Model Exchange interface instead)
    interface = "co-simulation"

    def _interface_description(self):
        """The modelDescription's element of :attr:`interface` (a ValueError if the FMU lacks
        it)."""
        found = self.md.coSimulation if self.interface == "co-simulation" else \
            self.md.modelExchange
        if found is None:
            raise ValueError(f"{self.name}: {self.path} has no {self.interface} interface")
        return found

    def _fmu_class(self):
        if self.fmi3:
            from fmpy.fmi3 import FMU3Slave
            return FMU3Slave
        return FMU2Slave

    def _instantiate(self):
        from fmpy.fmi2 import (
            calloc,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            free,
        )

        def logger(component, instance, status, category, message):
            if status >= 0:
                text = message.decode(errors="replace") if message else ""
                self.messages.append(f"[{_STATUS[status] if status < 6 else status}] {text}")

        if self.fmi3:
            def log3(env, status, category, message):
                logger(env, None, status, category, message)
            try:
                self.fmu.instantiate(visible=False, loggingOn=True, logMessage=log3)
            except Exception as exc:
                log = "; ".join(self.messages[-3:]) or "no log message"
                raise CoSimulationError(f"{self.name}: instantiate failed: {exc}: {log}") from None
            return

        self._logger = fmi2CallbackLoggerTYPE(logger)
        cb = fmi2CallbackFunctions()
        cb.logger = self._logger
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb
        try:
            self.fmu.instantiate(visible=False, callbacks=cb, loggingOn=True)
        except Exception as exc:
            log = "; ".join(self.messages[-3:]) or "no log message"
            raise CoSimulationError(f"{self.name}: instantiate failed: {exc}: {log}") from None

    def _call(self, what: str, fun, *args, t=None):
        """Run one FMI call; a status above warning becomes :class:`CoSimulationError`."""
        try:
            return fun(*args)
        except FMICallException as exc:
            self._raise(what, exc.status, t)

    def _raise(self, what, status, t):
        raise self.error(what, status, t) from None

    def error(self, what: str, status: int, t=None) -> CoSimulationError:
        """The :class:`CoSimulationError` of the call ``what`` (at time ``t``) that returned the
        FMI status ``status``: it names this FMU, the call, the status and the FMU's log."""
        log = "; ".join(self.messages[-3:]) or "no log message"
        at = f" at t = {t:.6g}" if t is not None else ""
        return CoSimulationError(f"{self.name}: {what}{at} returned {_STATUS[status]}: {log}",
                                 status=status, time=t)

    def raw_functions(self) -> dict:
        """The FMI functions as fmpy loaded them (name -> ctypes function), for callers that
        call the FMU directly (the compiled loop); empty when fmpy wraps the calls (a call
        logger is set)."""
        if self.fmu is None or getattr(self.fmu, "fmiCallLogger", None) is not None:
            return {}
        return dict(getattr(self.fmu, "_functions", {}))

    def instance(self) -> int:
        """The FMU instance's address (``fmi2Component``)."""
        c = self.fmu.component
        return c.value if hasattr(c, "value") else c

    def vr(self, name: str) -> int:
        try:
            return self.variables[name].valueReference
        except KeyError:
            raise ValueError(f"{self.name} has no variable {name!r}; it has: "
                             f"{', '.join(self.variables)}") from None

    def _set_start(self, name, value):
        v = self.variables.get(name)
        if v is None:
            raise ValueError(f"{self.name} has no parameter {name!r}; it has: "
                             f"{', '.join(n for n, x in self.variables.items() if x.causality == 'parameter')}")
        vr = [v.valueReference]
        if self.fmi3:
            setter = {"Float64": self.fmu.setFloat64, "Int32": self.fmu.setInt32,
                      "Boolean": self.fmu.setBoolean, "String": self.fmu.setString}[v.type]
            conv = {"Float64": float, "Int32": int, "Boolean": bool, "String": str}[v.type]
            self._call(f"set{v.type}({name})", setter, vr, [conv(value)])
            return
        if v.type == "Real":
            self._call(f"setReal({name})", self.fmu.setReal, vr, [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            self._call(f"setInteger({name})", self.fmu.setInteger, vr, [int(value)])
        elif v.type == "Boolean":
            self._call(f"setBoolean({name})", self.fmu.setBoolean, vr, [bool(value)])
        elif v.type == "String":
            self._call(f"setString({name})", self.fmu.setString, vr, [str(value)])

    def _set_starts_fmi2(self):
        """The start values of an FMI 2.0 FMU, one call per type (each type's values in the
        order given). A call the FMU refuses is taken again one value at a time, so that the
        error names the variable (:meth:`_set_start`), as it would have been set alone."""
        groups = {}
        for name, value in self._start_values.items():
            v = self.variables.get(name)
            if v is None or v.type not in _FMI2_SETTERS:
                self._set_start(name, value)          # its own error
                continue
            groups.setdefault(v.type, []).append((name, v.valueReference, value))
        for type_, items in groups.items():
            method, conv = _FMI2_SETTERS[type_]
            try:
                getattr(self.fmu, method)([vr for _, vr, _ in items],
                                          [conv(value) for _, _, value in items])
            except FMICallException:
                for name, _, value in items:
                    self._set_start(name, value)

    def initialize(self, t0: float, stop_time: float | None = None):
        if self.fmi3:
            for name, value in self._start_values.items():
                self._set_start(name, value)
            self._call("enterInitializationMode", self.fmu.enterInitializationMode, None, t0,
                       stop_time)
            self._call("exitInitializationMode", self.fmu.exitInitializationMode)
            return
        self._call("setupExperiment", self.fmu.setupExperiment, None, t0, stop_time)
        self._set_starts_fmi2()
        self._call("enterInitializationMode", self.fmu.enterInitializationMode)
        self._call("exitInitializationMode", self.fmu.exitInitializationMode)

    def reset(self, start_values: dict | None = None):
        """Back to the state after instantiation (``fmi2Reset``/``fmi3Reset``), with new start
        values for the next :meth:`initialize` and an empty log: the instance and its loaded
        library serve another run (:class:`~orchestration.cosim.pool.SlavePool`). Only as good as
        the FMU's reset: a pool reuses only FMUs whose reset is known to be complete."""
        self._call("reset", self.fmu.reset)
        self.messages.clear()
        self._start_values = dict(start_values or {})
        self.sampled = _samples(self._start_values)

    def bind(self, inputs, outputs, record=(), derivative_orders: int = 0,
             output_derivative_orders: int = 0):
        """Preallocate the buffers of the real inputs and outputs exchanged every step, and of
        the outputs only recorded at output points. The hot calls go straight to the FMU's
        ctypes functions (as loaded by fmpy), without fmpy's per-call wrapper; their status is
        checked here. ``derivative_orders`` (1 or 2, on an FMU that interpolates inputs): the
        inputs' time derivatives follow their values in :meth:`set_inputs` and go to
        ``fmi2SetRealInputDerivatives``. ``output_derivative_orders`` (``q``, at most the FMU's
        :attr:`output_derivative_order`): :meth:`get_outputs` returns the outputs followed by
        their first ``q`` time derivatives (``fmi2GetRealOutputDerivatives``)."""
        def buffers(names):
            vr = (fmi2ValueReference * len(names))(*[self.vr(n) for n in names])
            val = (fmi2Real * len(names))()
            return vr, val, len(names), np.ctypeslib.as_array(val) if names else np.zeros(0)

        inputs = list(inputs)
        self._in_vr, self._in_val, self._n_in, self._in_np = buffers(inputs)
        self._out_vr, self._out_val, self._n_out, self._out_np = buffers(list(outputs))
        self._rec_vr, self._rec_val, self._n_rec, self._rec_np = buffers(list(record))
        nd = len(inputs) * derivative_orders
        self._n_der = nd
        self._der_vr = (fmi2ValueReference * nd)(*[self.vr(n) for n in inputs] * derivative_orders)
        self._der_order = (fmi2Integer * nd)(*[k for k in range(1, derivative_orders + 1)
                                               for _ in inputs])
        self._der_val = (fmi2Real * nd)()
        self._der_np = np.ctypeslib.as_array(self._der_val) if nd else np.zeros(0)
        q = output_derivative_orders
        if q > self.output_derivative_order:
            raise ValueError(f"{self.name}: {q} output derivative orders asked for; the FMU "
                             f"gives {self.output_derivative_order}")
        no = self._n_out * q
        self._n_oder = no
        self._oder_vr = (fmi2ValueReference * no)(*list(self._out_vr) * q)
        self._oder_order = (fmi2Integer * no)(*[k for k in range(1, q + 1)
                                                for _ in range(self._n_out)])
        self._oder_val = (fmi2Real * no)()
        self._oder_np = np.ctypeslib.as_array(self._oder_val) if no else np.zeros(0)
        if no:
            f, c = self.fmu, self.fmu.component
            if self.fmi3:
                self._get_oder_raw = lambda: f.fmi3GetOutputDerivatives(
                    c, self._oder_vr, no, self._oder_order, self._oder_val, no)
            else:
                get = getattr(f, "_functions", {}).get("fmi2GetRealOutputDerivatives") \
                    if getattr(f, "fmiCallLogger", None) is None else None
                get = get or f.fmi2GetRealOutputDerivatives
                self._get_oder_raw = lambda: get(c, self._oder_vr, no, self._oder_order,
                                                 self._oder_val)
        if self.fmi3:
            self._bind_fmi3()
            return
        fun = getattr(self.fmu, "_functions", {})
        c = self.fmu.component
        if nd:
            set_der = fun.get("fmi2SetRealInputDerivatives") or self.fmu.fmi2SetRealInputDerivatives
            self._set_derivatives_raw = lambda: set_der(c, self._der_vr, nd, self._der_order,
                                                        self._der_val)
        raw = {name: fun.get(f"fmi2{name}") for name in ("SetReal", "GetReal", "DoStep")}
        if all(raw.values()) and getattr(self.fmu, "fmiCallLogger", None) is None:
            set_real, get_real, do_step = raw["SetReal"], raw["GetReal"], raw["DoStep"]
            self._set_inputs_raw = lambda n: set_real(c, self._in_vr, n, self._in_val)
            self._get_outputs_raw = lambda: get_real(c, self._out_vr, self._n_out, self._out_val)
            self._get_record_raw = lambda: get_real(c, self._rec_vr, self._n_rec, self._rec_val)
            self._do_step_raw = lambda t, h: do_step(c, t, h, fmi2True)
        else:                                    # fmpy's checked wrappers (they raise)
            f = self.fmu
            self._set_inputs_raw = lambda n: f.fmi2SetReal(c, self._in_vr, n, self._in_val)
            self._get_outputs_raw = lambda: f.fmi2GetReal(c, self._out_vr, self._n_out,
                                                          self._out_val)
            self._get_record_raw = lambda: f.fmi2GetReal(c, self._rec_vr, self._n_rec,
                                                         self._rec_val)
            self._do_step_raw = lambda t, h: f.fmi2DoStep(c, t, h, fmi2True)

    def _bind_fmi3(self):
        """The hot calls of an FMI 3.0 FMU (fmi3SetFloat64, fmi3GetFloat64, fmi3DoStep)."""
        import ctypes

        from fmpy.fmi3 import fmi3Boolean, fmi3Float64

        f, c = self.fmu, self.fmu.component
        self._evt, self._term, self._early = fmi3Boolean(), fmi3Boolean(), fmi3Boolean()
        self._last = fmi3Float64()
        flags = (ctypes.byref(self._evt), ctypes.byref(self._term), ctypes.byref(self._early),
                 ctypes.byref(self._last))
        self._set_inputs_raw = lambda n: f.fmi3SetFloat64(c, self._in_vr, n, self._in_val, n)
        self._get_outputs_raw = lambda: f.fmi3GetFloat64(c, self._out_vr, self._n_out,
                                                         self._out_val, self._n_out)
        self._get_record_raw = lambda: f.fmi3GetFloat64(c, self._rec_vr, self._n_rec,
                                                        self._rec_val, self._n_rec)
        self._do_step_raw = lambda t, h: f.fmi3DoStep(c, t, h, fmi3Boolean(False), *flags)

    def _checked(self, what, fun, *args, t=None):
        try:
            status = fun(*args)
        except FMICallException as exc:
            status = exc.status
        if status is not None and status > 1:
            self._raise(what, status, t)

    def set_inputs(self, values, t=None, n=None):
        """Set the bound inputs to ``values`` (a sequence in the order of :meth:`bind`: the
        values, then, on an FMU bound with ``derivative_orders``, their time derivatives), or
        only the first ``n`` entries."""
        n_in = self._n_in
        n = n_in + self._n_der if n is None else n
        m = min(n, n_in)
        if m:
            self._in_np[:m] = values[:m]
            self._checked("setReal", self._set_inputs_raw, m, t=t)
        if n > n_in and self._n_der:
            self._der_np[:] = values[n_in:n_in + self._n_der]
            self._checked("setRealInputDerivatives", self._set_derivatives_raw, t=t)

    def get_outputs(self, t=None) -> np.ndarray:
        """The bound outputs (a new array), followed by their time derivatives when bound with
        ``output_derivative_orders``."""
        if self._n_out:
            self._checked("getReal", self._get_outputs_raw, t=t)
        if self._n_oder:
            self._checked("getRealOutputDerivatives", self._get_oder_raw, t=t)
            return np.concatenate((self._out_np, self._oder_np))
        return self._out_np.copy()

    def get_recorded(self, t=None) -> np.ndarray:
        """The outputs bound as recorded only (a view, overwritten by the next call)."""
        if self._n_rec:
            self._checked("getReal", self._get_record_raw, t=t)
        return self._rec_np

    def do_step(self, t: float, h: float):
        self._checked("doStep", self._do_step_raw, t, h, t=t)

    def get_state(self):
        if self.fmi3:
            return self._call("getFMUState", self.fmu.getFMUState)
        return self._call("getFMUstate", self.fmu.getFMUstate)

    def set_state(self, state):
        if self.fmi3:
            self._call("setFMUState", self.fmu.setFMUState, state)
        else:
            self._call("setFMUstate", self.fmu.setFMUstate, state)

    def free_state(self, state):
        if self.fmi3:
            self._call("freeFMUState", self.fmu.freeFMUState, state)
        else:
            self._call("freeFMUstate", self.fmu.freeFMUstate, state)

    def close(self):
        """``terminate`` and ``freeInstance``, then remove the folder the FMU was extracted to
        (when this slave extracted it); safe to call twice and after a failure. The library is
        unloaded once (fmpy's ``freeInstance`` does it): the instances of one folder share one
        loaded library, counted by the dynamic loader, and a second ``dlclose`` would unload it
        under another instance (a pooled one: :mod:`orchestration.cosim.pool`)."""
        if self.fmu is None:
            self._remove_unzipdir()
            return
        fmu, self.fmu = self.fmu, None
        try:
            fmu.terminate()
        except Exception:  # noqa: BLE001 - an FMU in error may refuse terminate; still free it
            pass
        try:
            fmu.freeInstance()          # fmpy's: fmi2FreeInstance, then freeLibrary (dlclose)
        finally:
            self._remove_unzipdir()

    def _remove_unzipdir(self):
        if getattr(self, "_own_unzipdir", False) and self._unzipdir:
            import shutil
            shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._unzipdir = None

