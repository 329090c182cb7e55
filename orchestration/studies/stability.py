"""Linear stability of the co-simulation: the transition matrix of one communication step.

At small amplitude the plant is its linearisation ``x' = A x + B F_c``, ``y = C x`` (sensors
``y = [x_o, phi_o, omega_o]``) and the controller is linear, so one communication step of the
master (:mod:`orchestration.cosim.master`) is a linear map ``z_{k+1} = Phi z_k`` of an augmented state

    z = [x, xc, y_k, y_{k-1} .. y_{k-p}, F_k, F_{k-1} .. F_{k-p}]

(plant state, filter state, the sensor and force samples the extrapolation of order ``p`` uses).
With output derivatives (``master.output_derivatives``) the registers are the newest samples
and their first ``p`` time derivatives instead, ``[y_k, y'_k, .., F_k, F'_k, ..]``. ``Phi`` models
what the master does, step by step:

* each source's polynomial is the one through the last ``p + 1`` samples (fewer at the start), or
  the Taylor polynomial of the newest sample and its derivatives (output derivatives); both are
  carried as the polynomial's Taylor coefficients ``[u, u', u'']`` at ``t_k``;
* each FMU gets over ``doStep`` either the step average of that polynomial, held
  (:func:`orchestration.cosim.coupling.extrapolation_weights`), or (``input_derivatives``, ``p >=
  1``) its value and its derivatives up to ``min(p, 2)`` at ``t_k`` (FMI's input derivatives);
* Gauss-Seidel: the second FMU gets the polynomial through the newest samples *including* the
  first FMU's output at ``t_k+1`` (an interpolation), or the Taylor polynomial of that output;
* the controller declares direct feedthrough, so before its output is read its inputs are set to
  their polynomial's value at ``t_k+1``; only with ``filter_order = 0`` does ``F_c`` depend on
  them;
* the controller advances its filter exactly for its input polynomial (held: a constant),
  :func:`controller_polynomial_step_map` (the filter driven by a chain of integrators, one matrix
  exponential);
* the plant FMU advances with its internal method on the substep grid of
  :class:`plant_fmu.integrators.base.Stepper` (whole substeps ``h``, then one shortened substep
  when ``H`` is not a multiple of ``h``), :func:`plant_polynomial_step_map`: the Runge-Kutta
  stages (and symplectic Euler's substep start) evaluate the input polynomial at their times (the
  polynomial's coefficients are states with the nilpotent dynamics ``d/dt [u, u', u''] = [u', u'',
  0]``, moved exactly from substep to substep), while ``genalpha`` and ``exponential`` hold its
  step average, as the FMUs do; for a linear method on a linear plant one substep is a matrix,
  e.g. RK4's ``R(hA) = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24`` with its input terms
  (:func:`substep_matrix` for a held input);
* with output derivatives, the FMUs' derivatives at ``t_k+1`` are those of their linear systems
  driven by the input polynomial of the step just taken, evaluated at its end (as the native FMUs
  compute them).

Two public step maps are the building blocks (a scheme other than the explicit ones, e.g. an
iterated one, is composed from them): :func:`plant_polynomial_step_map` ``(Phi, Gamma)`` with
``x(t+H) = Phi x(t) + Gamma [u, u', u'']`` for the plant FMU's method, and
:func:`controller_polynomial_step_map` ``(Ad, G)`` with ``xc(t+H) = Ad xc(t) + G [y, y', y'']``
(``F_c = C xc + D y`` with the ``C, D`` of the controller's model,
:func:`controller_fmu.spec.model_for`).

The spectral radius ``rho(Phi)`` decides: the co-simulation of the linearised loop decays iff
``rho < 1``. With ``kx = 0`` the cart's position and velocity are neither fed back nor felt by the
other states; they are left out structurally (``drift_free``), as in
:mod:`orchestration.studies.analysis`, because their double root at zero (one at 1 per step) would hide
the verdict.

:func:`integrator_step_limit` gives where a plant method fails on the plant's highest mode (its
stability function on the plant's eigenvalues); :func:`observed_spectral_radius` measures the
growth per step of a co-simulation's output samples (an eigensystem realisation of the sampled
outputs), which is what the tests and ``bench/stability_map.py`` compare with ``rho(Phi)``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.spec import model_for as controller_model
from plant_fmu.dynamics import plant_model
from plant_fmu.integrators.genalpha import genalpha_parameters
from plant_fmu.params import PlantParams

from ..scene.keys import ConfigError
from . import stability_intervals as _iv
from .analysis import linearisation

__all__ = ["METHODS", "FIXED_STEP_METHODS", "POLYNOMIAL_METHODS", "ALGORITHMS", "substep_matrix",
           "plant_step_map", "plant_polynomial_step_map", "controller_polynomial_step_map",
           "scene_coupling", "COUPLING_ORDERS", "implicit_transition_matrix", "couplings",
           "critical_step", "first_unstable", "stability_report", "spectral_radii",
           "substep_limit", "assumptions",
           "step_warning",
           "linear_plant", "transition_matrix", "spectral_radius", "scene_transition_matrix",
           "first_crossing", "first_instability", "critical_value", "highest_mode", "sdof_matrix",
           "substep_spectral_radius", "integrator_step_limit", "observed_spectral_radius",
           "hankel_poles", "LinearPlant", "SCHEMES", "Spectra", "observed_verdict"]

#: plant methods whose substep is a fixed linear map on a linear plant
METHODS = ("euler", "symplectic_euler", "rk4", "dopri5", "genalpha", "radau", "exponential")
#: the methods the plant FMU runs with fixed substeps (dopri5 and radau are adaptive in the FMU)
FIXED_STEP_METHODS = ("euler", "symplectic_euler", "rk4", "genalpha", "exponential")
#: the couplings the master offers, data for :func:`couplings`: per ``master.algorithm`` the
#: values of ``master.first`` whose maps differ (another algorithm is one line here, with its map
#: in :func:`transition_matrix`)
COUPLING_ORDERS = {"jacobi": ("controller",), "gauss-seidel": ("controller", "plant"),
                   "implicit": ("controller",)}
ALGORITHMS = tuple(COUPLING_ORDERS)
#: the coupling schemes of the stability map: (label, algorithm, first FMU)
SCHEMES = (("jacobi", "jacobi", "controller"),
           ("gs-controller-first", "gauss-seidel", "controller"),
           ("gs-plant-first", "gauss-seidel", "plant"))

_SNAP = 1e-7          # as plant_fmu.integrators.base: a substep ending this close lands on the end
_EPS = float(np.finfo(float).eps)


# ---------------------------------------------------------------------- explicit tableaus
def _tableau(method):
    """Butcher tableau ``(A, b)`` of the explicit methods (the published coefficients)."""
    if method == "euler":
        return np.zeros((1, 1)), np.ones(1)
    if method == "rk4":
        A = np.zeros((4, 4))
        A[1, 0] = A[2, 1] = 0.5
        A[3, 2] = 1.0
        return A, np.array([1, 2, 2, 1]) / 6.0
    if method == "dopri5":   # Dormand & Prince (1980), 5th-order weights (local extrapolation)
        A = np.zeros((7, 7))
        A[1, :1] = [1 / 5]
        A[2, :2] = [3 / 40, 9 / 40]
        A[3, :3] = [44 / 45, -56 / 15, 32 / 9]
        A[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
        A[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
        b = np.array([35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0])
        A[6, :6] = b[:6]
        return A, b
    raise ValueError(method)


_S6 = math.sqrt(6.0)
#: Radau IIA (3 stages, order 5), Hairer & Wanner II, Table IV.5.6
_A_RADAU = np.array([
    [(88 - 7 * _S6) / 360, (296 - 169 * _S6) / 1800, (-2 + 3 * _S6) / 225],
    [(296 + 169 * _S6) / 1800, (88 + 7 * _S6) / 360, (-2 - 3 * _S6) / 225],
    [(16 - _S6) / 36, (16 + _S6) / 36, 1 / 9]])


def _check_method(method):
    if method not in METHODS:
        raise ValueError(f"method = {method!r} is not a linear fixed-step method; allowed: "
                         f"{', '.join(METHODS)}")


def _augmented(A, B):
    """``[[A, B], [0, 0]]``: the input as a state with zero derivative (held over the step)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    return M


