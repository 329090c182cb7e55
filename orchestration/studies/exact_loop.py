"""The exact rung's monolithic closed loop: the geometrically exact beam on the cart
(:mod:`plant_fmu.exact`) with the PD + low-pass controller, stepped as one system by generalized
alpha, by the numpy specification or by the C kernel (``kernel=True``: ``fp_exact_steps``, the
same steps to round-off, ``tests/plant/test_exact_kernel.py``): the monolithic reference of a scene
whose ``plant.fidelity`` is ``"exact"`` (:func:`orchestration.studies.reference.simulate_reference`)
and the studies ``bench/fidelity_gap.py``, ``bench/bench_exact.py``.
"""
from __future__ import annotations

import numpy as np

from controller_fmu.spec import model_for as controller_model
from plant_fmu.exact import (RADAU_A, RADAU_SPLIT_MAX, AffineForce, GeneralizedAlpha, NoConvergence,
                             RadauIIA, StageForce, exact_plant)
from plant_fmu.kernel import FP_NOCONVERGE, ExactKernel, ExactStepError

__all__ = ["ExactLoop", "exact_run"]


class ExactLoop:
    """The exact plant with the PD + low-pass controller, stepped as one system.

    ``method = "radau"`` (the exact rung's integrator, :class:`plant_fmu.exact.RadauIIA`): the
    filter ``xc' = Af xc + bf e`` (``F_c = -xc[0]``, or ``-e`` without a filter) is integrated in
    the same Radau stages as the beam, so the stage forces are affine in the stage errors,
    ``F_i = F0_i - sum_j Q_ij e_j`` (:class:`plant_fmu.exact.StageForce`): the collocation
    solution of the whole closed loop.

    ``method = "genalpha"`` (:class:`plant_fmu.exact.GeneralizedAlpha`, ``rho_inf``): the filter
    by the trapezoidal rule over each step, so ``F_{n+1} = F0 - Q0 e(q_{n+1}, qd_{n+1})`` with
    ``e = kx x_o + kp phi_o + kd omega_o``: the force is part of the step's Newton solve.

    ``plant``: the exact beam (:func:`plant_fmu.exact.exact_plant`); ``ctrl``: the controller's
    model (:func:`controller_fmu.spec.model_for`)."""

    def __init__(self, plant, ctrl, h: float, rho_inf: float = 0.9,
                 kernel: bool = False, method: str = "radau"):
        if ctrl.params.saturates:
            raise ValueError("the exact loop has no force saturation")
        if method not in ("radau", "genalpha"):
            raise ValueError(f"method = {method!r} is not allowed; allowed: radau, genalpha")
        self.plant, self.ctrl, self.h, self.method = plant, ctrl, h, method
        n = ctrl.nx
        if method == "radau":
            self.kernel, self._radau = kernel, {}
            self.ga = self._radau_at(h)[0]
            return
        self.ga = (ExactKernel(plant, h, rho_inf=rho_inf) if kernel
                   else GeneralizedAlpha(plant.system, h, rho_inf=rho_inf))
        if n:
            Am = np.eye(n) - 0.5 * h * ctrl.Af
            self.P = np.linalg.solve(Am, np.eye(n) + 0.5 * h * ctrl.Af)
            self.Q = np.linalg.solve(Am, 0.5 * h * ctrl.Bf[:, 0])

    def error(self, q, qd):
        """``(e, de/dq, de/dqd)``."""
        c = self.ctrl.params
        phi, om, dphi, dom_q, dom_v = self.plant.tip_angle_gradient(q, qd)
        de_q = c.kp * dphi + c.kd * dom_q
        de_q[0] += c.kx
        return c.kx * q[0] + c.kp * phi + c.kd * om, de_q, c.kd * dom_v

    def run(self, x0: np.ndarray, t_end: float, dt_out: float):
        """``(t, phi_o)`` on the output grid ``k dt_out``."""
        out = [self.plant.tip_angle(np.concatenate(st[:2]))[0]
               for st, _ in self.points(x0, t_end, dt_out)]
        return np.arange(len(out)) * dt_out, np.array(out)

    def _radau_at(self, h):
        """``(integrator, B, G)`` of a Radau step of ``h`` (kept per step size): the filter's
        stages are ``Xc = B (1 x xc) + G E`` (``E`` the stage errors)."""
        if h not in self._radau:
            ctrl, n = self.ctrl, self.ctrl.nx
            integ = (ExactKernel(self.plant, h, method="radau") if self.kernel
                     else RadauIIA(self.plant.system, h))
            B = G = None
            if n:
                B = np.linalg.inv(np.eye(3 * n) - h * np.kron(RADAU_A, ctrl.Af))
                G = h * B @ np.kron(RADAU_A, ctrl.Bf)
            self._radau[h] = (integ, B, G)
        return self._radau[h]

    def _radau_law(self, xc, B, G):
        """The stage force law of a step from the filter state ``xc``."""
        c, n = self.ctrl.params, self.ctrl.nx
        if n == 0:
            return StageForce((0.0, 0.0, 0.0), tuple(map(tuple, np.eye(3))), c.kx, c.kp, c.kd)
        X0 = B @ np.tile(xc, 3)
        F0 = tuple(-float(X0[i * n]) for i in range(3))
        Q = tuple(tuple(float(v) for v in G[i * n]) for i in range(3))
        return StageForce(F0, Q, c.kx, c.kp, c.kd)

    def _radau_step(self, st, xc, h, depth=0):
        """One Radau step of ``h`` of the loop: ``(state, filter state)``; a step whose Newton
        iteration does not converge is taken as two halves, down to
        :data:`~plant_fmu.exact.RADAU_SPLIT_MAX` (as the native FMU does)."""
        integ, B, G = self._radau_at(h)
        try:
            new = integ.step(st, self._radau_law(xc, B, G))
        except (NoConvergence, ExactStepError) as exc:
            if depth >= RADAU_SPLIT_MAX or getattr(exc, "code", FP_NOCONVERGE) != FP_NOCONVERGE:
                raise
            st, xc = self._radau_step(st, xc, 0.5 * h, depth + 1)
            return self._radau_step(st, xc, 0.5 * h, depth + 1)
        if self.ctrl.nx:
            E = np.asarray(integ.stage_error, float)
            xc = (B @ np.tile(xc, 3) + G @ E)[-self.ctrl.nx:]
        return new, xc

    def points(self, x0: np.ndarray, t_end: float, dt_out: float, progress=None):
        """The integrator's state and the force ``F_c`` at each point ``k dt_out`` of the output
        grid, from ``t = 0`` (a generator). ``progress(fraction)`` is called at each point."""
        nq, h = self.plant.nq, self.h
        per = int(round(dt_out / h))
        if per < 1 or abs(per * h - dt_out) > 1e-12 * dt_out:
            raise ValueError(f"the step {h} does not divide the output interval {dt_out}")
        xc = np.zeros(self.ctrl.nx)
        q, qd = x0[:nq], x0[nq:]
        e0 = self.error(q, qd)[0]
        F_now = -xc[0] if self.ctrl.nx else -e0
        n_out = int(round(t_end / dt_out))
        c = self.ctrl.params
        radau = self.method == "radau"
        st = self.ga.start(q, qd, F_now)
        yield st, F_now
        for k in range(n_out):
            for _ in range(per):
                if radau:
                    st, xc = self._radau_step(st, xc, h)
                    if not self.ctrl.nx:
                        e0 = self.error(st[0], st[1])[0]
                    continue
                if self.ctrl.nx:
                    base = self.P @ xc + self.Q * e0
                    F0, Q0 = -base[0], self.Q[0]
                else:
                    F0, Q0 = 0.0, 1.0
                st = self.ga.step(st, AffineForce(F0, Q0, c.kx, c.kp, c.kd))
                e0 = self.error(st[0], st[1])[0]
                if self.ctrl.nx:
                    xc = base + self.Q * e0
            if progress is not None:
                progress((k + 1) / n_out)
            yield st, (-xc[0] if self.ctrl.nx else -e0)


def exact_run(scene, n_elements: int, h: float, kernel: bool = False,
              method: str = "radau") -> np.ndarray:
    """``phi_o`` on the scene's output grid, of the scene's loop with the exact beam meshed with
    ``n_elements`` elements and stepped at ``h`` (it must divide the output interval) by
    ``method`` (``"radau"`` or ``"genalpha"``), by the numpy specification or (``kernel``) the C
    kernel."""
    p = scene.plant.params.replace(n_elements=n_elements)
    plant = exact_plant(p)
    loop = ExactLoop(plant, controller_model(scene.controller), h, kernel=kernel, method=method)
    x0 = plant.initial_state(phi=scene.initial.phi, x=scene.initial.x,
                             phi_dot=scene.initial.phi_dot, x_dot=scene.initial.x_dot)
    return loop.run(x0, scene.output.stop_time, scene.output.output_interval)[1]
