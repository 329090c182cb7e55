"""The Hermite coupling (``master.coupling = "hermite"``; orchestration/cosim/coupling.py,
``Coupling.hermite`` and ``hermite_rows``): its weights against a second construction, its
order of convergence against the monolithic reference, its compiled loop against its Python
loop, and the settings it refuses."""
from __future__ import annotations

import math

import numpy as np
import pytest

from orchestration.cosim.coupling import hermite_rows
from orchestration.scene.keys import ConfigError
from orchestration.scene.schema import load_scene
from orchestration.studies.reference import simulate_reference

from test_compiled import assert_same_rows, both, pair, unzipped  # noqa: F401 (fixtures)


# ---------------------------------------------------------------------- the weights
def _least_squares_quadratic(coef, h):
    """The least-squares quadratic over [0, h] of the polynomial ``coef`` (power basis in s),
    by a second route: dense Gauss-Legendre samples and numpy's lstsq; (average, value, slope,
    second derivative at 0)."""
    x, w = np.polynomial.legendre.leggauss(20)
    s = (x + 1) * h / 2
    y = np.polynomial.polynomial.polyval(s, coef)
    V = np.vander(s, 3, increasing=True) * np.sqrt(w)[:, None]
    a = np.linalg.lstsq(V, y * np.sqrt(w), rcond=None)[0]
    return np.array([a[0] + a[1] * h / 2 + a[2] * h * h / 3, a[0], a[1], 2 * a[2]])


@pytest.mark.parametrize("q", [1, 2, 3, 4])
@pytest.mark.parametrize("h", [1e-3, 2e-3, 0.5])
def test_rows_are_the_least_squares_quadratic_of_the_taylor_and_hermite_polynomials(q, h):
    """On a random polynomial of degree 2q + 1 (which its Hermite data determine exactly) and of
    degree q (its Taylor data): the rows applied to the samples' values and derivatives give the
    least-squares quadratic that dense samples give."""
    rng = np.random.default_rng(q)
    for _ in range(3):
        coef = rng.standard_normal(2 * q + 2) / h ** np.arange(2 * q + 2)
        ders = [np.polynomial.polynomial.polyder(coef, j) if j else coef for j in range(q + 1)]
        at = [[np.polynomial.polynomial.polyval(t, d) for d in ders] for t in (0.0, h)]
        got = hermite_rows(q, True, h) @ np.array(at[0] + at[1])
        want = _least_squares_quadratic(coef, h)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
        taylor = coef[:q + 1]
        got = hermite_rows(q, False, h) @ np.array([taylor[j] * math.factorial(j)
                                                    for j in range(q + 1)])
        want = _least_squares_quadratic(taylor, h)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


# ---------------------------------------------------------------------- accuracy
#: the plant integrated far below the coupling's error (Dormand-Prince at 1e-11)
TIGHT = ["plant.integrator=dopri5", "plant.rtol=1e-11", "plant.atol=1e-12", "stop_time=2"]


def _error(pair, sets) -> float:
    from orchestration.job import run_scene
    scene = load_scene("flexible_pd_lowpass", [*TIGHT, "fidelity.companion=false", *sets])
    run = run_scene(scene, pair, progress=False)
    ref = simulate_reference(scene)
    assert len(run.result) == len(ref)
    return float(np.max(np.abs(run.result["phi_o"] - ref["phi_o"])))


@pytest.mark.slow
def test_the_coupling_error_falls_at_fifth_order_and_far_below_the_polynomial_one(pair):
    """The filtered scene against the monolithic reference (DOP853 at 1e-12), the plant first:
    halving the step from 2 ms divides the error by at least 2^4.5 (the plant's input, a
    fourth-order Taylor polynomial, errs by O(h^5); measured 2^6), and at 1 ms the error is at
    least 100 times below that of the scene's polynomial coupling (third order)."""
    hermite = ["master.coupling=hermite", "master.first=plant"]
    e2 = _error(pair, ["master.step=2e-3", *hermite])
    e1 = _error(pair, ["master.step=1e-3", *hermite])
    poly = _error(pair, ["master.step=1e-3"])
    assert math.log2(e2 / e1) >= 4.5, (e2, e1)
    assert e1 * 100 <= poly, (e1, poly)


