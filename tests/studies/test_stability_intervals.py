"""The stable and unstable intervals of the communication step (``flexpend stability``,
orchestration/studies/stability_intervals.py), checked against runs of the real co-simulation.

For every coupling the master offers, the native FMUs run through the product's master
(``orchestration.simulate`` with ``master.*`` overrides) at steps just inside and just outside
each boundary the report gives (0.95 and 1.05 times it; the middle of an interval too narrow for
that, :func:`probe_steps`), from ``initial.phi = 1e-3`` on the scene's plant (the nonlinear rung:
at that angle its nonlinear terms are ~1e-6 of the motion), long enough to decide: ``N`` steps,
as many as the predicted growth or decay per step needs to change the amplitude a thousandfold
(200 to 4000). How a run ended (:func:`observed_verdict`, from ``phi_o, omega_o, F_c`` once per
step): it fell (the plant stopped it), grew tenfold (then a saturating force ends it in a limit
cycle), settled a hundredfold, or, in between, the growth per step fitted on its last fifth
decides. Inside, every run must settle; outside, none may. A run that settles follows the
predicted mode: its fitted decay per step is the predicted spectral radius to 1 % of
``1 - rho`` (while its last window is above 1e-4 of its start: further down the implicit
master's absolute tolerance, 1e-9 by default, is no longer small against the signals).

The rigid scene (no bending mode: one boundary per coupling, cheap runs) up to 0.2 s; the
filtered scene (4 modes: up to 20 boundaries per coupling) up to the default maximum step; and
the implicit master's claim on the filtered scene (stable on an interval holding twice the
default explicit coupling's first crossing and twice its largest stable step) up to 0.15 s.
"""
import math

import numpy as np
import pytest

import orchestration as fp
from orchestration.scene.schema import load_scene
from orchestration.studies.analysis import linearisation
from orchestration.studies.stability import (couplings, observed_verdict, spectral_radius,
                                             transition_matrix)
from orchestration.studies.stability_intervals import MAX_STEP, probe_steps, step_intervals

CHANNELS = ("phi_o", "omega_o", "F_c")
KEYS = ("algorithm", "first", "extrapolation", "input_derivatives", "output_derivatives",
        "coupling")


def _label(k):
    if k["coupling"] == "hermite":
        return "-".join([k["algorithm"], k["first"], "hermite"])
    return "-".join([k["algorithm"], k["first"], f"p{k['extrapolation']}"]
                    + ["in"] * k["input_derivatives"] + ["out"] * k["output_derivatives"])


COUPLINGS = couplings(load_scene("flexible_pd_lowpass").master)


def _predicted(scene, k, H):
    sc = load_scene(scene)
    return spectral_radius(transition_matrix(
        linearisation(sc).params, sc.controller, H, integrator=sc.plant.integrator,
        substep=sc.plant.step, **{key: k[key] for key in KEYS}))


def _run(scene, k, H, rho):
    """The verdict of the native FMUs' co-simulation of ``scene`` with the coupling ``k`` at the
    step ``H`` (:func:`observed_verdict`), with ``N`` from the predicted ``rho``."""
    N = int(min(4000, max(200, math.ceil(math.log(1e3) / abs(math.log(rho))))))
    sets = {"master.step": H, "output_interval": H, "stop_time": N * H, "initial.phi": 1e-3,
            "fidelity.companion": False,     # the coupling is observed, not the model's error
            **{f"master.{key}": k[key] for key in KEYS}}
    run = fp.simulate(scene, sets)
    Y = np.column_stack([run.result[c] for c in CHANNELS])
    return observed_verdict(Y, stopped=not run.completed)


