"""Explicit Runge-Kutta methods as tableaus run by one routine, and symplectic Euler.

The explicit methods are data: a Butcher tableau ``(A, B, C)`` (and for an embedded pair the error
weights ``E = B - B_hat``) as class attributes, run by :meth:`ExplicitRungeKutta._rk_step`, as in
``scipy.integrate._ivp.rk``. ``FSAL`` (first same as last) tableaus evaluate their last stage at
the new state and reuse it as the first stage of the next step.

Symplectic Euler is a partitioned method (velocity first, then position with the new velocity);
it is not a Runge-Kutta tableau on ``[q, qd]`` and has its own step.

When the model has the compiled kernel (``model.kernel``, :class:`plant_fmu.kernel.PlantKernel`:
the plant, nonlinear or linearised), the fixed substeps of a communication step run in one call
of its loop and the adaptive Dormand-Prince steps in one call of its adaptive loop: the same
tableaus, error control and arithmetic as the Python code here, which runs for any other model
and is what the compiled loops are tested against.
"""
from __future__ import annotations

import math

import numpy as np

from fmu_common.checks import check_bool, check_real
from .base import Stepper, _cap_message

__all__ = ["ExplicitRungeKutta", "ExplicitEuler", "RK4", "DormandPrince54", "SymplecticEuler"]

# return codes of the compiled loops (plant_fmu.kernel; not imported here: other models need no
# compiled kernel)
_FP_OK, _FP_CAP, _FP_UNDERFLOW = 0, 3, 4
#: accepted steps per call of the compiled adaptive loop (the loop continues with further calls)
_ADAPTIVE_CHUNK = 100_000


def _model_kernel(model):
    """The compiled kernel of ``model``, or None if it has none (a KernelError propagates: a
    plant whose kernel is missing must not fall back silently)."""
    return getattr(model, "kernel", None)


_SAFETY = 0.9
_MIN_FACTOR = 0.2
_MAX_FACTOR = 10.0


