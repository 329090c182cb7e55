"""The model-exchange master's compiled integration loop (``orchestration/cosim/native/fm_me.c``)
against its specification, the Python loop on scipy's Radau: the same steps, the same rows to
a small multiple of the tolerances, the same events and stops, and the keys that choose it."""
from __future__ import annotations

import numpy as np
import pytest

from orchestration.cosim import compiled_me
from orchestration.cosim.model_exchange import ModelExchangeMaster, ModelExchangeUnit
from orchestration.cosim.slave import RunInterrupted
from orchestration.job import RECORD, controller_start_values, plant_start_values, run_scene
from orchestration.scene.schema import PAPER_SCENES, load_scene
from orchestration.studies.reference import simulate_reference


@pytest.fixture(scope="module")
def pair(native) -> dict:
    from orchestration.export import fmu_pair
    return fmu_pair(native)


def _both(name, pair, items=()):
    """The scene ``name`` run by the Python loop and the compiled one."""
    runs = {}
    for compiled in ("false", "true"):
        scene = load_scene(name, ["master.interface=model-exchange",
                                  f"master.compiled={compiled}", *items])
        runs[compiled] = run_scene(scene, pair, progress=False)
    return runs["false"], runs["true"], scene


def _assert_rows_agree(py, c, settings, factor=10.0):
    """Every recorded column within ``factor`` times the solver's tolerance (rtol of the
    column's size, plus atol) of the Python loop's."""
    assert len(py) == len(c)
    np.testing.assert_array_equal(py["time"], c["time"])
    for col in py.dtype.names[1:]:
        bound = factor * (settings.rtol * np.max(np.abs(py[col])) + settings.atol)
        diff = float(np.max(np.abs(py[col] - c[col])))
        assert diff <= bound, (col, diff, bound)


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_the_compiled_loop_takes_the_python_loops_steps_and_gives_its_rows(pair, name):
    """The paper scenes (3 s): the same rows within 10 times the tolerances, nearly the same
    steps (the same method and step control, rounded differently), and both loops named."""
    py, c, scene = _both(name, pair, ["stop_time=3"])
    assert py.stats.loop == "model-exchange (radau)"
    assert c.stats.loop == "model-exchange (radau, compiled)"
    _assert_rows_agree(py.result, c.result, scene.master)
    assert abs(c.stats.steps - py.stats.steps) <= 0.02 * py.stats.steps + 2, \
        (c.stats.steps, py.stats.steps)
    assert c.stats.max_step_used <= scene.master.max_step * (1 + 1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_the_compiled_loop_meets_the_monolithic_reference(pair, name):
    """At rtol 1e-9 both loops agree with the monolithic reference (DOP853 at 1e-12 on the
    numpy model) within 1e-6 rad of phi_o, and with each other within 10 rtol."""
    py, c, scene = _both(name, pair, ["master.rtol=1e-9", "master.atol=1e-11"])
    ref = simulate_reference(scene)
    for run in (py, c):
        assert run.summary.get("stopped") is None
        assert float(np.max(np.abs(run.result["phi_o"] - ref["phi_o"]))) < 1e-6
    _assert_rows_agree(py.result, c.result, scene.master)


def test_a_fall_stops_at_the_same_event_with_the_plants_message(pair):
    """Without the P term the pendulum falls: the event indicator on phi_limit is located by
    both loops at the same time (to the event's resolution), event mode hears the plant ask
    to terminate, and the rows up to it agree."""
    py, c, scene = _both("flexible_pd_lowpass", pair, ["controller.kp=0", "stop_time=1"])
    sp, sc = py.summary["stopped"], c.summary["stopped"]
    assert abs(sp["time"] - sc["time"]) < 1e-8
    assert sc["reason"] == sp["reason"]
    assert "reached phi_limit" in sc["fmu_message"]
    _assert_rows_agree(py.result, c.result, scene.master)


def _units(scene, pair):
    return {"plant": ModelExchangeUnit(pair["plant"], "plant", plant_start_values(scene)),
            "controller": ModelExchangeUnit(pair["controller"], "controller",
                                            controller_start_values(scene))}


def test_a_stop_request_interrupts_the_compiled_loop_with_its_rows(pair):
    scene = load_scene("flexible_pd_lowpass", ["master.interface=model-exchange"])
    master = ModelExchangeMaster(_units(scene, pair), scene.connections, RECORD, scene.master)
    try:
        assert master.loop == "compiled"
        with pytest.raises(RunInterrupted) as info:
            master.run(0.0, 10.0, scene.output.output_interval, stop=lambda: True)
        exc = info.value
        assert 0.0 < exc.time < 10.0
        assert exc.stats.steps == compiled_me.CHUNK_STEPS
        assert len(exc.result) >= 1 and exc.result["time"][-1] <= exc.time
    finally:
        master.close()


def test_the_key_compiled_chooses_the_loop_and_says_why_not(pair):
    scene = load_scene("rigid_pd", ["master.interface=model-exchange", "master.solver=bdf",
                                    "master.compiled=true"])
    units = _units(scene, pair)
    try:
        with pytest.raises(ValueError, match="master.solver = 'bdf'.*Radau"):
            ModelExchangeMaster(units, scene.connections, RECORD, scene.master)
        auto = load_scene("rigid_pd", ["master.interface=model-exchange", "master.solver=bdf"])
        master = ModelExchangeMaster(units, auto.connections, RECORD, auto.master)
        assert master.loop == "python" and "bdf" in master.compiled_unavailable
    finally:
        for u in units.values():
            u.close()


def test_fmi3_fmus_keep_the_python_loop(native3):
    from orchestration.export import fmu_pair
    scene = load_scene("rigid_pd", ["master.interface=model-exchange"])
    units = _units(scene, fmu_pair(native3))
    try:
        master = ModelExchangeMaster(units, scene.connections, RECORD, scene.master)
        assert master.loop == "python"
        assert "FMI 3.0" in master.compiled_unavailable
    finally:
        for u in units.values():
            u.close()


def _fail_nth_call(unit, fname, argtypes, nth, status, keep):
    """Make the unit's ``fname`` return ``status`` at its ``nth`` call from now, for both loops
    (the Python loop's bound calls are bound again)."""
    import ctypes

    real = unit.fmu._functions[fname]
    count = [0]

    def call(*args):
        count[0] += 1
        return status if count[0] == nth else real(*args)
    cb = ctypes.CFUNCTYPE(ctypes.c_int, *argtypes)(call)
    keep.append(cb)
    unit.fmu._functions[fname] = cb
    unit._bind_hot()


@pytest.mark.parametrize("status, word", [(2, "discard"), (3, "error")])
def test_a_failed_call_ends_the_run_naming_the_fmu_the_call_and_the_status(pair, status, word):
    """fmi2GetDerivatives of the plant failing mid-run ends both loops with the same kind of
    CoSimulationError (FMU, call, status), the rows reached so far kept."""
    import ctypes

    from orchestration.cosim.slave import CoSimulationError

    argtypes = (ctypes.c_void_p, ctypes.POINTER(ctypes.c_double), ctypes.c_size_t)
    errors = {}
    for compiled in (False, True):
        scene = load_scene("flexible_pd_lowpass", ["master.interface=model-exchange",
                                                   f"master.compiled={str(compiled).lower()}"])
        units, keep = _units(scene, pair), []
        master = ModelExchangeMaster(units, scene.connections, RECORD, scene.master)
        _fail_nth_call(units["plant"], "fmi2GetDerivatives", argtypes, 2000, status, keep)
        try:
            with pytest.raises(CoSimulationError) as info:
                master.run(0.0, 10.0, scene.output.output_interval)
        finally:
            master.close()
        exc = errors[compiled] = info.value
        assert str(exc).startswith("plant: getDerivatives at t = ")
        assert f"returned {word}" in str(exc)
        assert exc.status == status and 0.0 < exc.time < 10.0
        assert 1 < len(exc.result) and exc.result["time"][-1] <= exc.time + 1e-12
    assert errors[True].time == pytest.approx(errors[False].time, rel=0.05)


def _completed_says(unit, nth, flag, keep):
    """Make the unit's fmi2CompletedIntegratorStep set ``flag`` (2: enter event mode, 3:
    terminate) at its ``nth`` call from now, for both loops."""
    import ctypes

    real = unit.fmu._functions["fmi2CompletedIntegratorStep"]
    count = [0]
    pint = ctypes.POINTER(ctypes.c_int)

    def call(c, no_prior, enter, terminate):
        status = real(c, no_prior, enter, terminate)
        count[0] += 1
        if count[0] == nth:
            (enter if flag == 2 else terminate)[0] = 1
        return status
    cb = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_int, pint, pint)(call)
    keep.append(cb)
    unit.fmu._functions["fmi2CompletedIntegratorStep"] = cb
    unit.fmu.fmi2CompletedIntegratorStep = cb


