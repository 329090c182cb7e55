"""The FMI 3.0 clocks of the native sampled controller, PDLowPassSampled (issue 38; docs/fmus.md,
"The sampled controller: PDLowPassSampled"): two importers that honour clocks, a Python host on
fmpy's FMI 3.0 API and a plain C host written to the standard, run it in co-simulation with event
mode (doStep to each tick, fmi3EnterEventMode, fmi3SetClock, the clocked inputs, F_c,
fmi3UpdateDiscreteStates) and get the forces of the specification (controller_fmu/sampled.py) to
round-off, and the forces of the same FMU run without event mode bit for bit; the description is
valid (fmpy validate, with its XSD check) and the other FMUs declare no clock."""
from __future__ import annotations

import shutil
import subprocess
import sys
from ctypes import c_double
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave, fmi3IntervalQualifier, fmi3ValueReference

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.sampled import SampledController

HOST_C = Path(__file__).with_name("fmi3_clocked_host.c")
SENSORS = ("x_o", "phi_o", "omega_o")
CASES = [dict(filter_order=2, sample_period=0.005, delay=0.0, discretization="tustin"),
         dict(filter_order=2, sample_period=0.005, delay=0.002, discretization="zoh"),
         dict(filter_order=1, sample_period=0.004, delay=0.004, discretization="tustin"),
         dict(filter_order=0, sample_period=0.003, delay=0.001, discretization="zoh",
              force_limit=20.0)]
N = 60                                       # force ticks per run


@pytest.fixture(scope="module")
def sampled3(native3):
    return native3["PDLowPassSampled"]


def _open(path, start, event_mode):
    md = read_model_description(path)
    f = FMU3Slave(guid=md.guid, unzipDirectory=extract(path),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="c")
    f.instantiate(eventModeUsed=event_mode)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    f.enterInitializationMode(startTime=0.0)
    for k, v in start.items():
        if isinstance(v, str):
            f.setString([vr[k]], [v])
        elif isinstance(v, int):
            f.setInt32([vr[k]], [v])
        else:
            f.setFloat64([vr[k]], [float(v)])
    return f, vr


def _timing(f, clocks):
    """(intervals, shifts, qualifiers) of the clocks, as an importer reads them."""
    n = len(clocks)
    vrs = (fmi3ValueReference * n)(*clocks)
    iv, sh, q = (c_double * n)(), (c_double * n)(), (fmi3IntervalQualifier * n)()
    f.getIntervalDecimal(vrs, iv, q)
    f.getShiftDecimal(vrs, sh)
    return list(iv), list(sh), list(q)


def _events(interval, shift, n_force):
    """The importer's schedule from the clocks' timing: [(t, sample, force)] up to the n-th force
    tick, t_i = t_start + shift + i interval (section 2.2.9, periodic clocks)."""
    out, i_s, i_f = [], 0, 0
    tol = 1e-9 * min(interval)
    while i_f < n_force:
        ts, tf = shift[0] + i_s * interval[0], shift[1] + i_f * interval[1]
        te = min(ts, tf)
        s, fo = ts <= te + tol, tf <= te + tol
        out.append((te, s, fo))
        i_s += s
        i_f += fo
    return out


def _spec_forces(p, events, samples):
    """SampledController driven on the events' grid, the sensors set at each tick: the force at
    each force tick (no delay: the feedthrough at the tick)."""
    spec = SampledController(p)
    forces, k = [], 0
    for j, (te, s, fo) in enumerate(events):
        y = samples[k] if s else np.zeros(3)
        if fo:
            forces.append(spec.output(y) if s else spec.held)
        k += s
        if j + 1 < len(events):
            spec.step(te, events[j + 1][0] - te, y)
    return np.array(forces)


def _event(f, vr, clocks, ins, s, fo, samples, k, t, out):
    """One event of the clocked run, in event mode at ``t``: the clocks that tick (``s``: the
    sample's, ``fo``: the force's) activated, the ``k``-th sample set, ``F_c`` read into
    ``out``, the discrete states updated; ``(k after it, updateDiscreteStates' result)``."""
    f.setClock([c for c, on in zip(clocks, (s, fo)) if on], [True] * (s + fo))
    if s:
        f.setFloat64(ins, list(samples[k]))
        k += 1
    if fo:
        out.append((t, f.getFloat64([vr["F_c"]])[0]))
    return k, f.updateDiscreteStates()


def _clocked_run(path, start, samples):
    """Python host with event mode: [(t, F_c)] at the force ticks, the clocks' timing."""
    f, vr = _open(path, start, True)
    clocks = [vr["sample_clock"], vr["force_clock"]]
    interval, shift, q = _timing(f, clocks)
    f.exitInitializationMode()                    # event mode at the start time
    ins = [vr[n] for n in SENSORS]
    out, t, k, in_event = [], 0.0, 0, True
    for te, s, fo in _events(interval, shift, N):
        if te > t:
            if in_event:
                f.enterStepMode()
            f.doStep(t, te - t)
            t = te
            f.enterEventMode()
            in_event = True
        k, (need, terminate, *_) = _event(f, vr, clocks, ins, s, fo, samples, k, t, out)
        assert not need and not terminate
        assert f.getClock(clocks) == [False, False]       # deactivated by the update
    f.enterStepMode()
    f.terminate()
    f.freeInstance()
    return np.array(out), (interval, shift, q)


