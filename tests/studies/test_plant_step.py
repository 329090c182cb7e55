"""The plant step's preflight (orchestration/studies/plant_step.py): a run whose plant FMU would
step unstably at ``plant.step`` is refused before it starts, naming ``plant.step``.

The case of issue 34: the filtered scene with ``plant.EI = 1500`` and 8 modes, whose fastest
mode (about 12200 rad/s) puts RK4 at the default ``plant.step = 2.5e-4`` about 5 % beyond its
limit; the run used to finish 0.11 rad off the monolithic reference with a warning that blamed
``master.step``. The limits are checked against independent computations: RK4's stability
polynomial ``1 + z + z^2/2 + z^3/6 + z^4/24`` written out here, the plant's eigenvalues by numpy,
a bisection here; the undamped oscillator's textbook limits (RK4 ``h w = 2 sqrt(2)``, symplectic
Euler ``h w = 2``, explicit Euler none); and the real FMUs beyond and within the limit.
"""
import math
import re

import numpy as np
import pytest

import orchestration as fp
from orchestration.cli import main
from orchestration.job import check_plant_step, run_scene, step_warning
from orchestration.scene.schema import PAPER_SCENES, load_scene
from orchestration.studies import stability
from orchestration.studies.plant_step import check, step_limit, unstable
from orchestration.studies.reference import simulate_reference
from plant_fmu.dynamics import plant_model

#: the issue's scene: RK4 at plant.step = 2.5e-4 beyond its limit on the fastest mode
STIFF = {"plant.EI": 1500, "plant.n_modes": 8, "stop_time": 3}
LIMIT = re.compile(r"the largest stable plant\.step is ([0-9.e+-]+) s")


def _rk4(z):
    return 1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24


