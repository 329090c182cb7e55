"""The strongly coupled master (``master.algorithm = "implicit"``, orchestration/cosim/implicit.py)
with the real native FMUs on the filtered scene (flexible_pd_lowpass).

Stability is observed as in tests/studies/test_stability.py: the largest pole of the
output samples of a small motion (``initial.phi = 1e-3``, the linear plant, so the samples are those
of a linear system), realised from their block-Hankel matrix.

The scene's own explicit coupling (Gauss-Seidel, controller first, quadratic extrapolation passed
as input derivatives) is not monotone in the step: stable below ~15 ms, with windows of growth and
decay up to ~59 ms, and growing everywhere above. Its largest stable step, bisected on the
master's growth verdict (observed spectral radius 0.99996 at 58.955 ms, 1.00016 at 58.965 ms), is
:data:`EXPLICIT_LIMIT`; the tests check it on both sides and that no stable window lies above it
up to twice it.
"""
import math

import numpy as np
import pytest
from conftest import hand_stepped

from orchestration.job import simulate
from orchestration.scene.keys import ConfigError
from orchestration.scene.records import MasterSettings
from orchestration.scene.schema import load_scene, scene_from_config
from orchestration.studies.reference import simulate_reference
from orchestration.studies.stability import (critical_step, implicit_transition_matrix,
                                             observed_spectral_radius, scene_coupling,
                                             spectral_radius, transition_matrix)

SCENE = "flexible_pd_lowpass"
#: the largest stable communication step of the scene's own explicit coupling (s)
EXPLICIT_LIMIT = 0.05896
SMALL = {"initial.phi": 1e-3, "plant.phi_limit": math.inf, "plant.energy_limit": math.inf,
         "plant.fidelity": "linear"}
OBSERVED = ["phi_o", "omega_o", "F_c", "eta_1", "eta_2"]
IMPLICIT = {"master.algorithm": "implicit"}
JACOBIANS = ("newton", "iqn-ils")
#: the filtered scene's controller (flexible_pd_lowpass.toml)
SCENE_CONTROLLER = {"controller.kp": 500.0, "controller.kd": 5.0, "controller.filter_order": 2,
                    "controller.cutoff": 97.3, "controller.filter_damping": 0.1}


def _growth(H, extra=None, n=80):
    """The observed growth factor per step of a small motion (start-up steps left out)."""
    r = simulate(SCENE, {**SMALL, "master.step": H, "output_interval": H, "stop_time": n * H,
                         **(extra or {})})
    if r.summary["stopped"] is not None:
        return math.inf
    Y = np.column_stack([r.result[c] for c in OBSERVED])[5:]
    return observed_spectral_radius(Y, rtol=1e-8)


