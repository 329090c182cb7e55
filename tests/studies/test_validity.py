"""The measured validity bound (orchestration/studies/validity.py, bench/validity_map.py) and
``plant.fidelity = "auto"`` climbing the ladder on it (orchestration/studies/fidelity.py)."""
import json
import math

import numpy as np
import pytest

from orchestration.job import run_scene
from orchestration.studies.summary import summarize
from orchestration.report.text import run_lines
from orchestration.scene.schema import load_scene
from orchestration.studies.fidelity import available_ladder, climb
from orchestration.studies.reference import COLUMNS, simulate_reference
from orchestration.studies.validity import BOUND_FILE, RANGE, bounds

DATA = json.loads(BOUND_FILE.read_text(encoding="utf-8"))


def _model(rung, f):
    """The JSON's model evaluated here, independently of RungBound (its terms written out), at
    the features ``f`` (D, W, A, T, I, V)."""
    m = DATA["rungs"][rung]["model"]
    value = {**f, "A3": f["A"] ** 3}
    return max(m["floor"], sum(c * value[k] for k, c in m["terms"].items()))


@pytest.mark.parametrize("rung", sorted(DATA["rungs"]))
def test_the_bound_bounds_every_error_it_was_fitted_on(rung):
    pts = np.asarray(DATA["rungs"][rung]["fit_points"])      # the features (RANGE), E
    assert len(pts) > 50
    b = bounds()[rung]
    assert np.all(pts[:, -1] <= b(dict(zip(RANGE, pts.T))))


@pytest.mark.parametrize("rung", sorted(DATA["rungs"]))
def test_the_bound_bounds_the_held_out_case(rung):
    """The sweep's held-out case (bench/validity_map.py HELD_OUT) was measured, not fitted."""
    pts = np.asarray(DATA["rungs"][rung]["held_out_points"])
    assert len(pts) > 5
    assert all(row[-1] <= _model(rung, dict(zip(RANGE, row))) for row in pts)


def _history(scene, tip, omega, phi):
    """A result with the given histories (the columns the summary reads)."""
    n = len(tip)
    res = np.zeros(n, dtype=[(c, "f8") for c in COLUMNS])
    res["time"] = np.arange(n) * scene.output.output_interval
    res["tip_deflection"], res["omega_o"], res["phi_o"] = tip, omega, phi
    return res


def test_the_summary_states_the_model_evaluated_on_the_runs_history():
    scene = load_scene("flexible_pd_lowpass", {"stop_time": 1.0, "initial.phi": 0.2})
    res = simulate_reference(scene, rtol=1e-8, atol=1e-10)
    v = summarize(res, scene)["validity"]
    L, t = scene.plant.params.L, res["time"]
    d = np.abs(res["tip_deflection"]) / L
    f = {"D": d.max(), "W": np.max(np.abs(res["omega_o"])), "A": np.max(np.abs(res["phi_o"])),
         "T": np.max(d * t), "I": np.trapezoid(d, t),
         "V": np.sum(np.abs(np.diff(res["tip_deflection"]))) / L}
    assert v["rung"] == "nonlinear" and v["warnings"] == []
    assert v["model_form_error"] == pytest.approx(_model("nonlinear", f), rel=1e-9)
    assert v["relative"] == pytest.approx(v["model_form_error"] / f["A"], rel=1e-12)
    text = "\n".join(run_lines(scene.name, summarize(res, scene)))
    assert f"model-form error <= {v['model_form_error']:.1e} rad" in text
    assert "5 % of L" not in text and "5 %" not in text


def test_a_run_beyond_the_measured_range_is_flagged():
    scene = load_scene("flexible_pd_lowpass", {"stop_time": 0.02})
    rng = DATA["rungs"]["nonlinear"]["range"]
    L = scene.plant.params.L
    tip = np.linspace(0, 1.5 * rng["D"] * L, 11)
    inside = summarize(_history(scene, tip / 2, np.full(11, 1.0), np.full(11, 0.1)), scene)
    assert inside["validity"]["warnings"] == []
    v = summarize(_history(scene, tip, np.full(11, 1.0), np.full(11, 0.1)), scene)["validity"]
    assert len(v["warnings"]) == 1 and "% of L" in v["warnings"][0]
    assert "the nonlinear rung was measured up to" in v["warnings"][0]
    fast = np.full(11, 2 * rng["W"])
    v = summarize(_history(scene, tip / 2, fast, np.full(11, 0.1)), scene)["validity"]
    assert len(v["warnings"]) == 1 and "omega_o" in v["warnings"][0]


def test_a_rigid_model_of_a_softer_beam_than_measured_is_flagged():
    stiff = load_scene("rigid_pd", {"stop_time": 1.0})
    soft = load_scene("rigid_pd", {"stop_time": 1.0, "plant.EI": 875.0})
    for sc, n in ((stiff, 0), (soft, 1)):
        v = summarize(simulate_reference(sc, rtol=1e-8, atol=1e-10), sc)["validity"]
        assert v["rung"] == "rigid nonlinear" and len(v["warnings"]) == n
    assert "softer" in v["warnings"][0]