def _unclocked_run(path, start, samples, events):
    """The same FMU without event mode (flexpend's master, fmi-sim): the ticks taken at doStep."""
    f, vr = _open(path, start, False)
    f.exitInitializationMode()
    ins = [vr[n] for n in SENSORS]
    out, k = [], 0
    for j, (te, s, fo) in enumerate(events):
        if s:
            f.setFloat64(ins, list(samples[k]))
            k += 1
        if fo:
            out.append(f.getFloat64([vr["F_c"]])[0])
        if j + 1 < len(events):
            f.doStep(te, events[j + 1][0] - te)
    f.terminate()
    f.freeInstance()
    return np.array(out)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_fmpy_with_event_mode_gives_the_specifications_forces(sampled3, case):
    start = CASES[case]
    p = ControllerParams(**start)
    samples = np.random.default_rng(10 + case).normal(0.0, [0.05, 0.2, 2.0], (N + 2, 3))
    got, (interval, shift, q) = _clocked_run(sampled3, start, samples)
    # the clocks' timing: the parameters' (fixed clocks read in initialization mode)
    assert interval == [p.sample_period] * 2 and shift == [0.0, p.delay]
    assert q == [2, 2]                                    # fmi3IntervalChanged
    events = _events(interval, shift, N)
    want = _spec_forces(p, events, samples)
    assert len(got) == N and np.all(got[:, 0] == [te for te, _, fo in events if fo])
    assert np.max(np.abs(got[:, 1] - want) / np.maximum(1.0, np.abs(want))) <= 1e-12
    assert np.count_nonzero(got[:, 1]) > N // 2
    # the unclocked path of the same binary: the same arithmetic, bit for bit
    assert np.array_equal(_unclocked_run(sampled3, start, samples, events), got[:, 1])


def _rational_samples(n):
    k = np.arange(n)
    return np.stack([((37 * k) % 101 - 50) / 500.0, ((53 * k) % 89 - 44) / 300.0,
                     ((71 * k) % 97 - 48) / 40.0], axis=1)


@pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                    reason="needs Linux and gcc")
@pytest.mark.parametrize("case", [0, 1, 2])
def test_a_plain_c_host_with_clocks_gives_the_specifications_forces(sampled3, tmp_path, case):
    from orchestration.export.native_fmus import fmi_include_dir
    exe = tmp_path / "clocked_host"
    subprocess.run(["gcc", "-O1", "-std=c99", "-Wall", "-Wextra", "-Werror",
                    f"-I{fmi_include_dir()}", "-o", str(exe), str(HOST_C), "-ldl"],
                   check=True, capture_output=True, text=True)
    md = read_model_description(sampled3)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = Path(extract(sampled3))
    start = CASES[case]
    p = ControllerParams(**start)
    args = [str(d / "binaries" / "x86_64-linux" / "PDLowPassSampled.so"), md.guid, str(N),
            *(str(vr[n]) for n in (*SENSORS, "F_c", "sample_clock", "force_clock")),
            str(vr["filter_order"]), str(p.filter_order),
            str(vr["sample_period"]), repr(p.sample_period), str(vr["delay"]), repr(p.delay),
            str(vr["discretization"]), p.discretization]
    proc = subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.split("\n")
    (i0, s0), (i1, s1) = (map(float, lines[j].split()) for j in (0, 1))
    assert (i0, s0, i1, s1) == (p.sample_period, 0.0, p.sample_period, p.delay)
    rows = np.array([[float(x) for x in line.split()] for line in lines[2:] if line])
    events = _events([i0, i1], [s0, s1], N)
    want = _spec_forces(p, events, _rational_samples(N + 2))
    assert rows.shape == (N, 3) and np.all(rows[:, 0] == np.arange(N))
    assert np.max(np.abs(rows[:, 2] - want) / np.maximum(1.0, np.abs(want))) <= 1e-12
    assert np.count_nonzero(rows[:, 2]) > N // 2