# ---------------------------------------------------------------------- settings
@pytest.mark.parametrize("change,message", [
    ({"implicit_tolerance": 0.0}, "master.implicit_tolerance = 0.0 is out of range"),
    ({"max_iterations": 0}, "master.max_iterations = 0 is out of range"),
    ({"implicit_jacobian": "broyden"}, "master.implicit_jacobian = 'broyden' is not allowed"),
    ({"implicit_scheme": "staggered"}, "master.implicit_scheme = 'staggered' is not allowed"),
    ({"algorithm": "implicit", "adaptive": True}, "master.adaptive = true is not allowed"),
    ({"algorithm": "implicit", "output_derivatives": True},
     "master.output_derivatives = true cannot be used here"),
])
def test_settings_are_checked(change, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")) as exc:
        MasterSettings(**change)
    assert "\n" not in str(exc.value)


# ---------------------------------------------------------------------- stability
def test_explicit_limit_is_the_largest_stable_step():
    """The explicit coupling decays just below the limit and grows just above it and on a grid
    up to twice it (no stable window above)."""
    assert _growth(0.999 * EXPLICIT_LIMIT) < 1.0
    for f in (1.001, 1.05, 1.2, 1.4, 1.6, 1.8, 2.0):
        assert _growth(f * EXPLICIT_LIMIT) > 1.0, f


@pytest.mark.parametrize("jacobian", JACOBIANS)
def test_implicit_is_stable_at_twice_the_explicit_limit(jacobian):
    H = 2.0 * EXPLICIT_LIMIT
    assert _growth(H) > 1.5                                  # the explicit coupling grows fast
    rho = _growth(H, {**IMPLICIT, "master.implicit_jacobian": jacobian})
    assert rho < 0.995, rho


# ---------------------------------------------------------------------- accuracy
@pytest.fixture(scope="module")
def reference():
    return simulate_reference(load_scene(SCENE))


@pytest.fixture(scope="module")
def runs():
    return {j: simulate(SCENE, {**IMPLICIT, "master.implicit_jacobian": j}) for j in JACOBIANS}


@pytest.mark.parametrize("jacobian", JACOBIANS)
def test_default_step_is_within_1e4_of_the_monolithic_reference(runs, reference, jacobian):
    r = runs[jacobian]
    assert r.summary["stopped"] is None
    err = np.max(np.abs(r.result["phi_o"] - reference["phi_o"]))
    assert err < 1e-4, err
    s = r.summary
    assert 1 <= s["iterations_per_step_mean"] <= s["iterations_per_step_max"] \
        <= MasterSettings().max_iterations
    assert (s["jacobian_steps"] > 0) == (jacobian == "newton")


def test_newton_and_iqn_converge_to_one_solution(runs):
    """Both iterate to the same fixed point of each step; they differ by what the tolerance
    leaves: a force off by at most 1e-9 max(1, |F_c|) ~ 5e-7 N over a step moves the tip angle
    by far less than 1e-7 rad."""
    a, b = (runs[j].result for j in JACOBIANS)
    assert np.max(np.abs(a["phi_o"] - b["phi_o"])) < 1e-7


#: the serial scheme, the plant first: the controller's force is the one unknown
SERIAL = {**IMPLICIT, "master.implicit_scheme": "serial", "master.first": "plant"}


@pytest.mark.parametrize("jacobian", JACOBIANS)
def test_the_serial_scheme_converges_to_the_same_solution(runs, jacobian):
    """The serial scheme solves the same interface equations with fewer unknowns: the same
    samples to what the tolerance leaves (as Newton against IQN-ILS above), in fewer
    iterations per step with IQN-ILS (the force, a low-pass filter's output, is far better
    predicted than the tip rate with its bending)."""
    r = simulate(SCENE, {**SERIAL, "master.implicit_jacobian": jacobian})
    assert r.summary["stopped"] is None
    assert np.max(np.abs(r.result["phi_o"] - runs[jacobian].result["phi_o"])) < 1e-7
    if jacobian == "iqn-ils":
        assert r.summary["iterations_per_step_mean"] < \
            runs[jacobian].summary["iterations_per_step_mean"]


def test_broydens_update_meets_the_secant_and_changes_nothing_across_it():
    """Broyden's update of Newton's Jacobian: afterwards ``J du = dg``, and ``J v`` is unchanged
    for every ``v`` orthogonal to ``du`` (the least change that meets the secant); a zero
    ``du`` changes nothing."""
    from orchestration.cosim.implicit import _broyden
    rng = np.random.default_rng(7)
    for n in (1, 2, 4):
        J0 = rng.normal(size=(n, n))
        du, dg = rng.normal(size=n), rng.normal(size=n)
        J = J0.copy()
        _broyden(J, du, dg)
        np.testing.assert_allclose(J @ du, dg, rtol=1e-12, atol=1e-12)
        v = rng.normal(size=n)
        v -= (v @ du) / (du @ du) * du
        np.testing.assert_allclose(J @ v, J0 @ v, rtol=1e-12, atol=1e-12)
        J = J0.copy()
        _broyden(J, np.zeros(n), dg)
        assert np.array_equal(J, J0)


def test_a_step_that_does_not_converge_stops_the_run_with_one_line():
    r = simulate(SCENE, {**IMPLICIT, "master.max_iterations": 2, "stop_time": 0.1})
    stopped = r.summary["stopped"]
    assert stopped is not None and stopped["time"] == 0.0
    msg = stopped["fmu_message"]
    assert "\n" not in msg
    assert "did not converge by t = 0.002" in msg and "residual" in msg, msg


# ---------------------------------------------------------------------- the predicted map

@pytest.mark.parametrize("jacobian", JACOBIANS)
@pytest.mark.parametrize("p_extra,in_der", [(0, False), (1, False), (1, True), (2, False),
                                            (2, True)])
@pytest.mark.parametrize("H", [1.1e-3, 2 * EXPLICIT_LIMIT])
def test_linear_plant_follows_the_predicted_map(jacobian, p_extra, in_der, H):
    """The implicit master on the linear plant (off the substep grid at 1.1 ms; twice the
    explicit limit) against the converged map stepped by hand, every sample of the start-up
    included. At master.implicit_tolerance = 1e-12 each step's samples are the fixed point to
    1e-12 of max(1, |sample|) (so the motion is large, phi(0) = 1 rad, on the linear plant:
    every signal is of order 1 or more), and the comparison allows 1e-10 of each signal's
    largest value over 30 steps of a decaying loop."""
    scene = scene_from_config("implicit", {
        **SMALL, "initial.phi": 1.0, "plant.n_modes": 4, "controller.kx": 3.0, "master.step": H,
        "output_interval": H, "stop_time": 30 * H, **IMPLICIT,
        "master.implicit_jacobian": jacobian, "master.extrapolation": p_extra,
        "master.input_derivatives": in_der, "master.implicit_tolerance": 1e-12,
        **SCENE_CONTROLLER})
    res = simulate(scene).result
    hand = hand_stepped(scene, len(res))
    for j, col in enumerate(("phi_o", "omega_o", "x", "F_c")):
        scale = np.abs(res[col]).max()
        np.testing.assert_allclose(res[col], hand[:, j], rtol=0, atol=1e-10 * scale,
                                   err_msg=col)


@pytest.mark.parametrize("jacobian", JACOBIANS)
@pytest.mark.parametrize("first", ["plant", "controller"])
@pytest.mark.parametrize("H", [1.1e-3, 2 * EXPLICIT_LIMIT])
def test_the_serial_scheme_follows_the_predicted_map(jacobian, first, H):
    """The serial scheme, either FMU first, against the same converged map stepped by hand (the
    test above, at the scene's coupling: quadratic extrapolation passed as input
    derivatives): it iterates on fewer unknowns to the same fixed point."""
    scene = scene_from_config("implicit", {
        **SMALL, "initial.phi": 1.0, "plant.n_modes": 4, "controller.kx": 3.0, "master.step": H,
        "output_interval": H, "stop_time": 30 * H, **SERIAL, "master.first": first,
        "master.implicit_jacobian": jacobian, "master.implicit_tolerance": 1e-12,
        **SCENE_CONTROLLER})
    res = simulate(scene).result
    hand = hand_stepped(scene, len(res))
    for j, col in enumerate(("phi_o", "omega_o", "x", "F_c")):
        scale = np.abs(res[col]).max()
        np.testing.assert_allclose(res[col], hand[:, j], rtol=0, atol=1e-10 * scale,
                                   err_msg=col)


def test_prediction_is_stable_at_twice_the_explicit_limit():
    """The predicted spectral radius: the explicit coupling's largest stable step is
    EXPLICIT_LIMIT (stable just below, growing just above), and at twice it the converged implicit
    step decays while the explicit one grows; the same at twice the explicit coupling's first
    crossing (14.64 ms, the end of its first stable range)."""
    scene = load_scene(SCENE)
    p, c = scene.plant.params, scene.controller
    own = dict(algorithm="gauss-seidel", extrapolation=2, input_derivatives=True)
    assert scene_coupling(scene) == {**own, "first": "controller", "output_derivatives": False,
                                     "coupling": "polynomial"}
    rho = lambda H, **k: spectral_radius(transition_matrix(p, c, H, **k))  # noqa: E731
    assert rho(0.9999 * EXPLICIT_LIMIT, **own) < 1.0 < rho(1.0001 * EXPLICIT_LIMIT, **own)
    first = critical_step(p, c, **own)
    for H in (2 * EXPLICIT_LIMIT, 2 * first):
        assert rho(H, **own) > 1.0
        assert rho(H, **{**own, "algorithm": "implicit"}) < 1.0
        assert rho(H, **{**own, "algorithm": "implicit"}) == spectral_radius(
            implicit_transition_matrix(p, c, H))


def test_implicit_is_observed_stable_at_twice_the_first_crossing():
    H = 2 * 0.0146426972730365
    assert _growth(H) > 1.0
    assert _growth(H, IMPLICIT) < 1.0


#: the implicit coupling's predicted boundaries on the filtered scene (implicit_transition_matrix,
#: quadratic interpolation with input derivatives): the first crossing of rho = 1 (a window of
#: growth from 24.2 ms to 28.1 ms) and the end of the stable range above it
IMPLICIT_BOUNDARIES = ("first", "upper")


@pytest.fixture(scope="module")
def implicit_boundaries():
    import scipy.optimize
    scene = load_scene(SCENE)
    p, c = scene.plant.params, scene.controller
    rho = lambda H: spectral_radius(implicit_transition_matrix(p, c, H)) - 1.0  # noqa: E731
    return {"first": critical_step(p, c, algorithm="implicit", extrapolation=2,
                                   input_derivatives=True),
            "upper": scipy.optimize.brentq(rho, 0.1, 0.16, xtol=1e-12)}


@pytest.mark.parametrize("factor", (0.9, 0.95, 0.98, 1.02, 1.05, 1.1))
@pytest.mark.parametrize("boundary", IMPLICIT_BOUNDARIES)
def test_implicit_boundaries_observed(implicit_boundaries, boundary, factor):
    """Three points on each side of each boundary: the master's observed growth factor (linear
    plant, small motion) is the predicted spectral radius, and so is the verdict."""
    Hb = implicit_boundaries[boundary]
    assert 0.02 < Hb < 0.2
    H = factor * Hb
    scene = load_scene(SCENE)
    predicted = spectral_radius(implicit_transition_matrix(scene.plant.params, scene.controller,
                                                           H))
    grows = factor > 1              # both boundaries go from decay to growth
    assert (predicted > 1) == grows, predicted
    observed = _growth(H, IMPLICIT)
    assert observed == pytest.approx(predicted, abs=1e-6)
    assert (observed > 1) == grows


def test_iterations_are_in_the_summary_and_the_text(runs):
    """The run's stats, its summary and the text output say the iterations per step; the mean
    is the total over the steps, each step at least one evaluation and at most the cap."""
    from orchestration.report.text import run_lines
    r = runs["iqn-ils"]
    st, s = r.stats, r.summary
    assert st.steps == 5000 and st.steps <= st.iterations <= st.steps * st.max_iterations
    assert s["iterations_per_step_mean"] == st.iterations / st.steps
    assert s["iterations_per_step_max"] == st.max_iterations
    line = next(x for x in run_lines(SCENE, s) if "interface iterations per step" in x)
    assert f"mean {st.iterations / st.steps:.3g}, max {st.max_iterations}" in line
    explicit = simulate(SCENE, {"stop_time": 0.1})
    assert "iterations_per_step_mean" not in explicit.summary
    assert not any("iterations" in x for x in run_lines(SCENE, explicit.summary))
