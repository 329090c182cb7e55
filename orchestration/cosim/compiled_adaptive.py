"""The master's adaptive and implicit loops in C (``orchestration/cosim/native/fm_adaptive.c``),
bound with ctypes.

:class:`~orchestration.cosim.master.Master` runs it instead of :meth:`~orchestration.cosim.
master.Master._run_adaptive` (the readable specification) when every FMU can take it
(:func:`unavailable` says why not) and the key ``master.compiled`` allows it: the step control,
the rollback through the FMU states and both error estimators (``extrapolation`` and ``energy``)
run in C, making the FMI calls the Python loop makes, in the same order, with the same
arguments. As :mod:`orchestration.cosim.compiled` does, it receives the FMUs' instance pointers
and the FMI functions fmpy loaded; what stays in Python is the same (instantiation, the initial
outputs and the first row, raising the errors, the ``stop`` callback through ctypes).

The results agree with the Python loop's to a few units in the last place, not bit for bit: on
the adaptive grid the extrapolation weights solve a small Vandermonde system, which numpy hands
to LAPACK (OpenBLAS, whose operation order and fused multiply-adds depend on the CPU) and the C
loop solves by its own elimination; everything else is the same arithmetic in the same order.
``tests/cosim/test_compiled_adaptive.py`` holds the two together (rows, steps, rejections).

The implicit master (:class:`ImplicitRun`, ``master.algorithm = "implicit"``, stepped in Python
by :class:`~orchestration.cosim.implicit.InterfaceIteration`) runs in C the same way: the step
counters' grid with the Python master's own weights, Newton's difference Jacobian through the
FMU states, IQN-ILS with its reused columns. Its linear algebra is the C loop's own (Newton's
``(J - I) x = r`` by elimination with partial pivoting, IQN-ILS's least squares by a Jacobi SVD
with numpy's cut-off), so it too agrees to rounding, not bit for bit.
"""
from __future__ import annotations

import ctypes
import time

import numpy as np

from fmu_common import kernels

from .compiled import _CALLS, _address, _ints
from .compiled import _FUNCTIONS as _ALL_FUNCTIONS
from .compiled import unavailable as _fixed_unavailable
from .coupling import weight_table
from .implicit import REUSED_STEPS
from .slave import CoSimulationError, RunInterrupted

__all__ = ["unavailable", "load", "AdaptiveRun", "ImplicitRun", "KERNEL"]

KERNEL = "flexpend_adaptive"

# results of fa_run and fa_run_implicit, and why an implicit step failed (fm_adaptive.h)
_DONE, _FAILED, _STOPPED, _BADARG, _DISCARDED, _FULL, _DIVERGED = range(7)
_NOT_CONVERGED, _NOT_FINITE, _SINGULAR = 1, 2, 3
#: wall time between two returns to Python (progress, signal handlers)
CHUNK_SECONDS = 0.02
#: rejected steps' times collected in C between two returns to Python
_REJECTED_CAPACITY = 1024
_SLOTS = 4

_P = ctypes.c_void_p
_D = ctypes.c_double
_I = ctypes.c_int
_LL = ctypes.c_longlong


class _Slave(ctypes.Structure):
    _fields_ = [("c", _P), ("set_real", _P), ("get_real", _P), ("do_step", _P), ("set_der", _P),
                ("get_state", _P), ("set_state", _P), ("free_state", _P),
                ("n_in", _I), ("n_der", _I), ("n_out", _I), ("n_rec", _I),
                ("feedthrough", _I), ("mark", _I), ("at_start", _I), ("unknown", _I),
                ("in_vr", _P), ("in_src", _P), ("in_idx", _P), ("der_vr", _P),
                ("der_order", _P), ("out_vr", _P), ("rec_vr", _P),
                ("in_val", _P), ("der_val", _P), ("new_val", _P), ("rec_val", _P),
                ("saved", _P), ("hist", _P), ("snap", _P), ("peak", _P), ("peak_saved", _P),
                ("t", _D * _SLOTS), ("snap_t", _D * _SLOTS), ("count", _I), ("snap_count", _I),
                ("state", _P), ("rb_state", _P)]


