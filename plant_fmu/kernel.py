"""The plant's compiled kernel (``native/fp_plant.c``) bound to Python by ctypes.

:class:`PlantKernel` holds one plant's data (the invariants of :mod:`plant_fmu.beam`, passed in
``fp_plant``) and offers what the hot paths need: the right-hand side, the tip angle, the outputs
and energy, the exact Jacobians and output time derivatives, the fixed-substep loop of the
explicit methods and the adaptive Dormand-Prince loop.
:class:`plant_fmu.dynamics.PlantModel` and ``LinearPlantModel`` build one (their ``kernel``); the
numpy code there stays the specification, and ``tests/common/test_kernels.py`` holds the two to
1e-12.

Why ctypes. The kernel is a plain C library, not a Python extension, so that one binary serves
every consumer: this package under any CPython 3 (no rebuild per Python version), the pythonfmu
FMUs that ship it and load it under whatever Python their host has, and the native FMUs that link
the same sources. That rules out a CPython extension (tied to one Python ABI, and a win64 build
would need that Python's import library). Between ctypes and cffi's ABI mode, ctypes is in the
standard library, so an FMU needs nothing more in its host's Python, and the two cost the same
per call: measured side by side (``bench/bench_kernel.py``, one loaded 2-core machine), a call
with no argument 0.09 us by ctypes and 0.10 us by cffi, with three pointer arguments 0.22 and
0.25 us (an empty numba function of three arrays: 0.22 us). What costs is converting arguments:
numpy's ``.ctypes`` attribute alone takes ~0.8 us and ``argtypes`` conversions a few tenths per
argument, so the arguments here are built once (the struct passed ``byref``, ``c_void_p`` to
preallocated buffers, scalars set in place) and the state is copied in and out of the buffers.
``PlantModel.rhs`` then costs 1.05 us against 1.27 us for the numba kernel it replaced; the loops
of a communication step are one call each.
"""
from __future__ import annotations

import ctypes
import math
import threading
from pathlib import Path

import numpy as np

from fmu_common import kernels
from fmu_common.kernels import KernelError

__all__ = ["PlantKernel", "ExactKernel", "ExactStepError", "KernelError", "library", "FP_OK",
           "FP_BADARG", "FP_NONFINITE", "FP_CAP", "FP_UNDERFLOW", "FP_NOCONVERGE", "METHODS",
           "OUT"]

FP_OK, FP_BADARG, FP_NONFINITE, FP_CAP, FP_UNDERFLOW, FP_NOCONVERGE = 0, 1, 2, 3, 4, 5

#: the built-in methods of the fixed-step loop (fp_plant.h)
METHODS = {"euler": 0, "rk4": 1, "dopri5": 2, "symplectic_euler": 3}

#: layout of :meth:`PlantKernel.outputs` (FP_OUT_* of fp_plant.h); eta_j at OUT["eta"] + j - 1
OUT = {"x_o": 0, "x_dot": 1, "phi_o": 2, "omega_o": 3, "phi": 4, "tip_deflection": 5,
       "energy": 6, "eta": 7}

_NATIVE = Path(__file__).resolve().parent / "native"
_P = ctypes.c_void_p
_D = ctypes.c_double


class _Plant(ctypes.Structure):
    _fields_ = [("n", ctypes.c_int), ("linear", ctypes.c_int), ("preload", ctypes.c_int),
                ("I0", _D), ("I1", _D), ("I2", _D), ("g", _D),
                ("I3", _P), ("I5", _P), ("K", _P), ("D", _P), ("Kg", _P), ("tip_slope", _P),
                ("tip_defl", _P), ("nx", ctypes.c_int), ("I3I3", _D), ("I3I5", _D), ("I5I5", _D),
                ("stiffened", ctypes.c_int), ("npts", ctypes.c_int), ("pts", _P)]


class _Tableau(ctypes.Structure):
    _fields_ = [("stages", ctypes.c_int), ("A", _P), ("B", _P), ("C", _P), ("E", _P),
                ("fsal", ctypes.c_int)]


class _Input(ctypes.Structure):
    _fields_ = [("u0", _D), ("du", _D), ("d2u", _D), ("tu", _D)]


class _Adaptive(ctypes.Structure):
    _fields_ = [("rtol", _D), ("atol", _P), ("n_atol", ctypes.c_int), ("max_step", _D),
                ("min_step", _D), ("max_steps", ctypes.c_long), ("h_abs", _D),
                ("nfev", ctypes.c_long), ("nsteps", ctypes.c_long), ("nrejected", ctypes.c_long),
                ("fail_h", _D), ("fail_min_step", _D)]


