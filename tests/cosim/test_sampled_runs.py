"""The sampled controller in the loop (issue 38), on the native pair, the master landing on
every tick and tick + delay:

* runs either side of every boundary of the sample period that the sampled loop's analysis
  predicts (orchestration/studies/sampled.py: the plant discretised exactly with the hold and
  the delay), for the three paper scenes with no delay and a full period's: the run's verdict is
  the predicted one and the crossing mode's fitted growth rate is its predicted pole's;
* as the sample period shrinks, the runs converge to the continuous controller's at order one;
* the pythonfmu controller and the native one give the same runs to round-off, the compiled
  loop the Python loop's bit for bit;
* the master's step lands on every instant (or the scene is refused in one line).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from orchestration.export import fmu_pair
from orchestration.job import run_scene
from orchestration.scene.schema import load_scene
from orchestration.studies.sampled import boundaries, sampled_poles

SHORT = {"initial.phi": 0.01, "fidelity.companion": "false"}


@pytest.fixture(scope="module")
def pair(native):
    """The native pair with the other families (PDLowPassSampled among them)."""
    return fmu_pair(native)


def _run(fmus, scene, T, tau):
    h = T / 12                                 # lands on every tick and tick + delay
    sets = {**SHORT, "controller.sample_period": T, "controller.delay": tau, "master.step": h,
            "output_interval": T, "stop_time": round(10.0 / T) * T}
    return run_scene(load_scene(scene, [f"{k}={v}" for k, v in sets.items()]), fmus,
                     progress=False)


BOUNDARIES = [(scene, fraction, *edge)
              for scene in ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
              for fraction in (0.0, 1.0)
              for edge in boundaries(scene, fraction)]


@pytest.mark.parametrize("scene,fraction,edge,below,delta", BOUNDARIES,
                         ids=[f"{s}-tau{f:g}T-{1e3 * e:.4g}ms" for s, f, e, _, _ in BOUNDARIES])
def test_runs_just_inside_and_outside_each_predicted_boundary(pair, scene, fraction, edge,
                                                              below, delta):
    """Either side of each boundary the run's verdict is the predicted one, and the growth rate
    of the mode that crosses, fitted in the run's phi_o (matrix pencil, within 30 % of its
    frequency), is its predicted pole's (the s-plane equivalent log(z) / T)."""
    from orchestration.studies.fit import fit_mode
    for T, stable in (((1 - delta) * edge, below), ((1 + delta) * edge, not below)):
        run = _run(pair, scene, T, fraction * T)
        s = sampled_poles(scene, T, fraction * T).s
        s = s[np.isfinite(s) & (s.imag > 1.0)]
        crossing = s[np.argmax(s.real)]
        assert run.summary["stable"] == stable, (T, run.summary["verdict_reason"])
        f = fit_mode(run.result["time"], run.result["phi_o"],
                     (0.7 * crossing.imag, 1.3 * crossing.imag), near=crossing.imag)
        assert f.frequency == pytest.approx(crossing.imag, rel=0.01)
        assert f.rate == pytest.approx(crossing.real, abs=2e-3 + 0.02 * abs(crossing.real))


def test_the_pythonfmu_controller_runs_the_native_ones_loop_to_round_off(pair, fmus):
    """The two flavours of the sampled controller (the native PDLowPassSampled, the pythonfmu
    PDLowPass on the same C kernel's difference equation), each with the native plant: the same
    run to round-off (their sums are ordered differently)."""
    T, tau = 0.006, 0.003
    python = {"plant": pair["plant"], "controller": fmus["PDLowPass"]}
    a, b = (_run(f, "rigid_pd", T, tau).result for f in (pair, python))
    assert len(a) == len(b) > 100
    for name in ("phi_o", "omega_o", "x", "F_c"):
        scale = max(1e-300, float(abs(a[name]).max()))
        assert float(abs(a[name] - b[name]).max()) <= 1e-12 * scale, name


@pytest.mark.parametrize("tau", [0.0, 0.004])
def test_the_compiled_loop_runs_the_sampled_loop_bit_for_bit_as_the_python_loop(pair, tau):
    T = 0.008
    runs = {}
    for compiled in ("true", "false"):
        sets = {**SHORT, "controller.sample_period": T, "controller.delay": tau,
                "master.step": 0.001, "output_interval": 0.01, "stop_time": 1.0,
                "master.compiled": compiled}
        runs[compiled] = run_scene(load_scene("flexible_pd_lowpass",
                                              [f"{k}={v}" for k, v in sets.items()]),
                                   pair, progress=False)
    assert runs["true"].stats.loop == "compiled" and runs["false"].stats.loop == "python"
    a, b = runs["true"].result, runs["false"].result
    assert len(a) == len(b) == 101
    for name in a.dtype.names:
        assert np.array_equal(a[name], b[name]), name