class _Master(ctypes.Structure):
    _fields_ = [("n_slaves", _I), ("gauss_seidel", _I), ("p", _I), ("correct_startup", _I),
                ("rollback", _I), ("n_sources", _I), ("slaves", _P), ("order", _P),
                ("sources", _P), ("t0", _D), ("h", _D), ("dt_out", _D), ("tol", _D),
                ("min_step", _D), ("max_step", _D), ("n_out", _LL),
                ("f_slave", _I), ("f_idx", _I), ("x_slave", _I), ("x_idx", _I), ("f_pred", _I),
                ("n_cols", _I), ("col_slave", _P), ("col_rec", _P), ("col_index", _P),
                ("out", _P), ("go_on", _P), ("rejected_times", _P), ("rej_cap", _LL),
                ("n_rej", _LL), ("j", _LL), ("t", _D), ("step", _D), ("err_prev", _D),
                ("work", _D), ("steps", _LL), ("rejected", _LL), ("forced", _LL),
                ("min_used", _D), ("max_used", _D), ("rows", _LL),
                ("counters", _I), ("newton", _I), ("serial", _I), ("weights", _P), ("total", _LL),
                ("m_out", _LL), ("k", _LL), ("max_it", _I), ("size", _I), ("itol", _D),
                ("consumer", _P), ("u", _P), ("g", _P), ("r", _P), ("up", _P), ("col", _P),
                ("x", _P), ("lu", _P), ("lg", _P), ("jac", _P), ("a", _P), ("have_jac", _I), ("n_reuse", _I),
                ("reuse_cols", _I * REUSED_STEPS), ("max_cols", _I), ("cv", _P), ("cw", _P),
                ("svd_m", _P), ("svd_v", _P), ("alpha", _P), ("iterations", _LL),
                ("max_iterations", _I), ("fail_kind", _I), ("jacobian_steps", _LL),
                ("fail_residual", _D), ("fail_iterations", _I), ("pad_", _I),
                ("fail_slave", _I), ("fail_call", _I), ("fail_status", _I), ("fail_timed", _I),
                ("fail_time", _D), ("pow_arg", _D), ("pow1", _D), ("pow2", _D)]


_GO_ON = ctypes.CFUNCTYPE(ctypes.c_int)
_lib = None


def load():
    """The adaptive loop's library (built at install; rebuilt when stale in a checkout), checked
    against the structs above. Raises :class:`fmu_common.kernels.KernelError`."""
    global _lib
    if _lib is None:
        lib = kernels.load(KERNEL, kernels.native_dir(KERNEL))
        for name, struct in (("fa_sizeof_slave", _Slave), ("fa_sizeof_master", _Master)):
            fn = getattr(lib, name)
            fn.restype = ctypes.c_size_t
            if fn() != ctypes.sizeof(struct):
                raise kernels.KernelError(f"{KERNEL}: {name}() = {fn()}, the binding's struct "
                                          f"has {ctypes.sizeof(struct)} bytes: rebuild it")
        for fn in (lib.fa_run, lib.fa_run_implicit):
            fn.argtypes = [ctypes.POINTER(_Master), ctypes.c_longlong]
            fn.restype = ctypes.c_int
        lib.fa_round9.argtypes = [ctypes.c_double]
        lib.fa_round9.restype = ctypes.c_double
        lib.fa_weights.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_int, ctypes.c_int,
                                   ctypes.POINTER(ctypes.c_double)]
        lib.fa_weights.restype = ctypes.c_int
        _lib = lib
    return _lib


#: the FMI 2.0 functions this loop calls (fa_slave's function pointers, in order): the fixed-step
#: loop's but fmi2GetRealOutputDerivatives
_FUNCTIONS = _ALL_FUNCTIONS[:7]


def unavailable(coupling, slaves: dict) -> str | None:
    """Why the compiled adaptive or implicit loop cannot run ``coupling`` over ``slaves``, or
    None when it can: the FMUs the compiled fixed-step loop takes (:func:`orchestration.cosim.
    compiled.unavailable`), no sampled controller, and the FMU states that the rollback, the
    corrected first step and the implicit iteration restore."""
    why = _fixed_unavailable(coupling, slaves, False)
    if why:
        return why
    implicit = coupling.algorithm == "implicit"
    for name, s in slaves.items():
        if coupling.out_der[name]:
            return "the extrapolation from output derivatives runs in Python in the adaptive " \
                   "and implicit masters"
        if s.sampled:
            return f"{name} is a sampled controller (its adaptive or implicit step runs in " \
                   "Python)"
        fun = s.raw_functions()
        if (implicit or coupling.settings.error_estimator == "extrapolation"
                or coupling.correct_startup):
            missing = [f for f in _FUNCTIONS[4:] if fun.get(f) is None]
            if missing:
                return f"{name} lacks {', '.join(missing)}"
    return None


