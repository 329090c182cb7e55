"""The monolithic reference: plant and controller as one ODE, solved by scipy at tight tolerance.

It is the continuous-time closed loop that the co-simulation approaches as its communication step
shrinks, and the yardstick of the co-simulation's error. With a sampled controller
(``controller.sample_period > 0``) it is the hybrid loop: the plant solved between the
controller's instants with the force held, the controller's difference equation at its ticks
(:mod:`controller_fmu.sampled`), which the co-simulation meets up to the plant FMU's own
integration error (its coupling is exact on the instants' grid). Its results have the columns of the
master's results (:data:`COLUMNS`), on the same output grid.

At ``plant.fidelity = "exact"`` the plant is the geometrically exact beam, whose stiff axial modes
rule out an explicit solver: the reference is then the exact rung's monolithic loop
(:class:`~orchestration.studies.exact_loop.ExactLoop` on the C kernel), plant and controller
stepped as one system by Radau IIA at the plant FMU's own step ``plant.exact_step``, so that it
measures the coupling's error, not the time step's (``bench/exact_convergence.py`` gives that).
"""
from __future__ import annotations

import math

import numpy as np

from controller_fmu.spec import model_for as controller_model
from plant_fmu.dynamics import model_for

from ..scene.keys import ConfigError

__all__ = ["COLUMNS", "ClosedLoop", "simulate_reference", "exact_reference", "check_reference",
           "exact_first_mode_tip"]

#: Result columns, time first (a numpy structured array of float64).
COLUMNS = ("time", "x", "x_dot", "phi_o", "omega_o", "F_c", "tip_deflection", "eta_1", "energy")


class ClosedLoop:
    """The monolithic closed loop of a scene: state ``[plant state, filter state]``."""

    def __init__(self, scene):
        if not scene.resolved:
            raise ConfigError(f"{scene.name}: plant.n_modes or plant.fidelity is 'auto': choose "
                              "the model first (orchestration.studies.fidelity.select_model)")
        p, c = scene.plant.params, scene.controller
        self.plant = model_for(p, scene.plant.fidelity)
        self.ctrl = controller_model(c)
        self.np = self.plant.nx
        self.x0 = np.concatenate([
            self.plant.initial_state(phi=scene.initial.phi, x=scene.initial.x,
                                     phi_dot=scene.initial.phi_dot, x_dot=scene.initial.x_dot),
            self.ctrl.initial_state()])
        self.Af, self.bf = self.ctrl.Af, self.ctrl.Bf[:, 0]
        # A filter starting at rest outputs F_c = 0, which is what the controller FMU does too.

    def sensors(self, z):
        phi_o, omega_o = self.plant.tip_angle(z[:self.np])
        return (float(z[0]), phi_o, omega_o)

    def force(self, z) -> float:
        return self.ctrl.output(z[self.np:], self.sensors(z))

    def rhs(self, t, z):
        y = self.sensors(z)
        xp, xc = z[:self.np], z[self.np:]
        F = self.ctrl.output(xc, y)
        dz = np.empty_like(z)
        dz[:self.np] = self.plant.rhs(t, xp, F)
        if xc.size:
            dz[self.np:] = self.Af @ xc + self.bf * self.ctrl.error_signal(y)
        return dz

    def row(self, t, z) -> tuple:
        o = self.plant.outputs(t, z[:self.np])
        eta = o["eta"]
        return (t, o["x_o"], o["x_dot"], o["phi_o"], o["omega_o"], self.force(z),
                o["tip_deflection"], float(eta[0]) if eta.size else 0.0, o["energy"])


def simulate_reference(scene, rtol: float = 1e-12, atol: float = 1e-12, method: str = "DOP853",
                       progress=None):
    """Solve the scene's closed loop monolithically; a structured array on the output grid.

    At ``plant.fidelity = "exact"`` the loop is the exact beam's (:func:`exact_reference`;
    ``rtol``, ``atol`` and ``method`` do not apply). ``progress(fraction)``: called as the
    solution advances (the fraction: the solver's time over the stop time), and with 1.0 at the
    end. Raises ``RuntimeError`` if the solver fails (the message is scipy's).
    """
    import scipy.integrate      # here: a run without ``--reference`` does not need it

    if scene.resolved and scene.plant.fidelity == "exact":
        return exact_reference(scene, progress)
    loop = ClosedLoop(scene)
    if scene.controller.sampled:
        return _sampled_reference(scene, loop, rtol, atol, method, progress)
    t_end, dt = scene.output.stop_time, scene.output.output_interval
    n_out = int(round(t_end / dt))
    t_eval = np.arange(n_out + 1) * dt
    t_eval[-1] = min(t_eval[-1], t_end)
    rhs = loop.rhs
    if progress is not None and t_end > 0:
        reached = [0.0]

        def telling(t, z, f=loop.rhs):
            if t >= reached[0] + 1e-3 * t_end:     # at most a thousand reports
                reached[0] = t
                progress(min(t / t_end, 1.0))
            return f(t, z)
        rhs = telling
    sol = scipy.integrate.solve_ivp(rhs, (0.0, t_end), loop.x0, method=method, rtol=rtol,
                                    atol=atol, t_eval=t_eval)
    if not sol.success:
        raise RuntimeError(f"reference solution failed: {sol.message}")
    out = np.zeros(sol.t.size, dtype=[(c, "f8") for c in COLUMNS])
    for i, t in enumerate(sol.t):
        out[i] = loop.row(t, sol.y[:, i])
    if progress is not None:
        progress(1.0)
    return out


