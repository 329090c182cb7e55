"""The error figure (orchestration/studies/error_figure.py, bench/error_figure.py): a run on a
floating-frame rung states ``kappa * max |phi_o(run) - phi_o(companion)| + floor``, its companion
the stiffened rung with the modes that matter, through the same FMUs and master; a figure that
cannot be trusted is no number and says why; ``plant.fidelity = "auto"`` climbs on it."""
import json
import math

import numpy as np
import pytest

from orchestration import job
from orchestration.job import run_scene
from orchestration.report.figures import outcome_text
from orchestration.report.text import run_lines
from orchestration.scene.schema import load_scene
from orchestration.studies import error_figure as ef
from orchestration.studies.exact_loop import exact_run
from orchestration.studies.plant_step import rung_params, step_limit
from orchestration.sweeps.engine import summary_row
from plant_fmu.beam import analytic_frequencies

DATA = json.loads(ef.FIGURE_FILE.read_text(encoding="utf-8"))
KV = {"plant.damping": "kelvin-voigt"}


def _pair(native):
    return {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}


def _run(native, name, keys, **kw):
    return run_scene(load_scene(name, keys), _pair(native), progress=False, **kw)


def _floor(res, scene):
    """The JSON's floor evaluated here, its terms written out (independently of
    error_figure.TERMS), on the companion's result."""
    p = scene.plant.params
    D = np.max(np.abs(res["tip_deflection"])) / p.L
    W = np.max(np.abs(res["omega_o"]))
    damped = DATA["damped"]
    ringing = 0.0 if (p.damping == damped["law"] and p.zeta >= damped["zeta"]) else 1.0
    w1 = 1.8751040687119611 ** 2 * math.sqrt(p.EI / (p.rho * p.EA / p.E * p.L ** 4))
    value = {"D": D, "D_ringing": D * ringing, "D_stiffness": D * w1 ** 2 * p.L / p.g,
             "D2": D * D, "kd_W": scene.controller.kd * W, "1": 1.0}
    f = DATA["floor"]
    return f["safety"] * sum(c * value[k] for k, c in f["terms"].items())


# ---------------------------------------------------------------------- the companion
@pytest.mark.parametrize("name,keys", [("flexible_pd_lowpass", {}), ("rigid_pd", {}),
                                       ("flexible_pd_lowpass", {"plant.EI": 1500.0}),
                                       ("flexible_pd_lowpass", {"plant.L": 1.2})])
def test_the_companion_carries_the_cantilever_modes_below_its_frequency(name, keys):
    """Counted on the analytic cantilever frequencies (not the FE model the product reads):
    the paper's beam 8, rigid_pd's stiff beam 3, EI 1500 7; never fewer than the run's."""
    scene = load_scene(name, keys)
    p = scene.plant.params
    below = int(np.sum(analytic_frequencies(p, 12) <= ef.COMPANION_FREQUENCY))
    want = min(ef.COMPANION_MODES, max(below, p.n_modes, 1))
    cs = ef.companion_scene(scene)
    assert cs.plant.params.n_modes == want
    assert cs.plant.fidelity == "stiffened" and cs.plant.integrator == "rk4"
    assert (name, want) != ("rigid_pd", 8)                 # the stiff beam's modes do not matter
    big = ef.companion_scene(load_scene(name, {**keys, "plant.n_modes": 8}))
    assert big.plant.params.n_modes == 8


@pytest.mark.parametrize("keys", [{}, {"plant.EI": 1500.0}, {"plant.zeta": 0.0}])
def test_the_companion_steps_within_a_margin_of_rk4s_limit(keys):
    """plant.step of the companion: within STEP_MARGIN of RK4's stability limit on its plant and
    a whole fraction of the communication step; the scene's own step when that is within it
    (the paper's modal scene at 8 modes: 2.5e-4 s of a 3.13e-4 s limit)."""
    scene = load_scene("flexible_pd_lowpass", keys)
    cs = ef.companion_scene(scene)
    h = cs.plant.step
    limit = step_limit("rk4", rung_params(cs.plant.params, "stiffened"))[0]
    assert h <= ef.STEP_MARGIN * limit
    k = scene.master.step / h
    assert abs(k - round(k)) < 1e-9
    if scene.plant.step <= ef.STEP_MARGIN * limit:
        assert h == scene.plant.step
    else:
        assert h > ef.STEP_MARGIN * limit * (1 - 1 / k) - 1e-15     # the largest such fraction
    from orchestration.job import check_plant_step
    assert check_plant_step(cs) is None                     # neither refused nor warned