class _Run:
    """What the adaptive and the implicit runs share: the structs of ``master``'s slaves with
    their history after the initial outputs ``cur`` at ``t0`` (stamped ``stamp``), the rows of
    ``out``, the calls in chunks of about :data:`CHUNK_SECONDS` and the errors raised as in
    Python. :attr:`rows_written` and :attr:`t_reached` say how far it got, however it ended."""

    def __init__(self, master, cur: dict, t0: float, stamp: float, out: np.ndarray):
        lib = load()
        cp, slaves, st = master.coupling, master.slaves, master.settings
        self.lib, self.py_slaves = lib, slaves
        self.min_step = master.min_step
        self.rows_written, self.t_reached = 1, t0
        names = list(slaves)
        index = {n: i for i, n in enumerate(names)}
        keep = self._keep = []                   # every buffer the structs point to

        def buf(values, ctype=ctypes.c_int):
            a = _ints(list(values), ctype)
            keep.append(a)
            return ctypes.addressof(a)

        def work(n):
            a = np.zeros(max(1, n))
            keep.append(a)
            return a.ctypes.data

        self.slaves = (_Slave * len(names))()
        for i, n in enumerate(names):
            s, c = slaves[n], self.slaves[i]
            fun = s.raw_functions()
            c.c = s.instance()
            (c.set_real, c.get_real, c.do_step, c.set_der, c.get_state, c.set_state,
             c.free_state) = [_address(fun.get(f)) for f in _FUNCTIONS]
            ins, n_der = cp.inputs[n], cp.n_der[n]
            c.n_in, c.n_der = len(ins), n_der
            c.n_out, c.n_rec = len(cp.outputs[n]), len(cp.recorded[n])
            c.feedthrough = int(bool(s.feedthrough))
            c.in_vr = buf([s.vr(x.dst_var) for x in ins], ctypes.c_uint)
            c.in_src = buf([index[x.src] for x in ins])
            c.in_idx = buf([cp.out_index[x.src][x.src_var] for x in ins])
            c.der_vr = buf([s.vr(x.dst_var) for x in ins] * n_der, ctypes.c_uint)
            c.der_order = buf([k for k in range(1, n_der + 1) for _ in ins])
            c.out_vr = buf([s.vr(v) for v in cp.outputs[n]], ctypes.c_uint)
            c.rec_vr = buf([s.vr(v) for v in cp.recorded[n]], ctypes.c_uint)
            for field, size in (("in_val", c.n_in), ("der_val", c.n_in * n_der),
                                ("new_val", c.n_out), ("rec_val", c.n_rec), ("saved", c.n_out),
                                ("hist", _SLOTS * c.n_out), ("snap", _SLOTS * c.n_out),
                                ("peak", c.n_out), ("peak_saved", c.n_out)):
                setattr(c, field, work(size))
            # the history after the initial outputs: one sample at t0; the peaks its sizes
            u = np.asarray(cur[n], dtype=float)
            ctypes.memmove(c.hist, u.ctypes.data, 8 * c.n_out)
            peak = np.abs(u)
            ctypes.memmove(c.peak, peak.ctypes.data, 8 * c.n_out)
            c.t[0], c.count = stamp, 1
        cols = list(cp.record.items())
        col_slave = [index[s] for _, (s, _v) in cols]
        col_rec = [int(v not in cp.out_index[s]) for _, (s, v) in cols]
        col_index = [cp.recorded[s].index(v) if r else cp.out_index[s][v]
                     for (_, (s, v)), r in zip(cols, col_rec)]
        self.rows = out.view(np.float64).reshape(len(out), 1 + len(cols))
        self.rejected = np.zeros(_REJECTED_CAPACITY)
        self.struct = m = _Master()
        self.weights = weight_table()
        m.n_slaves, m.gauss_seidel = len(names), int(cp.algorithm == "gauss-seidel")
        m.p, m.correct_startup = cp.p, int(cp.correct_startup)
        m.rollback = int(st.error_estimator == "extrapolation" or cp.algorithm == "implicit")
        sources = list(dict.fromkeys(c.src for c in cp.connections))
        m.n_sources, m.sources = len(sources), buf([index[n] for n in sources])
        m.slaves = ctypes.addressof(self.slaves)
        m.order = buf([index[n] for n in cp.order])
        m.t0, m.h, m.tol = t0, master.h, master.tol
        m.min_step, m.max_step = master.min_step, master.max_step
        m.dt_out, m.n_out = master.h, 1           # the adaptive run's own: AdaptiveRun
        if not m.rollback:                        # the energy estimator's bond
            fsrc, fvar, xsrc, xvar = master.BOND
            m.f_slave, m.f_idx = index[fsrc], cp.out_index[fsrc][fvar]
            m.x_slave, m.x_idx = index[xsrc], cp.out_index[xsrc][xvar]
            m.f_pred = int(cp.algorithm == "jacobi" or cp.order[0] == xsrc)
        m.n_cols = len(cols)
        m.col_slave, m.col_rec, m.col_index = buf(col_slave), buf(col_rec), buf(col_index)
        m.out = self.rows.ctypes.data
        m.rejected_times, m.rej_cap, m.n_rej = self.rejected.ctypes.data, len(self.rejected), 0
        m.j, m.t, m.step, m.err_prev, m.work = 1, t0, min(master.h, master.max_step), 1.0, 0.0
        m.min_used, m.max_used, m.rows = np.inf, 0.0, 1

    def _go(self, stop):
        """The ``stop`` callback for C (kept alive by the caller), and the list of what it
        raised."""
        raised = []

        def go_on():
            try:
                return 0 if stop() else 1
            except BaseException as exc:  # noqa: BLE001 - re-raised below, out of C
                raised.append(exc)
                return 0
        return _GO_ON(go_on), raised

    def _raise(self, rc, raised):
        """Raise what the result ``rc`` of a call means, as the Python loop raises it."""
        m = self.struct
        if rc == _STOPPED:
            if raised:
                raise raised[0]
            raise RunInterrupted(self.t_reached)
        if rc == _FAILED:
            name = list(self.py_slaves)[m.fail_slave]
            t = m.fail_time if m.fail_timed else None
            raise self.py_slaves[name].error(_CALLS[m.fail_call], m.fail_status, t)
        if rc == _DISCARDED:
            raise CoSimulationError(f"an FMU discarded the step at t = {m.fail_time:.6g}"
                                    f" even at min_step = {self.min_step}", status=2,
                                    time=m.fail_time)
        raise CoSimulationError(f"the compiled master refused its arguments (fm_adaptive.c "
                                f"returned {rc}); master.compiled = false runs the Python loop")


