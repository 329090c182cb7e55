"""The sampled controller (``controller.sample_period > 0``) in ``flexpend analyze`` and
``flexpend stability`` (and their Python functions): the discrete-time loop beside the
continuous one, its stable sample periods and ``--sampled-region``. The rigid pendulum's limits
are checked against its closed-form zero-order hold (the hyperbolic functions of ``sqrt(a) T``,
no matrix exponential) and the Jury conditions; the physics of the loop itself is in
tests/studies/test_sampled.py."""
import json
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from orchestration import api
from orchestration.cli import main
from orchestration.scene.schema import load_scene
from orchestration.studies.analysis import linearisation

SAMPLED = ["--set", "controller.sample_period=0.004", "--set", "controller.delay=0.002"]


def _rigid(T, kp, kd, p):
    """The rigid pendulum on its cart, linearised upright, ``phidd = a phi + b F``, discretised by
    hand: ``Phi = [[cosh, sinh / w], [w sinh, cosh]](w T)``, ``Gamma = b [(cosh - 1) / w^2,
    sinh / w]`` (``w = sqrt(a)``); with ``F_k = -(kp phi_k + kd omega_k)``."""
    mb = p.rho * p.EA / p.E * p.L
    M0 = np.array([[p.m + mb, -mb * p.L / 2], [-mb * p.L / 2, mb * p.L ** 2 / 3]])
    Minv = np.linalg.inv(M0)
    a, b = Minv[1, 1] * mb * p.g * p.L / 2, Minv[1, 0]
    w = math.sqrt(a)
    ch, sh = math.cosh(w * T), math.sinh(w * T)
    Phi = np.array([[ch, sh / w], [w * sh, ch]])
    Gam = b * np.array([[(ch - 1) / a], [sh / w]])
    return Phi, Gam, np.array([[kp, kd]])


def _rigid_limits():
    """The largest stable T with no delay (the Jury conditions of ``z^2 - tr z + det``: the
    first of ``1 - det``, ``1 - tr + det``, ``1 + tr + det`` to reach 0) and with a full period's
    delay (the 3 x 3 loop ``[[Phi, Gamma], [-K, 0]]``'s spectral radius reaching 1)."""
    sc = load_scene("rigid_pd")
    p, c = linearisation(sc).params, sc.controller

    def jury(T):
        Phi, G, K = _rigid(T, c.kp, c.kd, p)
        Acl = Phi - G @ K
        tr, det = np.trace(Acl), np.linalg.det(Acl)
        return min(1 - det, 1 - tr + det, 1 + tr + det)

    def delayed(T):
        Phi, G, K = _rigid(T, c.kp, c.kd, p)
        M = np.block([[Phi, G], [-K, np.zeros((1, 1))]])
        return 1.0 - np.abs(np.linalg.eigvals(M)).max()

    out = []
    for f in (jury, delayed):
        Ts = np.geomspace(1e-4, 0.05, 2000)
        i = next(i for i, T in enumerate(Ts) if f(T) <= 0)
        out.append(brentq(f, Ts[i - 1], Ts[i], xtol=1e-14, rtol=1e-12))
    return out


@pytest.fixture(scope="module")
def rigid_limits():
    return _rigid_limits()


def test_analyze_of_a_sampled_scene_adds_its_discrete_time_loop():
    a = api.analyze(overrides={"controller.sample_period": 0.004, "controller.delay": 0.002})
    sp = a.sampled
    assert (sp.T, sp.tau, sp.discretization) == (0.004, 0.002, "tustin")
    # the s-plane equivalents are log(z) / T: exp(s T) gives z back
    finite = np.isfinite(sp.s.real)
    np.testing.assert_allclose(np.exp(sp.s[finite] * sp.T), sp.z[finite], atol=1e-12)
    # the loop's order: the plant without the cart's drift states (kx = 0), the filter, F_{k-1}
    p, c = a.plant, a.controller
    assert c.kx == 0
    assert len(sp.z) == 2 * (p.n_modes + 1) + c.filter_order + 1
    assert sp.margin == pytest.approx(1 - np.abs(sp.z).max(), abs=0)
    assert sp.stable == (np.abs(sp.z).max() < 1)
    # the continuous fields stay the continuous loop's
    cont = api.analyze()
    assert cont.sampled is None
    np.testing.assert_array_equal(a.eigenvalues, cont.eigenvalues)