# ---------------------------------------------------------------------- the figure
@pytest.mark.slow
def test_the_figure_is_kappa_times_the_difference_from_the_companion_plus_the_floor(native):
    """Recomputed from two runs: the run, and its companion run here on its own (the modes and
    the step the summary names, the rest of the scene as it is)."""
    keys = {"initial.phi": 0.3, "stop_time": 1.0}
    r = _run(native, "flexible_pd_lowpass", keys)
    f = r.summary["error_figure"]
    c = f["companion"]
    assert c["n_modes"] == 8 and c["rung"] == "stiffened" and c["damping"] == "modal"
    assert not c["own"] and f["untrusted"] is None
    comp_keys = {**keys, "plant.fidelity": "stiffened", "plant.n_modes": 8,
                 "plant.step": c["plant_step"], "fidelity.companion": False}
    comp = _run(native, "flexible_pd_lowpass", comp_keys)
    assert "error_figure" not in comp.summary               # fidelity.companion = false
    diff = np.max(np.abs(r.result["phi_o"] - comp.result["phi_o"]))
    floor = _floor(comp.result, comp.scene)
    assert f["difference"] == pytest.approx(diff, rel=1e-12, abs=1e-15)
    assert f["floor"] == pytest.approx(floor, rel=1e-12)
    assert f["figure"] == pytest.approx(DATA["kappa"] * diff + floor, rel=1e-12)
    assert f["relative"] == pytest.approx(f["figure"] / np.max(np.abs(r.result["phi_o"])))
    assert DATA["kappa"] >= 1
    lines = run_lines("x", r.summary)
    mine = [ln for ln in lines if ln.strip().startswith("error")]
    bound = [ln for ln in lines if "global bound: model-form error <=" in ln]
    assert len(mine) == 1 and len(bound) == 1
    assert f"error <= {f['figure']:.1e} rad" in mine[0]
    assert "the stiffened rung, 8 modes, modal damping 0.1 %" in mine[0]
    assert "(companion: stiffened, 8 modes, modal" in outcome_text(r.summary)
    row = summary_row(r.summary)
    assert row["model_form_error"] == f["figure"]
    assert row["model_form_basis"] == "against the stiffened rung, 8 modes, modal damping 0.1 %"


@pytest.mark.slow
def test_a_run_on_its_companions_model_states_the_floor_alone(native, monkeypatch):
    """The stiffened rung at 8 modes is the companion's model: no second run, the figure is the
    floor on its own motion."""
    calls = []
    once = job._run_once
    monkeypatch.setattr(job, "_run_once", lambda *a, **k: calls.append(a[0]) or once(*a, **k))
    r = _run(native, "flexible_pd_lowpass", {**KV, "plant.fidelity": "stiffened",
                                             "plant.n_modes": 8, "stop_time": 1.0})
    f = r.summary["error_figure"]
    assert len(calls) == 1 and f["companion"]["own"] and f["difference"] == 0.0
    assert f["figure"] == pytest.approx(_floor(r.result, r.scene), rel=1e-12)
    assert "its own error, the floor" in "\n".join(run_lines("x", r.summary))


def _reference(scene, n_elements, h):
    return exact_run(scene.replace(plant=scene.plant.with_model(scene.plant.params.n_modes,
                                                                 "exact")), n_elements, h,
                     kernel=True)