class _Exact(ctypes.Structure):
    _fields_ = [("ne", ctypes.c_int), ("L", _D), ("EA", _D), ("EI", _D), ("rhoA", _D), ("g", _D),
                ("m", _D), ("beta_kv", _D), ("h", _D), ("rho_inf", _D), ("tol", _D),
                ("max_iter", ctypes.c_int), ("nq", ctypes.c_int), ("le", _D), ("am", _D),
                ("af", _D), ("gamma", _D), ("beta", _D), ("bp", _D), ("gw", _D * 5),
                ("gd1", _D * 20), ("gd2", _D * 20), ("modal", ctypes.c_void_p)]


class _ExactForce(ctypes.Structure):
    _fields_ = [("F0", _D), ("Q0", _D), ("kx", _D), ("kp", _D), ("kd", _D)]


class _RadauForce(ctypes.Structure):
    _fields_ = [("F0", _D * 3), ("Q", _D * 9), ("kx", _D), ("kp", _D), ("kd", _D)]


_lib = None


def library() -> ctypes.CDLL:
    """The plant kernel's library for this platform (loaded once; :class:`KernelError` if it is
    missing or does not match its sources)."""
    global _lib
    if _lib is None:
        lib = kernels.load("flexpend_plant", _NATIVE)
        lib.fp_energy.restype = ctypes.c_double
        lib.fp_work_size.restype = ctypes.c_long
        lib.fp_jacobian_work_size.restype = ctypes.c_long
        lib.fp_exact_work_size.restype = ctypes.c_long
        lib.fp_radau_work_size.restype = ctypes.c_long
        lib.fp_exact_modal_size.restype = ctypes.c_long
        lib.fp_exact_modal_work_size.restype = ctypes.c_long
        for name in ("fp_rhs", "fp_tip", "fp_outputs"):
            getattr(lib, name).restype = None
        _lib = lib
    return _lib


def _addr(a: np.ndarray) -> _P:
    return _P(a.ctypes.data)


def _f64(a, shape=None) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    if shape is not None:
        a = a.reshape(shape)
    return a


class _TableauData:
    """A Butcher tableau as the kernel reads it (arrays kept alive with the struct)."""

    def __init__(self, A, B, C, E=None, fsal=False):
        s = np.asarray(B).size
        self.arrays = [_f64(A, (s, s)), _f64(B, (s,)), _f64(C, (s,))]
        self.arrays.append(None if E is None else _f64(E, (s,)))
        ptr = [None if a is None else _addr(a) for a in self.arrays]
        self.struct = _Tableau(s, *ptr, int(bool(fsal)))
        self.ref = ctypes.byref(self.struct)
        self.stages = s


