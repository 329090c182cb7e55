"""``flexpend stability`` and the run's warning: the stable and unstable intervals of the
communication step of every coupling, checked against the spectral radius of the transition
matrix itself (one matrix at a time), the text, ``--max-step``, progress, Ctrl-C and the
refusals. The intervals against runs of the FMUs: tests/studies/test_stability_intervals.py."""
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
from orchestration.studies.stability_intervals import one_blas_thread

KEYS = {"algorithm", "first", "extrapolation", "input_derivatives", "output_derivatives",
        "coupling", "critical_step", "intervals"}


@pytest.fixture(scope="module")
def filtered():
    """``api.stability`` of the filtered scene, computed once (the commands below print it)."""
    return api.stability("flexible_pd_lowpass")


@pytest.fixture
def cached(monkeypatch, filtered):
    monkeypatch.setattr(api, "stability", lambda scene, overrides, **kw: filtered)


def _json(capsys, *args):
    assert main(["stability", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _rho(scene, H):
    return spectral_radius(scene_transition_matrix(scene, H=H))


def _radii(scene, k, Hs):
    """rho of the coupling ``k`` at the steps ``Hs``, one matrix at a time."""
    p, c = scene.plant.params, scene.controller
    with one_blas_thread():
        return np.array([spectral_radius(transition_matrix(
            p, c, float(H), **{key: k[key] for key in KEYS if key not in ("critical_step",
                                                                        "intervals")}))
            for H in Hs])


def test_json_of_the_filtered_scene(capsys, cached):
    """The documented shape; the scene's critical step is where rho(Phi) of its own transition
    matrix reaches 1: below 1 on a fine grid up to it (400 points), above just beyond it."""
    r = _json(capsys, "flexible_pd_lowpass")
    assert set(r) == {"min_step", "max_step", "scene", "couplings", "loop"}
    assert (r["min_step"], r["max_step"]) == (1e-4, 0.05)
    assert r["loop"] == "the nonlinear rung's linearisation (4 modes, modal damping 0.1 %)"
    assert set(r["scene"]) == {"coupling", "critical_step", "intervals", "rho", "stable",
                               "substep_limit"}
    assert r["scene"]["coupling"] == {"algorithm": "gauss-seidel", "first": "controller",
                                      "extrapolation": 2, "input_derivatives": True,
                                      "output_derivatives": False, "coupling": "polynomial",
                                      "step": 0.002}
    scene = load_scene("flexible_pd_lowpass")
    Hc = r["scene"]["critical_step"]
    assert max(_rho(scene, H) for H in np.linspace(2e-3, 0.999 * Hc, 400)) < 1
    assert _rho(scene, 1.001 * Hc) > 1
    assert r["scene"]["stable"] and r["scene"]["rho"] == pytest.approx(_rho(scene, 2e-3),
                                                                        rel=1e-12)
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
    assert len(r["couplings"]) == 3 * 7 + 5 + 2 and all(set(c) == KEYS for c in r["couplings"])
    own = next(c for c in r["couplings"] if all(
        c[k] == v for k, v in r["scene"]["coupling"].items() if k != "step"))
    assert own["critical_step"] == pytest.approx(Hc, rel=1e-9)
    assert own["intervals"] == r["scene"]["intervals"]
    # Jacobi with the hold: a narrow window (0.8 %, rho <= 1.00012) from 7.28 ms, below the
    # main crossing at 8.03 ms (the probe: "fails near 8 ms"); both are rho = 1
    hold = next(c for c in r["couplings"] if c["algorithm"] == "jacobi"
                and c["extrapolation"] == 0)
    rho = lambda H: spectral_radius(transition_matrix(  # noqa: E731
        scene.plant.params, scene.controller, H, algorithm="jacobi"))
    assert rho(0.9999 * hold["critical_step"]) < 1 < rho(1.0001 * hold["critical_step"])
    assert max(rho(H) for H in np.linspace(1e-3, 0.9999 * hold["critical_step"], 2000)) < 1
    assert [i["stable"] for i in hold["intervals"]] == [True, False, True, False, True, False]


def test_intervals_are_the_spectral_radius_one_matrix_at_a_time(filtered):
    """Every coupling's intervals tile [0.1 ms, 50 ms], stable and unstable in turn; at each
    boundary rho crosses 1 (1e-6 either side, one matrix at a time, not the scan's stacks), and
    inside each interval, at 12 points spread over it, rho is on the interval's side of 1. An
    unstable interval's rho_max is its largest radius (at least each point's)."""
    scene = load_scene("flexible_pd_lowpass")
    for c in filtered["couplings"]:
        iv = c["intervals"]
        assert iv[0]["from"] == 1e-4 and iv[-1]["to"] == 0.05
        assert all(a["to"] == b["from"] and a["stable"] != b["stable"]
                   for a, b in zip(iv, iv[1:]))
        edges = np.array([i["to"] for i in iv[:-1]])
        below, above = _radii(scene, c, edges * (1 - 1e-6)), _radii(scene, c, edges * (1 + 1e-6))
        for i, b, lo, hi in zip(iv, edges, below, above):
            assert (lo < 1 < hi) if i["stable"] else (hi < 1 < lo), (c, b, lo, hi)
        for i in iv:
            Hs = np.geomspace(i["from"], i["to"], 14)[1:-1]
            rho = _radii(scene, c, Hs)
            assert np.all((rho < 1) == i["stable"]), (c, i, Hs[(rho < 1) != i["stable"]])
            if not i["stable"]:
                assert i["rho_max"] >= rho.max()
            else:
                assert i["rho_max"] is None
    assert filtered["couplings"][0]["critical_step"] == filtered["couplings"][0]["intervals"][1][
        "from"]


def test_couplings_follow_the_masters_rules():
    """The pythonfmu FMUs give no output derivatives: those couplings are not offered."""
    ks = stability.couplings(MasterSettings(fmus="python"))
    assert len(ks) == 4 * 5 and not any(k["output_derivatives"] for k in ks)
    ks = stability.couplings(MasterSettings())
    # and the Hermite coupling, Gauss-Seidel with either FMU first (native FMUs only)
    assert len(ks) == 3 * 7 + 5 + 2
    assert [k["first"] for k in ks if k.get("coupling") == "hermite"] == ["controller", "plant"]


def test_text_says_which_intervals_are_stable(capsys, cached, filtered):
    assert main(["stability", "flexible_pd_lowpass"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "communication steps 0.1 to 50 ms" in out[0]
    assert any("assumes the plant is linearised" in line for line in out)
    own = [line.strip() for line in out[out.index(next(x for x in out if "its coupling" in x)):]]
    assert own[1] == "master.step = 2 ms: stable (rho = %.6g per step)" % filtered["scene"]["rho"]
    assert own[2] == "stable at every step up to 14.64 ms (the first crossing of rho = 1)"
    expect = ", ".join(f"{i['from'] * 1e3:.4g}-{i['to'] * 1e3:.4g}"
                       for i in filtered["scene"]["intervals"] if i["stable"])
    assert own[3] == f"stable:   {expect} ms" and own[3].startswith("stable:   0.1-14.64, 20.9-")
    assert own[4].startswith("unstable: 14.64-20.9 (rho up to 1.02284)")
    # every coupling: its stable intervals; Jacobi with the hold has three
    hold = next(line for line in out if "jacobi, zero-order hold" in line)
    assert hold.split("  ")[-1].strip() == "0.1-7.284, 7.341-7.491, 7.523-8.032 ms"
    assert out[-1] == ("  stable at every step up to the largest first crossing: implicit, "
                       "extrapolation 1, held average (38.07 ms)")


def test_max_step_and_progress(capsys, monkeypatch):
    """``--max-step`` bounds the scan (the rigid scene: one boundary per coupling below 0.2 s,
    none below 5 ms: every coupling stable throughout); a bad one is one line, exit 2. The
    progress callback sees the fraction done grow to 1; on stderr it is a progress line."""
    seen = []
    r = api.stability("rigid_pd", max_step=0.005, progress=lambda f, label: seen.append(f))
    assert r["max_step"] == 0.005 and seen == sorted(seen) and seen[-1] == 1.0
    assert all(c["intervals"] == [{"from": 1e-4, "to": 0.005, "stable": True, "rho_max": None}]
               and c["critical_step"] is None for c in r["couplings"])
    for bad in ("0", "20", "nan"):
        assert main(["stability", "rigid_pd", "--max-step", bad]) == 2
        err = capsys.readouterr().err
        assert "--max-step" in err and "allowed: a step in seconds from 0.001 to 10" in err
        assert err.count("\n") == 1
    with pytest.raises(ValueError, match="max_step = 20; allowed"):
        api.stability("rigid_pd", max_step=20)
    # the command's progress line (shown at once here: no delay) and its text
    import orchestration.report.progress as progress

    class Now(progress.Progress):
        def __init__(self, label, stream=None, delay=0.0):
            super().__init__(label, stream, delay=0.0)
    monkeypatch.setattr(progress, "Progress", Now)
    assert main(["stability", "rigid_pd", "--max-step", "0.005"]) == 0
    cap = capsys.readouterr()
    assert "flexpend stability: 100 %" in cap.err
    assert "stable at every step up to 5 ms" in cap.out


def test_ctrl_c_stops_the_scan(capsys, monkeypatch):
    """A Ctrl-C is honoured at the scan's next progress report: exit 130, one line."""
    from orchestration import cli

    def interrupted(scene, overrides, *, max_step, progress):
        cli.INTERRUPTS.count = 1
        progress(0.5)
        raise AssertionError("the scan went on")
    monkeypatch.setattr(api, "stability", interrupted)
    assert main(["stability", "rigid_pd"]) == 130
    assert capsys.readouterr().err.endswith("flexpend: interrupted\n")


def test_the_front_door_exports_stability():
    """``orchestration.stability`` is the documented function, in ``__all__``."""
    import orchestration as fp

    assert "stability" in fp.__all__ and fp.stability is api.stability


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