class AdaptiveRun(_Run):
    """One adaptive run in C of ``master`` (a :class:`~orchestration.cosim.master.Master`) from
    the initial outputs ``cur`` at ``t0`` (row 0 of ``out`` written): ``n_out`` output points
    ``dt_out`` apart.

    ``run(stats, progress, stop)`` steps to the end; failures and interruptions raise as in the
    Python loop.
    """

    def __init__(self, master, cur: dict, t0: float, dt_out: float, n_out: int,
                 out: np.ndarray):
        super().__init__(master, cur, t0, t0, out)
        m = self.struct
        m.dt_out, m.n_out, self.n_out = dt_out, n_out, n_out

    def run(self, stats, progress=None, stop=None):
        """Step to the last output point, counting into ``stats`` (a :class:`~orchestration.
        cosim.master.RunStats`)."""
        m = self.struct
        raised = []
        if stop is not None:
            callback, raised = self._go(stop)
            m.go_on = ctypes.cast(callback, _P).value
        chunk = 1                                  # output points per call, tuned to the clock
        try:
            while m.j <= self.n_out:
                j0, w0 = m.j, time.perf_counter()
                rc = self.lib.fa_run(ctypes.byref(m), min(self.n_out, j0 + chunk - 1))
                elapsed = time.perf_counter() - w0
                self._account(stats)
                if rc == _FULL:
                    continue
                if rc == _DONE:
                    if progress is not None:
                        progress((m.j - 1) / self.n_out)
                    taken = m.j - j0
                    if elapsed > 0 and taken:
                        chunk = max(1, min(4 * chunk, int(taken * CHUNK_SECONDS / elapsed)))
                    continue
                self._raise(rc, raised)
        finally:
            m.go_on = None
        return stats

    def _account(self, stats):
        """Copy the counters of the C loop into ``stats``; drain the rejected steps' times."""
        m = self.struct
        stats.steps, stats.rejected, stats.forced_accepts = m.steps, m.rejected, m.forced
        stats.min_step_used, stats.max_step_used = m.min_used, m.max_used
        stats.rejected_times.extend(self.rejected[:m.n_rej].tolist())
        m.n_rej = 0
        self.rows_written = max(self.rows_written, int(m.rows))
        self.t_reached = m.t