def substep_matrix(method: str, A, B, nq: int, h: float, rho_inf: float = 0.8) -> np.ndarray:
    """One substep ``h`` of ``method`` on ``x' = A x + B u`` (``u`` held), as a matrix on
    ``[x, u]`` (on ``[x, a, qdd, u]`` for ``genalpha``, whose auxiliary acceleration ``a`` and
    acceleration ``qdd`` are carried from substep to substep).

    ``x = [q, qd]`` with ``nq`` positions (the partitioned methods ``symplectic_euler`` and
    ``genalpha`` need it; ``A[:nq] = [0, I]``). ``rho_inf`` is genalpha's spectral radius at
    infinity. Explicit Runge-Kutta methods give the polynomial ``R(hA)`` and its input term.
    """
    _check_method(method)
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    if not (isinstance(h, (int, float)) and h > 0 and math.isfinite(h)):
        raise ValueError(f"h = {h!r}; allowed: a finite number > 0")
    n = A.shape[0]
    M = _augmented(A, B)
    N = M.shape[0]
    I = np.eye(N)
    if method in ("euler", "rk4", "dopri5"):
        a, b = _tableau(method)
        K = []
        for i in range(b.size):
            K.append(M @ (I + h * sum((a[i, j] * K[j] for j in range(i) if a[i, j]),
                                      np.zeros((N, N)))))
        return I + h * sum(bi * Ki for bi, Ki in zip(b, K))
    if method == "exponential":
        return scipy.linalg.expm(M * h)
    if method == "symplectic_euler":
        # qd+ = qd + h qdd(q, qd, u), then q+ = q + h qd+
        S = I + h * M
        S[:nq] = I[:nq] + h * S[nq:n]
        return S
    if method == "radau":
        # collocation: Z_i = h sum_j a_ij M (z + Z_j); z+ = z + Z_3 (stiffly accurate)
        s = 3
        Ms = np.kron(_A_RADAU, h * M)
        Z = np.linalg.solve(np.eye(s * N) - Ms, Ms @ np.tile(I, (s, 1)))
        return I + Z[(s - 1) * N:]
    # genalpha (Arnold & Bruls 2007) on [q, v, a, qdd, u], with the equation of motion
    # qdd_{n+1} = A2 [q_{n+1}; v_{n+1}] + B2 u at the end of the substep
    # Chung & Hulbert's alpha_m, alpha_f, beta, gamma from rho_inf
    g = genalpha_parameters(rho_inf)
    am, af, beta, gamma = g["alpha_m"], g["alpha_f"], g["beta"], g["gamma"]
    A2, B2 = A[nq:], B[nq:]
    nv = n - nq
    q, v = slice(0, nq), slice(nq, n)
    W = n + 2 * nv + B.shape[1]
    ia, iacc, iu = slice(n, n + nv), slice(n + nv, n + 2 * nv), slice(n + 2 * nv, W)
    Iw = np.eye(W)
    # a_{n+1} = ka a_n + kacc qdd_n + ca qdd_{n+1}
    ka, kacc, ca = -am / (1 - am), af / (1 - am), (1 - af) / (1 - am)
    # [q1; v1] = P w + Wx qdd_{n+1}
    P = np.zeros((n, W))
    P[q] = Iw[q] + h * Iw[v] + (h * h * (0.5 - beta) + h * h * beta * ka) * Iw[ia] \
        + h * h * beta * kacc * Iw[iacc]
    P[v] = Iw[v] + (h * (1 - gamma) + h * gamma * ka) * Iw[ia] + h * gamma * kacc * Iw[iacc]
    Wx = np.zeros((n, nv))
    Wx[q] = h * h * beta * ca * np.eye(nv)
    Wx[v] = h * gamma * ca * np.eye(nv)
    # qdd_{n+1} = A2 (P w + Wx qdd_{n+1}) + B2 u
    X = np.linalg.solve(np.eye(nv) - A2 @ Wx, A2 @ P + B2 @ Iw[iu])
    S = np.zeros((W, W))
    S[:n] = P + Wx @ X
    S[ia] = ka * Iw[ia] + kacc * Iw[iacc] + ca * X
    S[iacc] = X
    S[iu] = Iw[iu]
    return S


def _substeps(H: float, h: float):
    """The substeps the plant's fixed-step stepper takes over one communication step ``H``:
    ``[(count, size), ...]`` (whole substeps ``h``, then the shortened one off the grid). A
    count beyond a double (``plant.step`` of 1e-308 against a step of 100 s) is a ConfigError
    naming ``plant.step``."""
    n_grid = H / h
    if not math.isfinite(n_grid):
        raise ConfigError(f"plant.step = {h!r} s is out of range for a communication step of "
                          f"{H!r} s: {H!r} / {h!r} substeps is beyond a double")
    n_round = round(n_grid)
    if n_round >= 1 and abs(n_grid - n_round) <= _SNAP + 4 * _EPS * H / h:
        return [(n_round, h)]
    m = math.floor(n_grid)
    out = [(m, h)] if m else []
    return out + [(1, H - m * h)]


def plant_step_map(method: str, A, B, nq: int, H: float, h: float, rho_inf: float = 0.8):
    """``(Phi, Gamma)``: the plant's state after one communication step ``H`` with the input
    held, ``x(t + H) = Phi x(t) + Gamma u``, as the plant FMU's stepper takes it (substeps ``h``,
    the last one shortened when ``H`` is off the grid). For ``genalpha`` the auxiliary
    accelerations are re-initialised from the equation of motion at the start of the step (the
    stepper's ``reinit_on_input_change``, as the input changes every step)."""
    _check_method(method)
    for name, val in (("H", H), ("h", h)):
        if not (isinstance(val, (int, float)) and val > 0 and math.isfinite(val)):
            raise ValueError(f"{name} = {val!r}; allowed: a finite number > 0")
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    n, m = B.shape
    if method == "genalpha":
        nv = n - nq
        W = n + 2 * nv + m
        # [x, u] -> [x, a, qdd, u] with a = qdd = A2 x + B2 u
        E = np.zeros((W, n + m))
        E[:n, :n] = np.eye(n)
        acc = np.hstack([A[nq:], B[nq:]])
        E[n:n + nv] = acc
        E[n + nv:n + 2 * nv] = acc
        E[n + 2 * nv:, n:] = np.eye(m)
        T = E
        keep = np.r_[0:n, n + 2 * nv:W]
    else:
        T = np.eye(n + m)
        keep = None
    for count, size in _substeps(H, h):
        S = substep_matrix(method, A, B, nq, size, rho_inf)
        T = np.linalg.matrix_power(S, count) @ T
    if keep is not None:
        T = T[keep]
    return T[:n, :n], T[:n, n:]


#: plant methods that evaluate the input polynomial at their stage times (the others, genalpha
#: and exponential, hold its average over the communication step: the FMUs' do_step)
POLYNOMIAL_METHODS = ("euler", "symplectic_euler", "rk4")


def _steps(H, name: str = "H"):
    """``(Hs, scalar)``: a communication step, or a 1-d array of them, as a 1-d float array, and
    whether it was one number; a ValueError naming ``name`` for anything else."""
    try:
        arr = None if isinstance(H, (str, bytes, bool)) else np.asarray(H, dtype=float)
    except (TypeError, ValueError):
        arr = None
    if (arr is None or arr.ndim > 1 or arr.size == 0 or not np.all(np.isfinite(arr))
            or np.any(arr <= 0)):
        raise ValueError(f"{name} = {H!r}; allowed: a finite number > 0 (or a 1-d array of them)")
    return np.atleast_1d(arr), arr.ndim == 0


def _shift(h, m: int) -> np.ndarray:
    """The Taylor coefficients ``[u, u', u'']`` (``m`` inputs each) moved ``h`` ahead: the exact
    flow of the nilpotent dynamics ``u' = u'``, ``u'' ' = 0`` (a stack for an array ``h``)."""
    h = np.asarray(h, dtype=float)
    hb = h[..., None, None]
    I = np.eye(m)
    T = np.broadcast_to(np.eye(3 * m), h.shape + (3 * m, 3 * m)).copy()
    T[..., :m, m:2 * m] = T[..., m:2 * m, 2 * m:] = hb * I
    T[..., :m, 2 * m:] = 0.5 * hb * hb * I
    return T


def _at(s, m: int) -> np.ndarray:
    """The row block evaluating ``u(s) = u + u' s + u'' s^2 / 2`` from ``[u, u', u'']`` (a
    stack for an array ``s``)."""
    s = np.asarray(s, dtype=float)
    sb = s[..., None, None]
    I = np.eye(m)
    return np.concatenate([np.broadcast_to(I, s.shape + (m, m)), sb * I, 0.5 * sb * sb * I],
                          axis=-1)


def _polynomial_substep(method, A, B, nq, h):
    """One substep ``h`` of ``method`` on ``x' = A x + B u(s)`` as a matrix on ``[x, w]``, ``w`` the
    input's Taylor coefficients ``[u, u', u'']`` at the substep's start (moved to its end): the
    Runge-Kutta stages evaluate ``u`` at ``s = c_i h``, symplectic Euler at ``s = 0``. For an
    array ``h``, the stack of those matrices."""
    n, m = B.shape
    N = n + 3 * m
    h = np.asarray(h, dtype=float)
    hb = h[..., None, None]
    X = np.hstack([np.eye(n), np.zeros((n, 3 * m))])          # selects x
    Wsel = np.hstack([np.zeros((3 * m, n)), np.eye(3 * m)])   # selects w
    S = np.zeros(h.shape + (N, N))
    S[..., n:, :] = _shift(h, m) @ Wsel
    if method == "symplectic_euler":
        qd = X[nq:] + hb * (A[nq:] @ X + B[nq:] @ _at(0.0, m) @ Wsel)
        S[..., nq:n, :] = qd
        S[..., :nq, :] = X[:nq] + hb * qd[..., :n - nq, :]
        return S
    a, b = _tableau(method)
    c = a.sum(axis=1)
    K = []
    for i in range(b.size):
        Y = X + hb * sum((a[i, j] * K[j] for j in range(i) if a[i, j]), np.zeros((n, N)))
        K.append(A @ Y + B @ _at(c[i] * h, m) @ Wsel)
    S[..., :n, :] = X + hb * sum(bi * Ki for bi, Ki in zip(b, K))
    return S


