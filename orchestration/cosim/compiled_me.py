"""The model-exchange master's integration loop in C (``orchestration/cosim/native/fm_me.c``),
bound with ctypes.

:class:`~orchestration.cosim.model_exchange.ModelExchangeMaster` runs it instead of scipy's
solver when every FMU can take it (:func:`unavailable` says why not) and the key
``master.compiled`` allows it (``"auto"``, ``true``, ``false``, as for the co-simulation).

The integrator. A self-contained C integrator, not SUNDIALS: the kernels are compiled with plain
gcc at ``pip install``, and CVODE/IDA would need Debian's ``libsundials-dev`` on every machine
(and a fallback where it is absent). The C loop is scipy's ``Radau`` (Radau IIA of order 5,
Hairer and Wanner's RADAU5 logic as scipy writes it) ported step for step: the same initial
step, simplified Newton iteration on the transformed collocation system with the exact
Jacobian, error estimate, step-size control, Jacobian and LU reuse, and collocation dense
output. So the compiled master takes the Python master's steps, and its results agree with
``master.solver = "radau"`` in Python to rounding (the LU and the norms are summed in another
order than LAPACK's): ``tests/cosim/test_compiled_me.py`` holds the two together.
``master.solver = "bdf"`` keeps scipy's loop.

What stays in Python: instantiation, initialisation and the first output row; the rows' array
(the C loop writes into it); event mode (``ModelExchangeMaster._event``: the C loop locates an
indicator's sign change by scipy's Brent method on its dense output, stores the rows up to it
and returns; Python runs event mode and restarts the C integrator there, as the Python master
restarts scipy's solver), and so the plant's request to terminate past ``phi_limit``, with its
message; raising :class:`CoSimulationError` with the FMU's log, and :class:`RunInterrupted`.
The loop returns to Python every :data:`CHUNK_STEPS` steps for progress and the ``stop``
callback (the Python master asks it after every step).
"""
from __future__ import annotations

import ctypes

import numpy as np

from fmu_common import kernels

from .slave import CoSimulationError

__all__ = ["unavailable", "choose", "load", "CompiledME", "KERNEL"]

KERNEL = "flexpend_me"

# results of fme_run (fm_me.h)
(_DONE, _FAILED, _CHUNK, _BADARG, _EVENT, _STEP_EVENT, _TERMINATE, _TOO_SMALL,
 _FINISHED) = range(9)
_CALLS = {1: "setTime", 2: "setContinuousStates", 3: "setReal", 4: "getReal",
          5: "getDerivatives", 6: "getEventIndicators", 7: "getDirectionalDerivative",
          8: "completedIntegratorStep"}
#: steps between two returns to Python (progress, the stop callback, signal handlers)
CHUNK_STEPS = 64
#: the FMI 2.0 functions the loop calls (fme_unit's function pointers, in order)
_FUNCTIONS = ("fmi2SetTime", "fmi2SetContinuousStates", "fmi2GetDerivatives",
              "fmi2GetEventIndicators", "fmi2SetReal", "fmi2GetReal",
              "fmi2GetDirectionalDerivative", "fmi2CompletedIntegratorStep")

_P = ctypes.c_void_p
_I = ctypes.c_int
_D = ctypes.c_double
_LL = ctypes.c_longlong


class _Unit(ctypes.Structure):
    _fields_ = [("c", _P), *[(f, _P) for f in ("set_time", "set_x", "get_dx", "get_z",
                                               "set_real", "get_real", "dd", "completed")],
                *[(f, _I) for f in ("nx", "nz", "n_out", "n_in", "n_early", "n_late", "n_rec",
                                    "pad_")],
                *[(f, _P) for f in ("state_vr", "der_vr", "out_vr", "in_vr", "early_vr",
                                    "early_pos", "late_vr", "late_pos", "rec_vr", "rec_val")]]


class _Master(ctypes.Structure):
    _fields_ = [*[(f, _I) for f in ("n_units", "nx", "ny", "nu", "nz", "pad_")],
                ("units", _P), ("order", _P), ("src_pos", _P), ("rtol", _D), ("atol", _P),
                ("max_step", _D), ("t_bound", _D), ("t0", _D), ("interval", _D),
                ("n_out", _LL), ("rows", _LL), ("n_cols", _I), ("pad2_", _I),
                ("col_unit", _P), ("col_index", _P), ("out", _P), ("work", _P), ("iwork", _P),
                ("y", ctypes.POINTER(_D)), ("t", _D), ("t_event", _D),
                ("z_event", ctypes.POINTER(_D)), ("steps", _LL), ("evaluations", _LL),
                ("jacobians", _LL), ("min_step_used", _D), ("max_step_used", _D),
                ("fail_unit", _I), ("fail_call", _I), ("fail_status", _I), ("pad3_", _I),
                ("fail_time", _D),
                *[(f, _D) for f in ("t_old", "h_abs", "h_abs_old", "error_norm_old",
                                    "newton_tol")],
                *[(f, _I) for f in ("has_h_old", "has_err_old", "current_jac", "lu_valid",
                                    "has_sol", "laid_out")],
                ("pt_t", _D), ("pt_valid", _I), ("pad4_", _I)]