class ExplicitRungeKutta(Stepper):
    """An explicit Runge-Kutta tableau; fixed step, or adaptive if it has an embedded pair."""

    A: np.ndarray = np.zeros((1, 1))
    B: np.ndarray = np.ones(1)
    C: np.ndarray = np.zeros(1)
    #: error weights ``B - B_hat`` of an embedded pair (None: no error estimate)
    E: np.ndarray | None = None
    #: order of the embedded (error estimating) solution
    error_order: int = 0
    FSAL: bool = False
    POLYNOMIAL_INPUT = True

    def _init_method(self):
        s = self.B.size
        self._K = np.empty((s, self.nx))
        self._coef_h = None
        self._kernel = _model_kernel(self.model)
        if self._kernel is not None:
            self._ktab = self._kernel.tableau(self.A, self.B, self.C, self.E, self.FSAL)
        # the compiled adaptive loop is Dormand-Prince's: an FSAL pair with an order-4 estimate
        self._compiled_error_control = (self._kernel is not None and self.FSAL
                                        and self.E is not None and self.error_order == 4)
        if self.E is not None:
            self.adaptive = check_bool("adaptive", self.options["adaptive"])
            self.max_step = check_real("max_step", self.options["max_step"], low=0.0,
                                       allow_inf=True)
            self.min_step = check_real("min_step", self.options["min_step"], low=0.0,
                                       low_open=False, high=math.inf, high_open=True)
            self._h_abs = min(self.h, self.max_step)
            self._err_exp = -1.0 / (self.error_order + 1)
            self._scale_buf = np.empty(self.nx)
        if self.FSAL:
            self._f = self._fun(self.t, self.y, self._u_at(self.t))
            self.nfev += 1
            self._f_new = None

    def _input_changed(self):
        if self.FSAL:
            self._f = self._fun(self.t, self.y, self._u_at(self.t))
            self.nfev += 1

    def _coeffs(self, h):
        """Rows ``(i, c_i h, h A[i, :i], K[:i])`` and ``h B``, cached for the last h."""
        if h != self._coef_h:
            A, C, K = self.A, self.C, self._K
            self._rows = [(i, C[i] * h, h * A[i, :i], K[:i]) for i in range(1, self.B.size)]
            self._hb = h * self.B
            self._coef_h = h
        return self._rows, self._hb

    def _rk_step(self, t, y, h):
        """The generic Runge-Kutta step: fills the stage derivatives ``K``, returns ``y_new``."""
        rows, hb = self._coeffs(h)
        K, fun, u_at = self._K, self._fun, self._u_at
        if self.FSAL:
            K[0] = self._f
            ys = y
            for i, ch, a, Ki in rows:
                ys = y + a.dot(Ki)
                fi = fun(t + ch, ys, u_at(t + ch))
                K[i] = fi
            self._f_new = fi                  # f at (t + h, y_new): the next first stage
            self.nfev += len(rows)
            return ys                         # the last row of A is B: ys is y_new
        K[0] = fun(t, y, u_at(t))
        for i, ch, a, Ki in rows:
            K[i] = fun(t + ch, y + a.dot(Ki), u_at(t + ch))
        self.nfev += len(rows) + 1
        return y + hb.dot(K)

    _step_fixed = _rk_step

    def _full_substeps(self, t, y, h, t_base, k, n):
        """The fixed substeps in one compiled call when the model has the kernel: the same
        tableau and arithmetic, without Python per stage."""
        if self._kernel is None or self.FSAL or n < 1:
            return super()._full_substeps(t, y, h, t_base, k, n)
        return _compiled_substeps(self, self.name, self._ktab, self.B.size, t, y, h, t_base, k, n)

    def _commit(self):
        if self.FSAL:
            self._f = self._f_new

    def _advance_adaptive(self, t_end, max_steps=None):
        if not self._compiled_error_control:
            return super()._advance_adaptive(t_end, max_steps)
        return self._compiled_adaptive(t_end, single=False, max_steps=max_steps)

    def _compiled_adaptive(self, t_bound, single, max_steps=None):
        """Adaptive steps towards ``t_bound`` (one if ``single``; at most ``max_steps``) in the
        compiled loop, which runs the error control of :meth:`_step_adaptive` below."""
        kern, u = self._kernel, (self._u, self._du, self._d2u, self._tu)
        left = math.inf if max_steps is None else max_steps
        while True:
            rc, t, y, f, h_abs, nfev, nsteps, nrej, fail_h, fail_min = kern.dopri_advance(
                self._ktab, self.y, self._f, self.t, t_bound, u, rtol=self.rtol, atol=self.atol,
                max_step=self.max_step, min_step=self.min_step, h_abs=self._h_abs,
                max_steps=1 if single else int(min(_ADAPTIVE_CHUNK, left)))
            self.t, self.y, self._f, self._h_abs = t, y, f, h_abs
            self.nfev += nfev
            self.nsteps += nsteps
            self.nrejected += nrej
            if rc == _FP_UNDERFLOW:
                return False, (f"step size underflow at t = {t!r}: h = {fail_h!r} is below the "
                               f"minimum {fail_min!r}")
            if rc == _FP_OK or single:
                return True, None
            left -= nsteps
            if left <= 0:
                return False, _cap_message(max_steps, t, t_bound)

    def _step_adaptive(self, t_bound):
        """One accepted step with error control (the logic of scipy's ``RungeKutta``)."""
        if self._compiled_error_control:
            return self._compiled_adaptive(t_bound, single=True)
        t, y = self.t, self.y
        min_step = max(self.min_step, 10.0 * (np.nextafter(t, math.inf) - t))
        h_abs = self._h_abs
        rejected = False
        n = self.nx
        atol, rtol, E = self.atol, self.rtol, self.E
        scale = self._scale_buf
        if t_bound - t <= min_step:               # a rounding remainder: nothing to integrate
            self.t = t_bound
            return True, None
        while True:
            if h_abs < min_step:
                return False, (f"step size underflow at t = {t!r}: h = {h_abs!r} is below the "
                               f"minimum {min_step!r}")
            remaining = t_bound - t
            if h_abs >= remaining:
                h, t_new = remaining, t_bound
            elif 2.0 * h_abs > remaining:     # avoid a tiny last step: split the rest in two
                h = 0.5 * remaining
                t_new = t + h
            else:
                h, t_new = h_abs, t + h_abs
            y_new = self._rk_step(t, y, h)
            err = self._K.T.dot(E)
            np.maximum(np.abs(y), np.abs(y_new), out=scale)
            scale *= rtol
            scale += atol
            err /= scale
            error_norm = h * math.sqrt(err.dot(err) / n)
            if error_norm < 1.0:
                if error_norm == 0.0:
                    factor = _MAX_FACTOR
                else:
                    factor = min(_MAX_FACTOR, _SAFETY * error_norm ** self._err_exp)
                if rejected:
                    factor = min(1.0, factor)
                h_next = h * factor
                if h < h_abs and not rejected:
                    h_next = max(h_next, h_abs)   # a step shortened to t_bound keeps the proposal
                self._h_abs = min(h_next, self.max_step)
                self._f = self._f_new
                self.t, self.y = t_new, y_new
                self.nsteps += 1
                return True, None
            if error_norm != error_norm or error_norm == math.inf:
                factor = _MIN_FACTOR
            else:
                factor = max(_MIN_FACTOR, _SAFETY * error_norm ** self._err_exp)
            h_abs = h * factor
            rejected = True
            self.nrejected += 1

    def _method_state(self):
        s = {}
        if self.FSAL:
            s["f"] = self._f
        if self.E is not None:
            s["h_abs"] = self._h_abs
        return s

    def _set_method_state(self, s):
        if self.FSAL:
            self._f = np.array(s["f"], dtype=float)
        if self.E is not None:
            self._h_abs = float(s["h_abs"])


