"""The adaptive master on the paper scenes: it never falls to its minimum step.

Before the fix, steps were cut to reach each output point (a remnant of 1e-13 s after a step that
ended just short of it), and a remnant's samples, 1e-13 s apart, made the next extrapolation's
error explode: the filtered scene with the hold took 10^5 steps at ``min_step`` for 2 s."""
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