_lib = None


def load():
    """The compiled loop's library (built at install; rebuilt when stale in a checkout), checked
    against the structs above. Raises :class:`fmu_common.kernels.KernelError`."""
    global _lib
    if _lib is None:
        lib = kernels.load(KERNEL, kernels.native_dir(KERNEL))
        for name, struct in (("fme_sizeof_unit", _Unit), ("fme_sizeof_master", _Master)):
            fn = getattr(lib, name)
            fn.restype = ctypes.c_size_t
            if fn() != ctypes.sizeof(struct):
                raise kernels.KernelError(f"{KERNEL}: {name}() = {fn()}, the binding's struct "
                                          f"has {ctypes.sizeof(struct)} bytes: rebuild it")
        pm = ctypes.POINTER(_Master)
        for name in ("fme_work_doubles", "fme_work_ints"):
            getattr(lib, name).argtypes = [pm]
            getattr(lib, name).restype = ctypes.c_size_t
        for name in ("fme_start", "fme_restart"):
            getattr(lib, name).argtypes = [pm, _D, _P]
            getattr(lib, name).restype = _I
        lib.fme_run.argtypes = [pm, _LL]
        lib.fme_run.restype = _I
        _lib = lib
    return _lib


def unavailable(units: dict, solver: str) -> str | None:
    """Why the compiled loop cannot integrate ``units`` (name ->
    :class:`~orchestration.cosim.model_exchange.ModelExchangeUnit`) with ``solver``, or None
    when it can: Radau, FMI 2.0 FMUs that need no execution tool, with states, called through
    fmpy's raw functions."""
    if solver != "radau":
        return f"master.solver = {solver!r} runs scipy's solver in Python (the compiled " \
               "loop is Radau)"
    if not any(u.nx for u in units.values()):
        return "the FMUs have no continuous states"
    for name, u in units.items():
        if u.fmi3:
            return f"{name} is an FMI 3.0 FMU"
        me = u.md.modelExchange
        if me is None or me.needsExecutionTool:
            return f"{name} needs an execution tool"
        fun = u.raw_functions()
        if not fun:
            return f"{name} is not called through fmpy's raw FMI functions (a call logger is set)"
        missing = [f for f in _FUNCTIONS if fun.get(f) is None]
        if missing:
            return f"{name} lacks {', '.join(missing)}"
    return None


def _address(fun) -> int | None:
    return ctypes.cast(fun, _P).value if fun is not None else None


