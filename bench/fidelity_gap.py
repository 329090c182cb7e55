"""The fidelity gap: the floating-frame model against the geometrically exact beam
(:mod:`plant_fmu.exact`) on the paper's filtered scene, with the controller in the loop.

Both closed loops are monolithic (no co-simulation error): the floating frame by
:func:`orchestration.studies.reference.simulate_reference` (DOP853, rtol = atol = 1e-12), the exact
beam by its generalized-alpha stepper with the controller's filter integrated by the trapezoidal
rule in the same Newton solve (:class:`ExactLoop`). Structural damping is off on both sides (so the
damping laws, modal against Kelvin-Voigt, do not enter). For each initial angle: the largest
``|phi_o|`` difference over the run, for the default rung and with ``plant.gravity_preload``, and
the exact rung's own discretisation uncertainty (the mesh doubled, the step halved).

Measured (16 elements, h = 5e-5 against 1e-4 and 32 elements; 3 s; 5 min on one core):

    phi0     default   preload   (issue: default, preload)   exact: mesh      step   tip defl. max
    0.0500  2.90e-04  5.05e-05   (3.00e-04, 7.10e-05)        2.0e-05        4.4e-05  0.26%
    0.2000  9.34e-04  2.72e-04   (9.20e-04, 2.60e-04)        6.6e-05        1.4e-04  0.97%
    0.5236  1.30e-03  1.48e-03   (1.27e-03, 1.49e-03)        7.6e-05        1.5e-04  1.78%

The default rung's gap is 4 to 15 times the exact rung's uncertainty (mesh + step); the preload
rung's at 0.05 rad (5.05e-5) is within it. The step column halves when h halves (0.05 rad: 9.0e-5
at 2e-4 against 1e-4, 4.4e-5 at 1e-4 against 5e-5), first order rather than the integrator's
second: with no structural damping the mesh's high bending modes, excited by the undeformed start
and above 1/h, ring at ~1e-5 rad in the tip slope and the integrator damps them by an amount that
depends on h (open loop, 8 elements: the h/2 - h difference stays near 1.6e-5 rad from h = 2e-4
down to 2.5e-5, while a free pendulum's energy drift is second order). The floating frame with 4
modes has no such modes.

    python3 bench/fidelity_gap.py [--elements 16] [--step 1e-4] [--stop 3]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller_fmu.pd_lowpass import PDLowPassModel  # noqa: E402
from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.reference import simulate_reference  # noqa: E402
from plant_fmu.exact import ExactPlant, GeneralizedAlpha  # noqa: E402

ANGLES = (0.05, 0.2, math.pi / 6)
#: The issue's table (max |phi_o| difference, rad): default rung, with gravity_preload.
ISSUE = {0.05: (3.0e-4, 7.1e-5), 0.2: (9.2e-4, 2.6e-4), math.pi / 6: (1.27e-3, 1.49e-3)}


class ExactLoop:
    """The exact plant with the PD + low-pass controller, stepped by generalized alpha.

    The filter ``xc' = Af xc + bf e`` (``F_c = -xc[0]``, or ``-e`` without a filter) is integrated
    by the trapezoidal rule over each step, so ``F_{n+1} = F0 - Q0 e(q_{n+1}, qd_{n+1})`` with
    ``e = kx x_o + kp phi_o + kd omega_o``: the force is part of the step's Newton solve."""

    def __init__(self, plant: ExactPlant, ctrl: PDLowPassModel, h: float, rho_inf: float = 0.9):
        if ctrl.params.saturates:
            raise ValueError("the exact loop has no force saturation")
        self.plant, self.ctrl, self.h = plant, ctrl, h
        self.ga = GeneralizedAlpha(plant.system, h, rho_inf=rho_inf)
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
        nq, h = self.plant.nq, self.h
        per = int(round(dt_out / h))
        if abs(per * h - dt_out) > 1e-12 * dt_out:
            raise ValueError(f"the step {h} does not divide the output interval {dt_out}")
        xc = np.zeros(self.ctrl.nx)
        q, qd = x0[:nq], x0[nq:]
        e0 = self.error(q, qd)[0]
        F_now = -xc[0] if self.ctrl.nx else -e0
        st = self.ga.start(q, qd, F_now)
        n_out = int(round(t_end / dt_out))
        out = [self.plant.tip_angle(x0)[0]]
        for _ in range(n_out):
            for _ in range(per):
                if self.ctrl.nx:
                    base = self.P @ xc + self.Q * e0
                    F0, Q0 = -base[0], self.Q[0]
                else:
                    F0, Q0 = 0.0, 1.0

                def force(q, qd, F0=F0, Q0=Q0):
                    e, dq, dv = self.error(q, qd)
                    return F0 - Q0 * e, -Q0 * dq, -Q0 * dv

                st = self.ga.step(st, force)
                e0 = self.error(st[0], st[1])[0]
                if self.ctrl.nx:
                    xc = base + self.Q * e0
            out.append(self.plant.tip_angle(np.concatenate(st[:2]))[0])
        return np.arange(n_out + 1) * dt_out, np.array(out)


def scene_for(phi0: float, stop: float, preload: bool = False):
    return load_scene("flexible_pd_lowpass", {"initial.phi": phi0, "stop_time": stop,
                                              "plant.zeta": 0.0,
                                              "plant.gravity_preload": preload})


def exact_run(scene, n_elements: int, h: float):
    p = scene.plant.params.replace(n_elements=n_elements)
    plant = ExactPlant(p)
    loop = ExactLoop(plant, PDLowPassModel(scene.controller), h)
    x0 = plant.initial_state(phi=scene.initial.phi, x=scene.initial.x,
                             phi_dot=scene.initial.phi_dot, x_dot=scene.initial.x_dot)
    return loop.run(x0, scene.output.stop_time, scene.output.output_interval)[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=16)
    ap.add_argument("--step", type=float, default=1e-4)
    ap.add_argument("--stop", type=float, default=3.0)
    args = ap.parse_args(argv)
    ne, h = args.elements, args.step
    print(f"exact rung: {ne} elements, h = {h / 2:g}; its uncertainty: {2 * ne} elements against "
          f"{ne} (at h = {h:g}), and h = {h / 2:g} against {h:g}")
    print("phi0     default   preload   (issue: default, preload)   exact: mesh      step   "
          "tip defl. max")
    for phi0 in ANGLES:
        sc = scene_for(phi0, args.stop)
        t0 = time.perf_counter()
        coarse = exact_run(sc, ne, h)
        cost = time.perf_counter() - t0
        fine = exact_run(sc, ne, h / 2)
        ref = fine
        step = np.max(np.abs(fine - coarse))        # bounds the error of ``fine`` (order >= 1)
        mesh = np.max(np.abs(exact_run(sc, 2 * ne, h) - coarse))
        run = simulate_reference(sc)
        pre = simulate_reference(scene_for(phi0, args.stop, preload=True))["phi_o"]
        d_def, d_pre = np.max(np.abs(run["phi_o"] - ref)), np.max(np.abs(pre - ref))
        i_def, i_pre = ISSUE[phi0]
        defl = np.max(np.abs(run["tip_deflection"])) / sc.plant.params.L
        print(f"{phi0:6.4f}  {d_def:.2e}  {d_pre:.2e}   ({i_def:.2e}, {i_pre:.2e})        "
              f"{mesh:.1e}        {step:.1e}  {defl:.2%}   [{cost:.0f} s per exact run at h]",
              flush=True)

if __name__ == "__main__":
    main()