def plant_polynomial_step_map(method: str, A, B, nq: int, H, h: float,
                              rho_inf: float = 0.8, cache: dict | None = None):
    """``(Phi, Gamma)``: the plant FMU's state after one communication step ``H`` when its input
    is the polynomial ``u(t + s) = u + u' s + u'' s^2 / 2`` (FMI's input derivatives):
    ``x(t + H) = Phi x(t) + Gamma @ [u, u', u'']`` (``Gamma`` has ``3 m`` columns, the ``m``
    values, then the first and the second derivatives). The methods of
    :data:`POLYNOMIAL_METHODS` evaluate the polynomial at their stage times on the substep grid
    of :func:`plant_step_map`; ``genalpha`` and ``exponential`` hold its average over ``H`` (as
    the plant FMUs do). A held input is ``[u, 0, 0]``. ValueError for a method that is no fixed
    linear map in the FMU (``dopri5``, ``radau``: adaptive there). For a 1-d array ``H``, the
    stacks of the maps, one per step (the whole substep's matrix and its powers computed
    once). ``cache``: a dict the caller keeps between calls, where the substep's matrix and its
    powers are kept for the next call (by method, plant and substep)."""
    if method not in FIXED_STEP_METHODS:
        raise ValueError(f"method = {method!r}: the plant FMU's step is a fixed linear map only "
                         f"for {', '.join(FIXED_STEP_METHODS)} (dopri5 and radau run adaptively "
                         f"in the FMU)")
    Hs, scalar = _steps(H)
    _steps(h, "h")
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    n = A.shape[0]
    if method not in POLYNOMIAL_METHODS:
        maps = [plant_step_map(method, A, B, nq, float(Hk), h, rho_inf) for Hk in Hs]
        Phi = np.stack([m[0] for m in maps])
        G = np.stack([m[1] for m in maps])
        Hb = Hs[:, None, None]
        Gamma = np.concatenate([G, 0.5 * Hb * G, Hb * Hb / 6.0 * G], axis=-1)
    else:
        key = (method, float(h), nq, A.tobytes(), B.tobytes())
        mine = (cache if cache is not None else {}).setdefault(key, {})
        if "S" not in mine:
            mine["S"] = _polynomial_substep(method, A, B, nq, h)
        S, powers = mine["S"], mine.setdefault("powers", {})
        T = np.empty((Hs.size,) + S.shape)
        short, sizes = [], []
        for k, Hk in enumerate(Hs):
            T[k] = np.eye(S.shape[0])
            for count, size in _substeps(float(Hk), h):
                if size == h:
                    if count not in powers:
                        powers[count] = np.linalg.matrix_power(S, count)
                    T[k] = powers[count]
                else:                       # the shortened substep, always the last
                    short.append(k)
                    sizes.append(size)
        if short:
            T[short] = _polynomial_substep(method, A, B, nq, np.array(sizes)) @ T[short]
        Phi, Gamma = T[:, :n, :n], T[:, :n, n:]
    return (Phi[0], Gamma[0]) if scalar else (Phi, Gamma)


def controller_polynomial_step_map(c: ControllerParams, H):
    """``(Ad, G)``: the controller FMU's filter state after one communication step ``H`` when its
    sensors are the polynomials ``y(t + s) = y + y' s + y'' s^2 / 2``: ``xc(t + H) = Ad xc(t) + G
    @ [y, y', y'']`` (``y = [x_o, phi_o, omega_o]``; ``G`` has 9 columns), exact (the filter
    driven by a chain of integrators, one matrix exponential, as
    the model's ``discretize_polynomial`` forms it). Held sensors are ``[y, 0, 0]``. The force is
    ``F_c = C xc + D y`` (the model's, :func:`controller_fmu.spec.model_for`). For
    a 1-d array ``H``, the stacks of the maps, one per step."""
    if not isinstance(c, ControllerParams):
        raise TypeError(f"c must be a ControllerParams, got {type(c).__name__}")
    Hs, scalar = _steps(H)
    ctrl = controller_model(c)
    n = ctrl.nx
    M = np.zeros((n + 3, n + 3))          # the generator per second: [xc, e, e', e'']
    M[:n, :n] = ctrl.Af
    M[:n, n] = ctrl.Bf[:, 0]
    M[n, n + 1] = M[n + 1, n + 2] = 1.0
    E = scipy.linalg.expm(Hs[:, None, None] * M)
    Ad, Ge = E[:, :n, :n], E[:, :n, n:]
    G = np.concatenate([Ge[..., j:j + 1] * ctrl.gains for j in range(3)], axis=-1)
    return (Ad[0], G[0]) if scalar else (Ad, G)


# ---------------------------------------------------------------------- the plant, drift-free
@dataclass(frozen=True)
class LinearPlant:
    """The linearised plant ``(A, B, C)`` (sensors ``x_o, phi_o, omega_o``) with ``nq``
    positions; ``keep`` are the indices of the full state it retains."""
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    nq: int
    keep: np.ndarray


def linear_plant(p: PlantParams, drift_free: bool = True) -> LinearPlant:
    """The plant linearised at the upright rest state; with ``drift_free`` the cart's position
    and velocity are removed when no other state depends on them (always, at the upright state),
    and then ``C``'s ``x_o`` row is zero."""
    if not isinstance(p, PlantParams):
        raise TypeError(f"p must be a PlantParams, got {type(p).__name__}")
    return _linear_plant(p, bool(drift_free))


@functools.lru_cache(maxsize=64)
def _linear_plant(p: PlantParams, drift_free: bool) -> LinearPlant:
    A, B, C, _ = plant_model(p).state_space()
    nq = p.n_modes + 2
    keep = np.arange(A.shape[0])
    if drift_free:
        drift = [0, nq]
        rest = np.array([i for i in keep if i not in drift])
        if not np.any(A[np.ix_(rest, drift)] != 0.0):
            A, B, C = A[np.ix_(rest, rest)], B[rest], C[:, rest]
            keep, nq = rest, nq - 1
    return LinearPlant(A, B, C, nq, keep)


# ---------------------------------------------------------------------- the macro step
def _taylor_of_samples(nodes, H) -> np.ndarray:
    """``W`` (3 x s): the Taylor coefficients ``[u, u', u'']`` at ``t_k`` (derivatives in
    seconds) of the polynomial through ``s`` samples at ``nodes`` (in steps from ``t_k``, newest
    first) are ``W @ samples``; the coefficients beyond its degree are 0. For ``H`` an array of
    shape ``(K, 1, 1)`` (a batch of steps), the weights are a list of three lists of ``s``
    weights, each a number (independent of the step) or an array of that shape."""
    s = len(nodes)
    M = np.array([[float(t) ** j / math.factorial(j) for j in range(s)] for t in nodes])
    W = np.zeros((3, s))
    W[:s] = np.linalg.inv(M)[:3]
    if np.ndim(H) == 0:
        return W / (H ** np.arange(3.0))[:, None]
    return [[float(W[i, j]) if i == 0 or W[i, j] == 0 else W[i, j] / H ** i for j in range(s)]
            for i in range(3)]


def _taylor_moved(q: int, delta) -> list:
    """The weights (3 x q+1, as :func:`_taylor_of_samples`' for a batch) giving the Taylor
    coefficients at ``t_k`` from the value and ``q`` derivatives at ``t_k + delta`` (seconds, a
    number or a batch of them), the polynomial of degree ``q`` (output derivatives)."""
    W = [[0.0] * (q + 1) for _ in range(3)]
    for i in range(min(3, q + 1)):
        for j in range(i, q + 1):
            W[i][j] = 1.0 if j == i else (-delta) ** (j - i) / math.factorial(j - i)
    return W


def _dot(w, rows):
    """``sum w_i rows_i`` over the weights that are not the number 0 (a weight may be an array
    of shape ``(K, 1, 1)``, a row block ``(r, N)`` or ``(K, r, N)``)."""
    out = None
    for wi, r in zip(w, rows):
        if np.ndim(wi) == 0 and wi == 0:
            continue
        out = wi * r if out is None else out + wi * r
    return np.zeros_like(rows[0]) if out is None else out


def _check_scheme(algorithm, first, extrapolation):
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm = {algorithm!r}; allowed: {', '.join(ALGORITHMS)}")
    if first not in ("controller", "plant"):
        raise ValueError(f"first = {first!r}; allowed: controller, plant")
    if extrapolation not in (0, 1, 2) or isinstance(extrapolation, bool):
        raise ValueError(f"extrapolation = {extrapolation!r}; allowed: 0, 1, 2")


def _batched(maps, K: int, name: str):
    """A step map ``(M, G)`` as stacks of ``K`` (a single map is the map of one step)."""
    M, G = (np.asarray(a, dtype=float) for a in maps)
    if M.ndim == 2:
        M, G = M[None], G[None]
    if M.shape[0] != K or G.shape[0] != K:
        raise ValueError(f"{name} holds {M.shape[0]} maps for {K} steps; allowed: one per step")
    return M, G


