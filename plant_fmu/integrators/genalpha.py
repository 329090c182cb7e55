"""Generalized-alpha for second-order systems ``M(q) qdd = f(q, qd, t, u)`` (Arnold & Bruls 2007).

The method of the flexible multibody codes (Exudyn, Chrono, MBDyn), in the form of Arnold & Bruls
("Convergence of the generalized-alpha scheme for constrained mechanical systems", Multibody
Syst. Dyn. 18, 2007), which is Chung & Hulbert's (J. Appl. Mech. 60, 1993) with the equation of
motion enforced at the end of the step. With ``qdd_n`` the true acceleration and ``a_n`` the
"acceleration-like" auxiliary variable::

    M(q_{n+1}) qdd_{n+1} = f(q_{n+1}, v_{n+1}, t_{n+1}, u)
    (1 - alpha_m) a_{n+1} + alpha_m a_n = (1 - alpha_f) qdd_{n+1} + alpha_f qdd_n
    q_{n+1} = q_n + h v_n + h^2 (1/2 - beta) a_n + h^2 beta a_{n+1}
    v_{n+1} = v_n + h (1 - gamma) a_n + h gamma a_{n+1}

The unknown is ``qdd_{n+1}``; Newton iterates on it. The model's ``rhs`` returns ``[qd, qdd]`` with
``qdd = M(q)^-1 f`` (the plant solves ``M`` in O(n) itself), so the residual is
``r(qdd) = qdd - M^-1 f(q(qdd), v(qdd))`` -- the same root as ``M qdd - f`` -- and the Newton
matrix is ``S = I - gamma' h J_v - beta' h^2 J_q`` with ``J_q, J_v`` the blocks ``d qdd/dq`` and
``d qdd/dv`` of the model's Jacobian (analytic ``model.jac`` if present, else forward differences),
``beta' = beta (1-alpha_f)/(1-alpha_m)``, ``gamma' = gamma (1-alpha_f)/(1-alpha_m)``. The Newton is
"modified": ``S`` is factored once and kept while it converges; it is refreshed after a failed
iteration or a slow one, as in Hairer & Wanner's RADAU5 (whose convergence test, with the rate of
the previous step, ends a linear problem after one iteration).

Parameters from the spectral radius at infinity ``rho_inf`` in [0, 1] (Chung & Hulbert)::

    alpha_m = (2 rho_inf - 1)/(rho_inf + 1),  alpha_f = rho_inf/(rho_inf + 1),
    gamma = 1/2 + alpha_f - alpha_m,           beta = (gamma + 1/2)^2 / 4

second-order accurate (``gamma = 1/2 + alpha_f - alpha_m``) and unconditionally stable
(``alpha_m <= alpha_f <= 1/2``, ``beta >= 1/4 + (alpha_f - alpha_m)/2``). ``rho_inf = 1`` is the
trapezoidal rule (no numerical damping), ``rho_inf = 0`` annihilates the highest frequencies in one
step.

Initialisation: ``qdd_0`` from ``M(q_0) qdd_0 = f`` and ``a_0 = qdd_0``. When the input ``u``
changes between communication steps (zero-order hold, so the acceleration jumps), both are
re-initialised the same way at the current state (option ``reinit_on_input_change``, default
True; one extra evaluation). Without it, the stale ``a_n`` puts an O(h) error into the velocity at
every jump and the method drops to first order on piecewise-constant inputs.
"""
from __future__ import annotations

import math

import numpy as np

from ..params import check_int, check_real
from .base import LU, Stepper, numerical_jacobian

__all__ = ["GeneralizedAlpha", "genalpha_parameters"]

_EPS = np.finfo(float).eps


