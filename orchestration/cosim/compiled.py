"""The master's fixed-step loop in C (``orchestration/cosim/native/fm_master.c``), bound with
ctypes.

:class:`~orchestration.cosim.master.Master` runs it instead of its Python loop when every FMU can
take it (:func:`unavailable` says why not) and the key ``compiled`` allows it. The FMUs stay loaded,
instantiated and initialised by fmpy; the C loop receives their instance pointers and the
addresses of the FMI functions fmpy loaded, and makes the calls the Python loop makes, in the
same order, with the same arguments. Its results are bit-identical to the Python loop's
(``tests/cosim/test_compiled.py``): the extrapolation weights come from the same cache, and
the arithmetic is done operation for operation as numpy does it.

What stays in Python: instantiation, initialisation, the consistent initial outputs and the first
output row; the rows' array (the C loop writes into it); raising :class:`CoSimulationError` with the
FMU's log, and :class:`RunInterrupted`. The ``stop`` callback is asked after every step, as in the
Python loop (through a ctypes callback: about 0.1 us). The loop returns to Python at output points
about every 20 ms of wall time, to report progress and let Python's signal handlers run.
"""
from __future__ import annotations

import ctypes
import functools
import itertools
import time

import numpy as np

from fmu_common import kernels

from .coupling import HERMITE_MAX_ORDER, hermite_rows, weight_table
from .slave import CoSimulationError, RunInterrupted

__all__ = ["unavailable", "load", "CompiledRun", "KERNEL"]

KERNEL = "flexpend_master"

# results of fm_run and the calls of fail_call (fm_master.h)
_DONE, _FAILED, _STOPPED, _BADARG = range(4)
_CALLS = {1: "setReal", 2: "setRealInputDerivatives", 3: "doStep", 4: "getReal",
          5: "getFMUstate", 6: "setFMUstate", 7: "freeFMUstate", 8: "getRealOutputDerivatives"}
#: wall time between two returns to Python (progress, signal handlers)
CHUNK_SECONDS = 0.02
#: the FMI 2.0 functions the loop calls (fm_slave's function pointers, in order)
_FUNCTIONS = ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep", "fmi2SetRealInputDerivatives",
              "fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate",
              "fmi2GetRealOutputDerivatives")

_P = ctypes.c_void_p


class _Slave(ctypes.Structure):
    _fields_ = [("c", _P), ("set_real", _P), ("get_real", _P), ("do_step", _P), ("set_der", _P),
                ("get_state", _P), ("set_state", _P), ("free_state", _P), ("get_der", _P),
                ("n_in", ctypes.c_int), ("n_der", ctypes.c_int), ("n_out", ctypes.c_int),
                ("n_rec", ctypes.c_int), ("n_oder", ctypes.c_int), ("feedthrough", ctypes.c_int),
                ("sampled", ctypes.c_int),
                ("in_vr", _P), ("in_src", _P), ("in_idx", _P), ("der_vr", _P),
                ("der_order", _P), ("out_vr", _P), ("rec_vr", _P), ("oder_vr", _P),
                ("oder_order", _P),
                ("in_val", _P), ("der_val", _P), ("new_val", _P), ("rec_val", _P),
                ("saved", _P), ("hist", _P),
                ("newest", ctypes.c_longlong), ("count", ctypes.c_int), ("mark", ctypes.c_int),
                ("state", _P)]


class _Master(ctypes.Structure):
    _fields_ = [("n_slaves", ctypes.c_int), ("gauss_seidel", ctypes.c_int), ("p", ctypes.c_int),
                ("correct_startup", ctypes.c_int), ("slaves", _P), ("order", _P),
                ("t0", ctypes.c_double), ("h", ctypes.c_double),
                ("total", ctypes.c_longlong),
                ("m", ctypes.c_longlong), ("weights", _P), ("n_cols", ctypes.c_int),
                ("pad_", ctypes.c_int), ("col_slave", _P), ("col_rec", _P), ("col_index", _P),
                ("out", _P), ("go_on", _P), ("k", ctypes.c_longlong), ("rows", ctypes.c_longlong),
                ("fail_slave", ctypes.c_int), ("fail_call", ctypes.c_int),
                ("fail_status", ctypes.c_int), ("fail_timed", ctypes.c_int),
                ("fail_time", ctypes.c_double), ("dweights", ctypes.c_double * 54),
                ("taylor", ctypes.c_double * 60), ("hermite", ctypes.c_int),
                ("pad2_", ctypes.c_int), ("hweights", _P)]