def test_the_clocks_refuse_what_the_standard_forbids(sampled3):
    """A clock activated off its tick, a clocked input set while its clock is inactive, a step
    that skips a tick: refused with the state unchanged (the run then goes on as it should)."""
    start = dict(sample_period=0.01, delay=0.004)
    f, vr = _open(sampled3, start, True)
    clocks = [vr["sample_clock"], vr["force_clock"]]
    f.exitInitializationMode()
    with pytest.raises(FMICallException):
        f.setClock([clocks[1]], [True])                   # the force ticks at 0.004, not 0
    with pytest.raises(FMICallException):
        f.setFloat64([vr["phi_o"]], [0.3])                # sample_clock not active
    with pytest.raises(FMICallException):
        f.setClock(clocks, [True, True])                  # one call: neither is activated
    assert f.getClock(clocks) == [False, False]
    f.setClock([clocks[0]], [True])
    f.setFloat64([vr["phi_o"]], [0.3])
    f.updateDiscreteStates()
    f.enterStepMode()
    with pytest.raises(FMICallException):
        f.doStep(0.0, 0.005)                              # across the force's tick
    f.doStep(0.0, 0.004)
    with pytest.raises(FMICallException):
        f.doStep(0.004, 0.001)                            # its clock was not activated
    f.enterEventMode()
    f.setClock([clocks[1]], [True])
    F = f.getFloat64([vr["F_c"]])[0]
    f.updateDiscreteStates()
    want = SampledController(ControllerParams(**start))
    want.step(0.0, 0.004, [0.0, 0.3, 0.0])
    assert F == pytest.approx(want.held, rel=1e-12) and F != 0.0
    f.enterStepMode()
    f.doStep(0.004, 0.006)
    with pytest.raises(FMICallException):
        f.doStep(0.01, 0.001)                             # the tick at 0.01 not taken
    f.terminate()
    f.freeInstance()


def test_the_description_is_valid_and_only_the_sampled_fmu_has_clocks(native3):
    from fmpy.validation import validate_fmu
    assert validate_fmu(native3["PDLowPassSampled"]) == []
    import zipfile

    import fmpy
    from lxml import etree
    xsd = Path(fmpy.__file__).parent / "schema" / "fmi3" / "fmi3ModelDescription.xsd"
    with zipfile.ZipFile(native3["PDLowPassSampled"]) as zf:
        doc = etree.fromstring(zf.read("modelDescription.xml"))
    schema = etree.XMLSchema(file=str(xsd))
    assert schema.validate(doc), schema.error_log
    md = read_model_description(native3["PDLowPassSampled"])
    byname = {v.name: v for v in md.modelVariables}
    clocks = [v for v in md.modelVariables if v.type == "Clock"]
    assert [c.name for c in clocks] == ["sample_clock", "force_clock"]
    others = [v.valueReference for v in md.modelVariables if v.type != "Clock"]
    assert min(c.valueReference for c in clocks) > max(others)
    assert md.coSimulation.hasEventMode
    for n in SENSORS:
        assert [c.name for c in byname[n].clocks] == ["sample_clock"]
    assert [c.name for c in byname["F_c"].clocks] == ["force_clock"]
    for name, path in native3.items():
        if name == "PDLowPassSampled":
            continue
        m = read_model_description(path)
        assert not m.coSimulation.hasEventMode
        assert not any(v.type == "Clock" or v.clocks for v in m.modelVariables)


def test_the_other_fmus_still_refuse_clocks(native3):
    f, vr = _open(native3["PDLowPass"], {}, False)
    with pytest.raises(FMICallException):
        _timing(f, [1000])
    f.exitInitializationMode()
    with pytest.raises(FMICallException):
        f.setClock([vr["F_c"]], [True])
    f.terminate()
    f.freeInstance()


def test_an_fmu_state_restored_in_step_mode_replays_the_clocked_run(sampled3):
    """fmi3GetFMUState between two events, then fmi3SetFMUState: the clocked run from there
    gives the same forces again, bit for bit (the state holds the sample index, the filter and
    the pending force; whether the instance uses its clocks is the instance's, not the
    state's)."""
    start = CASES[1]
    samples = np.random.default_rng(3).normal(0.0, [0.05, 0.2, 2.0], (N + 2, 3))
    f, vr = _open(sampled3, start, True)
    clocks = [vr["sample_clock"], vr["force_clock"]]
    interval, shift, _ = _timing(f, clocks)
    f.exitInitializationMode()
    ins = [vr[n] for n in SENSORS]
    events = _events(interval, shift, 20)
    saved, runs = None, []
    for attempt in range(2):
        out, t, k, in_event = [], 0.0, 0, True
        if saved is not None:
            f.setFMUState(saved)
            t, in_event = saved_at                # k counts the samples skipped below
        for te, s, fo in events:
            if te < t or (te == t and not in_event):
                k += s
                continue
            if te > t:
                if in_event:
                    f.enterStepMode()
                if saved is None and k >= 8:
                    saved, saved_at = f.getFMUState(), (t, False)
                f.doStep(t, te - t)
                t = te
                f.enterEventMode()
                in_event = True
            k, _ = _event(f, vr, clocks, ins, s, fo, samples, k, t, out)
        f.enterStepMode()
        in_event = False
        runs.append(out)
    replay = runs[1]
    assert len(replay) > 5 and replay == runs[0][-len(replay):]
    f.freeFMUState(saved)
    f.terminate()
    f.freeInstance()
