"""FMI 3.0's independent variable ``time`` of the native FMUs (issue 37, 3).

The FMI 3.0 descriptions declare ``time`` (causality independent) at its value reference in the
table (71 in the plant, 21 in the controller); ``fmi3GetFloat64`` reads it as the instance's time
wherever a getter is allowed, and a set is refused (FMI 3.0 section 2.4.7.4: the independent
variable is not set with ``fmi3Set{VariableType}``). The reference value is the time fmpy's own
master is at when it reads it (``fmpy.simulate_fmu``'s step callback, CS and ME), and the start
time it passed; FMI 2.0, which declares no ``time``, still knows no such value reference.
"""
from __future__ import annotations

import shutil

import pytest

from conftest import fmi_status
from fmu_common.variables import independent_variable
from orchestration.export.model_description import TABLES

NAMES = ("FlexiblePendulum", "PDLowPass")
START = 0.25          # not 0: the value must come from the start time the master passed


@pytest.fixture(scope="module")
def dirs3(native3):
    from fmpy import extract
    out = {n: extract(p) for n, p in native3.items()}
    yield out
    for d in out.values():
        shutil.rmtree(d, ignore_errors=True)


def _time_vr(name: str) -> int:
    return independent_variable(TABLES[name][1])[0]


def _instance(unzipdir, fmi_type: str, logs: list):
    from fmpy import read_model_description
    from fmpy.fmi3 import FMU3Model, FMU3Slave
    md = read_model_description(unzipdir)
    iface = md.coSimulation if fmi_type == "CoSimulation" else md.modelExchange
    cls = FMU3Slave if fmi_type == "CoSimulation" else FMU3Model
    fmu = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=iface.modelIdentifier,
              instanceName="t")
    fmu.instantiate(loggingOn=False,
                    logMessage=lambda env, status, cat, msg: logs.append((status, msg.decode())))
    return md, fmu


def test_the_time_value_references_are_where_they_were():
    """The value reference of ``time`` does not move (the table's position; issue 37, 3)."""
    assert _time_vr("FlexiblePendulum") == 71 and _time_vr("PDLowPass") == 21


@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
@pytest.mark.parametrize("name", NAMES)
def test_time_reads_the_time_fmpy_is_at(dirs3, name, fmi_type):
    """After initialisation and after every step (CS) or integrator step (ME: in
    continuous-time mode, the time fmpy last set), ``time`` is the time fmpy's master is at."""
    import fmpy
    logs = []
    md, fmu = _instance(dirs3[name], fmi_type, logs)
    vr = _time_vr(name)
    assert [v.valueReference for v in md.modelVariables if v.name == "time"] == [vr]
    seen = []

    def step_finished(t, recorder):
        seen.append((t, fmu.getFloat64([vr])[0]))
        return True
    fmpy.simulate_fmu(dirs3[name], fmi_type=fmi_type, start_time=START, stop_time=START + 0.05,
                      output_interval=0.01, fmu_instance=fmu, step_finished=step_finished,
                      solver="Euler", step_size=1e-3, terminate=False)
    assert len(seen) >= 5
    for t, got in seen:
        assert got == t, (t, got)
    assert seen[-1][0] == pytest.approx(START + 0.05)
    assert not [m for s, m in logs if s > 0], logs
    # where fmpy left it (CS: step mode; ME: terminated by simulateME) and terminated
    now = fmu.getFloat64([vr])[0]
    assert now == seen[-1][1]
    if fmi_type == "CoSimulation":
        fmu.terminate()
        assert fmu.getFloat64([vr])[0] == now
    fmu.freeInstance()


@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
@pytest.mark.parametrize("name", NAMES)
def test_time_in_initialization_and_event_mode(dirs3, name, fmi_type):
    """Instantiated (no start time yet: 0), initialization mode (the startTime given), event
    mode (ME: the time set before it), mixed with other variables in one call."""
    logs = []
    md, fmu = _instance(dirs3[name], fmi_type, logs)
    vr = _time_vr(name)
    other = next(v for v in md.modelVariables if v.causality == "output")
    assert fmu.getFloat64([vr])[0] == 0.0
    fmu.enterInitializationMode(startTime=START)
    assert fmu.getFloat64([vr])[0] == START
    fmu.exitInitializationMode()
    both = fmu.getFloat64([other.valueReference, vr, other.valueReference])
    assert both[1] == START and both[0] == both[2] == fmu.getFloat64([other.valueReference])[0]
    if fmi_type == "ModelExchange":
        fmu.updateDiscreteStates()
        fmu.enterContinuousTimeMode()
        fmu.setTime(START + 0.125)
        assert fmu.getFloat64([vr])[0] == START + 0.125
        fmu.enterEventMode()
        assert fmu.getFloat64([vr])[0] == START + 0.125
    else:
        fmu.doStep(currentCommunicationPoint=START, communicationStepSize=0.125)
        assert fmu.getFloat64([vr])[0] == START + 0.125
    fmu.terminate()
    fmu.freeInstance()
    assert not [m for s, m in logs if s > 0], logs


@pytest.mark.parametrize("name", NAMES)
def test_time_cannot_be_set_nor_read_as_another_type(dirs3, name):
    """A set of ``time`` is refused with a message naming it, and changes nothing (neither the
    time nor the other values of the call); a getter of another type names its type."""
    logs = []
    md, fmu = _instance(dirs3[name], "CoSimulation", logs)
    vr = _time_vr(name)
    param = next(v for v in md.modelVariables if v.causality == "parameter"
                 and v.type == "Float64")
    before = fmu.getFloat64([param.valueReference])[0]
    fmu.enterInitializationMode(startTime=START)
    assert fmi_status(fmu.setFloat64, [param.valueReference, vr], [before + 1.0, 9.0]) == 3
    assert "time" in logs[-1][1] and "independent variable" in logs[-1][1]
    assert "cannot be set" in logs[-1][1]
    assert fmu.getFloat64([vr, param.valueReference]) == [START, before]
    assert fmi_status(fmu.getInt32, [vr]) == 3
    assert "time" in logs[-1][1] and "Float64, not Int32" in logs[-1][1]
    assert fmi_status(fmu.getFloat32, [vr]) == 3
    assert "Float64, not Float32" in logs[-1][1]
    fmu.exitInitializationMode()
    fmu.doStep(currentCommunicationPoint=START, communicationStepSize=1e-3)
    assert fmi_status(fmu.setFloat64, [vr], [0.0]) == 3
    assert fmu.getFloat64([vr]) == [START + 1e-3]
    fmu.terminate()
    fmu.freeInstance()


@pytest.mark.parametrize("name", NAMES)
def test_fmi2_declares_no_time_and_knows_no_such_reference(native, name):
    """FMI 2.0 declares no ``time`` (its description has no independent variable): the value
    reference stays unknown there."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(native[name])
    assert "time" not in [v.name for v in md.modelVariables]
    unzipdir = __import__("fmpy").extract(native[name])
    try:
        logs = []
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFunctions,
                               fmi2CallbackFreeMemoryTYPE, fmi2CallbackLoggerTYPE, calloc, free)
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(
            lambda env, inst, status, cat, msg: logs.append((status, msg.decode())))
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
        fmu.instantiate(callbacks=cb)
        fmu.setupExperiment(startTime=START)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        vr = _time_vr(name)
        assert fmi_status(fmu.getReal, [vr]) == 3
        assert f"no variable with value reference {vr}" in logs[-1][1]
        assert fmi_status(fmu.setReal, [vr], [1.0]) == 3
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipdir, ignore_errors=True)