def genalpha_parameters(rho_inf: float) -> dict:
    """``alpha_m, alpha_f, beta, gamma`` of Chung & Hulbert's optimal generalized-alpha."""
    r = check_real("rho_inf", rho_inf, low=0.0, high=1.0, low_open=False)
    alpha_m = (2.0 * r - 1.0) / (r + 1.0)
    alpha_f = r / (r + 1.0)
    gamma = 0.5 + alpha_f - alpha_m
    beta = 0.25 * (gamma + 0.5) ** 2
    return {"alpha_m": alpha_m, "alpha_f": alpha_f, "beta": beta, "gamma": gamma}


class GeneralizedAlpha(Stepper):
    """Generalized-alpha (Arnold & Bruls), order 2, fixed step, Newton on the accelerations.

    Options: ``jac`` ("auto": ``model.jac`` if the model has one, else finite differences;
    "analytic"; "fd"), ``max_newton_iter`` (10), ``newton_tol`` (scaled by rtol/atol; default
    ``max(10 eps/rtol, min(0.03, sqrt(rtol)))``), ``jac_update_rate`` (1e-3: refresh the
    Jacobian when the Newton contraction rate of a step exceeds it), ``reinit_on_input_change``
    (True).
    """

    name = "genalpha"
    order = 2
    OPTIONS = {"jac": "auto", "max_newton_iter": 10, "newton_tol": None, "jac_update_rate": 1e-3,
               "reinit_on_input_change": True}

    def _init_method(self):
        o = self.options
        p = genalpha_parameters(self.rho_inf)
        self.alpha_m, self.alpha_f = p["alpha_m"], p["alpha_f"]
        self.beta, self.gamma = p["beta"], p["gamma"]
        jac = o["jac"]
        if jac not in ("auto", "analytic", "fd"):
            raise ValueError(f"jac = {jac!r} is not allowed; allowed: 'auto', 'analytic', 'fd'")
        has_jac = callable(getattr(self.model, "jac", None))
        if jac == "analytic" and not has_jac:
            raise ValueError("jac = 'analytic' but the model has no jac(t, x, u)")
        self._analytic = has_jac and jac != "fd"
        self.max_newton_iter = check_int("max_newton_iter", o["max_newton_iter"], low=1, high=100)
        tol = o["newton_tol"]
        if tol is None:
            tol = max(10 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5))
        self.newton_tol = check_real("newton_tol", tol, low=0.0, high=1e3)
        self.jac_update_rate = check_real("jac_update_rate", o["jac_update_rate"], low=0.0,
                                          high=1.0)
        self.reinit_on_input_change = bool(o["reinit_on_input_change"])
        self._init_acceleration()
        self._J = None
        self._jac_current = False
        self._lu = None
        self._lu_h = None
        self._faccon = 1.0
        self._coef_h = None
        self._scale = np.empty(self.nx)
        self._dy = np.empty(self.nx)

    def _init_acceleration(self):
        """``qdd = M(q)^-1 f(q, qd, u)`` at the current state, and ``a = qdd``."""
        f = self._fun(self.t, self.y, self._u)
        self.nfev += 1
        self._acc = f[self.nq:].copy()
        self._a = self._acc.copy()

    def _input_changed(self):
        if self.reinit_on_input_change:
            self._init_acceleration()

    def _jacobian(self, t, y):
        if self._analytic:
            J = np.array(self.model.jac(t, y, self._u), dtype=float)
        else:
            f0 = self._fun(t, y, self._u)
            J = numerical_jacobian(self._fun, t, y, self._u, f0)
            self.nfev += self.nx + 1
        self.njev += 1
        self._J = J
        self._jac_current = True
        self._lu = None

    def _factor(self, h):
        nq = self.nq
        c = self._coefs(h)
        J = self._J
        S = -c["gp"] * J[nq:, nq:] - c["bp"] * J[nq:, :nq]
        S[np.diag_indices(nq)] += 1.0
        self._lu = LU(S)
        self._lu_h = h
        self.nlu += 1

    def _coefs(self, h):
        if h != self._coef_h:
            am, af, b, g = self.alpha_m, self.alpha_f, self.beta, self.gamma
            ca = (1.0 - af) / (1.0 - am)
            self._c = {
                "ca": ca, "acc": af / (1.0 - am), "aa": -am / (1.0 - am),
                "qv": h, "qa": h * h * (0.5 - b), "qac": h * h * b,
                "va": h * (1.0 - g), "vac": h * g,
                "bp": h * h * b * ca, "gp": h * g * ca,
            }
            w = np.empty(self.nx)
            w[:self.nq] = self._c["bp"]
            w[self.nq:] = self._c["gp"]
            self._w = w
            self._coef_h = h
        return self._c

    def _step_fixed(self, t, y, h):
        if self._J is None:
            self._jacobian(t, y)
        while True:
            if self._lu is None or self._lu_h != h:
                self._factor(h)
            y_new = self._newton(t, y, h)
            if y_new is not None:
                return y_new
            if self._jac_current:
                self._fail_msg = (f"Newton iteration did not converge at t = {t!r} "
                                  f"(h = {h!r}, {self._newton_info})")
                return None
            self._jacobian(t, y)

    def _newton(self, t, y, h):
        nq = self.nq
        c = self._coefs(h)
        a, acc = self._a, self._acc
        a_c = c["acc"] * acc + c["aa"] * a            # a_{n+1} = a_c + ca * qdd_{n+1}
        q, v = y[:nq], y[nq:]
        y1 = np.empty(self.nx)
        y1[:nq] = q + c["qv"] * v + c["qa"] * a + c["qac"] * a_c
        y1[nq:] = v + c["va"] * a + c["vac"] * a_c
        x = acc.copy()                                 # predictor: qdd_{n+1} = qdd_n
        y1 += self._w * np.concatenate((x, x))
        scale = self._scale
        np.abs(y, out=scale)
        scale *= self.rtol
        scale += self.atol
        n = self.nx
        tol = self.newton_tol
        maxit = self.max_newton_iter
        faccon = self._faccon
        dn_old = None
        theta = 0.0
        w, dy, lu, fun, u, t1 = self._w, self._dy, self._lu, self._fun, self._u, t + h
        converged = False
        for it in range(maxit):
            F = fun(t1, y1, u)
            self.nfev += 1
            r = F[nq:] - x
            dx = lu.solve(r)
            dy[:nq] = dx
            dy[nq:] = dx
            dy *= w
            z = dy / scale
            dn = math.sqrt(z.dot(z) / n)
            if not math.isfinite(dn):
                break
            if dn_old is not None:
                theta = dn / dn_old
                if theta >= 0.99:
                    break
                faccon = theta / (1.0 - theta)
            x += dx
            y1 += dy
            if faccon * dn <= tol:
                converged = True
                break
            dn_old = dn
        self._newton_info = f"{it + 1} iterations, rate {theta:.3g}"
        if not converged:
            return None
        self._faccon = max(faccon, _EPS) ** 0.8
        self._a_new = a_c + c["ca"] * x
        self._acc_new = x
        self._theta = theta
        return y1

    def _commit(self):
        self._a = self._a_new
        self._acc = self._acc_new
        if self._theta > self.jac_update_rate:
            self._J = None             # refresh at the start of the next step
        self._jac_current = False

    def _method_state(self):
        return {"a": self._a, "acc": self._acc, "J": self._J, "jac_current": self._jac_current,
                "lu_h": self._lu_h if self._lu is not None else None, "faccon": self._faccon}

    def _set_method_state(self, s):
        self._a = np.array(s["a"], dtype=float)
        self._acc = np.array(s["acc"], dtype=float)
        self._J = None if s["J"] is None else np.array(s["J"], dtype=float)
        self._jac_current = bool(s["jac_current"])
        self._faccon = float(s["faccon"])
        self._lu = None
        self._lu_h = None
        if s["lu_h"] is not None and self._J is not None:
            nlu = self.nlu
            self._factor(float(s["lu_h"]))
            self.nlu = nlu