def _check(scene, row):
    """Every probe step of one coupling's intervals: the run's verdict is the interval's; a run
    that settles decays per step as predicted. The mismatches, as text."""
    bad = []
    for H, stable in probe_steps(row["intervals"]):
        rho = _predicted(scene, row, H)
        assert (rho < 1) == stable, (H, rho)         # the probe is on the interval's side
        verdict, ratio, factor = _run(scene, row, H, rho)
        if (verdict == "settles") != stable:
            bad.append(f"H = {H * 1e3:.4f} ms: predicted rho = {rho:.6f}, the run {verdict} "
                       f"(amplitude x {ratio:.3g}, fitted factor {factor:.6f})")
        elif stable and ratio > 1e-4 and abs(factor - rho) > 0.01 * (1 - rho):
            bad.append(f"H = {H * 1e3:.4f} ms: settles at {factor:.6f} per step, predicted "
                       f"{rho:.6f}")
    return bad


# ---------------------------------------------------------------------- the scan itself
def test_intervals_of_a_known_function():
    """A radius with three crossings on the grid and a window narrower than the grid's spacing
    (a bump between two grid points that neither shows) is split into its five intervals, the
    edges to 1e-7 of the roots computed by hand."""
    Hs = np.geomspace(1e-3, 1e-1, 201)                    # ratio 1.0233 between neighbours
    x = np.log(Hs[60]) + 0.3 * np.log(Hs[61] / Hs[60])    # the bump, off the grid
    w = 0.004                                             # half width in log H: 0.8 %

    def f(H):
        u = np.log(np.asarray(H, dtype=float))
        return 0.99 + 0.02 * np.maximum(0.0, 1 - ((u - x) / w) ** 2) \
            + 0.5 * ((u > np.log(3e-2)) & (u < np.log(5e-2)))
    rho = f(Hs)
    # the bump's top lies between grid points 60 and 61 and no grid point is above 1 there
    assert rho[59:63].max() < 1
    # a radius with a discrete local maximum beside the bump, as an eigenvalue's shoulder
    rho[60] += 1e-6
    got = step_intervals(Hs, rho, f)
    half = w * math.sqrt(0.5)                             # where 0.99 + 0.02 (1 - s^2) = 1
    edges = [math.exp(x - half), math.exp(x + half), 3e-2, 5e-2]
    assert [g[2] for g in got] == [True, False, True, False, True]
    for (a, b, _, _), e in zip(got, edges):
        assert b == pytest.approx(e, rel=1e-6)
    assert got[0][0] == Hs[0] and got[-1][1] == Hs[-1]
    assert got[1][3] == pytest.approx(1.01, abs=1e-6)     # the window's top


def test_probe_steps_are_inside_each_interval():
    iv = [(1e-4, 1e-2, True), (1e-2, 1.01e-2, False), (1.01e-2, 3e-2, True), (3e-2, 5e-2, False)]
    got = probe_steps(iv)
    assert got == [(pytest.approx(0.95e-2), True), (pytest.approx(math.sqrt(1.01e-4)), False),
                   (pytest.approx(1.05 * 1.01e-2), True), (pytest.approx(0.95 * 3e-2), True),
                   (pytest.approx(1.05 * 3e-2), False)]
    # an interval too narrow for both: its middle, once
    assert probe_steps([(1e-4, 1e-2, True), (1e-2, 1.08e-2, False)])[1] == \
        (pytest.approx(math.sqrt(1.08e-4)), False)
    assert probe_steps([(1e-4, 0.2, True)]) == [(pytest.approx(0.19), True)]


def test_verdicts_of_known_signals():
    """A decaying, a growing and a saturating oscillation, and a stopped run."""
    n = np.arange(600)[:, None]
    osc = np.hstack([np.cos(0.3 * n), np.sin(0.3 * n)])
    assert observed_verdict(0.99 ** n * osc)[0] == "settles"
    v, ratio, factor = observed_verdict(0.9995 ** n * osc)       # undecided by the amplitude
    assert v == "settles" and 0.01 < ratio < 1 and factor == pytest.approx(0.9995, abs=1e-9)
    # a slow growth still below the decaying mode it started under: the fit decides
    v, ratio, factor = observed_verdict(0.995 ** n * osc + 1e-3 * 1.001 ** n * osc[:, ::-1])
    assert v == "grows" and ratio < 1 and factor == pytest.approx(1.001, abs=1e-9)
    # a limit cycle: grown, then constant
    assert observed_verdict(np.minimum(1.02 ** n, 5.0) * osc)[0] == "grows"
    assert observed_verdict(osc, stopped=True)[0] == "falls"