def _step_maps(p, c, Hs, extrapolation, input_derivatives, integrator, substep, drift_free,
               step_index, plant_map, controller_map=None):
    """What :func:`transition_matrix` and :func:`implicit_transition_matrix` share for the steps
    ``Hs`` (a 1-d array): ``step_index`` checked, the linear plant, the input derivative orders
    the FMUs take, the plant's step maps for a polynomial input (a held-input ``plant_map``
    padded) and the filter's, stacked over the steps: ``(plant, n_der, (Pp, Gp), (Ad, Gc))``."""
    if step_index is not None and (not isinstance(step_index, int) or step_index < 0):
        raise ValueError(f"step_index = {step_index!r}; allowed: None or an integer >= 0")
    n_der = min(extrapolation, 2) if input_derivatives else 0
    plant = linear_plant(p, drift_free=drift_free and c.kx == 0.0)
    if plant_map is None:
        plant_map = plant_polynomial_step_map(integrator, plant.A, plant.B, plant.nq, Hs, substep)
    Pp, Gp = _batched(plant_map, Hs.size, "plant_map")
    if Gp.shape[-1] == 1:            # a held-input map
        if n_der:
            raise ValueError("plant_map is a held-input map (plant_step_map); input derivatives "
                             "need plant_polynomial_step_map's")
        Gp = np.concatenate([Gp, np.zeros(Gp.shape[:-1] + (2,))], axis=-1)
    if controller_map is None:
        controller_map = controller_polynomial_step_map(c, Hs)
    return plant, n_der, (Pp, Gp), _batched(controller_map, Hs.size, "controller_map")


def transition_matrix(p: PlantParams, c: ControllerParams, H, *,
                      algorithm: str = "gauss-seidel", first: str = "controller",
                      extrapolation: int = 0, input_derivatives: bool = False,
                      output_derivatives: bool = False, integrator: str = "rk4",
                      substep: float = 2.5e-4, drift_free: bool = True,
                      step_index: int | None = None, plant_map=None, controller_map=None,
                      coupling: str = "polynomial", _predictor: bool = False) -> np.ndarray:
    """``Phi`` with ``z_{k+1} = Phi z_k`` for one communication step ``H`` of the master.

    ``z = [x, xc, y_k .. y_k-p, F_k .. F_k-p]`` (``x`` without the cart's position and velocity
    when ``drift_free`` and ``kx = 0``); with ``output_derivatives`` the registers are the
    newest samples and their ``p`` time derivatives instead, ``[y_k, y'_k .., F_k, F'_k ..]``.
    ``input_derivatives``: the FMUs get the polynomial's value and derivatives at ``t_k`` (orders
    up to ``min(p, 2)``) instead of its held step average. ``step_index = k`` gives the map of the
    ``k``-th step, when fewer than ``p + 1`` samples exist (``None``: the steady map).
    ``plant_map`` may pass a precomputed :func:`plant_polynomial_step_map` for the same plant
    and ``H`` (or :func:`plant_step_map`'s, for held inputs only), ``controller_map`` a
    precomputed :func:`controller_polynomial_step_map`.

    ``H`` may be a 1-d array of steps: then the stack of their matrices, ``(len(H), N, N)``
    (the maps passed, if any, stacked alike).

    With extrapolation from past samples (``p >= 1``, no output derivatives) the master predicts
    the first step with held inputs, rolls it back and takes it again with the inputs
    interpolated between ``t_0`` and the predicted samples at ``t_1``
    (:meth:`orchestration.cosim.master.Master._startup_step`); ``step_index = 0`` gives that
    corrected map.

    ``coupling = "hermite"`` (Gauss-Seidel; ``extrapolation``, ``input_derivatives`` and
    ``output_derivatives`` do not apply): the Hermite coupling of
    :class:`~orchestration.cosim.coupling.Coupling`, whose registers are the newest samples with
    every derivative the FMUs give, ``z = [x, xc, y_k and its first two derivatives, F_k
    and its first four]``
    (:func:`_hermite_matrix`); it has no start-up step: every step has the same map.
    """
    if not isinstance(c, ControllerParams):
        raise TypeError(f"c must be a ControllerParams, got {type(c).__name__}")
    _check_scheme(algorithm, first, extrapolation)
    Hs, scalar = _steps(H)
    if coupling not in ("polynomial", "hermite"):
        raise ValueError(f"coupling = {coupling!r}; allowed: polynomial, hermite")
    if coupling == "hermite":
        if algorithm != "gauss-seidel":
            raise ValueError(f"coupling = 'hermite' is a Gauss-Seidel coupling; algorithm = "
                             f"{algorithm!r} is not allowed with it")
        if integrator not in FIXED_STEP_METHODS:
            raise ValueError(f"integrator = {integrator!r}: the plant FMU's substeps are a fixed "
                             f"linear map only for {', '.join(FIXED_STEP_METHODS)}")
        maps = _step_maps(p, c, Hs, 2, True, integrator, substep, drift_free, None, plant_map,
                          controller_map)
        Phi = _hermite_matrix(c, Hs, maps, first, integrator)
        return Phi[0] if scalar else Phi
    if algorithm == "implicit":
        if output_derivatives:
            raise ValueError("output_derivatives = True: the implicit master interpolates "
                             "between the step's samples; allowed: False")
        return implicit_transition_matrix(p, c, H, extrapolation=extrapolation,
                                          input_derivatives=input_derivatives,
                                          integrator=integrator, substep=substep,
                                          drift_free=drift_free, step_index=step_index,
                                          plant_map=plant_map, controller_map=controller_map)
    if integrator not in FIXED_STEP_METHODS:
        raise ValueError(f"integrator = {integrator!r}: the plant FMU's substeps are a fixed "
                         f"linear map only for {', '.join(FIXED_STEP_METHODS)} (dopri5 and radau "
                         f"run adaptively in the FMU)")
    if output_derivatives and not (input_derivatives and extrapolation >= 1):
        raise ValueError("output_derivatives = True needs input_derivatives = True and "
                         "extrapolation >= 1 (as master.output_derivatives)")
    maps = _step_maps(p, c, Hs, extrapolation, input_derivatives, integrator, substep,
                      drift_free, step_index, plant_map, controller_map)
    Phi = _explicit_matrix(p, c, Hs, maps, algorithm, first, extrapolation, output_derivatives,
                           integrator, step_index, _predictor)
    return Phi[0] if scalar else Phi


def _explicit_matrix(p, c, Hs, maps, algorithm, first, extrapolation, output_derivatives,
                     integrator, step_index, predictor):
    """:func:`transition_matrix` of an explicit coupling for the steps ``Hs`` (a 1-d array) and
    their maps (:func:`_step_maps`): the stack ``(K, N, N)``."""
    taylor = bool(output_derivatives)
    plant, n_der, (Pp, Gp), (Ad, Gc) = maps
    ctrl = controller_model(c)
    Ac, Bc, Cc, Dc = ctrl.state_space()                  # F = Cc xc + Dc y
    C = plant.C
    nx, nc, ny, P = Pp.shape[-1], ctrl.nx, C.shape[0], extrapolation + 1
    K = Hs.size
    H = Hs[:, None, None]           # the steps, broadcast against (K, rows, N) row blocks
    # state layout
    ix = slice(0, nx)
    ic = slice(nx, nx + nc)
    iy = [slice(nx + nc + j * ny, nx + nc + (j + 1) * ny) for j in range(P)]
    o = nx + nc + P * ny
    iF = [slice(o + j, o + j + 1) for j in range(P)]
    N = o + P
    I = np.eye(N)
    k = math.inf if step_index is None or taylor else step_index
    s_old = int(min(P, k + 1))      # samples up to t_k
    s_new = int(min(P, k + 2))      # samples up to t_k+1 (the second FMU of Gauss-Seidel)
    Y = [I[s] for s in iy]          # the registers: y_k, y_k-1, ... (or y_k, y'_k, ...)
    F = [I[s] for s in iF]
    x, xc = I[ix], I[ic]
    avg = [1.0, H / 2, H * H / 6]   # the step average of the Taylor polynomial
    end = [1.0, H, H * H / 2]       # its value at t_k+1

    def coefficients(rows, newest=False):
        """The Taylor coefficients at ``t_k`` (three row blocks) of the polynomial through the
        registers ``rows`` (newest first); ``newest``: ``rows[0]`` is the new sample at t_k+1."""
        if taylor:
            W = _taylor_moved(P - 1, H if newest else 0.0)
        else:
            W = _taylor_of_samples([j + (1 if newest else 0) for j in range(0, -len(rows), -1)],
                                   H)
        return [_dot(W[i], rows) for i in range(3)]

    def fmu_input(a):
        """What the FMU gets over the step, as Taylor coefficients at t_k: the held average, or
        the value and ``n_der`` derivatives."""
        if not n_der:
            return [_dot(avg, a), 0 * a[0], 0 * a[0]]
        return [a[j] if j <= n_der else 0 * a[0] for j in range(3)]

    def plant_step(a):
        x1, ys = _plant_sample(plant, Pp, Gp, x, fmu_input(a), H, integrator)
        return x1, ys[:P if taylor else 1]

    def ctrl_step(a):
        u = fmu_input(a)
        xc1 = Ad @ xc + sum(Gc[..., 3 * j:3 * j + 3] @ u[j] for j in range(3))
        # the force at t_k+1: the sensors moved to their polynomial's value there
        out = [Cc @ xc1 + Dc @ _dot(end, a)]
        if taylor:     # the FMU's derivatives: its step's input polynomial at the step's end
            ye, dye, d2ye = _dot(end, u), u[1] + H * u[2], u[2]
            d1 = Ac @ xc1 + Bc @ ye
            out += [Cc @ d1 + Dc @ dye, Cc @ (Ac @ d1 + Bc @ dye) + Dc @ d2ye][:P - 1]
        return xc1, out

    if step_index == 0 and P >= 2 and not taylor and not predictor:
        # the corrected first step: the predicted samples at t_1 (the map of the held step) stand
        # in for the newest samples; the first FMU interpolates through them and t_0
        Mp = _explicit_matrix(p, c, Hs, maps, algorithm, first, extrapolation,
                              output_derivatives, integrator, 0, True)
        Yold, Fold = [Mp[:, iy[0]], Y[0]], [Mp[:, iF[0]], F[0]]
        old = dict(newest=True)
        s_new = 2
    else:
        Yold, Fold, old = Y[:s_old], F[:s_old], {}

    if algorithm == "jacobi":
        x1, ys = plant_step(coefficients(Fold, **old))
        xc1, Fs = ctrl_step(coefficients(Yold, **old))
    elif first == "controller":
        xc1, Fs = ctrl_step(coefficients(Yold, **old))
        # the second FMU: through the first FMU's new sample at t_1 (which replaces a predicted
        # one)
        x1, ys = plant_step(coefficients(Fs if taylor else [Fs[0]] + F[:s_new - 1],
                                         newest=True))
    else:
        x1, ys = plant_step(coefficients(Fold, **old))
        xc1, Fs = ctrl_step(coefficients(ys if taylor else [ys[0]] + Y[:s_new - 1],
                                         newest=True))
    Phi = np.zeros((K, N, N))
    Phi[:, ix] = x1
    Phi[:, ic] = xc1
    if taylor:
        for j in range(P):
            Phi[:, iy[j]] = ys[j]
            Phi[:, iF[j]] = Fs[j]
    else:
        Phi[:, iy[0]] = ys[0]
        Phi[:, iF[0]] = Fs[0]
        for j in range(1, P):
            Phi[:, iy[j]] = Y[j - 1]
            Phi[:, iF[j]] = F[j - 1]
    return Phi


