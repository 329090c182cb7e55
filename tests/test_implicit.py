"""The strongly coupled master (``master.algorithm = "implicit"``, orchestration/cosim/implicit.py)
with the real native FMUs on the filtered scene (flexible_pd_lowpass).

Stability is observed as in tests/test_stability_boundaries.py: the largest pole of the output
samples of a small motion (``initial.phi = 1e-3``, the linear plant, so the samples are those of a
linear system), realised from their block-Hankel matrix.

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

from orchestration.job import simulate
from orchestration.scene.keys import ConfigError
from orchestration.scene.records import MasterSettings
from orchestration.studies.reference import simulate_reference
from orchestration.studies.stability import observed_spectral_radius

SCENE = "flexible_pd_lowpass"
#: the largest stable communication step of the scene's own explicit coupling (s)
EXPLICIT_LIMIT = 0.05896
SMALL = {"initial.phi": 1e-3, "plant.phi_limit": math.inf, "plant.energy_limit": math.inf,
         "plant.fidelity": "linear"}
OBSERVED = ["phi_o", "omega_o", "F_c", "eta_1", "eta_2"]
IMPLICIT = {"master.algorithm": "implicit"}
JACOBIANS = ("newton", "iqn-ils")


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
    from orchestration.scene.schema import load_scene
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


def test_a_step_that_does_not_converge_stops_the_run_with_one_line():
    r = simulate(SCENE, {**IMPLICIT, "master.max_iterations": 2, "stop_time": 0.1})
    stopped = r.summary["stopped"]
    assert stopped is not None and stopped["time"] == 0.0
    msg = stopped["fmu_message"]
    assert "\n" not in msg
    assert "did not converge by t = 0.002" in msg and "residual" in msg, msg