class ImplicitRun(_Run):
    """One implicit run in C of ``master`` (``master.algorithm = "implicit"``; its
    :class:`~orchestration.cosim.implicit.InterfaceIteration` ``iteration`` receives the
    counts): ``total`` steps of ``master.h`` from ``t0`` with the history stamped with the step
    counters, a row every ``m`` steps into ``out`` (row 0 written).

    ``run(stats, progress, stop)`` steps to the end; failures (an FMI status, a step that does
    not converge) and interruptions raise as in the Python loop.
    """

    def __init__(self, master, iteration, cur: dict, t0: float, m_out: int, total: int,
                 out: np.ndarray):
        super().__init__(master, cur, t0, 0.0, out)
        m, cp, st = self.struct, master.coupling, master.settings
        self.iteration, self.t0, self.h, self.total = iteration, t0, master.h, total
        names = list(master.slaves)
        index = {n: i for i, n in enumerate(names)}
        m.counters, m.correct_startup = 1, 0
        m.newton = int(st.implicit_jacobian == "newton")
        m.serial = int(iteration.serial)
        for n, i in index.items():
            self.slaves[i].unknown = int(n in iteration.slices)
        m.weights = self.weights.ctypes.data
        m.total, m.m_out, m.k = total, m_out, 0
        m.max_it, m.itol, m.size = st.max_iterations, st.implicit_tolerance, iteration.size
        consumer = np.zeros((len(names), len(names)), dtype=np.intc)
        for src, dsts in iteration.consumers.items():
            for d in dsts:
                consumer[index[src], index[d]] = 1
        n, cols = max(1, iteration.size), (REUSED_STEPS + 1) * st.max_iterations
        self._arrays = arrays = {"consumer": consumer}
        for field, size in (("u", n), ("g", n), ("r", n), ("up", n), ("col", n), ("x", n),
                            ("lu", n), ("lg", n),
                            ("jac", n * n), ("a", n * n), ("cv", cols * n), ("cw", cols * n),
                            ("svd_m", cols * n), ("svd_v", n * n), ("alpha", cols)):
            arrays[field] = np.zeros(size)
        for field, a in arrays.items():
            setattr(m, field, a.ctypes.data)
        m.max_cols = cols

    def run(self, stats, progress=None, stop=None):
        """Take the steps, counting into ``stats``."""
        m = self.struct
        raised = []
        if stop is not None:
            callback, raised = self._go(stop)
            m.go_on = ctypes.cast(callback, _P).value
        chunk = int(m.m_out)
        try:
            while m.k < self.total:
                k0, w0 = m.k, time.perf_counter()
                rc = self.lib.fa_run_implicit(ctypes.byref(m), min(self.total, k0 + chunk))
                elapsed = time.perf_counter() - w0
                self._account(stats)
                if rc == _DONE:
                    if progress is not None:
                        progress(m.k / self.total)
                    taken = m.k - k0
                    if elapsed > 0 and taken:
                        chunk = max(m.m_out, min(4 * chunk, int(taken * CHUNK_SECONDS / elapsed)
                                                 // m.m_out * m.m_out))
                    continue
                if rc == _DIVERGED:
                    it, k = self.iteration, int(m.k)
                    raise (it.singular(k, k + 1, m.fail_residual) if m.fail_kind == _SINGULAR
                           else it.not_converged(k, k + 1, m.fail_residual, m.fail_iterations))
                self._raise(rc, raised)
        finally:
            m.go_on = None
        return stats

    def _account(self, stats):
        """Copy the steps and the iteration counts of the C loop."""
        m, it = self.struct, self.iteration
        stats.steps = int(m.k)
        it.iterations, it.max_iterations = int(m.iterations), int(m.max_iterations)
        it.jacobian_steps = int(m.jacobian_steps)
        self.rows_written = max(self.rows_written, int(m.rows))
        self.t_reached = self.t0 + int(m.k) * self.h