# ---------------------------------------------------------------------- the compiled loop
@pytest.mark.parametrize("first", ["plant", "controller"])
@pytest.mark.parametrize("filter_order", [2, 0])
def test_the_compiled_loop_is_bit_identical(pair, unzipped, first, filter_order):  # noqa: F811
    """The compiled loop against the Python loop, row for row and bit for bit, with either FMU
    first and a controller with a filter or without (a feedthrough FMU)."""
    sets = ["master.coupling=hermite", f"master.first={first}", "stop_time=0.5",
            f"controller.filter_order={filter_order}", "master.step=1e-3"]
    if filter_order == 0:
        sets += ["controller.kd=2"]
    py, c = both("flexible_pd_lowpass", sets, pair, unzipped)
    assert py.summary["completed"] and c.summary["completed"]
    assert_same_rows(py.result, c.result)
    assert np.ptp(c.result["phi_o"]) > 0.01


# ---------------------------------------------------------------------- settings
@pytest.mark.parametrize("item, why", [
    ("master.fmus=python", "the pythonfmu FMUs give no output derivatives"),
    ("master.algorithm=jacobi", "Gauss-Seidel coupling"),
    ("master.adaptive=true", "fixed step"),
    ("master.input_derivatives=false", "master.input_derivatives = false"),
    ("master.interface=model-exchange", "co-simulation FMUs")])
def test_settings_it_cannot_take_are_refused_naming_why(item, why):
    with pytest.raises(ConfigError, match="master.coupling = 'hermite' cannot be used here"
                                          ".*" + why):
        load_scene("flexible_pd_lowpass", ["master.coupling=hermite", item])


def test_a_rung_without_output_derivatives_is_refused_naming_it():
    """The stiffened and exact rungs' FMUs give no output derivatives."""
    for fidelity in ("stiffened", "exact"):
        with pytest.raises(ConfigError, match=f"plant.fidelity = '{fidelity}' cannot be used "
                                              "with master.coupling = 'hermite'"):
            load_scene("flexible_pd_lowpass", ["master.coupling=hermite",
                                               f"plant.fidelity={fidelity}"])


def test_an_fmu_without_output_derivatives_is_refused_with_a_message():
    """A slave whose FMU declares no output derivatives (maxOutputDerivativeOrder 0) is named."""
    from types import SimpleNamespace

    from orchestration.cosim.coupling import Coupling
    from orchestration.scene.records import MasterSettings
    from orchestration.scene.wiring import parse_connection
    from orchestration.scene.records import DEFAULT_CONNECTIONS

    class Fake(SimpleNamespace):
        def vr(self, name):
            return 0
    slaves = {n: Fake(output_derivative_order=order, interpolates_inputs=True, variables={},
                      md=None) for n, order in (("plant", 0), ("controller", 4))}
    with pytest.raises(ValueError, match="needs the output derivatives of every FMU.*plant "
                                         "gives none"):
        Coupling(slaves, [parse_connection(c) for c in DEFAULT_CONNECTIONS], {},
                 MasterSettings(coupling="hermite"))


def test_the_stability_prediction_has_its_map_and_a_run_checks_its_steps():
    """The scene's coupling for the stability study is the Hermite one (its transition matrix:
    tests/studies/test_stability.py), and a run's step warning judges it: none at 2 ms, the
    coupling's predicted limit beyond its first crossing (14.69 ms with the plant first), the
    plant step's limit first."""
    from orchestration.studies.stability import hermite_coupling, scene_coupling, step_warning
    scene = load_scene("flexible_pd_lowpass", ["master.coupling=hermite", "master.first=plant"])
    assert scene_coupling(scene) == hermite_coupling("plant")
    assert step_warning(scene) is None
    beyond = load_scene("flexible_pd_lowpass", ["master.coupling=hermite", "master.first=plant",
                                                "master.step=0.016", "output_interval=0.016"])
    assert "master.step = 0.016 s is beyond the stability limit" in step_warning(beyond)
    plant = load_scene("flexible_pd_lowpass", ["master.coupling=hermite", "plant.step=2e-3"])
    assert "plant.step" in step_warning(plant)


def test_a_sampled_controller_takes_its_own_coupling_whatever_master_coupling_says():
    """A sampled controller couples exactly on its ticks (Jacobi, held inputs): the scene's
    master.coupling does not apply to it, as its algorithm and extrapolation do not."""
    scene = load_scene("flexible_pd_lowpass", ["master.coupling=hermite",
                                               "controller.sample_period=0.002"])
    m = scene.run_master
    assert (m.algorithm, m.coupling, m.input_derivatives) == ("jacobi", "polynomial", False)