def test_analyze_json_and_text_of_a_sampled_scene(capsys):
    assert main(["analyze", "--json", *SAMPLED]) == 0
    out = json.loads(capsys.readouterr().out)
    s = out["sampled"]
    z = np.array([complex(*v) for v in s["z"]])
    assert s["spectral_radius"] == pytest.approx(np.abs(z).max(), rel=1e-15)
    assert s["margin"] == pytest.approx(1 - np.abs(z).max(), rel=1e-12)
    assert s["stable"] is bool(np.abs(z).max() < 1)
    assert (s["T"], s["tau"], s["discretization"]) == (0.004, 0.002, "tustin")
    assert main(["analyze", *SAMPLED]) == 0
    text = capsys.readouterr().out
    assert "sampled controller: T = 4 ms, delay tau = 2 ms, tustin filter" in text
    assert f"margin 1 - max |z| = {s['margin']:+.6f}" in text
    # a continuous scene: no word of it
    assert main(["analyze", "--json"]) == 0
    assert "sampled" not in json.loads(capsys.readouterr().out)
    assert main(["analyze"]) == 0
    assert "sampled" not in capsys.readouterr().out


def test_stability_of_a_sampled_rigid_scene_meets_the_closed_form(capsys, rigid_limits):
    T0, T1 = rigid_limits
    assert main(["stability", "rigid_pd", "--json", "--set", "controller.sample_period=0.004",
                 "--set", "master.step=0.001"]) == 0
    s = json.loads(capsys.readouterr().out)["sampled"]
    assert s["critical_periods"]["tau=0"] == pytest.approx(T0, rel=1e-7)
    assert s["critical_periods"]["tau=T"] == pytest.approx(T1, rel=1e-7)
    # at the scene's delay (0) the first stable interval ends at the same limit
    assert s["tau"] == 0 and s["intervals"][0][1] == pytest.approx(T0, rel=1e-7)
    assert s["critical"] == pytest.approx(T0, rel=1e-7)
    assert s["stable"] is True and s["margin"] > 0


def test_stability_text_of_a_sampled_scene(capsys):
    from orchestration.cli import sampled_stability_lines

    assert main(["stability", "flexible_pd_lowpass", "--json", "--max-step", "0.02",
                 *SAMPLED]) == 0
    r = json.loads(capsys.readouterr().out)["sampled"]
    assert r["scanned"] == [0.002, 0.02]                # from T = tau to --max-step
    text = "\n".join(sampled_stability_lines(r))
    assert "the sampled controller (T = 4 ms, delay tau = 2 ms, tustin filter)" in text
    assert f"largest stable T: {r['critical'] * 1e3:.4g} ms at tau = 2 ms" in text
    # the scene's own period lies in a stable interval iff its poles say stable
    inside = any(a <= r["T"] <= b for a, b in r["intervals"])
    assert inside == r["stable"] == (r["margin"] > 0)
    # and the boundary is where the verdict changes (poles computed afresh)
    sc = load_scene("flexible_pd_lowpass")
    loop = (linearisation(sc).params, sc.controller)
    from orchestration.studies.sampled import sampled_poles
    assert sampled_poles(loop, r["critical"] * (1 - 1e-6), 0.002).stable
    assert not sampled_poles(loop, r["critical"] * (1 + 1e-6), 0.002).stable
    # a continuous controller has no sampled part
    with pytest.raises(ValueError, match="sample_period > 0"):
        api.sampled_stability("flexible_pd_lowpass")


def test_sampled_region_writes_the_figure_and_prints_the_limits(tmp_path, capsys, rigid_limits):
    path = tmp_path / "region.png"
    assert main(["stability", "rigid_pd", "--json", "--sampled-region", str(path)]) == 0
    r = json.loads(capsys.readouterr().out)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [f.name for f in tmp_path.iterdir()] == ["region.png"]     # no temporary left
    crit = r["sampled_region"]["critical_periods"]
    assert list(crit) == ["rigid_pd", "flexible_pd", "flexible_pd_lowpass"]
    assert crit["rigid_pd"]["tau=0"] == pytest.approx(rigid_limits[0], rel=1e-7)
    assert crit["rigid_pd"]["tau=T"] == pytest.approx(rigid_limits[1], rel=1e-7)
    assert crit["flexible_pd"] == {"tau=0": None, "tau=T": None}   # unstable as T -> 0
    assert "sampled" not in r                                       # rigid_pd is continuous


@pytest.mark.parametrize("name,fragment", [
    ("region.txt", "allowed: a .png, .pdf or .svg file"),
    ("missing/region.png", "does not exist")])
def test_bad_sampled_region_is_one_line_exit_2(tmp_path, capsys, name, fragment):
    assert main(["stability", "rigid_pd", "--sampled-region", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1
    assert not (tmp_path / name).exists()
