"""The adaptive master on the paper scenes with the real native FMUs: its step never collapses
to ``master.min_step`` (issue 26, item 4). Counts from the run stats, not timing."""
import pytest

from orchestration.job import run_scene
from orchestration.scene.schema import load_scene

SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
#: the scenes' default coupling (quadratic extrapolation as input derivatives) and the paper's
#: zero-order hold, the coupling that once took 19,877 steps for 0.02 s
COUPLINGS = {"default": [],
             "hold": ["master.extrapolation=0", "master.input_derivatives=false"]}


@pytest.fixture(scope="module")
def paths(native):
    return {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}


def _stats(paths, scene, extra):
    scene = load_scene(scene, ["stop_time=1.0", "master.adaptive=true", *extra])
    return run_scene(scene, paths, progress=False).stats


@pytest.mark.parametrize("coupling", COUPLINGS)
@pytest.mark.parametrize("scene", SCENES)
@pytest.mark.parametrize("tol", [1e-2, 1e-4])
def test_no_step_is_forced_and_few_are_rejected(paths, scene, coupling, tol):
    """Before the fix every case forced steps through at min_step (slivers before output
    points, 112,088 forced accepts on the filtered scene's hold at 1e-4) and rejected many."""
    st = _stats(paths, scene, [f"master.tolerance={tol}", *COUPLINGS[coupling]])
    assert st.forced_accepts == 0
    assert st.rejected <= 0.1 * st.steps, (st.rejected, st.steps)


_HOLD_START = pytest.mark.xfail(strict=True, reason=(
    "issue 26, left open: the hold at 1e-4 on the flexible scenes still takes steps of a few "
    "min_step at the start (the beam modes in omega_o, held, at a tight tolerance)"))


@pytest.mark.parametrize("scene,coupling,tol", [
    *[(s, c, 1e-2) for s in SCENES for c in COUPLINGS],
    *[(s, "default", 1e-4) for s in SCENES],
    ("rigid_pd", "hold", 1e-4),
    pytest.param("flexible_pd", "hold", 1e-4, marks=_HOLD_START),
    pytest.param("flexible_pd_lowpass", "hold", 1e-4, marks=_HOLD_START)])
def test_the_step_never_falls_to_the_minimum(paths, scene, coupling, tol):
    """No step within ten minimum steps (before the fix: 5e-14 s, slivers before output points
    and a signal rising from 0 whose relative error does not fall with the step)."""
    st = _stats(paths, scene, [f"master.tolerance={tol}", *COUPLINGS[coupling]])
    min_step = load_scene(scene).master.min_step
    assert st.min_step_used > 10 * min_step, (st.min_step_used, st.steps, st.rejected)


@pytest.mark.parametrize("scene", SCENES)
def test_the_energy_estimator_never_rolls_back(paths, scene):
    """master.error_estimator = "energy" (ECCO's residual on the force-cart bond) only sets the
    next step: no step rejected, none forced, none near the minimum."""
    st = _stats(paths, scene, ["master.tolerance=1e-3", "master.error_estimator=energy"])
    assert st.rejected == 0 and st.forced_accepts == 0
    assert st.min_step_used > 10 * load_scene(scene).master.min_step, st.min_step_used


def test_an_unknown_estimator_is_refused():
    with pytest.raises(ValueError, match="master.error_estimator"):
        load_scene("rigid_pd", ["master.error_estimator=residual"])


@pytest.mark.parametrize("estimator", ["extrapolation", "energy"])
def test_a_failed_fmu_step_ends_the_run_with_its_message(paths, estimator, monkeypatch):
    """An FMU error in the middle of an adaptive run stops it with the FMU's message and the rows
    reached, for both estimators (the energy estimator, which takes no FMU state, once raised a
    KeyError freeing states it had not taken)."""
    from orchestration.cosim.master import Master
    from orchestration.cosim.slave import CoSimulationError

    step, calls = Master._step, []

    def failing(self, hist, t0, t1):
        calls.append(t0)
        if len(calls) == 20:
            raise CoSimulationError("the FMU failed here", status=3, time=t0)
        return step(self, hist, t0, t1)

    monkeypatch.setattr(Master, "_step", failing)
    # the Python loop, whose _step is replaced (the compiled loop's failures:
    # tests/cosim/test_compiled_adaptive.py)
    scene = load_scene("flexible_pd_lowpass", ["stop_time=1.0", "master.adaptive=true",
                                               f"master.error_estimator={estimator}",
                                               "master.compiled=false"])
    run = run_scene(scene, paths, progress=False)
    assert "the FMU failed here" in run.summary["stopped"]["fmu_message"]
    assert 0 < len(run.result) < 501
