"""Radau IIA of order 5: the implicit 3-stage collocation method for stiff problems.

The algorithm is that of Hairer & Wanner's RADAU5 ("Solving ODEs II", section IV.8) as written in
``scipy.integrate._ivp.radau``: the collocation system is transformed by the eigenvectors of the
method's matrix into one real and one complex linear system of size ``nx``, for
``MU_REAL/h I - J`` and ``MU_COMPLEX/h I - J``. Here the complex one is written as a real system
of size ``2 nx`` and both are inverted once per step size and Jacobian, so that each simplified
Newton iteration is one matrix-vector product (numpy calls, not flops, cost at this size). The
Jacobian ``J`` is ``model.jac`` where the model has one, otherwise forward differences of ``rhs``;
it is kept across steps while Newton converges fast. As in RADAU5 (and unlike scipy) the Newton
convergence test carries the contraction rate over from the previous step, so a linear problem
needs about one iteration per step. A fixed substep whose iteration fails even with a fresh
Jacobian is retried as two half substeps (``max_halvings`` times).

Adaptive by default (the embedded error estimate of RADAU5, predictive step control); with
``adaptive=False`` it takes fixed steps of ``h`` (no error estimate: one evaluation less per step).
A-stable and L-stable (stiffly accurate): on ``x'' = -w^2 x`` it damps every ``h w`` and
annihilates the infinitely stiff components.
"""
from __future__ import annotations

import math

import numpy as np

from fmu_common.checks import check_bool, check_int, check_real
from .base import Stepper, numerical_jacobian

__all__ = ["Radau5"]

_EPS = np.finfo(float).eps
S6 = 6 ** 0.5
C = np.array([(4 - S6) / 10, (4 + S6) / 10, 1.0])
E = np.array([-13 - 7 * S6, -13 + 7 * S6, -1]) / 3
MU_REAL = 3 + 3 ** (2 / 3) - 3 ** (1 / 3)
MU_COMPLEX = (3 + 0.5 * (3 ** (1 / 3) - 3 ** (2 / 3)) - 0.5j * (3 ** (5 / 6) + 3 ** (7 / 6)))
T = np.array([
    [0.09443876248897524, -0.14125529502095421, 0.03002919410514742],
    [0.25021312296533332, 0.20412935229379994, -0.38294211275726192],
    [1, 1, 0]])
TI = np.array([
    [4.17871859155190428, 0.32768282076106237, 0.52337644549944951],
    [-4.17871859155190428, -0.32768282076106237, 0.47662355450055044],
    [0.50287263494578682, -2.57192694985560522, 0.59603920482822492]])
# Interpolator coefficients (collocation polynomial, for the Newton predictor).
P = np.array([
    [13 / 3 + 7 * S6 / 3, -23 / 3 - 22 * S6 / 3, 10 / 3 + 5 * S6],
    [13 / 3 - 7 * S6 / 3, -23 / 3 + 22 * S6 / 3, 10 / 3 - 5 * S6],
    [1 / 3, -8 / 3, 10 / 3]])
#: the Butcher tableau (for reference and tests)
A_RADAU = np.array([
    [(88 - 7 * S6) / 360, (296 - 169 * S6) / 1800, (-2 + 3 * S6) / 225],
    [(296 + 169 * S6) / 1800, (88 + 7 * S6) / 360, (-2 - 3 * S6) / 225],
    [(16 - S6) / 36, (16 + S6) / 36, 1 / 9]])
B_RADAU = A_RADAU[2].copy()

_C_LIST = [float(c) for c in C]
_MIN_FACTOR = 0.2
_MAX_FACTOR = 10.0