class PlantKernel:
    """The compiled kernel bound to one plant's data.

    Parameters (the fields of ``fp_plant``): ``n`` modes, ``linear`` (the model linearised at the
    upright rest state), ``preload`` (the geometric stiffness ``Kg``), the invariants ``I0, I1,
    I2`` and ``g``, and the arrays ``I3, I5, K`` (diagonal), ``D`` (diagonal), ``Kg`` (n x n),
    ``tip_slope``, ``tip_defl``; for the stiffened model, its ``points``
    (:class:`plant_fmu.beam.MassPoints`). The arrays are copied.
    """

    def __init__(self, *, n, linear, preload, I0, I1, I2, g, I3, I5, K, D, Kg, tip_slope,
                 tip_defl, points=None):
        lib = self._lib = library()
        n = int(n)
        self._arrays = arrays = {k: _f64(v, (n,)) for k, v in (
            ("I3", I3), ("I5", I5), ("K", K), ("D", D), ("tip_slope", tip_slope),
            ("tip_defl", tip_defl))}
        arrays["Kg"] = _f64(Kg, (n, n)) if n else np.zeros(1)
        self._struct = _Plant(n, int(bool(linear)), int(bool(preload)), float(I0), float(I1),
                              float(I2), float(g), *(_addr(arrays[k]) for k in (
                                  "I3", "I5", "K", "D", "Kg", "tip_slope", "tip_defl")))
        if points is not None:
            P = points.s.size
            arrays["pts"] = _f64(np.hstack([points.s[:, None], points.m[:, None], points.N,
                                            points.G.reshape(P, n * n)]))
            self._struct.stiffened, self._struct.npts = 1, P
            self._struct.pts = _addr(arrays["pts"])
        self._p = ctypes.byref(self._struct)
        if lib.fp_plant_prepare(self._p) != FP_OK:
            raise ValueError("the plant data are out of range (a size is negative or an "
                             "invariant is not finite)")
        self.n, self.nx = n, self._struct.nx
        self.linear = bool(linear)
        # buffers and argument objects built once: a call then converts only the floats
        self._x = np.zeros(self.nx)
        self._dx = np.zeros(self.nx)
        self._out = np.zeros(OUT["eta"] + n)
        self._tip = np.zeros(2)
        self._px, self._pdx = _addr(self._x), _addr(self._dx)
        self._pout, self._ptip = _addr(self._out), _addr(self._tip)
        self._input = _Input()
        self._pinput = ctypes.byref(self._input)
        self._done = ctypes.c_long()
        self._pdone = ctypes.byref(self._done)
        self._t, self._h, self._n = _D(), _D(), ctypes.c_long()    # scalars passed by value
        self._work = {}
        self._lock = threading.Lock()
        self._f_rhs, self._f_energy, self._f_tip = lib.fp_rhs, lib.fp_energy, lib.fp_tip
        self._f_outputs, self._f_fixed = lib.fp_outputs, lib.fp_fixed_steps
        self._f_dopri = lib.fp_dopri_advance
        self._jwork = np.zeros(lib.fp_jacobian_work_size(self._p))
        self._pjwork = _addr(self._jwork)

    # ------------------------------------------------------------------ evaluations
    def rhs(self, x, u: float) -> np.ndarray:
        """``dx/dt`` at ``x`` with the force ``u`` (a new array)."""
        with self._lock:
            self._x[:] = x
            self._f_rhs(self._p, self._px, _D(u), self._pdx)
            return self._dx.copy()

    def energy(self, x) -> float:
        with self._lock:
            self._x[:] = x
            return self._f_energy(self._p, self._px)

    def tip(self, x) -> tuple[float, float]:
        """``(phi_o, omega_o)``."""
        with self._lock:
            self._x[:] = x
            self._f_tip(self._p, self._px, self._ptip)
            t = self._tip
            return float(t[0]), float(t[1])

    def outputs(self, x, energy: bool = True) -> np.ndarray:
        """Every output at ``x`` in the layout :data:`OUT` (a new array; the energy entry is NaN
        unless ``energy``)."""
        with self._lock:
            self._x[:] = x
            self._out[OUT["energy"]] = math.nan
            self._f_outputs(self._p, self._px, int(bool(energy)), self._pout)
            return self._out.copy()

    # ------------------------------------------------------------------ Jacobians
    def _check(self, rc, what):
        if rc == FP_BADARG and self._struct.stiffened:
            raise ValueError(f"{what}: not available for fidelity = 'stiffened' (nonlinear and "
                             f"linear have it)")
        if rc == FP_NONFINITE:
            raise ArithmeticError(f"{what}: a result is not finite")
        if rc != FP_OK:
            raise ValueError(f"{what}: bad argument (code {rc})")

    def jacobian(self, x, u: float):
        """``(J, b)``: ``J = d(dx/dt)/dx`` (nx x nx) and ``b = d(dx/dt)/dF_c`` at ``x`` with the
        force ``u`` (``fp_jacobian``; the specification is ``jacobian_numpy``)."""
        J, b = np.empty((self.nx, self.nx)), np.empty(self.nx)
        with self._lock:
            self._x[:] = x
            rc = self._lib.fp_jacobian(self._p, self._px, _D(u), _addr(J), _addr(b),
                                       self._pjwork)
        self._check(rc, "jacobian")
        return J, b

    def jvp(self, x, u: float, v, du: float = 0.0) -> np.ndarray:
        """``J v + b du`` without forming ``J`` (``fp_jvp``)."""
        v = _f64(v, (self.nx,))
        out = np.empty(self.nx)
        with self._lock:
            self._x[:] = x
            rc = self._lib.fp_jvp(self._p, self._px, _D(u), _addr(v), _D(du), _addr(out),
                                  self._pjwork)
        self._check(rc, "jvp")
        return out

    def output_jacobian(self, x) -> np.ndarray:
        """``C = d(outputs)/dx`` in the layout :data:`OUT` (``fp_output_jacobian``)."""
        C = np.empty((OUT["eta"] + self.n, self.nx))
        with self._lock:
            self._x[:] = x
            rc = self._lib.fp_output_jacobian(self._p, self._px, _addr(C))
        self._check(rc, "output_jacobian")
        return C

    def output_derivatives(self, x, u: float, du: float = 0.0):
        """``(d1, d2)``: the first and second time derivatives of every output (layout
        :data:`OUT`) at ``x`` with the force ``u`` and its rate ``du``
        (``fp_output_derivatives``)."""
        d1, d2 = np.empty(OUT["eta"] + self.n), np.empty(OUT["eta"] + self.n)
        with self._lock:
            self._x[:] = x
            rc = self._lib.fp_output_derivatives(self._p, self._px, _D(u), _D(du), _addr(d1),
                                                 _addr(d2), self._pjwork)
        self._check(rc, "output_derivatives")
        return d1, d2

    # ------------------------------------------------------------------ loops
    def tableau(self, A, B, C, E=None, fsal=False) -> _TableauData:
        """A tableau for :meth:`fixed_steps` and :meth:`dopri_advance` (build it once)."""
        return _TableauData(A, B, C, E, fsal)

    def _work_for(self, stages: int):
        w = self._work.get(stages)
        if w is None:
            buf = np.zeros((stages + 2) * self.nx)
            w = self._work[stages] = (buf, _addr(buf))
        return w[1]

    def _set_input(self, u):
        inp = self._input
        inp.u0, inp.du, inp.d2u, inp.tu = u

    def fixed_steps(self, method: str, tableau, y, u, t: float, h: float, n: int):
        """``n`` substeps of ``h`` from time ``t`` on a copy of ``y``: ``(y_new, done, code)``.

        ``method`` is ``"symplectic_euler"`` or any other name with ``tableau`` (from
        :meth:`tableau`); ``u = (u0, du, d2u, tu)`` is the input polynomial. ``done < n`` with
        ``code = FP_NONFINITE`` when a substep produced a non-finite state (``y_new``: the last
        finite one)."""
        if method == "symplectic_euler":
            code, tab, stages = 3, None, 1
        else:
            code, tab, stages = -1, tableau.ref, tableau.stages
        with self._lock:
            self._x[:] = y
            inp = self._input
            inp.u0, inp.du, inp.d2u, inp.tu = u
            self._t.value, self._h.value, self._n.value = t, h, n
            rc = self._f_fixed(self._p, code, tab, self._pinput, self._t, self._h, self._n,
                               self._px, self._work_for(stages), self._pdone)
            y_new, done = self._x.copy(), self._done.value
        if rc == FP_BADARG:
            raise ValueError(f"fixed_steps: bad argument (h = {h!r}, n = {n!r})")
        return y_new, done, rc

    def dopri_advance(self, tableau, y, f, t: float, t_end: float, u, *, rtol, atol, max_step,
                      min_step, h_abs, max_steps=100_000):
        """The adaptive Dormand-Prince loop from ``t`` towards ``t_end`` on copies of ``y`` and
        ``f`` (= f(t, y, u(t))). Returns ``(code, t, y, f, h_abs, nfev, nsteps, nrejected,
        fail_h, fail_min_step)``; ``code`` is FP_OK (t_end reached), FP_CAP (``max_steps`` steps
        taken: call again) or FP_UNDERFLOW."""
        nx = self.nx
        y = np.array(y, dtype=float)
        f = np.array(f, dtype=float)
        atol_arr = np.ascontiguousarray(np.atleast_1d(np.asarray(atol, dtype=float)))
        if atol_arr.size not in (1, nx):
            raise ValueError(f"atol must be a scalar or have {nx} entries")
        a = _Adaptive(float(rtol), _addr(atol_arr), atol_arr.size, float(max_step),
                      float(min_step), int(max_steps), float(h_abs), 0, 0, 0, math.nan, math.nan)
        tt = _D(t)
        with self._lock:
            self._set_input(u)
            rc = self._f_dopri(self._p, tableau.ref, self._pinput, ctypes.byref(tt), _D(t_end),
                               _addr(y), _addr(f), ctypes.byref(a),
                               self._work_for(tableau.stages))
        if rc == FP_BADARG:
            raise ValueError("dopri_advance: bad argument (tableau, tolerances or steps)")
        return (rc, tt.value, y, f, a.h_abs, a.nfev, a.nsteps, a.nrejected, a.fail_h,
                a.fail_min_step)


