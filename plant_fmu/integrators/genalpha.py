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
``qdd = M(q)^-1 f`` (the plant solves ``M`` in O(n) itself), so by default the residual is
``r(qdd) = qdd - M^-1 f(q(qdd), v(qdd))`` -- the same root as ``M qdd - f`` -- and the Newton
matrix is ``S = I - gamma' h J_v - beta' h^2 J_q`` with ``J_q, J_v`` the blocks ``d qdd/dq`` and
``d qdd/dv`` of the model's Jacobian (analytic ``model.jac`` if present, else forward differences),
``beta' = beta (1-alpha_f)/(1-alpha_m)``, ``gamma' = gamma (1-alpha_f)/(1-alpha_m)``. With
``residual="mass"`` it iterates on ``M(q) qdd - f(q, qd, u)`` itself (``model.mass_matrix`` and
``model.forces``), with ``S = M + gamma' h C_t + beta' h^2 K_t`` by differences. The Newton is
"modified": ``S`` is inverted once and kept while the iteration converges; it is refreshed after
a failed iteration or a slow one, as in Hairer & Wanner's RADAU5 (whose convergence test, with the
rate of the previous step, ends a linear problem after one iteration). A substep whose iteration
fails even with a fresh Jacobian is retried as two half substeps (``max_halvings`` times).

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

