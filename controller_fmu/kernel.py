"""The controller's compiled kernel (``native/fp_filter.c``) bound to Python by ctypes.

The exact discretisation of the low-pass filter over a step (a matrix exponential by scaling and
squaring with a Pade approximant, in C) and the filter step with a held or polynomial input; the
PDLowPass FMU steps with it. :meth:`controller_fmu.pd_lowpass.PDLowPassModel.discretize_polynomial`
(scipy's ``expm``) is the specification, and ``tests/common/test_kernels.py`` holds the two
together. ctypes for the reasons given in :mod:`plant_fmu.kernel` (a plain C library that any
Python, and the native FMUs, can load).
"""
from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

from fmu_common import kernels
from fmu_common.kernels import KernelError

from .pd_lowpass import ControllerParams

__all__ = ["FilterKernel", "KernelError", "library", "expm", "FPF_OK", "FPF_BADARG",
           "FPF_NONFINITE"]

FPF_OK, FPF_BADARG, FPF_NONFINITE = 0, 1, 2

_NATIVE = Path(__file__).resolve().parent / "native"
_D = ctypes.c_double
_D3 = ctypes.c_double * 3


class _Filter(ctypes.Structure):
    _fields_ = [("order", ctypes.c_int), ("kp", _D), ("kd", _D), ("kx", _D), ("cutoff", _D),
                ("damping", _D), ("force_limit", _D)]


_lib = None


def library() -> ctypes.CDLL:
    """The filter kernel's library for this platform (loaded once; :class:`KernelError` if it is
    missing or does not match its sources)."""
    global _lib
    if _lib is None:
        lib = kernels.load("flexpend_filter", _NATIVE)
        lib.fpf_expm_work_size.restype = ctypes.c_long
        lib.fpf_error.restype = None
        _lib = lib
    return _lib


def expm(A) -> np.ndarray:
    """The matrix exponential of the square matrix ``A`` by the kernel's ``fpf_expm``."""
    A = np.ascontiguousarray(A, dtype=float)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] < 1:
        raise ValueError(f"expm needs a square matrix, got shape {A.shape}")
    n = A.shape[0]
    E = np.empty_like(A)
    lib = library()
    work = np.empty(lib.fpf_expm_work_size(n))
    rc = lib.fpf_expm(n, ctypes.c_void_p(A.ctypes.data), ctypes.c_void_p(E.ctypes.data),
                      ctypes.c_void_p(work.ctypes.data))
    if rc == FPF_BADARG:
        raise ValueError("expm: the matrix has a non-finite entry")
    if rc != FPF_OK:
        raise ArithmeticError("expm: the result overflows")
    return E


