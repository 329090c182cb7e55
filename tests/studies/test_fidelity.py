"""Fidelity selection (plant.n_modes = "auto", plant.fidelity = "auto"), each choice checked by a
measurement of its own: the time responses fitted by the matrix pencil, or the co-simulated FMUs."""
import numpy as np
import pytest

from orchestration.scene.keys import ConfigError
from orchestration.studies.fidelity import output_difference, select_model
from orchestration.studies.reference import simulate_reference
from orchestration.studies.fit import dominant_oscillation
from orchestration.job import run_scene
from orchestration.scene.schema import load_scene

OUTPUTS = ["x", "phi_o", "omega_o", "F_c"]


def _with(scene, **values):
    return load_scene(scene, {k.replace("__", "."): v for k, v in values.items()})


def test_rigid_scene_needs_no_mode():
    scene = load_scene("rigid_pd", ["plant.n_modes=auto", "stop_time=3"])
    resolved, report = select_model(scene)
    assert resolved.plant.n_modes == 0 and report["n_modes"] == 0
    # measured: the rigid run agrees with a two-mode beam to the tolerance
    rigid = simulate_reference(_with(resolved, plant__n_modes=0), rtol=1e-8, atol=1e-10)
    beam = simulate_reference(_with(resolved, plant__n_modes=2), rtol=1e-8, atol=1e-10)
    assert max(output_difference(rigid, beam, OUTPUTS).values()) <= report["tolerance"]


def test_flexible_pd_needs_at_least_two_modes():
    scene = load_scene("flexible_pd", ["plant.n_modes=auto", "stop_time=2",
                                       "fidelity.max_modes=4"])
    resolved, report = select_model(scene)
    assert resolved.plant.n_modes >= 2
    assert "predict stability wrongly" in report["reason"]
    # measured on the time response (the matrix pencil over the whole 4 s: one mode's bending
    # decays at only 0.05/s): one mode lets the bending oscillation decay, two let it grow
    rates = {}
    for n in (1, 2):
        run = simulate_reference(_with(scene, plant__n_modes=n, plant__fidelity="nonlinear",
                                       initial__phi=0.05, stop_time=4.0), rtol=1e-8, atol=1e-10)
        rates[n] = dominant_oscillation(run["time"], run["eta_1"], (60.0, 1e4)).rate
    assert rates[1] < 0 < rates[2]


def _cosim_phi(fmus, scene, fidelity):
    paths = {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}
    return run_scene(_with(scene, plant__fidelity=fidelity), paths, progress=False)


@pytest.mark.slow
def test_auto_keeps_the_linear_rung_only_where_its_error_figure_allows(fmus):
    """From 0.05 rad the run starts on the linear rung; it keeps it exactly when the rung's
    stated error figure is within the tolerance. Checked by the co-simulated FMUs: the linear
    and nonlinear runs differ by no more than the two rungs' figures together (each bounds its
    distance to the exact beam)."""
    scene = load_scene("flexible_pd_lowpass", ["plant.fidelity=auto", "initial.phi=0.05",
                                               "stop_time=3"])
    r = run_scene(scene, {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]},
                  progress=False)
    lin, non = _cosim_phi(fmus, r.scene, "linear"), _cosim_phi(fmus, r.scene, "nonlinear")
    f_lin, f_non = lin.summary["error_figure"], non.summary["error_figure"]
    kept = f_lin["relative"] <= scene.fidelity.tolerance
    assert r.summary["model"]["fidelity"] == ("linear" if kept else "nonlinear")
    assert r.summary["model"]["n_modes"] == 4
    gap = np.max(np.abs(lin.result["phi_o"] - non.result["phi_o"]))
    assert gap <= f_lin["figure"] + f_non["figure"]


@pytest.mark.slow
def test_filtered_scene_from_pi_over_6_climbs_to_the_nonlinear_rung(fmus):
    scene = load_scene("flexible_pd_lowpass", ["plant.fidelity=auto", "stop_time=3"])
    r = run_scene(scene, {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]},
                  progress=False)
    assert r.scene.plant.fidelity == "nonlinear"
    assert "linear: error <=" in r.summary["model"]["reason"]
    assert "climbs to nonlinear" in r.summary["model"]["reason"]
    # measured by the co-simulated FMUs: the linear rung is off by more than the tolerance
    lin = _cosim_phi(fmus, r.scene, "linear").result["phi_o"]
    assert (np.max(np.abs(lin - r.result["phi_o"])) / np.max(np.abs(r.result["phi_o"]))
            > scene.fidelity.tolerance)


@pytest.mark.parametrize("item,fragment", [
    ("plant.n_modes=many", "plant.n_modes = 'many' is not allowed; allowed: an integer"),
    ("plant.fidelity=exactly", "plant.fidelity = 'exactly' is not allowed; allowed: nonlinear, "
                               "linear"),
    ("fidelity.tolerance=0", "fidelity.tolerance = 0.0 is out of range"),
    ("fidelity.max_modes=0", "fidelity.max_modes = 0 is out of range"),
    ('fidelity.outputs=["phi"]', "fidelity.outputs = ['phi'] is not allowed"),
])
def test_bad_fidelity_keys_are_named(item, fragment):
    with pytest.raises(ConfigError, match=fragment.replace("[", r"\[").replace("]", r"\]")
                       .replace("(", r"\(")):
        load_scene("flexible_pd", [item])


def test_analyze_refuses_auto(capsys):
    from orchestration.cli import main
    assert main(["analyze", "--set", "plant.n_modes=auto"]) == 2
    assert "plant.n_modes = 'auto' is chosen by a run" in capsys.readouterr().err
