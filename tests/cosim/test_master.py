"""The co-simulation master against the monolithic reference, the linear analysis and libcosimpy."""
import numpy as np
import pytest

from orchestration.studies.analysis import analyze
from orchestration.cosim.master import Master
from orchestration.cosim.slave import Slave
from orchestration.cosim.coupling import _History, extrapolation_weights
from orchestration.scene.wiring import parse_connection
from orchestration.studies.reference import simulate_reference
from orchestration.job import RECORD, controller_start_values, plant_start_values, run_scene
from orchestration.scene.records import DEFAULT_CONNECTIONS, MasterSettings
from orchestration.scene.schema import load_scene


@pytest.fixture(scope="module")
def paths(fmus):
    return {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}


# The plant integrates far more accurately than the coupling, so that the error measured is the
# coupling's: adaptive Dormand-Prince at tight tolerance.
ACCURATE_PLANT = ["plant.integrator=dopri5", "plant.rtol=1e-10", "plant.atol=1e-12"]


def _error(paths, scene_name, step, extra=()):
    scene = load_scene(scene_name, ["stop_time=1.0", "output_interval=0.02", f"master.step={step}",
                                    *ACCURATE_PLANT, *extra])
    res = run_scene(scene, paths, progress=False).result
    ref = simulate_reference(scene)
    np.testing.assert_array_equal(res["time"], ref["time"])
    return float(np.max(np.abs(res["phi_o"] - ref["phi_o"])))


def _order(paths, scene_name, extra, steps=(2e-3, 1e-3, 5e-4)):
    errs = [_error(paths, scene_name, h, extra) for h in steps]
    slopes = np.diff(np.log(errs)) / np.diff(np.log(steps))
    return errs, slopes


def test_extrapolation_weights_are_exact_for_polynomials():
    """The held value is the step average of the polynomial through past samples."""
    times = [-0.2, -0.1, 0.0]
    for deg in range(3):
        u = lambda t: (1 + 2 * t + 3 * t * t) if deg == 2 else (1 + 2 * t if deg == 1 else 5.0)  # noqa
        w = extrapolation_weights(times[2 - deg:], 0.0, 0.1)
        exact = {0: 5.0, 1: 1 + 2 * 0.05, 2: 1 + 2 * 0.05 + 3 * 0.01 / 3}[deg]
        assert float(w @ [u(t) for t in times[2 - deg:]]) == pytest.approx(exact, rel=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["rigid_pd", "flexible_pd_lowpass"])
@pytest.mark.parametrize("p,expected", [(0, 1.0), (1, 2.0)], ids=["zoh", "linear"])
def test_convergence_order_to_monolithic_reference(paths, scene, p, expected):
    errs, slopes = _order(paths, scene, [f"master.extrapolation={p}"])
    assert np.all(slopes > expected - 0.25) and np.all(slopes < expected + 0.5), (errs, slopes)


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_input_derivatives_raise_the_order_to_three(paths, algorithm):
    """With the extrapolation polynomial passed as input derivatives (the FMUs integrate it over
    the step instead of holding its average), quadratic extrapolation gives a third-order
    coupling error; held, it stays second order."""
    errs, slopes = _order(paths, "flexible_pd_lowpass", [
        "master.extrapolation=2", "master.input_derivatives=true",
        f"master.algorithm={algorithm}"])
    assert np.all(slopes > 3.0 - 0.25) and np.all(slopes < 3.5), (errs, slopes)
    held, held_slopes = _order(paths, "flexible_pd_lowpass", [
        "master.extrapolation=2", "master.input_derivatives=false", f"master.algorithm={algorithm}"])
    assert np.all(held_slopes < 2.5) and errs[-1] < held[-1] / 4, (errs, held)


@pytest.mark.slow
@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_jacobi_and_gauss_seidel_converge(paths, algorithm):
    errs, slopes = _order(paths, "flexible_pd_lowpass", [f"master.algorithm={algorithm}",
                                                         "master.extrapolation=1"])
    assert errs[-1] < errs[0] / 8 and errs[-1] < 1e-3, errs


@pytest.mark.slow
def test_adaptive_master_meets_its_tolerance(paths):
    """The error against the monolithic reference stays below the tolerance and falls with it."""
    errors = []
    for tol in (1e-3, 1e-4):
        scene = load_scene("flexible_pd_lowpass", [
            "stop_time=0.5", "output_interval=0.02", "master.adaptive=true",
            f"master.tolerance={tol}", "master.extrapolation=1", *ACCURATE_PLANT])
        r = run_scene(scene, paths, progress=False)
        ref = simulate_reference(scene)
        errors.append(float(np.max(np.abs(r.result["phi_o"] - ref["phi_o"]))))
        assert errors[-1] < tol
        assert r.stats.rejected >= 1        # the start (a 260 N jump) forces rejections
        assert r.stats.min_step_used < r.stats.max_step_used
        assert r.stats.forced_accepts == 0
    # the estimate is the state's local error per step (the input's error times the step, order
    # p + 2 = 3): the global error goes as tol^(1 - 1/3), 10^(2/3) = 4.6 per decade
    assert errors[1] < errors[0] / 3, errors