class CompiledME:
    """The C integration loop over the units of ``master`` (a
    :class:`~orchestration.cosim.model_exchange.ModelExchangeMaster` whose units are initialised),
    writing the rows of ``out`` from row 1 (row 0 stored). ``atol``: the absolute tolerance of
    each state."""

    def __init__(self, master, out: np.ndarray, t0: float, stop_time: float,
                 output_interval: float, atol: np.ndarray):
        self.lib = lib = load()
        self.master = master
        names = list(master.units)
        index = {n: i for i, n in enumerate(names)}
        keep = self._keep = []                   # every buffer the structs point to

        def buf(values, ctype=ctypes.c_int):
            values = list(values)
            a = (ctype * max(1, len(values)))(*values)
            keep.append(a)
            return ctypes.addressof(a)

        src_pos = master.S.argmax(axis=1)        # the output (in y) each input reads
        self.units = (_Unit * len(names))()
        for i, n in enumerate(names):
            u, c = master.units[n], self.units[i]
            fun = u.raw_functions()
            c.c = u.instance()
            (c.set_time, c.set_x, c.get_dx, c.get_z, c.set_real, c.get_real, c.dd,
             c.completed) = [_address(fun.get(f)) for f in _FUNCTIONS]
            early, late = master._early[n], master._late[n]
            c.nx, c.nz = u.nx, u.nz
            c.n_out, c.n_in = len(master.out_vrs[n]), len(master.in_vrs[n])
            c.n_early, c.n_late, c.n_rec = len(early), len(late), len(master.rec_vrs[n])
            uint = ctypes.c_uint
            c.state_vr, c.der_vr = buf(u.state_vrs, uint), buf(u.der_vrs, uint)
            c.out_vr, c.in_vr = buf(master.out_vrs[n], uint), buf(master.in_vrs[n], uint)
            su = master.su[n].start
            c.early_vr = buf([master.in_vrs[n][k] for k in early], uint)
            c.early_pos = buf([src_pos[su + k] for k in early])
            c.late_vr = buf([master.in_vrs[n][k] for k in late], uint)
            c.late_pos = buf([src_pos[su + k] for k in late])
            c.rec_vr = buf(master.rec_vrs[n], uint)
            c.rec_val = buf([0.0] * c.n_rec, ctypes.c_double)
        cols = list(master.record.values())
        self.rows = out.view(np.float64).reshape(len(out), 1 + len(cols))
        self.atol = np.ascontiguousarray(atol, dtype=float)
        st = self.struct = _Master()
        st.n_units, st.nx, st.ny, st.nu = len(names), master.nx, master.ny, master.nu
        st.nz = sum(u.nz for u in master.units.values())
        st.units = ctypes.addressof(self.units)
        st.order = buf([index[n] for n in master.order])
        st.src_pos = buf(src_pos.tolist())
        st.rtol, st.atol = master.settings.rtol, self.atol.ctypes.data
        st.max_step, st.t_bound = master.settings.max_step, stop_time
        st.t0, st.interval = t0, output_interval
        st.n_out, st.rows = len(out) - 1, 1
        st.n_cols = len(cols)
        st.col_unit = buf([index[s] for s, _v in cols])
        st.col_index = buf([master.recorded[s].index(v) for s, v in cols])
        st.out = self.rows.ctypes.data
        self.work = np.zeros(lib.fme_work_doubles(ctypes.byref(st)))
        self.iwork = np.zeros(lib.fme_work_ints(ctypes.byref(st)), dtype=np.intc)
        st.work, st.iwork = self.work.ctypes.data, self.iwork.ctypes.data

    @property
    def rows_written(self) -> int:
        return int(self.struct.rows)

    @property
    def t(self) -> float:
        """The integrator's time."""
        return float(self.struct.t)

    def _checked(self, rc: int):
        """Raise the error of a failed call (or return ``rc``)."""
        st, units = self.struct, list(self.master.units.values())
        if rc == _FAILED:
            raise units[st.fail_unit].error(_CALLS[st.fail_call], st.fail_status, st.fail_time)
        if rc == _TERMINATE:
            raise units[st.fail_unit].stopped("completedIntegratorStep asked to terminate",
                                              st.fail_time)
        if rc == _TOO_SMALL:
            raise CoSimulationError(f"the radau solver failed at t = {st.t:.6g}: Required step "
                                    "size is less than spacing between numbers.", status=3,
                                    time=st.t)
        if rc == _FINISHED:
            raise CoSimulationError(f"the solver finished at t = {st.t:.9g} before the last "
                                    "output point", status=3, time=st.t)
        if rc == _BADARG:
            raise CoSimulationError("the compiled model-exchange master refused its arguments; "
                                    "master.compiled = false runs scipy's solver")
        return rc

    def start(self, t0: float, z: np.ndarray):
        z = np.ascontiguousarray(z, dtype=float)
        self._checked(self.lib.fme_start(ctypes.byref(self.struct), t0, z.ctypes.data))

    def run(self, stats, progress=None, stop=None):
        """Integrate to the last output point: event mode through the master's ``_event``."""
        from .slave import RunInterrupted

        st, n_out = self.struct, len(self.rows) - 1
        try:
            while True:
                rc = self._checked(self.lib.fme_run(ctypes.byref(st), CHUNK_STEPS))
                self._account(stats)
                if progress is not None and st.rows > 1:
                    progress((st.rows - 1) / n_out)
                if rc == _DONE:
                    return
                if rc == _EVENT:
                    t, z = st.t_event, np.ctypeslib.as_array(st.z_event, (st.nx,)).copy()
                    self.master._event(t, z)
                    self._checked(self.lib.fme_restart(ctypes.byref(st), t, z.ctypes.data))
                elif rc == _STEP_EVENT:
                    self.master._event(st.t, np.ctypeslib.as_array(st.y, (st.nx,)).copy())
                if stop is not None and stop():
                    raise RunInterrupted(st.t)
        finally:
            self._account(stats)

    def _account(self, stats):
        st = self.struct
        stats.steps = int(st.steps)
        stats.min_step_used, stats.max_step_used = st.min_step_used, st.max_step_used
        self.master.evaluations, self.master.jacobians = int(st.evaluations), int(st.jacobians)


def choose(units: dict, settings) -> tuple[str | None, str]:
    """``(why the compiled loop cannot run, the loop to run)`` for ``settings.compiled``:
    ``"auto"`` the compiled loop where it can run (a warning when its library does not load),
    ``False`` the Python loop, ``True`` the compiled loop or a ValueError saying why not."""
    import warnings

    compiled = settings.compiled
    why = unavailable(units, settings.solver)
    if compiled and why is None:
        try:
            load()                           # before any run
        except kernels.KernelError as exc:   # missing or stale library of a broken install
            why = f"the compiled loop's library does not load: {exc}"
            if compiled == "auto":
                warnings.warn(f"{why}; scipy's solver runs", RuntimeWarning, stacklevel=3)
    if compiled is True and why is not None:
        raise ValueError(f"master.compiled = True, but {why}")
    return why, "compiled" if compiled and why is None else "python"
