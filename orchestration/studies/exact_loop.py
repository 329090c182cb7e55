"""The exact rung's monolithic closed loop: the geometrically exact beam on the cart
(:mod:`plant_fmu.exact`) with the PD + low-pass controller, stepped as one system by generalized
alpha, by the numpy specification or by the C kernel (``kernel=True``: ``fp_exact_steps``, the
same steps to round-off, ``tests/test_exact_kernel.py``): the monolithic reference of a scene
whose ``plant.fidelity`` is ``"exact"`` (:func:`orchestration.studies.reference.simulate_reference`)
and the studies ``bench/fidelity_gap.py``, ``bench/bench_exact.py``.
"""
from __future__ import annotations

import numpy as np

from controller_fmu.pd_lowpass import PDLowPassModel
from plant_fmu.exact import AffineForce, ExactPlant, GeneralizedAlpha
from plant_fmu.kernel import ExactKernel

__all__ = ["ExactLoop", "exact_run"]


class ExactLoop:
    """The exact plant with the PD + low-pass controller, stepped by generalized alpha.

    The filter ``xc' = Af xc + bf e`` (``F_c = -xc[0]``, or ``-e`` without a filter) is integrated
    by the trapezoidal rule over each step, so ``F_{n+1} = F0 - Q0 e(q_{n+1}, qd_{n+1})`` with
    ``e = kx x_o + kp phi_o + kd omega_o``: the force is part of the step's Newton solve."""

    def __init__(self, plant: ExactPlant, ctrl: PDLowPassModel, h: float, rho_inf: float = 0.9,
                 kernel: bool = False):
        if ctrl.params.saturates:
            raise ValueError("the exact loop has no force saturation")
        self.plant, self.ctrl, self.h = plant, ctrl, h
        self.ga = (ExactKernel(plant, h, rho_inf=rho_inf) if kernel
                   else GeneralizedAlpha(plant.system, h, rho_inf=rho_inf))
        n = ctrl.nx
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
        st = self.ga.start(q, qd, F_now)
        n_out = int(round(t_end / dt_out))
        c = self.ctrl.params
        yield st, F_now
        for k in range(n_out):
            for _ in range(per):
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


def exact_run(scene, n_elements: int, h: float, kernel: bool = False) -> np.ndarray:
    """``phi_o`` on the scene's output grid, of the scene's loop with the exact beam meshed with
    ``n_elements`` elements and stepped at ``h`` (it must divide the output interval), by the
    numpy specification or (``kernel``) the C kernel."""
    p = scene.plant.params.replace(n_elements=n_elements)
    plant = ExactPlant(p)
    loop = ExactLoop(plant, PDLowPassModel(scene.controller), h, kernel=kernel)
    x0 = plant.initial_state(phi=scene.initial.phi, x=scene.initial.x,
                             phi_dot=scene.initial.phi_dot, x_dot=scene.initial.x_dot)
    return loop.run(x0, scene.output.stop_time, scene.output.output_interval)[1]