def test_rollback_restores_state_exactly(paths):
    scene = load_scene("flexible_pd_lowpass")
    slaves = {"plant": Slave(paths["plant"], "plant", plant_start_values(scene)),
              "controller": Slave(paths["controller"], "controller",
                                  controller_start_values(scene))}
    try:
        m = Master(slaves, [parse_connection(c) for c in DEFAULT_CONNECTIONS], RECORD,
                   MasterSettings(step=1e-3, first="plant", extrapolation=0,
                                  input_derivatives=False))
        for s in slaves.values():
            s.initialize(0.0, 1.0)
        hist = {n: _History(3) for n in slaves}
        for n, s in slaves.items():
            hist[n].push(0.0, s.get_outputs())
        for k in range(50):
            new = m._macro_step(hist, k * 1e-3, (k + 1) * 1e-3)
            for n in slaves:
                hist[n].push((k + 1) * 1e-3, new[n])
        states = {n: s.get_state() for n, s in slaves.items()}
        snaps = {n: hist[n].snapshot() for n in slaves}

        def ten_steps():
            rows = []
            for j in range(10):
                t0, t1 = 0.05 + j * 1e-3, 0.05 + (j + 1) * 1e-3
                new = m._macro_step(hist, t0, t1)
                for n in slaves:
                    hist[n].push(t1, new[n])
                rows.append(np.concatenate([new["plant"], new["controller"]]))
            return np.array(rows)

        first = ten_steps()
        for n, s in slaves.items():
            s.set_state(states[n])
            hist[n].restore(snaps[n])
        again = ten_steps()
        np.testing.assert_array_equal(first, again)
        assert not np.array_equal(first[0], first[-1])   # the loop did move
        assert "plant.phi_o" in m.connection_table()
    finally:
        for s in slaves.values():
            s.close()


@pytest.mark.slow
@pytest.mark.parametrize("scene,verdict,band", [
    ("rigid_pd", True, None),
    ("flexible_pd", False, (140, 160)),
    ("flexible_pd_lowpass", True, None),
])
def test_paper_scenes_verdicts_and_rates_at_small_amplitude(paths, scene, verdict, band):
    """Verdicts of docs/model.md; fitted rates within 10 % of the linear analysis at phi0 = 0.05."""
    sc = load_scene(scene, ["initial.phi=0.05", "master.step=1e-3", "output_interval=0.002",
                            "master.extrapolation=1", "stop_time=4"])
    r = run_scene(sc, paths, progress=False)
    s = r.summary
    assert s["stable"] is verdict
    eig = analyze(sc.plant.params, sc.controller).eigenvalues
    slow_lin = min((z for z in eig if 5 < z.imag < 30), key=lambda z: abs(z.imag - 10.2))
    assert s["slow"]["rate"] == pytest.approx(slow_lin.real, rel=0.10)
    assert s["slow"]["frequency"] == pytest.approx(slow_lin.imag, rel=0.10)
    if sc.plant.n_modes:
        bend_lin = max((z for z in eig if 100 < z.imag < 200), key=lambda z: z.real)
        assert s["bending"]["rate"] == pytest.approx(bend_lin.real, rel=0.10)
        assert s["bending"]["frequency"] == pytest.approx(bend_lin.imag, rel=0.10)
    if band:
        assert band[0] < s["bending"]["frequency"] < band[1]


def test_master_jacobi_agrees_with_libcosim(paths, fmus, tmp_path):
    """libcosim's fixed-step algorithm is Jacobi with a zero-order hold: outputs of step k feed the
    inputs of step k + 1. The master with the same settings must give the same numbers."""
    from test_fmu_libcosim import H, PLANT_OUT, PLANT_START, STEPS, run_libcosim

    cosim = run_libcosim(fmus, tmp_path)
    slaves = {"plant": Slave(paths["plant"], "plant", PLANT_START),
              "controller": Slave(paths["controller"], "controller")}
    record = {v: ("plant", v) for v in PLANT_OUT}
    record["F_c"] = ("controller", "F_c")
    try:
        m = Master(slaves, [parse_connection(c) for c in DEFAULT_CONNECTIONS], record,
                   algorithm="jacobi", step=H, extrapolation=0)
        res, stats = m.run(0.0, STEPS * H, H)
    finally:
        for s in slaves.values():
            s.close()
    assert stats.steps == STEPS
    ours = np.column_stack([res[c] for c in [*PLANT_OUT, "F_c"]])[1:]
    assert np.max(np.abs(ours - cosim)) <= 1e-9
    assert np.ptp(ours[:, 2]) > 0.1