def _validity(rung, D, W, phi_max, outside=()):
    """A summary's validity entry; the exact rung (the reference) has no bound."""
    if rung not in DATA["rungs"]:
        return {"rung": rung, "model_form_error": None, "relative": None,
                "outside": list(outside)}
    bound = _model(rung, {"D": D, "W": W, "A": phi_max, "T": D, "I": D, "V": 4 * D})
    return {"rung": rung, "model_form_error": bound, "relative": bound / phi_max,
            "outside": list(outside)}


def test_climb_decides_on_the_tolerance():
    v = _validity("linear", 0.01, 2.0, 0.2)
    assert climb("linear", v, 0.5 * v["relative"])[0] == "nonlinear"
    assert climb("linear", v, 2.0 * v["relative"])[0] is None
    assert climb("linear", _validity("linear", 0.01, 2.0, 0.2, ["far"]), 1.0)[0] == "nonlinear"
    top = available_ladder()[-1]
    nxt, why = climb(top, _validity(top, 0.01, 2.0, 0.2), 0.0)
    assert nxt is None and "kept" in why
    if top != "exact":
        assert "top available rung" in why and "exact not available" in why


@pytest.mark.slow
def test_auto_climbs_when_the_tolerance_is_below_the_rungs_bound(native):
    """A short filtered run on the native FMUs without the companion that makes the error
    figure (``fidelity.companion = false``: the bound is the fallback that decides): with the
    tolerance below the linear rung's bound it runs again on nonlinear; above it it stays."""
    paths = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    keys = {"plant.fidelity": "auto", "initial.phi": 0.05, "stop_time": 0.5,
            "fidelity.companion": False}
    first = run_scene(load_scene("flexible_pd_lowpass", {**keys, "fidelity.tolerance": 1.0}),
                      paths, progress=False)
    v = first.summary["validity"]
    assert first.scene.plant.fidelity == "linear" and v["rung"] == "linear"
    assert first.summary["model"]["fidelity"] == "linear"
    tight = run_scene(load_scene("flexible_pd_lowpass",
                                 {**keys, "fidelity.tolerance": 0.5 * v["relative"]}),
                      paths, progress=False)
    assert tight.scene.plant.fidelity == "nonlinear"
    assert tight.summary["validity"]["rung"] == "nonlinear"
    assert "climbs to nonlinear" in tight.summary["model"]["reason"]
    assert math.isfinite(tight.summary["validity"]["model_form_error"])


def test_export_climbs_on_the_monolithic_runs():
    """Without a co-simulation (flexpend export) the ladder is climbed on the scene's monolithic
    runs, by the same rule: from pi/6 the linear rung's bound is far beyond 5 %, not from 0.05
    at a tolerance above that rung's bound there."""
    from orchestration.studies.fidelity import select_model

    big = load_scene("flexible_pd_lowpass", ["plant.fidelity=auto", "stop_time=1"])
    chosen, report = select_model(big, monolithic=True)
    assert chosen.plant.fidelity == "nonlinear" and "climbs to nonlinear" in report["reason"]
    small = load_scene("flexible_pd_lowpass", ["plant.fidelity=auto", "stop_time=1",
                                               "initial.phi=0.05"])
    linear = small.replace(plant=small.plant.with_model(4, "linear"))
    lin = summarize(simulate_reference(linear, rtol=1e-8, atol=1e-10), linear)
    tol = 2 * lin["validity"]["relative"]
    chosen, report = select_model(load_scene(small, {"fidelity.tolerance": tol}),
                                  monolithic=True)
    assert chosen.plant.fidelity == "linear" and "kept" in report["reason"]


def test_the_ladder_holds_only_the_rungs_the_scenes_fmus_run():
    """The exact rung runs in the native FMUs' co-simulation only, and the stiffened rung gives
    no Jacobians, which the Model Exchange master needs: a pythonfmu scene climbs to the
    stiffened rung, a Model Exchange one to the nonlinear rung, and each says that is where it
    stops; a native co-simulation has every rung (the exact rung's law, Kelvin-Voigt, set: it
    refuses the modal law with damping, tests/export/test_exact_fmu.py)."""
    tops = {"master.fmus=native": "exact", "master.fmus=python": "stiffened",
            "master.interface=model-exchange": "nonlinear"}
    for key, want in tops.items():
        scene = load_scene("flexible_pd_lowpass", ["plant.fidelity=auto",
                                                   "plant.damping=kelvin-voigt", key])
        ladder = available_ladder(scene)
        assert ladder == available_ladder()[:available_ladder().index(want) + 1], key
        if want == "exact":
            continue
        nxt, why = climb(want, _validity(want, 0.01, 2.0, 0.2), 0.0, ladder)
        assert why.startswith(f"{want}: model-form error")
        assert nxt is None and "top available rung" in why


def test_the_stiffened_rung_is_one_rung_whatever_gravity_preload_says():
    """The stiffened rung always carries the self-weight's stiffness (dynamics.py): with
    plant.gravity_preload = true it is the same rung and has the same measured bound."""
    from orchestration.studies.validity import rung_name
    names = {rung_name(load_scene("flexible_pd_lowpass", {"plant.fidelity": "stiffened",
                                                          "plant.gravity_preload": pre}).plant)
             for pre in (False, True)}
    assert names == {"stiffened"} and "stiffened" in DATA["rungs"]