@pytest.mark.slow
@pytest.mark.parametrize("keys", [
    {**KV, "initial.phi": 0.3},                         # an angle not on the grid
    {"plant.zeta": 0.0, "controller.kp": 700.0},        # kp alone, not the grid's gains
    {**KV, "plant.EI": 1500.0},                         # a stiffer beam than any on the grid
])
def test_off_the_grid_the_figure_is_never_below_the_error_and_at_most_3_times_it(native, keys):
    """Short runs (1.5 s) of cases the study did not fit on, against a coarse exact reference
    (24 elements, 0.25 ms) whose own error, measured against a finer one (32 elements,
    0.125 ms), is under a tenth of every error compared."""
    keys = {**keys, "stop_time": 1.5}
    scene = load_scene("flexible_pd_lowpass", {**keys, "plant.fidelity": "nonlinear"})
    ref = _reference(scene, 24, 2.5e-4)
    own = np.max(np.abs(ref - _reference(scene, 32, 1.25e-4)))
    for rung in ("linear", "nonlinear", "stiffened"):
        r = _run(native, "flexible_pd_lowpass", {**keys, "plant.fidelity": rung})
        f = r.summary["error_figure"]
        err = np.max(np.abs(r.result["phi_o"] - ref))
        assert own < 0.1 * err, (rung, own, err)
        assert f["untrusted"] is None, f["why"]
        assert err <= f["figure"] <= 3 * err, (rung, err, f["figure"])


# ---------------------------------------------------------------------- no figure, and why
def _falls(native):
    return _run(native, "flexible_pd_lowpass", {"controller.kp": 100.0, "stop_time": 2.0})


def _integrator(native):
    keys = {"plant.EI": 1500.0, "plant.n_modes": 8, "stop_time": 0.1}
    return _run(native, "flexible_pd_lowpass", keys, check_step=False)


def _no_companion(native):
    return _run(native, "flexible_pd_lowpass", {"master.output_derivatives": True,
                                                "stop_time": 0.5})


def _grows(native):
    return _run(native, "flexible_pd", {**KV, "stop_time": 1.5})


def _far(native):
    return _run(native, "flexible_pd_lowpass", {"initial.phi": 0.95, "stop_time": 1.0})


def _coarse(native):
    return _run(native, "flexible_pd_lowpass", {"master.extrapolation": 0,
                                                "master.input_derivatives": False,
                                                "stop_time": 1.0})


@pytest.mark.slow
@pytest.mark.parametrize("make,key,words", [
    (_falls, "diverged", "it stopped at t = "),
    (_integrator, "integrator", "plant.step = 0.00025 s is beyond the stability limit"),
    (_no_companion, "companion", "it cannot run: plant.fidelity = 'stiffened' cannot be used"),
    (_grows, "grows", "a fitted oscillation at +"),
    (_far, "outside", "|phi_o| reaches 0.956 rad"),
    (_coarse, "outside", "the coupling: master.extrapolation = 0"),
])
def test_a_figure_that_cannot_be_trusted_is_no_number_and_says_why(native, make, key, words):
    r = make(native)
    f = r.summary["error_figure"]
    assert f["figure"] is None and f["relative"] is None
    assert f["untrusted"] == key and words in f["why"], f["why"]
    lines = run_lines("x", r.summary)
    mine = [ln.strip() for ln in lines if ln.strip().startswith("error")]
    assert mine == [f"error: no figure ({f['why']})"]
    assert f"({ef.UNTRUSTED[key]}: " in mine[0]
    assert summary_row(r.summary)["model_form_error"] is None
    assert summary_row(r.summary)["model_form_basis"] == f["why"]


