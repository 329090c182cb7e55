"""The adaptive master on the paper scenes: it never falls to its minimum step.

Before the fix, steps were cut to reach each output point (a remnant of 1e-13 s after a step that
ended just short of it), and a remnant's samples, 1e-13 s apart, made the next extrapolation's
error explode: the filtered scene with the hold took 10^5 steps at ``min_step`` for 2 s."""
import numpy as np
import pytest

from orchestration import simulate

SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")


@pytest.mark.parametrize("tol", [1e-2, 1e-4])
@pytest.mark.parametrize("scene", SCENES)
def test_never_at_its_minimum_step(scene, tol):
    run = simulate(scene, {"master.adaptive": True, "master.tolerance": tol, "stop_time": 1.0})
    s, m = run.stats, run.scene.master
    assert s.forced_accepts == 0
    assert s.min_step_used > 2 * m.min_step


def test_the_hold_does_not_collapse():
    """The paper's zero-order hold at a tolerance of 1e-2: first-order steps, not the minimum."""
    run = simulate("flexible_pd_lowpass", {"master.adaptive": True, "master.tolerance": 1e-2,
                                           "master.extrapolation": 0,
                                           "master.input_derivatives": False, "stop_time": 1.0})
    s, m = run.stats, run.scene.master
    assert s.forced_accepts == 0 and s.min_step_used > 2 * m.min_step


def _error(run):
    return float(np.max(np.abs(run.result["phi_o"] - run.reference["phi_o"])))


def test_energy_estimator_steps_without_rollback(monkeypatch):
    """ECCO's estimator: no step rejected, no FMU state taken but the first step's (its
    prediction corrected, as at a fixed step), and the error against the monolithic reference
    falls as the tolerance does."""
    from orchestration.cosim.slave import Slave

    taken = []
    get_state = Slave.get_state
    monkeypatch.setattr(Slave, "get_state", lambda self: taken.append(self) or get_state(self))
    errors = []
    for tol in (1e-2, 1e-4):
        run = simulate("flexible_pd_lowpass", {
            "master.adaptive": True, "master.error_estimator": "energy", "master.tolerance": tol,
            "master.max_step": 0.01, "output_interval": 0.01, "stop_time": 3.0}, reference=True)
        assert run.stats.rejected == 0 and run.stats.forced_accepts == 0
        assert len(taken) == 2          # the two FMUs, once, for the corrected first step
        taken.clear()
        assert run.stats.min_step_used > 2 * run.scene.master.min_step
        errors.append(_error(run))
    assert errors[1] < errors[0]


def test_energy_estimator_needs_the_cart_velocity():
    from orchestration.cosim.master import VELOCITY, _power_bond
    from orchestration.scene.records import MasterSettings

    class Coupling:            # a loop whose plant records no velocity
        connections = [type("C", (), {"src": "c", "src_var": "F", "dst": "p", "dst_var": "F"})()]
        outputs = {"c": ["F"], "p": ["phi_o"]}
        recorded = {"c": [], "p": []}
        out_index = {"c": {"F": 0}}

    with pytest.raises(ValueError, match=VELOCITY):
        _power_bond(Coupling())
    with pytest.raises(ValueError, match="master.error_estimator"):
        MasterSettings(error_estimator="ecco")