def test_the_master_lands_on_every_tick_delay_and_output_point():
    """The step a sampled scene runs: the scene's when it lands on every instant, else the
    largest below it that does (a divisor of the instants' greatest common divisor)."""
    from orchestration.scene.records import tick_step
    assert tick_step(5e-4, 6e-3, 3e-3, 1e-2) == 5e-4
    h = tick_step(2e-3, 5e-3, 0.0, 1e-2)                 # gcd 5 ms: 3 steps of 5/3 ms
    assert h == pytest.approx(5e-3 / 3, rel=1e-15)
    h = tick_step(1e-3, 7e-3, 2e-3, 1e-2)                # gcd 1 ms
    assert h == pytest.approx(1e-3, rel=1e-15)
    scene = load_scene("rigid_pd", ["controller.sample_period=0.005", "master.step=0.002"])
    assert scene.run_master.step == pytest.approx(5e-3 / 3) and \
        scene.run_master.algorithm == "jacobi"


@pytest.mark.parametrize("sets", [["controller.sample_period=0.0061234567",
                                   "controller.delay=0.001"],
                                  ["controller.sample_period=1e-320"],
                                  ["controller.sample_period=1e-6"]])
def test_instants_on_no_common_grid_are_one_line(sets):
    from orchestration.scene.keys import ConfigError
    with pytest.raises(ConfigError) as info:
        load_scene("rigid_pd", sets)
    assert "\n" not in str(info.value) and "common grid" in str(info.value)


def test_as_the_sample_period_shrinks_the_runs_converge_to_the_continuous_loop_at_order_one(pair):
    """Without delay the sampled loop tends to the continuous one as T -> 0; the zero-order hold
    delays the force by T / 2 on average (and the prewarped Tustin filter differs from the
    continuous one only at O(T^2)), so the runs' difference from the continuous controller's run
    falls as T: halving T halves it (observed order 1)."""
    base = ["stop_time=1.0", "output_interval=0.008", "fidelity.companion=false",
            "initial.phi=0.05"]
    ref = run_scene(load_scene("flexible_pd_lowpass", base + ["master.step=0.0001"]), pair,
                    progress=False).result
    errors = []
    for T in (0.004, 0.002, 0.001):
        r = run_scene(load_scene("flexible_pd_lowpass",
                                 base + [f"controller.sample_period={T}", "master.step=0.0005"]),
                      pair, progress=False).result
        errors.append(float(np.abs(r["phi_o"] - ref["phi_o"]).max()))
    orders = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    assert all(0.9 <= q <= 1.15 for q in orders), (errors, orders)


def test_the_coupling_is_exact_the_run_meets_the_hybrid_reference_at_the_plants_order(pair):
    """The monolithic reference of a sampled scene (orchestration.studies.reference: the plant
    solved by DOP853 at 1e-12 between the controller's instants, the specification's controller
    at the ticks) against the co-simulation: the difference is the plant FMU's own RK4 error
    alone (no coupling error: the force is piecewise constant on the grid), so it falls at
    order four as plant.step halves, and the sampled reference is far from the continuous
    controller's."""
    from orchestration.studies.reference import simulate_reference
    base = ["controller.sample_period=0.005", "controller.delay=0.005", "stop_time=2",
            "fidelity.companion=false", "output_interval=0.01"]
    ref = simulate_reference(load_scene("flexible_pd_lowpass", base))
    errors = []
    for ps in (1.25e-4, 6.25e-5):
        run = run_scene(load_scene("flexible_pd_lowpass", base + [f"plant.step={ps}"]), pair,
                        progress=False).result
        assert len(run) == len(ref)
        errors.append(float(np.abs(run["phi_o"] - ref["phi_o"]).max()))
    assert 3.5 <= math.log2(errors[0] / errors[1]) <= 5.5, errors
    cont = simulate_reference(load_scene("flexible_pd_lowpass",
                                         ["stop_time=2", "output_interval=0.01"]))
    assert float(np.abs(cont["phi_o"] - ref["phi_o"]).max()) > 1e4 * errors[1]