_GO_ON = ctypes.CFUNCTYPE(ctypes.c_int)
_lib = None


def load():
    """The compiled loop's library (built at install; rebuilt when stale in a checkout), checked
    against the structs above. Raises :class:`plant_fmu.kernels.KernelError`."""
    global _lib
    if _lib is None:
        lib = kernels.load(KERNEL, kernels.native_dir(KERNEL))
        for name, struct in (("fm_sizeof_slave", _Slave), ("fm_sizeof_master", _Master)):
            fn = getattr(lib, name)
            fn.restype = ctypes.c_size_t
            if fn() != ctypes.sizeof(struct):
                raise kernels.KernelError(f"{KERNEL}: {name}() = {fn()}, the binding's struct "
                                          f"has {ctypes.sizeof(struct)} bytes: rebuild it")
        lib.fm_run.argtypes = [ctypes.POINTER(_Master), ctypes.c_longlong]
        lib.fm_run.restype = ctypes.c_int
        _lib = lib
    return _lib


def _address(fun) -> int | None:
    """The address of the C function of the ctypes function ``fun`` (what its buffer holds;
    ``ctypes.cast(fun, c_void_p).value``, at a third of the cost), or None."""
    return _P.from_buffer(fun).value if fun is not None else None


def unavailable(coupling, slaves: dict, adaptive: bool) -> str | None:
    """Why the compiled loop cannot run ``coupling`` (a :class:`~orchestration.cosim.coupling.
    Coupling`) over ``slaves``, or None when it can: a fixed step, and FMI 2.0 FMUs that need no
    execution tool (a pythonfmu FMU runs Python: it keeps the Python loop), called through fmpy's
    raw functions, with the capabilities the coupling uses (FMU states for the corrected first
    step, input derivatives through ``fmi2SetRealInputDerivatives``, output derivatives through
    ``fmi2GetRealOutputDerivatives``)."""
    if adaptive:
        return "the adaptive communication step runs in Python"
    for name, s in slaves.items():
        if s.fmi3:
            return f"{name} is an FMI 3.0 FMU"
        cs = s.md.coSimulation
        if cs is None or cs.needsExecutionTool:
            return f"{name} needs an execution tool (a pythonfmu FMU runs Python)"
        fun = s.raw_functions()
        if not fun:
            return f"{name} is not called through fmpy's raw FMI functions (a call logger is set)"
        needed = list(_FUNCTIONS[:3])
        if coupling.out_der[name]:
            needed.append(_FUNCTIONS[7])
        if coupling.n_der[name]:
            if not coupling.interpolates[name]:
                return f"{name} takes input derivatives as variables, not through " \
                       "fmi2SetRealInputDerivatives"
            needed.append(_FUNCTIONS[3])
        if coupling.correct_startup:
            needed += _FUNCTIONS[4:7]
        missing = [f for f in needed if fun.get(f) is None]
        if missing:
            return f"{name} lacks {', '.join(missing)}"
    return None


def _ints(values, ctype=ctypes.c_int):
    return (ctype * max(1, len(values)))(*values)


@functools.lru_cache(maxsize=16)
def hermite_table(h: float) -> np.ndarray:
    """The Hermite coupling's weights for the compiled loop at the step ``h`` (fm_master.h's
    ``hweights``): ``hermite_rows(q, two_point, h)`` for q = 1 .. HERMITE_MAX_ORDER, zero-padded
    to 2 HERMITE_MAX_ORDER + 2 columns; computed once per step, read-only."""
    hw = np.zeros((HERMITE_MAX_ORDER, 2, 4, 2 * HERMITE_MAX_ORDER + 2))
    for q in range(1, HERMITE_MAX_ORDER + 1):
        for two in (0, 1):
            W = hermite_rows(q, bool(two), h)
            hw[q - 1, two, :, :W.shape[1]] = W
    hw.flags.writeable = False
    return hw