def _rk4_bisection(p) -> float:
    """The first substep where RK4 amplifies an eigenvalue of the linearised plant more than its
    exact flow does (``|R(h lambda)| > max(1, |exp(h lambda)|)``), by bisection."""
    lam = np.linalg.eigvals(plant_model(p).state_space()[0])

    def bad(h):
        return bool(np.any(np.abs(_rk4(h * lam)) > np.maximum(1.0, np.abs(np.exp(h * lam)))
                           + 1e-12))
    lo, hi = 1e-3 / np.max(np.abs(lam)), 4.0 / np.max(np.abs(lam))
    assert not bad(lo) and bad(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if bad(mid) else (mid, hi)
    return lo


@pytest.fixture(scope="module")
def refusal():
    """The one-line refusal of the issue's scene and the limit it prints."""
    with pytest.raises(fp.ConfigError) as exc:
        check_plant_step(load_scene("flexible_pd_lowpass", STIFF))
    text = str(exc.value)
    return text, float(LIMIT.search(text).group(1))


# ---------------------------------------------------------------------- the stability criterion
@pytest.mark.parametrize("method,limit", [("rk4", 2 * math.sqrt(2)), ("symplectic_euler", 2.0)])
def test_undamped_oscillator_limits_are_the_textbooks(method, limit):
    w = 300.0
    A = np.array([[0.0, 1.0], [-w * w, 0.0]])
    assert not unstable(method, A, 1, (1 - 1e-6) * limit / w)
    assert unstable(method, A, 1, (1 + 1e-6) * limit / w)


def test_explicit_euler_amplifies_an_undamped_mode_at_every_step():
    """``|1 + i h w| = sqrt(1 + (h w)^2)``: above 1 at every step (from h w = 1e-4 the growth
    per step, 5e-9, is above the tolerance of 1e-9 that rounding needs)."""
    A = np.array([[0.0, 1.0], [-1.0, 0.0]])
    assert all(unstable("euler", A, 1, h) for h in (1e-4, 1e-3, 1.0))


def test_a_physically_growing_mode_is_not_an_instability():
    """``x'' = 49 x``: roots +-7/s. RK4 grows the +7 root (|R| > 1) but less than the exact flow
    does: not an instability, up to where the -7 root leaves RK4's region (h = 2.785 / 7)."""
    A = np.array([[0.0, 1.0], [49.0, 0.0]])
    h = 0.3
    assert abs(_rk4(7 * h)) > 1 and not unstable("rk4", A, 1, h)
    assert unstable("rk4", A, 1, 2.8 / 7) and not unstable("rk4", A, 1, 2.78 / 7)


def test_symplectic_euler_on_the_whole_plant():
    """Symplectic Euler's limit on the 8-mode plant against its substep matrix as
    orchestration.studies.stability builds it (the cart kept): 0.01 % within the limit one
    eigenvalue exceeds 1 (the pendulum's, +7/s: physical), 0.01 % beyond it a second one."""
    p = load_scene("flexible_pd_lowpass", {"plant.n_modes": 8}).plant.params
    h = step_limit("symplectic_euler", p)[0]
    A, B = plant_model(p).state_space()[:2]
    nq = A.shape[0] // 2
    for factor, growing in ((0.9999, 1), (1.0001, 2)):
        S = stability.substep_matrix("symplectic_euler", A, B, nq, factor * h)[:-1, :-1]
        assert np.sum(np.abs(np.linalg.eigvals(S)) > 1 + 1e-6) == growing


# ---------------------------------------------------------------------- the issue's scene
def test_the_issues_scene_is_refused_naming_plant_step(refusal):
    text, h = refusal
    assert text.count("\n") == 0
    assert "plant.step = 0.00025 s" in text and "master.step" not in text
    assert "plant.integrator = 'rk4'" in text and "fastest mode" in text
    lam = np.linalg.eigvals(plant_model(load_scene("flexible_pd_lowpass", STIFF).plant.params)
                            .state_space()[0])
    fastest = float(np.max(np.abs(lam)))
    assert f"({fastest:.6g} rad/s" in text
    assert "'dopri5' (adaptive) has no limit" in text
    assert h < 2.5e-4


def test_the_printed_limit_is_the_bisection_of_rk4s_polynomial(refusal):
    p = load_scene("flexible_pd_lowpass", STIFF).plant.params
    expected = _rk4_bisection(p)
    assert refusal[1] == pytest.approx(expected, rel=1e-6)
    assert refusal[1] <= expected             # rounded down: the printed step is stable
    # on the imaginary axis alone the limit would be 2 sqrt(2) / |lambda|: damping moves it
    lam = np.linalg.eigvals(plant_model(p).state_space()[0])
    assert expected > 2 * math.sqrt(2) / np.max(np.abs(lam))


def test_cli_refuses_with_exit_2_and_one_line(capsys, tmp_path):
    sets = [x for k, v in STIFF.items() for x in ("--set", f"{k}={v}")]
    assert main(["run", "flexible_pd_lowpass", *sets, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "plant.step = 0.00025 s" in err
    assert "master.step" not in err
    assert not (tmp_path / "flexible_pd_lowpass.csv").exists()


def test_simulate_and_the_ladder_refuse_before_running():
    with pytest.raises(ValueError, match=r"plant\.step = 0\.00025 s is beyond"):
        fp.simulate("flexible_pd_lowpass", STIFF)
    # plant.fidelity = auto: every rung the ladder may climb to is checked first
    with pytest.raises(fp.ConfigError, match=r"plant\.step = 0\.00025 s is beyond"):
        fp.simulate("flexible_pd_lowpass", {**STIFF, "plant.fidelity": "auto"})


def test_a_model_chosen_by_a_run_is_checked_once_chosen(monkeypatch, native):
    """``plant.n_modes = "auto"``: nothing to check until the run chooses the model; then the
    refusal says which model was chosen (the choice itself stubbed here: 8 modes)."""
    from orchestration import job

    scene = load_scene("flexible_pd_lowpass", {**STIFF, "plant.n_modes": "auto"})
    assert check_plant_step(scene) is None

    def choose(sc, progress=None):
        return (sc.replace(plant=sc.plant.with_model(8, "nonlinear")),
                {"n_modes": 8, "fidelity": "nonlinear", "fidelity_auto": False, "reason": ""})
    monkeypatch.setattr(job, "select_model", choose)
    pair = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    with pytest.raises(fp.ConfigError, match=r"plant\.step = 0\.00025 s is beyond .*\(the model "
                       r"chosen: 8 modes, nonlinear\)$"):
        run_scene(scene, pair, progress=False)


def test_within_the_limit_runs_close_to_the_reference_beyond_it_grows(native, refusal):
    """At 0.9 times the printed limit the run is refused no more, warned no more, and it is
    within 1e-3 rad of the monolithic reference (the coupling's error at master.step = 2 ms is
    about 1e-4 rad, README "Accuracy"); forced through at the scene's own plant.step (beyond
    the limit) it is more than ten times further off."""
    pair = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    scene = load_scene("flexible_pd_lowpass", {**STIFF, "plant.step": 0.9 * refusal[1]})
    assert check_plant_step(scene) is None and step_warning(scene) is None
    ref = simulate_reference(scene)
    good = run_scene(scene, pair, progress=False)
    assert good.completed
    err_good = np.max(np.abs(good.result["phi_o"] - ref["phi_o"]))
    assert err_good < 1e-3
    forced = run_scene(load_scene("flexible_pd_lowpass", STIFF), pair, progress=False,
                       check_step=False)
    n = min(len(forced.result), len(ref))
    err_forced = np.max(np.abs(forced.result["phi_o"][:n] - ref["phi_o"][:n]))
    assert err_forced > 10 * err_good


@pytest.mark.parametrize("factor", [0.99, 1.01])
def test_a_step_just_beyond_the_limit_grows(native, factor):
    """The same plant, linear rung (the linearisation the limit is computed on, whose growth
    nothing bounds), from a small angle, forced through at 1 % beyond the limit: its fastest
    mode (mostly eta_8) grows by orders of magnitude in 0.1 s; 1 % within, it decays."""
    pair = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    base = {**STIFF, "plant.fidelity": "linear", "initial.phi": 1e-3, "stop_time": 0.1,
            "plant.phi_limit": math.inf, "plant.energy_limit": math.inf}
    h = step_limit("rk4", load_scene("flexible_pd_lowpass", base).plant.params)[0]
    scene = load_scene("flexible_pd_lowpass", {**base, "plant.step": factor * h})
    assert (check(scene).verdict == "beyond") == (factor > 1)
    r = run_scene(scene, pair, progress=False, check_step=False)
    eta = np.abs(r.result["eta_8"])
    t = r.result["time"]
    early, late = eta[t <= 0.02].max(), eta[t >= 0.08].max()
    if factor > 1:
        assert late > 1e3 * early
    else:
        assert late < early


def test_the_coupling_warning_names_plant_step_when_the_integrator_is_the_cause():
    """Forced beyond the limit the co-simulation's own prediction finds a largest stable
    communication step at the integrator's limit (the substep shortened to it): the warning
    names plant.step, not master.step. Near the limit it warns, naming plant.step."""
    scene = load_scene("flexible_pd_lowpass", STIFF)
    text = stability.step_warning(scene)
    assert text.startswith("plant.step = 0.00025 s is beyond") and "master.step" not in text
    near = load_scene("flexible_pd_lowpass", {**STIFF, "plant.step": 2.3e-4})
    assert check_plant_step(near).startswith("plant.step = 0.00023 s is within 10 %")
    assert "master.step" not in stability.step_warning(near)


def test_a_sweep_marks_the_refused_run_and_runs_the_rest(native, tmp_path):
    s = fp.sweep("flexible_pd_lowpass", values={"plant.EI": [875, 1500]}, serial=True,
                 overrides={"plant.n_modes": 8, "stop_time": 0.1, "output_interval": 0.01},
                 out=tmp_path, progress=False)
    rows = {r["plant.EI"]: r for r in s.rows}
    assert rows[875]["status"] == "ok"
    assert rows[1500]["status"] == "failed"
    assert "plant.step = 0.00025 s is beyond" in rows[1500]["message"]


# ---------------------------------------------------------------------- what is not refused
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_the_paper_scenes_are_not_refused(name):
    scene = load_scene(name)
    if scene.plant.n_modes_auto:        # rigid_pd: the choice is 0 modes (README)
        scene = scene.replace(plant=scene.plant.with_model(0, scene.plant.fidelity))
    assert check_plant_step(scene) is None


@pytest.mark.parametrize("sets", [{"plant.integrator": "dopri5"},
                                  {"plant.integrator": "exponential", "plant.fidelity": "linear"},
                                  {"plant.fidelity": "exact", "plant.n_elements": 8},
                                  {"master.interface": "model-exchange"},
                                  {"master.step": 1e-4, "plant.step": 1e-3}])
def test_no_limit_or_no_plant_integrator_is_not_refused(sets):
    """Adaptive, exact and A-stable methods have no limit; the exact rung steps by its own
    implicit method; Model Exchange does not use the plant's; a communication step shorter than
    the limit keeps the substeps below it whatever plant.step says."""
    scene = load_scene("flexible_pd_lowpass", {**STIFF, **sets})
    assert check_plant_step(scene) is None


def test_the_stiffened_rung_is_judged_on_its_preloaded_linearisation():
    """The self-weight's compression lowers the fastest mode a little: the stiffened rung's
    limit is the preload rung's, slightly above the nonlinear rung's."""
    p = load_scene("flexible_pd_lowpass", STIFF).plant.params
    stiff = check(load_scene("flexible_pd_lowpass", {**STIFF, "plant.fidelity": "stiffened"}))
    assert stiff.limit == pytest.approx(_rk4_bisection(p.replace(gravity_preload=True)),
                                        rel=1e-6)
    assert stiff.limit > step_limit("rk4", p)[0]


def _plain_bisection(bad, lo, hi):
    while hi - lo > 4 * np.finfo(float).eps * hi:
        mid = 0.5 * (lo + hi)
        if bad(mid):
            hi = mid
        else:
            lo = mid
    return lo, hi


@pytest.mark.parametrize("levels", [1, 3, 6])
def test_the_tree_bisection_ends_where_the_plain_loop_ends(levels):
    """plant_step._bisect judges several levels of midpoints at once; it must take the plain
    loop's path exactly, on a monotone predicate and on one that is not (a stability boundary
    with islands), wherever the boundary lies."""
    from orchestration.studies.plant_step import _bisect

    rng = np.random.default_rng(levels)
    for _ in range(30):
        edge = float(rng.uniform(0.1, 0.9))
        islands = rng.uniform(0.0, 1.0, 6)

        def monotone(h):
            return np.asarray(h) >= edge

        def ragged(h):
            h = np.asarray(h)
            return (h >= edge) ^ (np.abs(h[..., None] - islands).min(axis=-1) < 0.01)

        for bad in (monotone, ragged):
            lo, hi = (0.0, 1.0) if not bad(0.0) and bad(1.0) else (0.0, 2.0)
            assert _bisect(bad, lo, hi, levels) == _plain_bisection(bad, lo, hi)


@pytest.mark.parametrize("method", ["rk4", "euler", "symplectic_euler"])
def test_the_verdict_from_the_grid_floor_is_the_verdict_from_the_limit(method):
    """A substep well below the grid's floor is judged ``ok`` without the bisection: the verdict
    is the one the bisected limit gives, for steps all around the limit (below the floor, between
    the floor and the limit, within the margin, beyond), on several beams."""
    from orchestration.studies.plant_step import MARGIN, stable_floor

    for EI, n_modes in ((875.0, 2), (875.0, 4), (300.0, 8)):
        scene = load_scene("flexible_pd", {"plant.EI": EI, "plant.n_modes": n_modes,
                                           "plant.integrator": method})
        p = scene.plant.params
        limit = step_limit(method, p)[0]
        floor = stable_floor(method, p)
        assert 0 < floor <= limit
        for h in (0.5 * floor, (1 - MARGIN) * floor, 0.99 * floor, 0.95 * limit,
                  (1 - MARGIN) * limit * 1.001, 0.999 * limit, 1.001 * limit, 2 * limit):
            c = check(load_scene("flexible_pd", {"plant.EI": EI, "plant.n_modes": n_modes,
                                                 "plant.integrator": method,
                                                 "plant.step": h, "master.step": 0.01,
                                                 "output_interval": 0.01}))
            expected = ("beyond" if h > limit else "near" if h > (1 - MARGIN) * limit
                        else "ok")
            assert c.verdict == expected, (EI, n_modes, h, floor, limit)
            assert c.limit == limit