class ExplicitEuler(ExplicitRungeKutta):
    """Explicit (forward) Euler, order 1; unstable on an undamped oscillator for every h."""

    name = "euler"
    order = 1
    A = np.zeros((1, 1))
    B = np.array([1.0])
    C = np.array([0.0])


class RK4(ExplicitRungeKutta):
    """The classical 4-stage Runge-Kutta method, order 4, fixed step."""

    name = "rk4"
    order = 4
    A = np.array([[0.0, 0.0, 0.0, 0.0],
                  [0.5, 0.0, 0.0, 0.0],
                  [0.0, 0.5, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0]])
    B = np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6])
    C = np.array([0.0, 0.5, 0.5, 1.0])


class DormandPrince54(ExplicitRungeKutta):
    """Dormand-Prince 5(4): 7 stages (FSAL, so 6 new evaluations per step), order 5.

    Adaptive by default (error control on the embedded 4th-order solution, local extrapolation);
    with ``adaptive=False`` it takes fixed steps of ``h`` with the 5th-order solution.
    Options: ``adaptive`` (True), ``max_step`` (inf), ``min_step`` (0: only the 10-ulp floor).
    """

    name = "dopri5"
    order = 5
    error_order = 4
    FSAL = True
    OPTIONS = {"adaptive": True, "max_step": math.inf, "min_step": 0.0}
    C = np.array([0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1, 1])
    A = np.array([
        [0, 0, 0, 0, 0, 0, 0],
        [1 / 5, 0, 0, 0, 0, 0, 0],
        [3 / 40, 9 / 40, 0, 0, 0, 0, 0],
        [44 / 45, -56 / 15, 32 / 9, 0, 0, 0, 0],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0, 0],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0, 0],
        [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0]])
    B = np.array([35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0])
    B_HAT = np.array([5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100,
                      1 / 40])
    E = B - B_HAT


class SymplecticEuler(Stepper):
    """Symplectic (semi-implicit) Euler: ``qd+ = qd + h qdd(q, qd)``, then ``q+ = q + h qd+``.

    Order 1, one evaluation per step; on ``x'' = -w^2 x`` bounded iff ``h w < 2`` (it conserves a
    modified energy). Velocity-dependent forces are taken explicitly at the old velocity.
    """

    name = "symplectic_euler"
    order = 1
    POLYNOMIAL_INPUT = True

    def _init_method(self):
        self._kernel = _model_kernel(self.model)

    def _step_fixed(self, t, y, h):
        nq = self.nq
        y_new = y + h * self._fun(t, y, self._u_at(t))   # q + h qd_n (replaced below), qd + h qdd
        self.nfev += 1
        y_new[:nq] = y[:nq] + h * y_new[nq:]
        return y_new

    def _full_substeps(self, t, y, h, t_base, k, n):
        """The fixed substeps in one compiled call when the model has the kernel."""
        if self._kernel is None or n < 1:
            return super()._full_substeps(t, y, h, t_base, k, n)
        return _compiled_substeps(self, self.name, None, 1, t, y, h, t_base, k, n)


def _compiled_substeps(st, method, tableau, stages, t, y, h, t_base, k, n):
    """``n`` substeps of ``h`` of ``st`` in the kernel's fixed-step loop; the return value of
    :meth:`Stepper._full_substeps`."""
    y, done, _ = st._kernel.fixed_steps(method, tableau, y, (st._u, st._du, st._d2u, st._tu), t,
                                        h, n)
    st.nfev += done * stages
    k += done
    t = t_base + k * h
    if done < n:
        st.nfev += stages
        return t, y, k, f"non-finite state after the substep from t = {t!r} (h = {h!r})"
    return t, y, k, None