#: the output derivative orders the Hermite coupling reads: the plant FMU's and the controller's
#: (plant_fmu.interface and controller_fmu.interface's MAX_OUTPUT_DERIVATIVE_ORDER)
HERMITE_ORDERS = {"plant": 2, "controller": 4}


def _hermite_matrix(c, Hs, maps, first, integrator):
    """:func:`transition_matrix` of the Hermite coupling (``Coupling.hermite``) for the steps
    ``Hs`` and their maps (:func:`_step_maps` with input derivatives of order 2): the stack ``(K,
    N, N)``. The FMU that steps first gets its source's Taylor polynomial at ``t_k`` (the
    registers), the second the Hermite polynomial through its source's registers and new sample
    at ``t_k+1``; each as its least-squares quadratic over the step
    (:func:`~orchestration.cosim.coupling.hermite_rows`). The plant's new sample: its outputs and
    their derivatives with its step polynomial's value and rate at the step's end (the plant FMU's
    output derivatives after a step). The controller's: ``F`` and four derivatives of the filter
    driven by the sensors' value and two rates at ``t_k+1`` (their third derivative 0): the
    plant's new sample when the plant stepped first (the master sets them), else the controller's
    own step polynomial at its end."""
    from ..cosim.coupling import hermite_rows
    plant, _, (Pp, Gp), (Ad, Gc) = maps
    ctrl = controller_model(c)
    Ac, Bc, Cc, Dc = ctrl.state_space()                  # F = Cc xc + Dc y
    C = plant.C
    qy, qF = HERMITE_ORDERS["plant"], HERMITE_ORDERS["controller"]
    nx, nc, ny = Pp.shape[-1], ctrl.nx, C.shape[0]
    K = Hs.size
    H = Hs[:, None, None]
    ix, ic = slice(0, nx), slice(nx, nx + nc)
    iy = [slice(nx + nc + j * ny, nx + nc + (j + 1) * ny) for j in range(qy + 1)]
    o = nx + nc + (qy + 1) * ny
    iF = [slice(o + j, o + j + 1) for j in range(qF + 1)]
    N = o + qF + 1
    I = np.eye(N)
    Y, F = [I[s] for s in iy], [I[s] for s in iF]
    x, xc = I[ix], I[ic]
    end = [1.0, H, H * H / 2]       # a quadratic's value at t_k+1 from its Taylor coefficients

    def held(q, rows):
        """The least-squares quadratic over the step (value and two derivatives at t_k) of the
        Taylor polynomial of ``rows`` (q + 1 blocks) or of the Hermite polynomial of ``rows``
        (2 (q + 1) blocks: t_k's, then t_k+1's)."""
        W = np.stack([hermite_rows(q, len(rows) > q + 1, float(h)) for h in Hs])
        return [_dot([W[:, r, j][:, None, None] for j in range(len(rows))], rows)
                for r in (1, 2, 3)]

    def plant_step(u):
        return _plant_sample(plant, Pp, Gp, x, u, H, integrator)

    def ctrl_step(u):
        return Ad @ xc + sum(Gc[..., 3 * j:3 * j + 3] @ u[j] for j in range(3))

    def ctrl_sample(xc1, ys):
        """F and its derivatives: v_j = xc^(j) = Ac v_j-1 + Bc y^(j-1), F^(j) = Cc v_j + Dc
        y^(j), the sensors' derivatives beyond the second 0."""
        v, out = xc1, []
        for j in range(qF + 1):
            yj = ys[j] if j < len(ys) else None
            out.append(Cc @ v + (Dc @ yj if yj is not None else 0 * (Cc @ v)))
            if j < qF:
                v = Ac @ v + (Bc @ yj if yj is not None else 0 * v)
        return out

    if first == "plant":
        x1, ys = plant_step(held(qF, F))
        xc1 = ctrl_step(held(qy, Y + ys))
        Fs = ctrl_sample(xc1, ys)
    else:
        u = held(qy, Y)
        xc1 = ctrl_step(u)
        Fs = ctrl_sample(xc1, [_dot(end, u), u[1] + H * u[2], u[2]])
        x1, ys = plant_step(held(qF, F + Fs))
    Phi = np.zeros((K, N, N))
    Phi[:, ix] = x1
    Phi[:, ic] = xc1
    for j in range(qy + 1):
        Phi[:, iy[j]] = ys[j]
    for j in range(qF + 1):
        Phi[:, iF[j]] = Fs[j]
    return Phi


def _plant_sample(plant, Pp, Gp, x, u, H, integrator):
    """The plant FMU's step from the state rows ``x`` with the input polynomial ``u`` (its Taylor
    coefficients at ``t_k``, three row blocks) and its new sample: ``(x1, [y, y', y''])``, the
    outputs' derivatives with the stepper's input at ``t_k+1`` (the plant FMU's output
    derivatives after a step); a method that holds its input's average holds it there too."""
    A, B, C = plant.A, plant.B, plant.C
    x1 = Pp @ x + sum(Gp[..., j:j + 1] @ u[j] for j in range(3))
    if integrator not in POLYNOMIAL_METHODS:           # the FMU holds the average
        u = [_dot([1.0, H / 2, H * H / 6], u), 0 * u[0], 0 * u[0]]
    ue, due = _dot([1.0, H, H * H / 2], u), u[1] + H * u[2]   # the stepper's input at t_k+1
    d1 = A @ x1 + B @ ue
    return x1, [C @ x1, C @ d1, C @ (A @ d1 + B @ due)]


def spectral_radius(M: np.ndarray) -> float:
    """``max |eig(M)|``."""
    return float(np.max(np.abs(np.linalg.eigvals(M)))) if M.size else 0.0


def spectral_radii(M: np.ndarray) -> np.ndarray:
    """``max |eig(M_k)|`` of each matrix of the stack ``M`` (shape ``(K, N, N)``)."""
    M = np.asarray(M, dtype=float)
    if not M.shape[-1]:
        return np.zeros(M.shape[0])
    return np.max(np.abs(np.linalg.eigvals(M)), axis=-1)


def scene_transition_matrix(scene, H: float | None = None, step_index=None, drift_free=True):
    """:func:`transition_matrix` for a scene's plant, controller and master (its step and
    coupling, :func:`scene_coupling`; the plant's integrator and substep)."""
    m = scene.master
    return transition_matrix(linearisation(scene).params, scene.controller,
                             m.step if H is None else H,
                             **scene_coupling(scene), integrator=scene.plant.integrator,
                             substep=scene.plant.step, drift_free=drift_free,
                             step_index=step_index)


def scene_coupling(scene) -> dict:
    """The scene's coupling as :func:`transition_matrix`'s keywords (``algorithm``, ``first``,
    ``extrapolation``, ``input_derivatives``, ``output_derivatives``, ``coupling``); a ValueError
    for a master that has no transition matrix (adaptive, or Model Exchange); the Hermite
    coupling's are :func:`hermite_coupling`'s."""
    m = scene.master
    if m.adaptive:
        raise ValueError("master.adaptive = true: an adaptive master has no fixed transition "
                         "matrix; allowed: false")
    if m.interface != "co-simulation":
        raise ValueError(f"master.interface = {m.interface!r} integrates the plant and the "
                         "controller as one system: no communication step to predict; allowed: "
                         "'co-simulation'")
    if m.coupling == "hermite":
        return hermite_coupling(m.first)
    return {"algorithm": m.algorithm, "first": m.first, "extrapolation": m.extrapolation,
            "input_derivatives": m.input_derivatives and m.extrapolation >= 1,
            "output_derivatives": m.output_derivatives, "coupling": "polynomial"}