# ---------------------------------------------------------------------- the climb
@pytest.mark.slow
def test_auto_climbs_while_the_figure_exceeds_the_tolerance(native, monkeypatch):
    """The filtered scene (3 s): at a tolerance between the nonlinear and the stiffened rungs'
    stated figures (measured here, each rung run on its own) the climb stops at the stiffened
    rung; the companion runs once for every rung, and the exact rung never runs. At 1 % it
    stops at the first rung whose figure is within 1 % (the linear rung's is not)."""
    keys = {"stop_time": 3.0}
    rel = {rung: _run(native, "flexible_pd_lowpass", {**keys, "plant.fidelity": rung})
           .summary["error_figure"]["relative"] for rung in ("linear", "nonlinear", "stiffened")}
    assert rel["linear"] > rel["nonlinear"] > rel["stiffened"]
    calls = []
    once = job._run_once
    monkeypatch.setattr(job, "_run_once", lambda *a, **k: calls.append(a[0]) or once(*a, **k))
    tol = math.sqrt(rel["nonlinear"] * rel["stiffened"])
    r = _run(native, "flexible_pd_lowpass", {**keys, "plant.fidelity": "auto",
                                             "fidelity.tolerance": tol})
    assert r.scene.plant.fidelity == "stiffened" and r.summary["model"]["fidelity"] == "stiffened"
    assert [(s.plant.fidelity, s.plant.params.n_modes) for s in calls] == [
        ("linear", 4), ("stiffened", 8), ("nonlinear", 4), ("stiffened", 4)]
    reason = r.summary["model"]["reason"]
    assert "linear: error <=" in reason and "climbs to nonlinear" in reason
    assert "climbs to stiffened" in reason and reason.endswith("kept")
    calls.clear()
    r = _run(native, "flexible_pd_lowpass", {**keys, "plant.fidelity": "auto",
                                             "fidelity.tolerance": 0.01})
    first = next(rung for rung in ("linear", "nonlinear", "stiffened") if rel[rung] <= 0.01)
    assert r.scene.plant.fidelity == first and rel["linear"] > 0.01
    assert all(s.plant.fidelity != "exact" for s in calls)


@pytest.mark.slow
def test_a_companion_that_is_the_next_rungs_run_is_not_run_again(native, monkeypatch):
    """At 8 modes the stiffened rung is the companion: the climb takes the companion's run as
    its run (run once, by the linear rung's figure), and at a tolerance no figure meets it goes
    on to the exact rung (its run, then the same at twice the step: its numerical error)."""
    calls = []
    once = job._run_once
    monkeypatch.setattr(job, "_run_once", lambda *a, **k: calls.append(a[0]) or once(*a, **k))
    r = _run(native, "flexible_pd_lowpass", {"plant.n_modes": 8, "plant.fidelity": "auto",
                                             "fidelity.tolerance": 1e-6, "stop_time": 0.5})
    assert [s.plant.fidelity for s in calls] == ["linear", "stiffened", "nonlinear", "exact",
                                                 "exact"]
    assert r.scene.plant.fidelity == "exact" and "numerical_error" in r.summary
    assert "(its run: the companion's)" in r.summary["model"]["reason"]


@pytest.mark.slow
def test_without_a_companion_the_measured_bound_decides_the_climb(native):
    """The companion cannot run (output derivatives: the stiffened rung gives none): the climb
    falls back on the measured global bound and says so."""
    r = _run(native, "flexible_pd_lowpass", {"plant.fidelity": "auto", "stop_time": 1.0,
                                             "master.output_derivatives": True,
                                             "initial.phi": 0.05})
    assert "the measured global bound" in r.summary["model"]["reason"]


# ---------------------------------------------------------------------- the measured range
@pytest.mark.slow
@pytest.mark.parametrize("name", ["rigid_pd", "flexible_pd_lowpass", "flexible_pd"])
def test_the_paper_scenes_are_inside_the_measured_range(native, name):
    """Each paper scene as it is (pi/6, its gains, its length): its companion's motion is
    within the study's measured range without the margin; the stable two state a figure,
    flexible_pd's loop grows (not: outside)."""
    r = _run(native, name, {})
    f = r.summary["error_figure"]
    assert f["untrusted"] != "outside", f["why"]
    assert (f["untrusted"] is None) == (name != "flexible_pd"), f["why"]
    assert DATA["range"]["A"] >= math.pi / 6 * 1.1       # the grid went beyond the paper's angle
    if name != "flexible_pd":
        cs = ef.companion_scene(r.scene)
        comp = _run(native, name, {"plant.fidelity": "stiffened",
                                   "plant.n_modes": cs.plant.params.n_modes,
                                   "plant.step": cs.plant.step, "fidelity.companion": False})
        P = ef.features(comp.result, comp.scene, DATA["damped"])
        assert all(P[k] <= DATA["range"][k] for k in ("A", "D", "W")), P