class CompiledRun:
    """One fixed-step run in C of ``coupling`` over ``slaves``, from the signals' history ``hist``
    after the initial outputs, writing the rows of ``out`` (row 0 written).

    ``run(...)`` takes the steps and returns their number; failures and interruptions raise as in
    the Python loop.
    :attr:`steps` and :attr:`rows_written` say how far it got, however it ended.
    """

    def __init__(self, coupling, slaves: dict, hist, t0: float, m: int, total: int,
                 out: np.ndarray):
        lib = load()
        self.lib, self.coupling, self.t0, self.m, self.total = lib, coupling, t0, m, total
        self.py_slaves = slaves
        self.steps, self.rows_written = 0, 1
        names = list(slaves)
        index = {n: i for i, n in enumerate(names)}
        cp = coupling
        # The structs' arrays in two blocks: one of 32-bit unsigned integers (value references,
        # and indices and orders, all >= 0 and small: the C side's ints read the same bits) and
        # one of doubles (the work arrays and the histories). Each array's place is noted as it
        # is laid out; its field gets its address once the block exists.
        ints, at_int, sizes, at_dbl = [], [], [], []

        def ibuf(owner, field, values):
            at_int.append((owner, field, len(ints)))
            ints.extend(values)
            ints.append(0)                       # every array at least one entry long

        def dbuf(owner, field, size):            # the index of the array
            at_dbl.append((owner, field))
            sizes.append(max(1, size))
            return len(sizes) - 1

        self.slaves = (_Slave * len(names))()
        widths, hists = {}, {}
        for i, n in enumerate(names):
            s, c = slaves[n], self.slaves[i]
            fun = s.raw_functions()
            c.c = s.instance()
            (c.set_real, c.get_real, c.do_step, c.set_der, c.get_state, c.set_state,
             c.free_state, c.get_der) = [_address(fun.get(f)) for f in _FUNCTIONS]
            ins = cp.inputs[n]
            n_der = cp.n_der[n]
            c.n_in, c.n_der = len(ins), n_der
            c.n_out, c.n_rec = len(cp.outputs[n]), len(cp.recorded[n])
            c.n_oder = q = cp.out_der[n]
            width = widths[n] = c.n_out * (1 + q)   # a sample: the outputs, then derivatives
            c.feedthrough = int(bool(s.feedthrough))
            c.sampled = int(bool(s.sampled))
            in_vr = [s.vr(x.dst_var) for x in ins]
            out_vr = [s.vr(v) for v in cp.outputs[n]]
            ibuf(c, "in_vr", in_vr)
            ibuf(c, "in_src", [index[x.src] for x in ins])
            ibuf(c, "in_idx", [cp.out_index[x.src][x.src_var] for x in ins])
            ibuf(c, "der_vr", in_vr * n_der)
            ibuf(c, "der_order", [k for k in range(1, n_der + 1) for _ in ins])
            ibuf(c, "out_vr", out_vr)
            ibuf(c, "rec_vr", [s.vr(v) for v in cp.recorded[n]])
            ibuf(c, "oder_vr", out_vr * q)
            ibuf(c, "oder_order", [k for k in range(1, q + 1) for _ in cp.outputs[n]])
            for field, size in (("in_val", c.n_in), ("der_val", c.n_in * n_der),
                                ("new_val", width), ("rec_val", c.n_rec), ("saved", width)):
                dbuf(c, field, size)
            hists[n] = dbuf(c, "hist", 4 * max(1, width))
            # the history after the initial outputs: one sample at t0 (step 0)
            c.count = len(hist[n].u)
            c.newest = len(hist[n].u) - 1
        cols = list(cp.record.items())
        col_slave = [index[s] for _, (s, _v) in cols]
        col_rec = [int(v not in cp.out_index[s]) for _, (s, v) in cols]
        col_index = [cp.recorded[s].index(v) if r else cp.out_index[s][v]
                     for (_, (s, v)), r in zip(cols, col_rec)]
        self.rows = out.view(np.float64).reshape(len(out), 1 + len(cols))
        self.struct = st = _Master()
        st.n_slaves, st.gauss_seidel = len(names), int(cp.algorithm == "gauss-seidel")
        st.p, st.correct_startup = cp.p, int(cp.correct_startup)
        st.slaves = ctypes.addressof(self.slaves)
        ibuf(st, "order", [index[n] for n in cp.order])
        st.t0, st.h, st.total, st.m = t0, cp.h, total, m
        self.weights = weight_table()
        st.weights = self.weights.ctypes.data
        st.hermite = int(cp.hermite)
        if cp.hermite:                  # hermite_rows(q, two_point, h), as the Python loop's
            self.hweights = hermite_table(cp.h)
            st.hweights = self.hweights.ctypes.data
        st.n_cols = len(cols)
        ibuf(st, "col_slave", col_slave)
        ibuf(st, "col_rec", col_rec)
        ibuf(st, "col_index", col_index)
        st.out = self.rows.ctypes.data
        st.k, st.rows = 0, 1
        # the blocks (kept with the run: the structs point into them)
        self._ints = np.array(ints, dtype=np.uint32)
        base = self._ints.ctypes.data
        for owner, field, offset in at_int:
            setattr(owner, field, base + 4 * offset)
        offsets = [0, *itertools.accumulate(sizes)]
        self._doubles = np.zeros(offsets[-1])
        base = self._doubles.ctypes.data
        for (owner, field), offset in zip(at_dbl, offsets):
            setattr(owner, field, base + 8 * offset)
        self.hist = {}
        for n, j in hists.items():
            h = self._doubles[offsets[j]:offsets[j + 1]].reshape(4, -1)
            self.hist[n] = h
            for k, u in enumerate(hist[n].u):
                h[k, :widths[n]] = u

    def run(self, stats, progress=None, stop=None) -> int:
        """Take the steps; their number (``total``)."""
        st, m = self.struct, self.m
        raised = []
        if stop is not None:
            def go_on():
                try:
                    return 0 if stop() else 1
                except BaseException as exc:  # noqa: BLE001 - re-raised below, out of C
                    raised.append(exc)
                    return 0
            callback = _GO_ON(go_on)
            st.go_on = ctypes.cast(callback, _P).value
        chunk = m * max(1, 256 // m)              # steps per call, tuned to CHUNK_SECONDS
        try:
            while st.k < self.total:
                k0, w0 = st.k, time.perf_counter()
                rc = self.lib.fm_run(ctypes.byref(st), min(self.total, k0 + chunk))
                elapsed = time.perf_counter() - w0
                self._account(stats)
                if rc == _DONE:
                    if progress is not None:
                        progress(st.k / self.total)
                    taken = st.k - k0
                    if elapsed > 0 and taken:
                        chunk = max(m, min(4 * chunk, int(taken * CHUNK_SECONDS / elapsed)
                                           // m * m))
                    continue
                if rc == _STOPPED:
                    if raised:
                        raise raised[0]
                    raise RunInterrupted(self.t_reached)
                if rc == _FAILED:
                    name = list(self.py_slaves)[st.fail_slave]
                    t = st.fail_time if st.fail_timed else None
                    raise self.py_slaves[name].error(_CALLS[st.fail_call], st.fail_status, t)
                raise CoSimulationError(f"the compiled master refused its arguments (fm_run "
                                        f"returned {rc}); master.compiled = false runs the "
                                        f"Python loop")
        finally:
            st.go_on = None
        return st.k

    def _account(self, stats):
        st = self.struct
        stats.steps = self.steps = int(st.k)
        self.rows_written = max(self.rows_written, int(st.rows))

    @property
    def t_reached(self) -> float:
        """The time of the last step taken (``t0`` before the first)."""
        return self.t0 + self.steps * self.coupling.h