# ---------------------------------------------------------------------- boundaries
def first_crossing(f, grid, level: float = 1.0, xtol_rel: float = 1e-6):
    """The first ``x`` of the increasing ``grid`` where ``f(x) - level`` changes sign from
    negative to positive, refined by Brent's method; ``None`` if it never does on the grid."""
    grid = np.asarray(grid, dtype=float)
    prev = None
    for xv in grid:
        v = f(float(xv)) - level
        if prev is not None and prev[1] < 0 <= v:
            a, b = prev[0], float(xv)
            return float(scipy.optimize.brentq(lambda s: f(s) - level, a, b,
                                               xtol=xtol_rel * a, rtol=4 * _EPS))
        prev = (float(xv), v)
    return None


def first_instability(f, grid, level: float = 1.0, xtol_rel: float = 1e-6):
    """The first ``x`` where ``f`` reaches ``level``, ``f`` evaluated on the increasing ``grid``
    up to the first point at or above ``level``, and also inside a window between grid points:
    at every discrete local maximum of ``f`` before that point, ``f`` is maximised on the two
    intervals beside it (bounded Brent); the first window found, or else the grid's crossing,
    is refined by Brent's method. ``None`` if ``f`` stays below ``level``. A window whose bump
    is narrower than the grid's spacing is not seen."""
    grid = np.asarray(grid, dtype=float)
    vals = []
    for xv in grid:
        vals.append(f(float(xv)))
        if vals[-1] >= level:
            break
    crossed = vals[-1] >= level

    def refine(a, b):
        return float(scipy.optimize.brentq(lambda s: f(s) - level, a, b, xtol=xtol_rel * a,
                                           rtol=4 * _EPS))

    for i in range(1, len(vals) - 1):
        if vals[i] >= vals[i - 1] and vals[i] >= vals[i + 1]:
            a, b = float(grid[i - 1]), float(grid[i + 1])
            top = scipy.optimize.minimize_scalar(lambda s: -f(s), bounds=(a, b),
                                                 method="bounded",
                                                 options={"xatol": xtol_rel * a})
            if -top.fun >= level:
                return refine(a, float(top.x))
    if crossed and len(vals) >= 2:
        return refine(float(grid[len(vals) - 2]), float(grid[len(vals) - 1]))
    return None


def critical_value(f, lo: float, hi: float, n: int = 60, level: float = 1.0):
    """The first crossing of ``f = level`` (from below) on a log grid of ``n`` points in
    ``[lo, hi]``, refined; ``None`` if none."""
    if not (0 < lo < hi):
        raise ValueError(f"need 0 < lo < hi, got lo = {lo!r}, hi = {hi!r}")
    return first_crossing(f, np.geomspace(lo, hi, n), level)


# ---------------------------------------------------------------------- integrator limits
def highest_mode(p: PlantParams) -> complex:
    """The eigenvalue (upper half-plane) of the linearised plant with the largest modulus."""
    A = plant_model(p).state_space()[0]
    lam = np.linalg.eigvals(A)
    lam = lam[lam.imag >= 0]
    return complex(lam[np.argmax(np.abs(lam))])


def sdof_matrix(lam: complex):
    """``(A, B, nq)`` of the single oscillator ``q'' + 2 zeta w q' + w^2 q = u`` whose
    eigenvalues are ``lam`` and its conjugate (``w = |lam|``, ``zeta = -Re lam / |lam|``)."""
    w = abs(lam)
    zeta = -lam.real / w
    A = np.array([[0.0, 1.0], [-w * w, -2.0 * zeta * w]])
    return A, np.array([[0.0], [1.0]]), 1


def substep_spectral_radius(method: str, lam: complex, h: float, rho_inf: float = 0.8) -> float:
    """The spectral radius of one substep of ``method`` on the oscillator with eigenvalues
    ``lam``, ``conj(lam)`` and the input held at zero: the method's stability function there
    (``|R(h lam)|`` for a Runge-Kutta method)."""
    A, B, nq = sdof_matrix(lam)
    S = substep_matrix(method, A, B, nq, h, rho_inf)
    return spectral_radius(S[:-1, :-1])      # without the (held) input


def integrator_step_limit(method: str, lam: complex, h_max: float = 10.0, rho_inf: float = 0.8):
    """The largest substep for which ``method`` is stable on the mode ``lam`` (the first ``h``
    where :func:`substep_spectral_radius` exceeds 1, on a grid ``h |lam|`` in ``[1e-4, h_max]``,
    refined); ``None`` when it is stable on the whole range (A-stable methods), 0 when it is
    unstable already at ``h |lam| = 1e-4``."""
    w = abs(lam)
    f = lambda h: substep_spectral_radius(method, lam, h, rho_inf)  # noqa: E731
    level = 1.0 + 1e-12    # |R| = 1 to rounding on an undamped mode is marginal, not unstable
    if f(1e-4 / w) > level:
        return 0.0          # unstable at every step (explicit Euler on an undamped mode)
    return critical_value(f, 1e-4 / w, h_max / w, n=200, level=level)