# ---------------------------------------------------------------------- against the FMUs
@pytest.fixture(scope="module")
def rigid():
    return {tuple(r[k] for k in KEYS): r
            for r in fp.stability("rigid_pd", max_step=0.2)["couplings"]}


@pytest.fixture(scope="module")
def filtered():
    return {tuple(r[k] for k in KEYS): r
            for r in fp.stability("flexible_pd_lowpass")["couplings"]}


@pytest.mark.slow
@pytest.mark.parametrize("k", COUPLINGS, ids=[_label(k) for k in COUPLINGS])
def test_rigid_scene_boundaries_are_observed(native, rigid, k):
    """The rigid PD scene (feedthrough, no filter) up to 0.2 s: at most one boundary per
    coupling; without one, the run at 0.95 times 0.2 s settles."""
    row = rigid[tuple(k[key] for key in KEYS)]
    assert len(row["intervals"]) <= 2
    assert _check("rigid_pd", row) == []


@pytest.mark.slow
@pytest.mark.parametrize("k", COUPLINGS, ids=[_label(k) for k in COUPLINGS])
def test_filtered_scene_boundaries_are_observed(native, filtered, k):
    """The filtered scene up to the default maximum step (0.05 s): every boundary, on both
    sides."""
    assert MAX_STEP == 0.05
    row = filtered[tuple(k[key] for key in KEYS)]
    assert _check("flexible_pd_lowpass", row) == []


@pytest.mark.slow
def test_implicit_master_is_stable_on_an_interval_beyond_the_explicit_limits(native):
    """The implicit master with its default polynomial (quadratic, input derivatives) on the
    filtered scene: stable on one interval that holds twice the default explicit coupling's
    first crossing and twice the top of its last stable interval, with the explicit coupling
    unstable at both; its edges observed. With the end value held (zero-order hold) it is
    unstable at twice the first crossing."""
    r = fp.stability("flexible_pd_lowpass", max_step=0.15)
    rows = {tuple(c[k] for k in KEYS): c for c in r["couplings"]}
    explicit = r["scene"]["intervals"]
    first = r["scene"]["critical_step"]
    top = max(i["to"] for i in explicit if i["stable"])
    implicit = rows["implicit", "controller", 2, True, False, "polynomial"]["intervals"]
    held = rows["implicit", "controller", 0, False, False, "polynomial"]["intervals"]

    def where(intervals, H):
        return next(i for i in intervals if i["from"] <= H <= i["to"])
    island = where(implicit, 2 * first)
    assert island["stable"] and island["from"] < 2 * first < 2 * top < island["to"]
    assert not where(explicit, 2 * first)["stable"] and not where(explicit, 2 * top)["stable"]
    assert not where(held, 2 * first)["stable"]
    k = dict(zip(KEYS, ("implicit", "controller", 2, True, False, "polynomial")))
    for H, stable in [(0.95 * island["from"], False), (1.05 * island["from"], True),
                      (2 * first, True), (2 * top, True), (0.95 * island["to"], True),
                      (1.05 * island["to"], False)]:
        rho = _predicted("flexible_pd_lowpass", k, H)
        assert (rho < 1) == stable, (H, rho)
        assert (_run("flexible_pd_lowpass", k, H, rho)[0] == "settles") == stable, H
    hold = dict(zip(KEYS, ("implicit", "controller", 0, False, False, "polynomial")))
    rho = _predicted("flexible_pd_lowpass", hold, 2 * first)
    assert rho > 1 and _run("flexible_pd_lowpass", hold, 2 * first, rho)[0] != "settles"