def _run_completed_says(pair, compiled, flag):
    from orchestration.cosim.slave import CoSimulationError

    scene = load_scene("flexible_pd_lowpass", ["master.interface=model-exchange", "stop_time=1",
                                               f"master.compiled={str(compiled).lower()}"])
    units, keep = _units(scene, pair), []
    master = ModelExchangeMaster(units, scene.connections, RECORD, scene.master)
    if flag:
        _completed_says(units["controller"], 300, flag, keep)
    try:
        return master.run(0.0, 1.0, scene.output.output_interval)
    except CoSimulationError as exc:
        return exc, exc.stats
    finally:
        master.close()


def test_completed_integrator_step_asking_for_event_mode_or_to_terminate(pair):
    """A unit's fmi2CompletedIntegratorStep asking for event mode: both loops run event mode
    (this product changes nothing there) and go on to the rows of a clean run; asking to
    terminate: both stop with the FMU named, at the same time, after the same steps."""
    clean = _run_completed_says(pair, False, 0)[0]
    scene = load_scene("flexible_pd_lowpass", ["master.interface=model-exchange"])
    for compiled in (False, True):
        rows, stats = _run_completed_says(pair, compiled, 2)
        _assert_rows_agree(clean, rows, scene.master)
    stopped = [_run_completed_says(pair, compiled, 3)[0] for compiled in (False, True)]
    for exc in stopped:
        assert str(exc).startswith("controller: completedIntegratorStep asked to terminate at t")
        assert exc.status == 3 and len(exc.result) > 1
    assert stopped[1].time == pytest.approx(stopped[0].time, rel=1e-3)
    assert stopped[1].stats.steps == stopped[0].stats.steps == 300