class Radau5(Stepper):
    """Radau IIA, order 5, implicit; adaptive (default) or fixed step.

    Options: ``adaptive`` (True), ``max_step`` (inf), ``min_step`` (0), ``jac`` ("auto":
    ``model.jac`` if the model has one, else forward differences; "analytic"; "fd"),
    ``max_newton_iter`` (6 adaptive, 10 fixed step), ``newton_tol`` (the bound on the estimated
    remaining Newton error in the RMS norm scaled by ``atol + rtol |y|``; adaptive: ``max(10
    eps/rtol, min(0.03, sqrt(rtol)))`` as RADAU5 and scipy, fixed step: 1),
    ``jac_update_rate`` (refresh the Jacobian when the contraction rate exceeds it: 1e-3 with
    ``model.jac``, as scipy, 0.1 with finite differences), ``max_halvings`` (3, fixed step only:
    a substep whose Newton iteration fails even with a fresh Jacobian is retried as two half
    substeps, recursively, before the stepper fails; the adaptive mode shrinks h instead).
    """

    name = "radau"
    order = 5
    OPTIONS = {"adaptive": True, "max_step": math.inf, "min_step": 0.0, "jac": "auto",
               "max_newton_iter": None, "newton_tol": None, "jac_update_rate": None,
               "max_halvings": 3}

    def _init_method(self):
        o = self.options
        self.adaptive = check_bool("adaptive", o["adaptive"])
        self.max_step = check_real("max_step", o["max_step"], low=0.0, allow_inf=True)
        self.min_step = check_real("min_step", o["min_step"], low=0.0, low_open=False,
                                   high=math.inf, high_open=True)
        jac = o["jac"]
        if jac not in ("auto", "analytic", "fd"):
            raise ValueError(f"jac = {jac!r} is not allowed; allowed: 'auto', 'analytic', 'fd'")
        has_jac = callable(getattr(self.model, "jac", None))
        if jac == "analytic" and not has_jac:
            raise ValueError("jac = 'analytic' but the model has no jac(t, x, u)")
        self._analytic = has_jac and jac != "fd"
        maxit = o["max_newton_iter"]
        if maxit is None:   # adaptive: give up early and shrink h; fixed: h cannot shrink
            maxit = 6 if self.adaptive else 10
        self.max_newton_iter = check_int("max_newton_iter", maxit, low=1, high=100)
        self.max_halvings = check_int("max_halvings", o["max_halvings"], low=0, high=30)
        tol = o["newton_tol"]
        if tol is None:   # adaptive: well below the controlled local error (RADAU5, scipy)
            tol = max(10 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5)) if self.adaptive else 1.0
        self.newton_tol = check_real("newton_tol", tol, low=0.0, high=1e3)
        rate = o["jac_update_rate"]
        if rate is None:   # a difference Jacobian costs nx + 1 evaluations, an iteration three
            rate = 1e-3 if self._analytic else 0.1
        self.jac_update_rate = check_real("jac_update_rate", rate, low=0.0, high=1.0)
        n = self.nx
        self._f = self._fun(self.t, self.y, self._u)
        self.nfev += 1
        self._J = None
        self._jac_current = False
        self._lu_h = None
        self._Binv = None
        self._faccon = 1.0
        self._h_abs = min(self.h, self.max_step)
        self._h_abs_old = None
        self._err_old = None
        self._sol = None            # (t_old, h, y_old, Q) of the last step's collocation polynomial
        self._I = np.eye(n)
        self._F = np.empty((3, n))

    def _input_changed(self):
        if self.adaptive:          # f(t, y) enters the error estimate (fixed steps have none)
            self._f = self._fun(self.t, self.y, self._u)
            self.nfev += 1

    # ------------------------------------------------------------------ linear algebra
    def _jacobian(self, t, y, f=None):
        if self._analytic:
            J = np.array(self.model.jac(t, y, self._u), dtype=float)
        else:
            if f is None:
                f = self._fun_at(t, y)
            J = numerical_jacobian(self._fun, t, y, self._u, f)
            self.nfev += self.nx
        self.njev += 1
        self._J = J
        self._jac_current = True
        self._Binv = None

    def _factor(self, h):
        """Invert the Newton matrix of the transformed collocation system for step ``h``.

        The real system ``(MU_REAL/h I - J) dW0 = R0`` and the complex one
        ``((mr + i mi)/h I - J)(dW1 + i dW2) = R1 + i R2`` are written as one real block-diagonal
        system ``B dW = R`` of size 3n, and ``B`` is inverted block by block (two factorisations,
        counted in ``nlu``): each Newton iteration is then one matrix-vector product. The inverse
        only steers the simplified Newton iteration and filters the error estimate."""
        J, n, I = self._J, self.nx, self._I
        mr, mi = MU_COMPLEX.real / h, MU_COMPLEX.imag / h
        B = np.zeros((3 * n, 3 * n))
        C2 = np.empty((2 * n, 2 * n))
        C2[:n, :n] = C2[n:, n:] = mr * I - J
        C2[:n, n:] = -mi * I
        C2[n:, :n] = mi * I
        self.nlu += 2
        try:
            B[:n, :n] = np.linalg.inv(MU_REAL / h * I - J)
            B[n:, n:] = np.linalg.inv(C2)
        except np.linalg.LinAlgError:
            self._Binv = None
            return False
        self._Binv = B
        self._Binv_real = np.ascontiguousarray(B[:n, :n])
        self._Lam = np.array([[MU_REAL, 0.0, 0.0], [0.0, MU_COMPLEX.real, -MU_COMPLEX.imag],
                              [0.0, MU_COMPLEX.imag, MU_COMPLEX.real]]) / h
        self._E_h = E / h
        self._lu_h = h
        return True

    def _predict(self, t, y, h, f=None):
        """Initial guess of the stage increments ``Z``: the last collocation polynomial, or at the
        first step the explicit Euler increments ``c_i h f(t, y)``."""
        if self._sol is None:
            if f is None:
                f = self._fun_at(t, y)
            return np.outer(h * C, f)
        t_old, h_old, y_old, Q = self._sol
        x0, x1, x2 = ((t + h * c - t_old) / h_old for c in _C_LIST)
        p = np.array([[x0, x1, x2], [x0 * x0, x1 * x1, x2 * x2],
                      [x0 * x0 * x0, x1 * x1 * x1, x2 * x2 * x2]])
        return Q.dot(p).T + (y_old - y)

    def _solve_collocation(self, t, y, h, Z0, scale):
        """Simplified Newton on the collocation system; returns (converged, n_iter, Z, rate)."""
        W = TI.dot(Z0)
        Z = Z0
        F, Binv, Lam = self._F, self._Binv, self._Lam
        t0, t1, t2 = (t + h * c for c in _C_LIST)
        fun, u = self._fun, self._u
        tol = self.newton_tol
        maxit = self.max_newton_iter
        faccon = self._faccon
        dn_old = None
        rate = 0.0
        n = self.nx
        for k in range(maxit):
            F[0] = fun(t0, y + Z[0], u)
            F[1] = fun(t1, y + Z[1], u)
            F[2] = fun(t2, y + Z[2], u)
            self.nfev += 3
            R = TI.dot(F) - Lam.dot(W)
            dW = Binv.dot(R.reshape(-1)).reshape(3, n)
            z = (dW / scale).reshape(-1)
            dn = math.sqrt(z.dot(z) / (3 * n))
            if not dn < math.inf:
                break
            if dn_old is not None:
                rate = dn / dn_old
                if rate >= 0.99 or (self.adaptive and
                                   rate ** (maxit - 1 - k) / (1 - rate) * dn > tol):
                    break
                faccon = rate / (1 - rate)
            W = W + dW
            Z = T.dot(W)
            if dn == 0 or faccon * dn <= tol:
                self._faccon = max(faccon, _EPS) ** 0.8
                return True, k + 1, Z, rate
            dn_old = dn
        return False, k + 1, None, rate

    # ------------------------------------------------------------------ steps
    def _step_fixed(self, t, y, h):
        return self._step_fixed_halving(t, y, h, self.max_halvings)

    def _solve_fixed(self, t, y, h):
        if self._J is None:
            self._jacobian(t, y)
        Z0 = self._predict(t, y, h)
        scale = self.atol + np.abs(y) * self.rtol
        while True:
            if (self._Binv is None or self._lu_h != h) and not self._factor(h):
                ok, n_iter, rate = False, 0, math.nan
            else:
                ok, n_iter, Z, rate = self._solve_collocation(t, y, h, Z0, scale)
            if ok:
                break
            if self._jac_current:
                self._fail_msg = (f"Newton iteration did not converge at t = {t!r} (h = {h!r}, "
                                  f"{n_iter} iterations, rate {rate:.3g})")
                return None
            self._jacobian(t, y)
        self._pending = (t, h, y, Z, rate)
        return y + Z[-1]

    def _fun_at(self, t, y):
        self.nfev += 1
        return self._fun(t, y, self._u)

    def _save_aux(self):
        return self._sol

    def _restore_aux(self, saved):
        self._sol = saved

    def _commit(self):
        t, h, y, Z, rate = self._pending
        self._sol = (t, h, y, Z.T.dot(P))
        if rate > self.jac_update_rate:
            self._J = None
        self._jac_current = False

    def _step_adaptive(self, t_bound):
        t, y, f = self.t, self.y, self._f
        min_step = max(self.min_step, 10.0 * (np.nextafter(t, math.inf) - t))
        h_abs, h_abs_old, err_old = self._h_abs, self._h_abs_old, self._err_old
        if h_abs < min_step:
            h_abs, h_abs_old, err_old = min_step, None, None
        atol, rtol = self.atol, self.rtol
        if t_bound - t <= min_step:               # a rounding remainder: nothing to integrate
            self.t = t_bound
            return True, None
        if self._J is None:
            self._jacobian(t, y, f)
        rejected = False
        while True:
            if h_abs < min_step:
                return False, (f"step size underflow at t = {t!r}: h = {h_abs!r} is below the "
                               f"minimum {min_step!r}")
            remaining = t_bound - t
            if h_abs >= remaining:
                h, t_new = remaining, t_bound
            elif 2.0 * h_abs > remaining:
                h = 0.5 * remaining
                t_new = t + h
            else:
                h, t_new = h_abs, t + h_abs
            Z0 = self._predict(t, y, h, f)
            scale = atol + np.abs(y) * rtol
            while True:
                if (self._Binv is None or self._lu_h != h) and not self._factor(h):
                    converged = False
                else:
                    converged, n_iter, Z, rate = self._solve_collocation(t, y, h, Z0, scale)
                if converged or self._jac_current:
                    break
                self._jacobian(t, y, f)
            if not converged:
                h_abs = 0.5 * h
                rejected = True
                self.nrejected += 1
                continue
            y_new = y + Z[-1]
            ZE = self._E_h.dot(Z)
            error = self._Binv_real.dot(f + ZE)
            scale = atol + np.maximum(np.abs(y), np.abs(y_new)) * rtol
            z = error / scale
            err = math.sqrt(z.dot(z) / self.nx)
            safety = 0.9 * (2 * self.max_newton_iter + 1) / (2 * self.max_newton_iter + n_iter)
            if rejected and err > 1:
                error = self._Binv_real.dot(self._fun_at(t, y + error) + ZE)
                z = error / scale
                err = math.sqrt(z.dot(z) / self.nx)
            if not math.isfinite(err):
                h_abs = _MIN_FACTOR * h
                rejected = True
                self.nrejected += 1
                continue
            if err > 1:
                factor = self._predict_factor(h, h_abs_old, err, err_old)
                h_abs = h * max(_MIN_FACTOR, safety * factor)
                rejected = True
                self.nrejected += 1
                continue
            break
        recompute_jac = n_iter > 2 and rate > self.jac_update_rate
        factor = min(_MAX_FACTOR, safety * self._predict_factor(h, h_abs_old, err, err_old))
        if rejected:
            factor = min(1.0, factor)
        if not recompute_jac and factor < 1.2:
            factor = 1.0
        h_next = h * factor
        if h < self._h_abs and not rejected and h_next < self._h_abs:
            h_next = self._h_abs                # a step shortened to t_bound keeps the proposal
        f_new = self._fun(t_new, y_new, self._u)
        self.nfev += 1
        if recompute_jac:
            self._J = None                      # refreshed at the start of the next step
        self._jac_current = False
        self._h_abs_old = h
        self._err_old = err
        self._h_abs = min(h_next, self.max_step)
        self._sol = (t, h, y, Z.T.dot(P))
        self.t, self.y, self._f = t_new, y_new, f_new
        self.nsteps += 1
        return True, None

    @staticmethod
    def _predict_factor(h, h_old, err, err_old):
        if err_old is None or h_old is None or err == 0:
            multiplier = 1.0
        else:
            multiplier = h / h_old * (err_old / err) ** 0.25
        if err == 0:
            return _MAX_FACTOR
        return min(1.0, multiplier) * err ** -0.25

    # ------------------------------------------------------------------ snapshots
    def _method_state(self):
        sol = None
        if self._sol is not None:
            t_old, h_old, y_old, Q = self._sol
            sol = [t_old, h_old, y_old.tolist(), Q.tolist()]
        return {"f": self._f, "J": self._J, "jac_current": self._jac_current,
                "lu_h": self._lu_h if self._Binv is not None else None, "faccon": self._faccon,
                "h_abs": self._h_abs, "h_abs_old": self._h_abs_old, "err_old": self._err_old,
                "sol": sol}

    def _set_method_state(self, s):
        self._f = np.array(s["f"], dtype=float)
        self._J = None if s["J"] is None else np.array(s["J"], dtype=float)
        self._jac_current = bool(s["jac_current"])
        self._faccon = float(s["faccon"])
        self._h_abs = float(s["h_abs"])
        self._h_abs_old = s["h_abs_old"]
        self._err_old = s["err_old"]
        sol = s["sol"]
        self._sol = None if sol is None else (float(sol[0]), float(sol[1]),
                                              np.array(sol[2], dtype=float),
                                              np.array(sol[3], dtype=float))
        self._Binv = None
        self._lu_h = None
        if s["lu_h"] is not None and self._J is not None:
            nlu = self.nlu
            self._factor(float(s["lu_h"]))
            self.nlu = nlu