def exact_reference(scene, progress=None):
    """The monolithic reference of a scene at ``plant.fidelity = "exact"``: the exact beam of
    ``plant.n_elements`` elements with the scene's controller, stepped as one system by
    Radau IIA at ``plant.exact_step``, the filter in the same stages
    (:class:`~orchestration.studies.exact_loop.ExactLoop`, C kernel); the columns of :data:`COLUMNS` (``eta_1``: the tip deflection over
    :func:`exact_first_mode_tip`, as the native FMU gives it). ``progress(fraction)``: called
    at each output point. ConfigError (one line, :func:`check_reference`) when the loop cannot
    take the scene."""
    loop = _exact_loop(scene)
    plant, ini = loop.plant, scene.initial
    x0 = plant.initial_state(phi=ini.phi, x=ini.x, phi_dot=ini.phi_dot, x_dot=ini.x_dot)
    t_end, dt = scene.output.stop_time, scene.output.output_interval
    n1 = exact_first_mode_tip(scene.plant.params)
    rows = []
    for k, (st, F) in enumerate(loop.points(x0, t_end, dt, progress)):
        o = loop.ga.outputs(st)
        rows.append((k * dt, o[0], o[1], o[2], o[3], F, o[5], o[5] / n1, o[6]))
    out = np.zeros(len(rows), dtype=[(col, "f8") for col in COLUMNS])
    for i, r in enumerate(rows):
        out[i] = r
    return out


def check_reference(scene) -> None:
    """ConfigError (one line) if :func:`simulate_reference` cannot take ``scene``, before a run
    that asks for it: at the exact rung, a saturating controller (the exact loop has no
    saturation) or a ``plant.step`` that does not divide the output interval."""
    if scene.resolved and scene.plant.fidelity == "exact":
        _exact_loop(scene)


def _exact_loop(scene):
    from plant_fmu.exact import exact_plant

    from .exact_loop import ExactLoop

    h, dt = scene.plant.exact_step, scene.output.output_interval
    if scene.controller.saturates:
        raise ConfigError(f"{scene.name}: the exact reference has no force saturation "
                          "(controller.force_limit)")
    per = round(dt / h)
    if per < 1 or abs(per * h - dt) > 1e-12 * dt:
        raise ConfigError(f"{scene.name}: the exact reference steps at plant.exact_step = {h:g}, "
                          f"which must divide output_interval = {dt:g}")
    return ExactLoop(exact_plant(scene.plant.params), controller_model(scene.controller), h,
                     kernel=True, method="radau")


def exact_first_mode_tip(p) -> float:
    """``N_1(L)``, the first cantilever mode's tip deflection (mass-normalised, the mesh of
    ``p``): the exact rung's ``eta_1`` is its tip deflection over it (the modal coordinate that
    alone would give that deflection), as the native FMU computes it."""
    from plant_fmu.beam import unit_beam

    return float(unit_beam(p.n_elements, 1).tip_deflection[0] * (1.0 / math.sqrt(p.rhoA * p.L)))


def _sampled_reference(scene, loop: ClosedLoop, rtol, atol, method, progress):
    """The closed loop with the sampled controller (controller_fmu/sampled.py, the
    specification): the plant solved by scipy between the controller's instants (every tick and
    tick + delay) with the force held, the controller taking its samples at the ticks. A row at
    an instant holds the force that acts from it on (what the master records there)."""
    import scipy.integrate

    from controller_fmu.sampled import SampledController

    c = scene.controller
    ctrl = SampledController(c)
    plant, n = loop.plant, loop.np
    t_end, dt = scene.output.stop_time, scene.output.output_interval
    n_out = int(round(t_end / dt))
    t_out = np.arange(n_out + 1) * dt
    t_out[-1] = min(t_out[-1], t_end)
    out = np.zeros(t_out.size, dtype=[(col, "f8") for col in COLUMNS])
    xp = np.array(loop.x0[:n], dtype=float)
    t, i = 0.0, 0

    def row(t, x, F):
        o = plant.outputs(t, x)
        eta = o["eta"]
        return (t, o["x_o"], o["x_dot"], o["phi_o"], o["omega_o"], F, o["tip_deflection"],
                float(eta[0]) if eta.size else 0.0, o["energy"])

    while True:
        y = loop.sensors(np.concatenate([xp, np.zeros(loop.x0.size - n)]))
        F = ctrl.output(y)                         # the force from t on
        while i < t_out.size and t_out[i] <= t + ctrl.tol:
            out[i] = row(t_out[i], xp, F)          # (t_out[i] == t here: the grids share it)
            i += 1
        if t >= t_end - ctrl.tol or i >= t_out.size:
            break
        nxt = min(ctrl.next_instant(t), t_end)
        # the output points inside (t, nxt), then nxt itself
        inside = t_out[(t_out > t + ctrl.tol) & (t_out < nxt - ctrl.tol)]
        sol = scipy.integrate.solve_ivp(lambda s, x: plant.rhs(s, x, F), (t, nxt), xp,
                                        method=method, rtol=rtol, atol=atol,
                                        t_eval=np.append(inside, nxt))
        if not sol.success:
            raise RuntimeError(f"reference solution failed: {sol.message}")
        for k, ts in enumerate(inside):
            out[i] = row(ts, sol.y[:, k], F)
            i += 1
        ctrl.step(t, nxt - t, y)
        xp = sol.y[:, -1]
        t = nxt
        if progress is not None and t_end > 0:
            progress(min(t / t_end, 1.0))
    if progress is not None:
        progress(1.0)
    return out[:i]
