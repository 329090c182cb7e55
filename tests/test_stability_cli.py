"""``flexpend stability`` and the run's warning: the largest stable communication step of every
coupling, checked against the spectral radius of the transition matrix itself, and the refusals."""
import json
import math

import numpy as np
import pytest

from orchestration import api, job
from plant_fmu.dynamics import plant_model
from orchestration.cli import main
from orchestration.scene.records import MasterSettings
from orchestration.scene.schema import load_scene
from orchestration.studies import stability
from orchestration.studies.stability import (scene_transition_matrix, spectral_radius,
                                             transition_matrix)

KEYS = {"algorithm", "first", "extrapolation", "input_derivatives", "output_derivatives",
        "critical_step"}


@pytest.fixture(scope="module")
def filtered():
    """``api.stability`` of the filtered scene, computed once (the commands below print it)."""
    return api.stability("flexible_pd_lowpass")


@pytest.fixture
def cached(monkeypatch, filtered):
    monkeypatch.setattr(api, "stability", lambda scene, overrides: filtered)


def _json(capsys, *args):
    assert main(["stability", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _rho(scene, H):
    return spectral_radius(scene_transition_matrix(scene, H=H))


def test_json_of_the_filtered_scene(capsys, cached):
    """The documented shape; the scene's critical step is where rho(Phi) of its own transition
    matrix reaches 1: below 1 on a fine grid up to it (400 points), above just beyond it."""
    r = _json(capsys, "flexible_pd_lowpass")
    assert set(r) == {"scene", "couplings", "loop"}
    assert r["loop"] == "the nonlinear rung's linearisation (4 modes, modal damping 0.1 %)"
    assert set(r["scene"]) == {"coupling", "critical_step", "substep_limit"}
    assert r["scene"]["coupling"] == {"algorithm": "gauss-seidel", "first": "controller",
                                      "extrapolation": 2, "input_derivatives": True,
                                      "output_derivatives": False, "step": 0.002}
    scene = load_scene("flexible_pd_lowpass")
    Hc = r["scene"]["critical_step"]
    assert max(_rho(scene, H) for H in np.linspace(2e-3, 0.999 * Hc, 400)) < 1
    assert _rho(scene, 1.001 * Hc) > 1
    # the substep limit: where RK4's stability polynomial on the plant's damped modes reaches 1
    lam = np.linalg.eigvals(plant_model(scene.plant.params).state_space()[0])
    lam = lam[lam.real < 0]
    R = lambda h: np.max(np.abs(sum((h * lam) ** j / math.factorial(j)  # noqa: E731
                                    for j in range(5))))
    h = r["scene"]["substep_limit"]
    assert R(0.999 * h) < 1 < R(1.001 * h)
    # every coupling: Jacobi (one order) and Gauss-Seidel (two), the zero-order hold, then
    # orders 1 and 2 held, with input derivatives, and with output derivatives (native FMUs);
    # the implicit master the same but output derivatives
    assert len(r["couplings"]) == 3 * 7 + 5 and all(set(c) == KEYS for c in r["couplings"])
    own = next(c for c in r["couplings"] if all(
        c[k] == v for k, v in r["scene"]["coupling"].items() if k != "step"))
    assert own["critical_step"] == pytest.approx(Hc, rel=1e-9)
    # Jacobi with the hold: a narrow window (0.8 %, rho <= 1.00012) from 7.28 ms, below the
    # main crossing at 8.03 ms (the probe: "fails near 8 ms"); both are rho = 1
    hold = next(c for c in r["couplings"] if c["algorithm"] == "jacobi"
                and c["extrapolation"] == 0)["critical_step"]
    rho = lambda H: spectral_radius(transition_matrix(  # noqa: E731
        scene.plant.params, scene.controller, H, algorithm="jacobi"))
    assert rho(0.9999 * hold) < 1 < rho(1.0001 * hold)
    assert max(rho(H) for H in np.linspace(1e-3, 0.9999 * hold, 2000)) < 1


def test_couplings_follow_the_masters_rules():
    """The pythonfmu FMUs give no output derivatives: those couplings are not offered."""
    ks = stability.couplings(MasterSettings(fmus="python"))
    assert len(ks) == 4 * 5 and not any(k["output_derivatives"] for k in ks)
    assert len(stability.couplings(MasterSettings())) == 3 * 7 + 5


def test_text_names_the_largest(capsys, cached):
    assert main(["stability", "flexible_pd_lowpass"]) == 0
    out = capsys.readouterr().out
    assert "assumes the plant is linearised" in out
    assert "the largest step: implicit, extrapolation 1, held average" in out


@pytest.mark.parametrize("setting,why", [("master.adaptive=true", "adaptive master"),
                                         ("plant.integrator=dopri5", "'dopri5' is adaptive"),
                                         ("master.interface=model-exchange", "as one system")])
def test_refusals_are_one_line(capsys, setting, why):
    assert main(["stability", "flexible_pd_lowpass", "--set", setting]) == 2
    err = capsys.readouterr().err
    assert why in err and err.count("\n") == 1


def test_run_warns_beyond_the_limit(capsys, tmp_path):
    """Beyond the scene's critical step the run says so, once; within it, not; the cached answer
    is the computed one."""
    sets = ["--set", "stop_time=0.2", "--set", "output_interval=0.02", "--out"]
    scene = load_scene("flexible_pd_lowpass", ["master.step=0.02", "output_interval=0.02"])
    expected = stability.step_warning(scene)
    assert expected and "0.01464" in expected
    assert job.step_warning(scene) == expected and job.step_warning(scene) == expected
    assert main(["run", "flexible_pd_lowpass", "--set", "master.step=0.02", *sets,
                 str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: master.step = 0.02 s is beyond the stability limit") == 1
    assert main(["run", "flexible_pd_lowpass", *sets, str(tmp_path)]) == 0
    assert "warning" not in capsys.readouterr().err