class FilterKernel:
    """The compiled filter for one :class:`ControllerParams`: discretisations and steps.

    The filter state is held here (``x``, the filter output first); :meth:`step` advances it.
    """

    def __init__(self, p: ControllerParams):
        lib = self._lib = library()
        self.params = p
        self.order = p.filter_order
        self._struct = _Filter(p.filter_order, p.kp, p.kd, p.kx, p.cutoff, p.filter_damping,
                               p.force_limit)
        self._f = ctypes.byref(self._struct)
        if lib.fpf_check(self._f) != FPF_OK:
            raise ValueError(f"controller parameters out of range for the kernel: {p}")
        self.x = (_D * 2)()
        self.e = _D3()
        self._F = _D()
        self._px, self._pe, self._pF = ctypes.byref(self.x), ctypes.byref(self.e), ctypes.byref(
            self._F)
        self._step_fn = lib.fpf_step

    def discretize(self, h: float, poly: bool = True):
        """``(Ad, G)`` over ``h``: ``G`` has the columns ``e0, e1, e2`` (``poly``) or only the
        held-input column. numpy arrays (empty for order 0)."""
        n, ng = self.order, 3 if poly else 1
        Ad, G = np.zeros((n, n)), np.zeros((n, ng))
        rc = self._lib.fpf_discretize(self._f, _D(h), int(bool(poly)),
                                      ctypes.c_void_p(Ad.ctypes.data),
                                      ctypes.c_void_p(G.ctypes.data))
        if rc == FPF_BADARG:
            raise ValueError(f"discretize: the step h = {h!r} must be positive and finite")
        if rc != FPF_OK:
            raise ArithmeticError(f"discretize: the matrix exponential over h = {h!r} overflows")
        return Ad, G

    def prepared(self, h: float):
        """The discretisation over ``h`` as the ctypes arrays :meth:`step` takes."""
        Ad, G = self.discretize(h, poly=True)
        ad = (_D * 4)(*Ad.ravel())
        g = (_D * 6)(*G.ravel())
        return ctypes.byref(ad), ctypes.byref(g), (ad, g)

    def sampled(self, T: float, discretization: str):
        """``(Ad, Bd, Cd, Dd)`` of the sampled filter over ``T`` (``fpf_sampled``; shapes as
        :func:`controller_fmu.sampled.filter_difference_equation`)."""
        n = self.order
        Ad, Bd, Cd, Dd = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((1, n)), np.zeros((1, 1))
        ptr = [ctypes.c_void_p(a.ctypes.data) if a.size else None for a in (Ad, Bd, Cd)]
        rc = self._lib.fpf_sampled(self._f, _D(T), int(discretization == "tustin"), *ptr,
                                   ctypes.c_void_p(Dd.ctypes.data))
        if rc == FPF_BADARG:
            raise ValueError(f"sampled: T = {T!r} must be positive and finite (and below "
                             f"pi / cutoff for tustin)")
        if rc != FPF_OK:
            raise ArithmeticError(f"sampled: the difference equation over T = {T!r} is not "
                                  f"finite")
        return Ad, Bd, Cd, Dd

    # ------------------------------------------------------------------ continuous time
    def rhs(self, xc, e: float) -> np.ndarray:
        """``xc' = Af xc + Bf e`` (``fpf_rhs``; empty for order 0)."""
        x = (_D * 2)(*np.r_[np.asarray(xc, dtype=float).ravel(), 0.0, 0.0][:2])
        out = (_D * 2)()
        if self._lib.fpf_rhs(self._f, x, _D(e), out) != FPF_OK:
            raise ArithmeticError("rhs: the result is not finite")
        return np.array(out[:self.order])

    def linearize(self, xc, e: float = 0.0):
        """``(A, B, C, D)`` at the state ``xc`` and error signal ``e`` (``fpf_linearize``), the
        inputs in the FMU's order ``[phi_o, omega_o, x_o]``."""
        n = self.order
        x = (_D * 2)(*np.r_[np.asarray(xc, dtype=float).ravel(), 0.0, 0.0][:2])
        A, B = np.zeros((n, n)), np.zeros((n, 3))
        C, D = np.zeros((1, n)), np.zeros((1, 3))
        ptr = [ctypes.c_void_p(a.ctypes.data) if a.size else None for a in (A, B, C)]
        rc = self._lib.fpf_linearize(self._f, x, _D(e), *ptr, ctypes.c_void_p(D.ctypes.data))
        if rc != FPF_OK:
            raise ArithmeticError("linearize: the state or error signal is not finite")
        return A, B, C, D

    def output_derivatives(self, xc, e0: float, e1: float = 0.0, e2: float = 0.0,
                           orders: int = 2):
        """The first ``orders`` (1 to 4; default ``(dF_c/dt, d2F_c/dt2)``) time derivatives of
        ``F_c`` at the state ``xc`` for the error signal ``e0`` with the rates ``e1, e2``
        (``fpf_output_derivatives``; the error signal's higher derivatives are 0)."""
        if orders not in (1, 2, 3, 4):
            raise ValueError(f"orders = {orders!r}; allowed: 1, 2, 3, 4")
        x = (_D * 2)(*np.r_[np.asarray(xc, dtype=float).ravel(), 0.0, 0.0][:2])
        d = (_D * 4)()
        if self._lib.fpf_output_derivatives(self._f, x, _D3(e0, e1, e2), d) != FPF_OK:
            raise ArithmeticError("output_derivatives: a result is not finite")
        return tuple(d[:orders])

    def step(self, prepared, e0: float, e1: float = 0.0, e2: float = 0.0):
        """``x <- Ad x + G [e0, e1, e2]`` with the discretisation ``prepared``; returns the
        saturated force ``F_c``, or None (state unchanged) if the result would not be finite."""
        e = self.e
        e[0], e[1], e[2] = e0, e1, e2
        if self._step_fn(self._f, prepared[0], prepared[1], self._pe, self._px, self._pF):
            return None
        return self._F.value