# ---------------------------------------------------------------------- observation
def hankel_poles(signals, rows: int | None = None, rtol: float = 1e-8):
    """Poles per sample of the multichannel signal ``signals`` (shape ``(N, m)``), by the
    eigensystem realisation of its block-Hankel matrix (Kung's method): the order is the number
    of singular values above ``rtol`` times the largest, the poles the eigenvalues of the
    shift-invariant observability matrix. Exact for the samples of a linear system whose order is
    below ``rows * m``. Each channel is scaled by its RMS first."""
    Y = np.asarray(signals, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    N, m = Y.shape
    scale = np.sqrt(np.mean(Y * Y, axis=0))
    Y = Y[:, scale > 0] / scale[scale > 0]
    m = Y.shape[1]
    if m == 0:
        raise ValueError("signals are all zero: nothing to observe")
    if rows is None:
        rows = max(2, N // 3)
    cols = N - rows + 1
    if cols < 2 or rows < 2:
        raise ValueError(f"{N} samples are too few for {rows} block rows")
    Hk = np.empty((rows * m, cols))
    for i in range(rows):
        Hk[i * m:(i + 1) * m] = Y[i:i + cols].T
    U, sv, _ = np.linalg.svd(Hk, full_matrices=False)
    r = int(np.sum(sv > rtol * sv[0]))
    r = min(r, (rows - 1) * m)
    O = U[:, :r] * np.sqrt(sv[:r])
    Ad = np.linalg.lstsq(O[:-m], O[m:], rcond=None)[0]
    return np.linalg.eigvals(Ad)


def observed_spectral_radius(signals, rows: int | None = None, rtol: float = 1e-8) -> float:
    """``max |pole|`` of :func:`hankel_poles`: the growth factor per sample of the slowest
    decaying (or fastest growing) mode the samples show."""
    return float(np.max(np.abs(hankel_poles(signals, rows, rtol))))


# ---------------------------------------------------------------------- the scan's spectra
#: steps evaluated at once by :class:`Spectra` (bounds the stacks' memory)
_CHUNK = 512
#: eigenvalues of at least this modulus are watched for collisions on the real axis
#: (:func:`~orchestration.studies.stability_intervals.scan`)
NEAR_CIRCLE = _iv.NEAR_CIRCLE


class Spectra:
    """The spectra of every coupling in ``couplings`` (:func:`transition_matrix`'s keywords)
    for the plant ``p``, controller ``c`` and the plant FMU's ``integrator`` and ``substep``.
    ``self(H, which)``: ``rho`` (:meth:`spectra`). The step maps of a call are formed once for
    all its steps and couplings; the plant substep's matrix and powers once for all calls."""

    def __init__(self, p, c, couplings, *, integrator: str = "rk4", substep: float = 2.5e-4):
        _check_method(integrator)
        self.p, self.c, self.couplings = p, c, [dict(k) for k in couplings]
        self.integrator, self.substep = integrator, substep
        self.plant = linear_plant(p, drift_free=c.kx == 0.0)
        self.evaluations = 0
        self._powers = {}

    def maps(self, Hs):
        pl = self.plant
        return (plant_polynomial_step_map(self.integrator, pl.A, pl.B, pl.nq, Hs, self.substep,
                                          cache=self._powers),
                controller_polynomial_step_map(self.c, Hs))

    def __call__(self, H, which=None) -> np.ndarray:
        return self.spectra(H, which)[0]

    def spectra(self, H, which=None):
        """``(rho, gap)``: the spectral radius and, of the eigenvalues of modulus above
        :data:`NEAR_CIRCLE`, the smallest ``|Im lambda| / |lambda|`` (how near one is to the
        real axis, where a complex pair collides and splits; ``inf``: none is that large).
        ``which``: ``None``, every coupling at every step (arrays ``(len(couplings),
        len(H))``); a coupling's index, its row; an array of indices as long as ``H``, the
        coupling of each step (1-d arrays)."""
        Hs, _ = _steps(H)
        if which is None:
            idx = np.repeat(np.arange(len(self.couplings)), Hs.size)
            steps = np.tile(Hs, len(self.couplings))
        else:
            idx = np.broadcast_to(np.asarray(which, dtype=int), Hs.shape)
            steps = Hs
        rho, gap = np.empty(steps.size), np.empty(steps.size)
        uniq, back = np.unique(steps, return_inverse=True)
        for a in range(0, uniq.size, _CHUNK):
            part = uniq[a:a + _CHUNK]
            pm, cm = self.maps(part)
            sel = np.flatnonzero((back >= a) & (back < a + _CHUNK))
            for i in np.unique(idx[sel]):
                mine = sel[idx[sel] == i]
                at = back[mine] - a
                M = transition_matrix(self.p, self.c, part[at], integrator=self.integrator,
                                      substep=self.substep, plant_map=(pm[0][at], pm[1][at]),
                                      controller_map=(cm[0][at], cm[1][at]),
                                      **self.couplings[i])
                ev = np.linalg.eigvals(_deflated(M))
                mod = np.abs(ev)
                rho[mine] = mod.max(axis=1) if mod.shape[1] else 0.0
                near = np.abs(ev.imag) / np.where(mod > NEAR_CIRCLE, mod, np.nan)
                gap[mine] = np.min(np.where(np.isnan(near), np.inf, near), axis=1,
                                   initial=np.inf)
        self.evaluations += steps.size
        if which is None:
            shape = (len(self.couplings), Hs.size)
            return rho.reshape(shape), gap.reshape(shape)
        return rho, gap


def _deflated(M) -> np.ndarray:
    """The stack ``M`` without the states whose row or column is zero in every matrix of it
    (repeatedly): such a state only adds an eigenvalue 0 (the determinant of ``lambda I - M``
    expanded along that row or column is ``lambda`` times the rest's). The registers of a
    sensor nothing reads (``x_o`` when ``kx = 0``), the implicit master's unused oldest sample."""
    keep = np.arange(M.shape[-1])
    while keep.size:
        S = M[:, keep[:, None], keep]
        zero = np.all(S == 0, axis=(0, 2)) | np.all(S == 0, axis=(0, 1))
        if not zero.any():
            return S
        keep = keep[~zero]
    return M[:, :0, :0]


def observed_verdict(samples, stopped: bool = False, window: int | None = None):
    """How a co-simulation from a small initial state ended, from its exchanged outputs sampled
    once per communication step (``samples``, ``(N, m)``: e.g. ``phi_o, omega_o, F_c``):
    ``(verdict, ratio, factor)``. ``ratio``: the largest, over the channels, of the amplitude
    over the last ``window`` samples (default ``max(60, N // 5)``) divided by that channel's
    over the first ``window``; ``factor``: the growth per step fitted on the last window (the
    largest pole of its eigensystem realisation, :func:`observed_spectral_radius`; NaN if the
    run stopped).

    ``"falls"``: the run stopped (the plant FMU refused to go on: the pendulum fell, or its
    state was no longer finite); ``"grows"``: ``ratio > GROWN`` (1: it ended larger than it
    began; a growth, which the nonlinear plant may end in a limit cycle), or, when the amplitude
    decides nothing (``SETTLED < ratio <= GROWN``, ``SETTLED = 0.01``: a slow growth not yet
    above the decaying modes, or a slow decay), ``factor > 1``; ``"settles"``: ``ratio <=
    SETTLED``, or undecided and ``factor < 1`` (``GROWN``, ``SETTLED``:
    :mod:`~orchestration.studies.stability_intervals`). Nothing depends on how long the run
    took."""
    Y = np.asarray(samples, dtype=float)
    Y = Y[:, None] if Y.ndim == 1 else Y
    if stopped or not np.all(np.isfinite(Y)):
        return "falls", math.inf, math.nan
    W = window or max(60, Y.shape[0] // 5)
    if Y.shape[0] < 2 * W:
        raise ValueError(f"{Y.shape[0]} samples are too few for two windows of {W}")
    early = np.max(np.abs(Y[:W]), axis=0)
    use = early > 0
    ratio = float(np.max(np.max(np.abs(Y[-W:, use]), axis=0) / early[use]))
    factor = observed_spectral_radius(Y[-W:], rtol=1e-6)
    if ratio > _iv.GROWN:
        return "grows", ratio, factor
    if ratio <= _iv.SETTLED:
        return "settles", ratio, factor
    return ("grows" if factor > 1.0 else "settles"), ratio, factor


# ---------------------------------------------------------------------- every coupling of a scene
#: the range of communication steps :func:`critical_step` searches by default (s); its lower
#: end is the scan's smallest step
STEP_RANGE = (_iv.MIN_STEP, 1.0)
#: grid points per decade of the scans (:mod:`~orchestration.studies.stability_intervals`)
GRID_PER_DECADE = _iv.GRID_PER_DECADE


def hermite_coupling(first: str) -> dict:
    """The Hermite coupling (``master.coupling = "hermite"``) as :func:`transition_matrix`'s
    keywords: Gauss-Seidel, ``first`` first; the polynomial coupling's keys say what it reads
    (the value and two derivatives it passes, the output derivatives)."""
    return {"algorithm": "gauss-seidel", "first": first, "extrapolation": 2,
            "input_derivatives": True, "output_derivatives": True, "coupling": "hermite"}


def couplings(master) -> list[dict]:
    """Every coupling the master offers for ``master`` (a
    :class:`~orchestration.scene.records.MasterSettings`: its FMUs decide whether output
    derivatives are offered): :func:`transition_matrix`'s keywords, each allowed by
    ``MasterSettings``' rules (input derivatives only with a polynomial, ``p >= 1``; the Hermite
    coupling, :func:`hermite_coupling`, after the polynomial ones)."""
    from dataclasses import replace
    out = []
    for algorithm, firsts in COUPLING_ORDERS.items():
        for first in firsts:
            for p in (0, 1, 2):
                for ind in ((False, True) if p else (False,)):
                    for outd in ((False, True) if ind else (False,)):
                        try:
                            replace(master, algorithm=algorithm, first=first, extrapolation=p,
                                    input_derivatives=ind, output_derivatives=outd)
                        except ConfigError:
                            continue
                        out.append({"algorithm": algorithm, "first": first, "extrapolation": p,
                                    "input_derivatives": ind, "output_derivatives": outd,
                                    "coupling": "polynomial"})
    for first in COUPLING_ORDERS["gauss-seidel"]:
        try:
            replace(master, algorithm="gauss-seidel", first=first, coupling="hermite",
                    input_derivatives=True, adaptive=False)
        except ConfigError:
            continue
        out.append(hermite_coupling(first))
    return out


def critical_step(p: PlantParams, c: ControllerParams, *, integrator: str = "rk4",
                  substep: float = 2.5e-4, hi: float | None = None, **coupling):
    """The largest communication step below which every step is stable: the lower edge of the
    first unstable interval of :func:`~orchestration.studies.stability_intervals.scan` on
    ``[STEP_RANGE[0], hi]`` (default ``STEP_RANGE[1]``); ``None`` if there is none, ``0.0`` if
    the loop is unstable already at the smallest step (the continuous closed loop is). Above it
    the coupling may be stable again (:func:`stability_report` gives the intervals).
    ``coupling``: :func:`transition_matrix`'s keywords."""
    hi = STEP_RANGE[1] if hi is None else hi
    found = _iv.scan(Spectra(p, c, [coupling], integrator=integrator, substep=substep), hi,
                     min_step=STEP_RANGE[0])[0]
    return first_unstable(found)


def first_unstable(intervals):
    """The lower edge of the first unstable interval of ``intervals`` (``[(lo, hi, stable,
    peak)]``, :func:`~orchestration.studies.stability_intervals.step_intervals`), ``0.0`` if it
    is the first, ``None`` if there is none."""
    for i, (lo, _, stable, _) in enumerate(intervals):
        if not stable:
            return 0.0 if i == 0 else lo
    return None


def _scene_model(scene):
    """``(p, c, integrator, substep)`` of a scene whose co-simulation has a transition matrix;
    a ValueError saying why not."""
    scene_coupling(scene)          # its ValueError: adaptive, or Model Exchange
    if not scene.plant.resolved:
        raise ValueError("plant.n_modes or plant.fidelity = 'auto': a run chooses the model; "
                         "set them to predict")
    if scene.plant.integrator not in FIXED_STEP_METHODS:
        raise ValueError(f"plant.integrator = {scene.plant.integrator!r} is adaptive in the "
                         f"plant FMU: no fixed transition matrix; allowed: "
                         f"{', '.join(FIXED_STEP_METHODS)}")
    lin = linearisation(scene)
    if not lin.own:
        raise ValueError(f"plant.fidelity = {scene.plant.fidelity!r}: the floating frame's "
                         "transition matrix is not this rung's")
    return lin.params, scene.controller, scene.plant.integrator, scene.plant.step


def substep_limit(p: PlantParams, method: str):
    """The largest plant substep for which ``method`` is stable on the linearised plant: the
    limit that ``flexpend run`` checks ``plant.step`` against
    (:func:`orchestration.studies.plant_step.step_limit`: the method must amplify no mode that
    the exact flow does not); ``None`` when it has none (A-stable, adaptive or exact methods)."""
    from .plant_step import step_limit

    found = step_limit(method, p)
    return None if found is None else found[0]


def assumptions(scene) -> list[str]:
    """What the prediction of a scene assumes, one sentence each (empty: it is exact)."""
    out = []
    if scene.plant.fidelity != "linear":
        out.append("the plant is linearised at the upright rest state (plant.fidelity = "
                   "'nonlinear': large motions shift the limits)")
    if scene.controller.saturates:
        out.append("the force does not saturate (controller.force_limit)")
    return out


def stability_report(scene, max_step: float | None = None, progress=None) -> dict:
    """For the scene's own coupling and for every coupling the master offers (:func:`couplings`):
    the stable and unstable intervals of the communication step on ``[MIN_STEP, max_step]``
    (:func:`~orchestration.studies.stability_intervals.scan`; default
    :data:`~orchestration.studies.stability_intervals.MAX_STEP`) and the first crossing
    (:func:`first_unstable`), and the plant method's substep limit (:func:`substep_limit`;
    ``None``: A-stable)::

        {"min_step", "max_step",
         "scene": {"coupling": {..., "step"}, "critical_step", "intervals", "rho", "stable",
                   "substep_limit"},
         "couplings": [{"algorithm", "first", "extrapolation", "input_derivatives",
                        "output_derivatives", "coupling", "critical_step", "intervals"}, ...]}

    an interval being ``{"from", "to", "stable", "rho_max"}`` (seconds; ``rho_max``, of an
    unstable one: its largest spectral radius, the growth per step at worst; ``None`` for a
    stable one); ``rho`` and ``stable``: at the scene's own step.
    ``progress``: called with the fraction done. A ValueError for a scene without a transition
    matrix, or a bad ``max_step``."""
    MIN_STEP = _iv.MIN_STEP
    max_step = _iv.MAX_STEP if max_step is None else max_step
    if (isinstance(max_step, bool) or not isinstance(max_step, (int, float))
            or not 10 * MIN_STEP <= max_step <= 10.0):
        raise ValueError(f"max_step = {max_step!r}; allowed: a step in seconds from "
                         f"{10 * MIN_STEP:g} to 10")
    p, c, integrator, h = _scene_model(scene)
    own = scene_coupling(scene)
    ks = couplings(scene.master)
    if own not in ks:
        ks.append(own)
    spectra = Spectra(p, c, ks, integrator=integrator, substep=h)
    found = _iv.scan(spectra, float(max_step), progress=progress)

    def row(k, iv):
        return {**k, "critical_step": first_unstable(iv),
                "intervals": [{"from": a, "to": b, "stable": st, "rho_max": peak}
                              for a, b, st, peak in iv]}

    rows = [row(k, iv) for k, iv in zip(ks, found)]
    mine = rows[ks.index(own)]
    with _iv.one_blas_thread():
        rho = float(spectra(scene.master.step, ks.index(own))[0])
    return {"min_step": MIN_STEP, "max_step": float(max_step),
            "scene": {"coupling": {**own, "step": scene.master.step},
                      "critical_step": mine["critical_step"], "intervals": mine["intervals"],
                      "rho": rho, "stable": rho < 1.0,
                      "substep_limit": substep_limit(p, integrator)},
            "couplings": rows[:len(couplings(scene.master))]}


def step_warning(scene) -> str | None:
    """One line when the scene's plant substep is beyond or near its integrator's stability limit
    (:mod:`orchestration.studies.plant_step`: the line names ``plant.step``), or when its
    communication step is beyond the largest stable step of its coupling (:func:`critical_step`,
    searched up to the step only; the line names ``master.step``), both joined by "; "; else
    ``None`` (also for a scene without a transition matrix and a stable plant step). A plant
    step beyond its limit is the cause whatever the coupling: the coupling is then not judged
    (its search would find the integrator's limit and blame ``master.step``)."""
    from .plant_step import checks

    plant = [c for c in checks(scene) if c.verdict != "ok"]
    beyond = [c.error for c in plant if c.error]
    if beyond:
        return beyond[0]
    lines = [c.warning for c in plant][:1]
    try:
        p, c, integrator, h = _scene_model(scene)
    except ValueError:
        return lines[0] if lines else None
    H = scene.master.step
    Hc = critical_step(p, c, integrator=integrator, substep=h, hi=max(H, STEP_RANGE[0] * 2),
                       **scene_coupling(scene))
    if Hc and Hc < H:       # beyond; 0.0, unstable at every step, is not the step's doing
        where = ("the linearised loop is unstable at every step" if Hc == 0.0 else
                 f"its coupling's predicted largest stable step is {Hc:.4g} s")
        lines.append(f"master.step = {H:g} s is beyond the stability limit: {where} (flexpend "
                     f"stability {scene.name})")
    return "; ".join(lines) or None


# ---------------------------------------------------------------------- the implicit master
def implicit_transition_matrix(p: PlantParams, c: ControllerParams, H, *,
                               extrapolation: int = 2, input_derivatives: bool = True,
                               integrator: str = "rk4", substep: float = 2.5e-4,
                               drift_free: bool = True, step_index: int | None = None,
                               plant_map=None, controller_map=None) -> np.ndarray:
    """``Phi`` with ``z_{k+1} = Phi z_k`` for one converged step ``H`` of the implicit master
    (``master.algorithm = "implicit"``, :mod:`orchestration.cosim.implicit`).

    ``z = [x, xc, y_k .. y_k-p, F_k .. F_k-p]`` as :func:`transition_matrix` lays it out (``p =
    extrapolation``; the oldest sample is carried but not used: the step's polynomial runs through
    the unknown samples at ``t_k+1`` and ``p`` known ones).
    Over the step each FMU gets the polynomial through its source's samples up to the unknown
    ones at ``t_k+1`` (``extrapolation + 1`` of them, fewer at the start: ``step_index``), as
    input derivatives or held as its step average, exactly as :func:`transition_matrix` models
    an explicit coupling's polynomials (the plant's Runge-Kutta stages evaluate it,
    :func:`plant_polynomial_step_map`; the filter exact, :func:`controller_polynomial_step_map`).
    The step is converged when the outputs the FMUs give at ``t_k+1`` are the unknowns:

        y_1 = C x_1(y_1, F_1; z),   F_1 = C_c xc_1(y_1, F_1; z) + D_c y_1,

    a linear system in ``(y_1, F_1)`` solved here, whose solution is substituted into the step.
    The master reaches it to within ``master.implicit_tolerance``. ``H`` may be a 1-d array of
    steps (then the stack of their matrices, as :func:`transition_matrix`)."""
    if not isinstance(c, ControllerParams):
        raise TypeError(f"c must be a ControllerParams, got {type(c).__name__}")
    _check_scheme("gauss-seidel", "controller", extrapolation)
    Hs, scalar = _steps(H)
    plant, n_der, (Pp, Gp), (Ad, Gc) = _step_maps(p, c, Hs, extrapolation, input_derivatives,
                                                   integrator, substep, drift_free, step_index,
                                                   plant_map, controller_map)
    Cc, Dc = controller_model(c).state_space()[2:]
    C = plant.C
    nx, nc, ny = Pp.shape[-1], Ad.shape[-1], C.shape[0]
    Hb = Hs[:, None, None]
    m = extrapolation + 1
    iy = [slice(nx + nc + j * ny, nx + nc + (j + 1) * ny) for j in range(m)]
    o = nx + nc + m * ny
    iF = [slice(o + j, o + j + 1) for j in range(m)]
    N = o + m
    # rows over [z, y_1, F_1]: the unknowns are columns too, eliminated below
    E = np.eye(N + ny + 1)
    y1, F1 = E[N:N + ny], E[N + ny:]
    k = math.inf if step_index is None else step_index
    s = int(min(extrapolation + 1, k + 2))       # samples through t_k+1
    W = _taylor_of_samples(list(range(1, 1 - s, -1)), Hb)
    avg = [1.0, Hb / 2, Hb * Hb / 6]

    def fmu_input(rows):
        """The Taylor coefficients at t_k of the polynomial through ``rows`` (newest first, the
        first at t_k+1) as the FMU gets them: the value and ``n_der`` derivatives, or held."""
        a = [_dot(W[i], rows) for i in range(3)]
        if not n_der:
            return [_dot(avg, a), 0 * a[0], 0 * a[0]]
        return [a[j] if j <= n_der else 0 * a[0] for j in range(3)]

    u = fmu_input([F1] + [E[f] for f in iF][:s - 1])
    x1 = Pp @ E[:nx] + sum(Gp[..., j:j + 1] @ u[j] for j in range(3))
    v = fmu_input([y1] + [E[r] for r in iy][:s - 1])
    xc1 = Ad @ E[nx:nx + nc] + sum(Gc[..., 3 * j:3 * j + 3] @ v[j] for j in range(3))
    # (y_1, F_1) = K [z; y_1; F_1]  =>  (I - K_u) [y_1; F_1] = K_z z
    Fc1 = Cc @ xc1 + Dc @ y1
    K = np.concatenate([C @ x1, np.broadcast_to(Fc1, x1.shape[:-2] + Fc1.shape[-2:])], axis=-2)
    U = np.linalg.solve(np.eye(ny + 1) - K[..., N:], K[..., :N])

    def on_z(rows):
        return rows[..., :N] + rows[..., N:] @ U

    Phi = np.zeros((Hs.size, N, N))
    Phi[:, :nx] = on_z(x1)
    Phi[:, nx:nx + nc] = on_z(xc1)
    Phi[:, iy[0]] = U[:, :ny]
    Phi[:, iF[0]] = U[:, ny:]
    I = np.eye(N)
    for j in range(1, m):
        Phi[:, iy[j]] = I[iy[j - 1]]
        Phi[:, iF[j]] = I[iF[j - 1]]
    return Phi[0] if scalar else Phi