class ExactStepError(RuntimeError):
    """A step of the exact rung failed: ``code`` is the kernel's (FP_NONFINITE, FP_NOCONVERGE,
    FP_BADARG), ``state`` the last good state (after the steps taken) or None."""

    def __init__(self, message: str, code: int, state=None):
        super().__init__(message)
        self.code, self.state = code, state


class ExactKernel:
    """The exact rung's compiled step (``fp_exact_*``), the API of the numpy specification
    :class:`plant_fmu.exact.GeneralizedAlpha` on an :class:`plant_fmu.exact.ExactPlant`:
    :meth:`forces` as ``BeamSystem.forces``, :meth:`start` and :meth:`step` as the integrator's,
    with the force a number (held) or an :class:`plant_fmu.exact.AffineForce` (the closed loop's
    law; the kernel takes no other callable). :meth:`steps` runs ``n`` steps in one call."""

    _CODES = {FP_BADARG: "bad argument (a size, or a force that is not finite)",
              FP_NONFINITE: "a residual or the state is not finite",
              FP_NOCONVERGE: "Newton did not converge (or its matrix is singular)"}

    def __init__(self, plant, h: float, rho_inf: float = 0.9, tol: float | None = None,
                 max_iter: int = 30, method: str = "genalpha"):
        p = plant.params
        if not 0.0 <= rho_inf <= 1.0:
            raise ValueError(f"rho_inf = {rho_inf!r} is out of range; allowed: [0, 1]")
        if method not in ("genalpha", "radau"):
            raise ValueError(f"method = {method!r} is not allowed; allowed: genalpha, radau")
        if tol is None:
            from .exact import RADAU_TOL

            tol = RADAU_TOL if method == "radau" else 1e-11
        self.method = method
        lib = self._lib = library()
        self._struct = _Exact(int(p.n_elements), float(p.L), float(p.EA), float(p.EI),
                              float(p.rhoA), float(p.g), float(p.m), float(plant.beta_kv),
                              float(h), float(rho_inf), float(tol), int(max_iter))
        self._p = ctypes.byref(self._struct)
        if lib.fp_exact_prepare(self._p) != FP_OK:
            raise ValueError(f"the exact beam's data are out of range (h = {h!r}, max_iter = "
                             f"{max_iter!r}, or a parameter is not finite and positive)")
        self.h, self.nq = h, self._struct.nq
        self._modal = None                  # the modal law's C_f (fp_exact_modal), kept alive
        if getattr(plant, "modal", None) is not None:
            self._modal = np.zeros(lib.fp_exact_modal_size(self._p))
            mwork = np.zeros(lib.fp_exact_modal_work_size(self._p))
            if lib.fp_exact_modal(self._p, _D(float(p.zeta)), _addr(self._modal),
                                  _addr(mwork)) != FP_OK:
                raise ValueError("the exact beam's modal damping law could not be formed")
            self._struct.modal = self._modal.ctypes.data
        size = (lib.fp_radau_work_size if method == "radau" else lib.fp_exact_work_size)(self._p)
        self._work = np.zeros(size)
        self._pwork = _addr(self._work)
        self._force = _ExactForce()
        self._pforce = ctypes.byref(self._force)
        self._rforce = _RadauForce()
        self._prforce = ctypes.byref(self._rforce)
        self._e = np.zeros(3)
        self.stage_error = (0.0, 0.0, 0.0)
        self._done, self._iters = ctypes.c_long(), ctypes.c_long()
        self.newton_iterations = 0
        self._lock = threading.Lock()

    def _raise(self, rc: int, what: str, state=None):
        raise ExactStepError(f"exact {what}: {self._CODES.get(rc, f'code {rc}')} "
                             f"(h = {self.h})", rc, state)

    def forces(self, q, qd, u: float = 0.0, tangent: bool = True):
        """``(f, K, C)`` (``K, C``: None unless ``tangent``), as ``BeamSystem.forces``."""
        nq = self.nq
        q, qd = _f64(q, (nq,)), _f64(qd, (nq,))
        f = np.empty(nq)
        K = np.empty((nq, nq)) if tangent else None
        C = np.empty((nq, nq)) if tangent else None
        with self._lock:
            rc = self._lib.fp_exact_forces(self._p, _addr(q), _addr(qd), _D(u), _addr(f),
                                           _addr(K) if tangent else None,
                                           _addr(C) if tangent else None, None, self._pwork)
        if rc != FP_OK:
            self._raise(rc, "forces")
        return f, K, C

    def mass(self) -> np.ndarray:
        nq = self.nq
        z, f, M = np.zeros(nq), np.empty(nq), np.empty((nq, nq))
        with self._lock:
            self._lib.fp_exact_forces(self._p, _addr(z), _addr(z), _D(0.0), _addr(f), None, None,
                                      _addr(M), self._pwork)
        return M

    def _set_force(self, force):
        law = (float(force), 0.0, 0.0, 0.0, 0.0) if np.isscalar(force) else tuple(force)
        f = self._force
        f.F0, f.Q0, f.kx, f.kp, f.kd = law

    def _set_radau(self, force):
        from .exact import StageForce

        law = force if isinstance(force, StageForce) else StageForce.held(force)
        f = self._rforce
        f.F0[:] = [float(v) for v in law.F0]
        f.Q[:] = [float(v) for row in law.Q for v in row]
        f.kx, f.kp, f.kd = float(law.kx), float(law.kp), float(law.kd)

    def start(self, q, qd, force=0.0):
        """The integrator's state from consistent accelerations: ``(q, qd, qdd, a)`` for
        generalized alpha, ``(q, qd, qdd, jerk)`` (jerk 0) for Radau IIA."""
        nq = self.nq
        s = np.zeros(4 * nq)
        s[:nq], s[nq:2 * nq] = q, qd
        with self._lock:
            if self.method == "radau":
                self._set_radau(force)
                rc = self._lib.fp_radau_start(self._p, self._prforce, _addr(s), self._pwork)
            else:
                self._set_force(force)
                rc = self._lib.fp_exact_start(self._p, self._pforce, _addr(s), self._pwork)
        if rc != FP_OK:
            self._raise(rc, "start")
        return tuple(s.reshape(4, nq).copy())

    def steps(self, state, force=0.0, n: int = 1):
        """``n`` steps under one force law: the new state (a tuple as :meth:`start`'s).
        :class:`ExactStepError` if a step fails (its ``code``, and the state after the steps
        taken). With Radau IIA ``force`` is a number (held) or a
        :class:`plant_fmu.exact.StageForce`; :attr:`stage_error` holds the last step's stage
        errors."""
        s = np.concatenate([np.asarray(v, dtype=float) for v in state])
        if self.method == "radau":
            with self._lock:
                self._set_radau(force)
                self._iters.value = 0
                done, rc = 0, FP_OK
                for _ in range(n):
                    rc = self._lib.fp_radau_step(self._p, self._prforce, _addr(s), self._pwork,
                                                 ctypes.byref(self._iters), _addr(self._e))
                    if rc != FP_OK:
                        break
                    done += 1
                self.newton_iterations += self._iters.value
                self.stage_error = tuple(float(v) for v in self._e)
            state = tuple(s.reshape(4, self.nq))
            if rc != FP_OK:
                self._raise(rc, f"step {done + 1} of {n}", state)
            return state
        with self._lock:
            self._set_force(force)
            self._iters.value = 0
            rc = self._lib.fp_exact_steps(self._p, self._pforce, ctypes.c_long(n), _addr(s),
                                          self._pwork, ctypes.byref(self._done),
                                          ctypes.byref(self._iters))
            self.newton_iterations += self._iters.value
        state = tuple(s.reshape(4, self.nq))
        if rc != FP_OK:
            self._raise(rc, f"step {self._done.value + 1} of {n}", state)
        return state

    def step(self, state, force=0.0):
        return self.steps(state, force, 1)

    def outputs(self, state) -> np.ndarray:
        """The outputs at ``state`` (``(q, qd, ...)``, or ``[q, qd]``) in the layout :data:`OUT`
        up to the energy (``fp_exact_outputs``: the native FMU's at the exact rung)."""
        nq = self.nq
        s = np.concatenate([np.asarray(v, dtype=float).ravel() for v in state])[:2 * nq]
        s = _f64(s, (2 * nq,))
        out = np.empty(OUT["energy"] + 1)
        with self._lock:
            rc = self._lib.fp_exact_outputs(self._p, _addr(s), 1, _addr(out), self._pwork)
        if rc != FP_OK:
            self._raise(rc, "outputs")
        return out