from fmu_common.checks import check_bool, check_int, check_real
from .base import Stepper, numerical_jacobian

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

    Options: ``residual`` ("accelerations": ``qdd - M(q)^-1 f`` from ``model.rhs``, the fast
    path for models that solve ``M`` themselves; "mass": ``M(q) qdd - f(q, qd, u)`` from
    ``model.mass_matrix`` and ``model.forces``, the multibody form, with the Newton matrix
    ``M + gamma' h C_t + beta' h^2 K_t`` from finite differences of the residual), ``jac``
    ("auto": ``model.jac`` if the model has one, else finite differences; "analytic"; "fd"),
    ``max_newton_iter`` (10), ``newton_tol`` (1: Newton stops when the
    estimated remaining error of ``[q, v]``, in the RMS norm scaled by ``atol + rtol |y|``, is
    below it), ``jac_update_rate`` (refresh the Jacobian
    when the Newton contraction rate of a step exceeds it; 1e-3 with ``model.jac``, 0.1 with
    finite differences, which cost ``nx + 1`` evaluations), ``reinit_on_input_change``
    (True), ``max_halvings`` (3: a substep whose Newton iteration fails even with a fresh
    Jacobian is retried as two half substeps, recursively, before the stepper fails).
    """

    name = "genalpha"
    order = 2
    OPTIONS = {"residual": "accelerations", "jac": "auto", "max_newton_iter": 10,
               "newton_tol": None, "jac_update_rate": None, "max_halvings": 3,
               "reinit_on_input_change": True}

    def _init_method(self):
        o = self.options
        p = genalpha_parameters(self.rho_inf)
        self.alpha_m, self.alpha_f = p["alpha_m"], p["alpha_f"]
        self.beta, self.gamma = p["beta"], p["gamma"]
        residual = o["residual"]
        if residual not in ("accelerations", "mass"):
            raise ValueError(f"residual = {residual!r} is not allowed; allowed: 'accelerations', "
                             f"'mass'")
        self._mass_form = residual == "mass"
        if self._mass_form and not (callable(getattr(self.model, "mass_matrix", None))
                                    and callable(getattr(self.model, "forces", None))):
            raise ValueError("residual = 'mass' needs model.mass_matrix(q) and "
                             "model.forces(q, qd, u)")
        jac = o["jac"]
        if jac not in ("auto", "analytic", "fd"):
            raise ValueError(f"jac = {jac!r} is not allowed; allowed: 'auto', 'analytic', 'fd'")
        has_jac = callable(getattr(self.model, "jac", None)) and not self._mass_form
        if jac == "analytic" and not has_jac:
            raise ValueError("jac = 'analytic' but the model has no jac(t, x, u) (or residual = "
                             "'mass', whose Newton matrix is always by finite differences)")
        self._analytic = has_jac and jac != "fd"
        self.max_newton_iter = check_int("max_newton_iter", o["max_newton_iter"], low=1, high=100)
        self.max_halvings = check_int("max_halvings", o["max_halvings"], low=0, high=30)
        tol = 1.0 if o["newton_tol"] is None else o["newton_tol"]
        self.newton_tol = check_real("newton_tol", tol, low=0.0, high=1e3)
        rate = o["jac_update_rate"]
        if rate is None:   # a difference Jacobian costs nx + 1 evaluations, an iteration one
            rate = 1e-3 if self._analytic else 0.1
        self.jac_update_rate = check_real("jac_update_rate", rate, low=0.0, high=1.0)
        self.reinit_on_input_change = check_bool("reinit_on_input_change",
                                                 o["reinit_on_input_change"])
        self._init_acceleration()
        self._J = None
        self._jac_current = False
        self._Sinv = None
        self._lu_h = None
        self._faccon = 1.0
        self._ops_h = None
        self._residual = self._residual_function()
        self._atol_v = np.broadcast_to(self.atol, (self.nx,)).astype(float)
        self._rtol_v = np.full(self.nx, self.rtol)

    def _init_acceleration(self):
        """``qdd`` from ``M(q) qdd = f(q, qd, u)`` at the current state, and ``a = qdd``."""
        nq = self.nq
        if self._mass_form:
            q, v = self.y[:nq], self.y[nq:]
            acc = np.linalg.solve(self.model.mass_matrix(q), self.model.forces(q, v, self._u))
        else:
            acc = self._fun(self.t, self.y, self._u)[nq:]
        self.nfev += 1
        self._aa = np.concatenate((acc, acc))      # [a, qdd]

    def _residual_function(self):
        """``r(t, y1, x, u)`` whose root in ``x = qdd_{n+1}`` the Newton iteration seeks, with
        the sign for ``dx = S^-1 r``."""
        nq = self.nq
        if self._mass_form:
            mass, forces = self.model.mass_matrix, self.model.forces

            def res(t, y1, x, u):
                q1 = y1[:nq]
                return forces(q1, y1[nq:], u) - mass(q1).dot(x)
        else:
            fun = self._fun

            def res(t, y1, x, u):
                return fun(t, y1, u)[nq:] - x
        return res

    def _input_changed(self):
        if self.reinit_on_input_change:
            self._init_acceleration()

    def _jacobian(self, t, y):
        if self._mass_form:
            self._jacobian_mass(y)
            return
        if self._analytic:
            J = np.array(self.model.jac(t, y, self._u), dtype=float)
        else:
            f0 = self._fun(t, y, self._u)
            J = numerical_jacobian(self._fun, t, y, self._u, f0)
            self.nfev += self.nx + 1
        self.njev += 1
        self._J = J
        self._jac_current = True
        self._Sinv = None

    def _jacobian_mass(self, y):
        """``[M(q), K_t, C_t]`` with ``K_t = d(M(q) x - f)/dq``, ``C_t = -df/dv`` at the start of
        the step (``x = qdd_n``), by forward differences: ``2 nq + 1`` residual evaluations."""
        nq = self.nq
        q, v = y[:nq].copy(), y[nq:].copy()
        x = self._aa[nq:]
        mass, forces, u = self.model.mass_matrix, self.model.forces, self._u
        M0 = np.array(mass(q), dtype=float)
        g0 = M0.dot(x) - forces(q, v, u)
        J = np.empty((3, nq, nq))
        J[0] = M0
        for j in range(nq):
            for k, z in ((1, q), (2, v)):
                zj = z[j]
                d = math.sqrt(_EPS) * max(abs(zj), 1.0)
                z[j] = zj + d
                d = z[j] - zj
                J[k][:, j] = (mass(q).dot(x) - forces(q, v, u) - g0) / d
                z[j] = zj
        self.nfev += 2 * nq + 1
        self.njev += 1
        self._J = J
        self._jac_current = True
        self._Sinv = None

    def _factor(self, h):
        """The inverse of the Newton matrix ``S = I - gamma' h J_v - beta' h^2 J_q``.

        An explicit inverse (from an LU factorisation, counted in ``nlu``): it only steers the
        modified Newton iteration, whose fixed point is set by the residual, and a matrix-vector
        product is cheaper than a triangular solve for these small systems."""
        nq = self.nq
        ops = self._ops(h)
        J = self._J
        if self._mass_form:       # S = M + gamma' h C_t + beta' h^2 K_t
            S = J[0] + ops[3] * J[2] + ops[4] * J[1]
        else:
            S = -ops[3] * J[nq:, nq:] - ops[4] * J[nq:, :nq]
            S[np.diag_indices(nq)] += 1.0
        self.nlu += 1
        try:
            self._Sinv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            self._Sinv = None
            return False
        self._lu_h = h
        return True

    def _ops(self, h):
        """The step as matrices, for the last ``h``:

        ``P``: ``[q, v, a, qdd_n] -> [q1, v1]``: positions and velocities at the predictor
        ``qdd_{n+1} = qdd_n`` (a linear extrapolation is worse for the numerically damped high
        frequencies, whose acceleration alternates in sign, and at large ``h w`` it loses digits);
        ``W``: ``d[q1, v1]/d qdd_{n+1} = [beta' h^2 I; gamma' h I]``;
        ``M``: ``[a, qdd_n, qdd_{n+1}] -> [a_{n+1}, qdd_{n+1}]``.
        """
        if h != self._ops_h:
            am, af, b, g = self.alpha_m, self.alpha_f, self.beta, self.gamma
            nq = self.nq
            I = np.eye(nq)
            ca = (1.0 - af) / (1.0 - am)
            bp, gp = h * h * b * ca, h * g * ca
            # a_{n+1} = k_a a_n + k_acc qdd_n + ca qdd_{n+1}
            k_a, k_acc = -am / (1.0 - am), af / (1.0 - am)
            hb, hg = h * h * b, h * g
            blk = lambda i: slice(i * nq, (i + 1) * nq)  # noqa: E731
            q_, v_, a_, acc_ = (blk(i) for i in range(4))
            P = np.zeros((2 * nq, 4 * nq))
            P[q_, q_] = I
            P[q_, v_] = h * I
            P[q_, a_] = (h * h * (0.5 - b) + hb * k_a) * I
            P[q_, acc_] = (hb * k_acc + bp) * I
            P[v_, v_] = I
            P[v_, a_] = (h * (1.0 - g) + hg * k_a) * I
            P[v_, acc_] = (hg * k_acc + gp) * I
            W = np.vstack((bp * I, gp * I))
            M = np.zeros((2 * nq, 3 * nq))               # [a, qdd_n, qdd_{n+1}] -> [a', qdd']
            M[q_, q_] = k_a * I
            M[q_, v_] = k_acc * I
            M[q_, a_] = ca * I
            M[v_, a_] = I
            self._ops_c = (P, W, M, gp, bp)
            self._ops_h = h
        return self._ops_c

    def _step_fixed(self, t, y, h):
        return self._step_fixed_halving(t, y, h, self.max_halvings)

    def _solve_fixed(self, t, y, h):
        if self._J is None:
            self._jacobian(t, y)
        while True:
            if (self._Sinv is None or self._lu_h != h) and not self._factor(h):
                y_new = None
                self._newton_info = "singular Newton matrix"
            else:
                y_new = self._newton(t, y, h)
            if y_new is not None:
                return y_new
            if self._jac_current:
                self._fail_msg = (f"Newton iteration did not converge at t = {t!r} "
                                  f"(h = {h!r}, {self._newton_info})")
                return None
            self._jacobian(t, y)

    def _newton(self, t, y, h):
        nq, n = self.nq, self.nx
        P, W, M = self._ops(h)[:3]
        aa = self._aa
        y1 = P.dot(np.concatenate((y, aa)))
        x = aa[nq:].copy()                              # the predictor of qdd_{n+1}
        scale = self._atol_v + self._rtol_v * np.abs(y)
        tol, maxit, faccon = self.newton_tol, self.max_newton_iter, self._faccon
        Sinv, res, u, t1 = self._Sinv, self._residual, self._u, t + h
        dn_old = None
        theta = 0.0
        converged = False
        for it in range(maxit):
            dx = Sinv.dot(res(t1, y1, x, u))
            dy = W.dot(dx)
            z = dy / scale
            dn = math.sqrt(z.dot(z) / n)
            if not dn < math.inf:
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
        self.nfev += it + 1
        self._newton_info = f"{it + 1} iterations, rate {theta:.3g}"
        if not converged:
            return None
        self._faccon = max(faccon, _EPS) ** 0.8
        self._aa_new = M.dot(np.concatenate((aa, x)))
        self._theta = theta
        return y1

    def _save_aux(self):
        return self._aa

    def _restore_aux(self, saved):
        self._aa = saved

    def _commit(self):
        self._aa = self._aa_new
        if self._theta > self.jac_update_rate:
            self._J = None             # refresh at the start of the next step
        self._jac_current = False

    def _method_state(self):
        nq = self.nq
        return {"a": self._aa[:nq], "acc": self._aa[nq:], "J": self._J,
                "jac_current": self._jac_current,
                "lu_h": self._lu_h if self._Sinv is not None else None, "faccon": self._faccon}

    def _set_method_state(self, s):
        self._aa = np.concatenate([np.array(s[k], dtype=float) for k in ("a", "acc")])
        self._J = None if s["J"] is None else np.array(s["J"], dtype=float)
        self._jac_current = bool(s["jac_current"])
        self._faccon = float(s["faccon"])
        self._Sinv = None
        self._lu_h = None
        if s["lu_h"] is not None and self._J is not None:
            nlu = self.nlu
            self._factor(float(s["lu_h"]))
            self.nlu = nlu
