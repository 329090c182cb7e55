"""The native sampled controller, PDLowPassSampled (issue 38), FMI 2.0 and 3.0 co-simulation,
against its specification (controller_fmu/sampled.py): the same forces, bit for bit or to
round-off, on a grid that lands on every tick and tick + delay, for random sensors; a step across
an instant refused with the state unchanged; each family refusing the other's sample periods."""
from __future__ import annotations

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.sampled import SampledController

SENSORS = ("x_o", "phi_o", "omega_o")


def _open(path, version, start):
    md = read_model_description(path)
    d = extract(path)
    if version == 2:
        from fmpy.fmi2 import FMU2Slave as cls
    else:
        from fmpy.fmi3 import FMU3Slave as cls
    f = cls(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="c")
    f.instantiate()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    if version == 2:
        f.setupExperiment(startTime=0.0)
    f.enterInitializationMode() if version == 2 else f.enterInitializationMode(startTime=0.0)
    for k, v in start.items():
        if isinstance(v, str):
            f.setString([vr[k]], [v])
        elif isinstance(v, int):
            (f.setInteger if version == 2 else f.setInt32)([vr[k]], [v])
        elif version == 2:
            f.setReal([vr[k]], [float(v)])
        else:
            f.setFloat64([vr[k]], [float(v)])
    f.exitInitializationMode()
    return f, vr


def _get(f, version, vrs):
    return list(f.getReal(vrs) if version == 2 else f.getFloat64(vrs))


def _set(f, version, vrs, values):
    (f.setReal if version == 2 else f.setFloat64)(vrs, list(values))


def _step(f, version, t, h):
    if version == 2:
        f.doStep(t, h)
    else:
        f.doStep(t, h)


@pytest.fixture(scope="module")
def sampled_fmus(native, native3):
    return {2: native["PDLowPassSampled"], 3: native3["PDLowPassSampled"]}


CASES = [dict(filter_order=2, sample_period=0.005, delay=0.0, discretization="tustin"),
         dict(filter_order=2, sample_period=0.005, delay=0.002, discretization="zoh"),
         dict(filter_order=1, sample_period=0.004, delay=0.004, discretization="tustin"),
         dict(filter_order=0, sample_period=0.003, delay=0.001, discretization="zoh",
              force_limit=20.0)]


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_fmu_gives_the_specifications_forces(sampled_fmus, version, case):
    start = CASES[case]
    p = ControllerParams(**start)
    spec = SampledController(p)
    f, vr = _open(sampled_fmus[version], version, start)
    ins = [vr[n] for n in SENSORS]
    rng = np.random.default_rng(case)
    # the grid: every tick and tick + delay, and a point between
    T, tau = p.sample_period, p.delay
    points = sorted({round(k * T + s, 12) for k in range(60) for s in (0.0, tau, 0.37 * T)
                     if k * T + s <= 60 * T})
    t, worst = 0.0, 0.0
    for t1 in points[1:]:
        y = rng.normal(0.0, [0.1, 0.2, 2.0])
        _set(f, version, ins, y)
        want = spec.output(y)
        got = _get(f, version, [vr["F_c"]])[0]
        worst = max(worst, abs(got - want) / max(1.0, abs(want)))
        _step(f, version, t, t1 - t)
        spec.step(t, t1 - t, y)
        t = t1
    assert worst <= 1e-12
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("version", [2, 3])
def test_a_step_across_an_instant_is_refused_and_changes_nothing(sampled_fmus, version):
    start = dict(sample_period=0.01, delay=0.004)
    f, vr = _open(sampled_fmus[version], version, start)
    _set(f, version, [vr["phi_o"]], [0.3])
    with pytest.raises(FMICallException):
        _step(f, version, 0.0, 0.005)                   # across the force's instant 0.004
    _step(f, version, 0.0, 0.004)                       # lands on it: taken
    assert _get(f, version, [vr["F_c"]])[0] != 0.0
    f.terminate()
    f.freeInstance()


@pytest.mark.parametrize("version", [2, 3])
def test_each_controller_fmu_refuses_the_others_sample_periods(native, native3, version):
    fmus = native if version == 2 else native3
    for name, period in (("PDLowPass", 0.01), ("PDLowPassSampled", 0.0)):
        with pytest.raises(FMICallException):
            _open(fmus[name], version, {"sample_period": period})
