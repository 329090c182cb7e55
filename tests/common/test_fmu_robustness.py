"""Issue 16: no call an importer can make crashes the host or gets fmi2Fatal; each defect found by
the attack on the pythonfmu FMUs has a test here that failed before the loader and the adapter's
checks (the numbers in the names are the issue's items).

What each test checks against: the FMI 2.0 status the standard prescribes for the call (fmi2Error
for an illegal call or argument, fmi2Discard for a refused step), an untouched twin instance
(a refused call must leave the instance exactly as it was: the twin's outputs, bit for bit), and
the process's exit status (a crash is a negative status of the child process).
"""
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

H = 1e-3
HERE = Path(__file__).parents[1]


def status_of(fun, *args):
    try:
        fun(*args)
        return 0
    except FMICallException as exc:
        return exc.status


def run_child(code: str, timeout=600) -> subprocess.CompletedProcess:
    """``code`` in a child Python (the test's interpreter), so that a crash cannot take pytest
    down: the child's exit status says what happened."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, cwd=str(HERE))


def twin_outputs(open_fmu, name, steps, **start):
    twin = open_fmu(name, **start)
    for k in range(steps):
        assert twin.step(k * H, H) == 0
    return twin.outputs()


# ------------------------------------------------------------------ 3: no fmi2Fatal, no crash
FATAL_LOOP = r"""
import sys
sys.path.insert(0, ".")
from conftest import FmuInstance
from fmpy.fmi1 import FMICallException
inst = FmuInstance({dir!r}, {start!r})
statuses = set()
for vr in [999] * 1000:
    try:
        inst.fmu.getReal([vr])
        statuses.add(0)
    except FMICallException as exc:
        statuses.add(exc.status)
assert statuses == {{3}}, statuses
bad = [(inst.fmu.setReal, [inst.vr("{int_var}")[0]], [2.0]),        # wrong type
       (inst.fmu.setInteger, [inst.vr("{real_var}")[0]], [1]),       # wrong type
       (inst.fmu.setReal, [inst.vr("{output}")[0]], [1.0]),          # an output
       (inst.fmu.getReal, [inst.vr("{int_var}")[0]], None)]          # wrong type
for f, vr, v in bad * 50:
    try:
        f(vr, v) if v is not None else f(vr)
        raise SystemExit(f"{{f.__name__}} succeeded")
    except FMICallException as exc:
        assert exc.status == 3, exc.status
inst.fmu.doStep(0.0, 1e-3)                                            # still alive
out = inst.get("{output}")[0]
inst.close()
print("alive", repr(out))
"""


@pytest.mark.parametrize("name, output, start, int_var, real_var", [
    ("FlexiblePendulum", "phi_o", {"phi0": 0.1}, "n_modes", "phi0"),
    ("PDLowPass", "F_c", {"phi_o": 0.1}, "filter_order", "kp"),
])
def test_3_a_thousand_invalid_value_references_are_errors_and_the_process_lives(
        fmu_dirs, open_fmu, name, output, start, int_var, real_var):
    proc = run_child(FATAL_LOOP.format(dir=str(fmu_dirs[name]), output=output, start=start,
                                       int_var=int_var, real_var=real_var))
    assert proc.returncode == 0, proc.stderr[-3000:]
    twin = open_fmu(name, **start)
    assert twin.step(0.0, H) == 0
    assert proc.stdout.split()[-1] == repr(twin.get(output)[0])


def test_3_the_log_names_the_bad_reference_and_has_a_category(open_fmu):
    inst = open_fmu("FlexiblePendulum")
    assert status_of(inst.fmu.getReal, [999]) == 3
    status, category, message = inst.logs[-1]
    assert status == 3 and category == "logStatusError"
    assert "has no variable with value reference 999" in message


# ------------------------------------------------------------------ 4: states
def _serialized(inst):
    state = inst.fmu.getFMUstate()
    data = bytes(inst.fmu.serializeFMUstate(state))
    inst.fmu.freeFMUstate(state)
    return json.loads(data)


@pytest.mark.parametrize("change, words", [
    (lambda s: s["params"].update(n_modes=-1), "n_modes = -1 is out of range"),
    (lambda s: s["y"].__setitem__(0, math.nan), "y[0] = nan is not a finite number"),
    (lambda s: s["y"].pop(), "y must be a list of 12 numbers"),
    (lambda s: s.update(version=2), "version 2; this FMU reads version 1"),
    (lambda s: s.update(model="PDLowPass"), "it is a state of the model 'PDLowPass'"),
    (lambda s: s["params"].update(L=5e-324), "L = 5e-324 is out of range"),
    (lambda s: s["stepper"]["y"].__setitem__(1, math.inf), "stepper.y[1] = inf is not finite"),
])
def test_4_a_crafted_plant_state_is_refused_and_the_instance_is_unchanged(open_fmu, change,
                                                                           words):
    inst = open_fmu("FlexiblePendulum", phi0=0.2)
    assert inst.step(0.0, H) == 0
    state = _serialized(inst)
    change(state)
    blob = json.dumps(state).encode()
    assert status_of(inst.fmu.deSerializeFMUstate, blob) == 3
    assert words in inst.messages(3)
    assert inst.step(H, H) == 0
    assert inst.outputs() == twin_outputs(open_fmu, "FlexiblePendulum", 2, phi0=0.2)


def test_4_a_plant_state_is_refused_by_the_controller(open_fmu):
    plant = open_fmu("FlexiblePendulum", phi0=0.2)
    ctrl = open_fmu("PDLowPass", phi_o=0.1)
    assert ctrl.step(0.0, H) == 0
    pstate = plant.fmu.getFMUstate()
    assert status_of(ctrl.fmu.setFMUstate, pstate) == 3          # a pointer of another FMU
    assert "not an FMU state of this FMU" in ctrl.messages(3)
    blob = bytes(plant.fmu.serializeFMUstate(pstate))
    assert status_of(ctrl.fmu.deSerializeFMUstate, blob) == 3     # a blob of another model
    assert "not a valid PDLowPass state" in ctrl.messages(3)
    plant.fmu.freeFMUstate(pstate)
    assert ctrl.step(H, H) == 0
    assert ctrl.get("F_c") == twin_outputs(open_fmu, "PDLowPass", 2, phi_o=0.1)


def test_4_a_failed_restore_leaves_the_instance_exactly_as_it_was(open_fmu):
    """A state that passes the header but fails deeper (a stepper of another method) changes
    nothing: not the parameters, not the stepper, not the time."""
    inst = open_fmu("FlexiblePendulum", phi0=0.2)
    other = open_fmu("FlexiblePendulum", phi0=0.2, integrator="dopri5")
    assert other.step(0.0, H) == 0
    bad = _serialized(other)
    bad["params"] = _serialized(inst)["params"]       # rk4 parameters, a dopri5 stepper
    assert status_of(inst.fmu.deSerializeFMUstate, json.dumps(bad).encode()) == 3
    assert "stepper: ValueError: snapshot of method 'dopri5'" in inst.messages(3)
    assert inst.step(0.0, H) == 0
    assert inst.outputs() == twin_outputs(open_fmu, "FlexiblePendulum", 1, phi0=0.2)


def test_4_a_controller_state_with_nan_is_refused(open_fmu):
    ctrl = open_fmu("PDLowPass", phi_o=0.1)
    assert ctrl.step(0.0, H) == 0
    state = _serialized(ctrl)
    state["x"][1] = math.nan
    assert status_of(ctrl.fmu.deSerializeFMUstate, json.dumps(state).encode()) == 3
    assert "x[1] = nan is not a finite number" in ctrl.messages(3)


def test_4_a_freed_or_foreign_state_pointer_is_an_error(open_fmu):
    inst = open_fmu("PDLowPass")
    state = inst.fmu.getFMUstate()
    inst.fmu.freeFMUstate(state)
    assert status_of(inst.fmu.setFMUstate, state) == 3


# ------------------------------------------------------------------ 5: finite outputs
@pytest.mark.parametrize("start", [{"phi_dot0": 1e160}, {"x_dot0": 1e308}, {"phi0": 1e200}])
def test_5_extreme_initial_rates_are_a_bad_parameter_not_infinite_outputs(open_fmu, start):
    inst = open_fmu("FlexiblePendulum", **start)
    assert inst.init_status == 3
    assert "the initial state" in inst.messages(3) and "too large" in inst.messages(3)
    assert all(math.isfinite(v) for v in inst.outputs())
    assert inst.step(0.0, H) == 2


def test_8_a_subnormal_parameter_is_named(open_fmu):
    inst = open_fmu("FlexiblePendulum", L=5e-324)
    assert inst.init_status == 3
    assert "L = 5e-324 is out of range" in inst.messages(3)


# ------------------------------------------------------------------ 6: steps
@pytest.mark.parametrize("name, start", [("FlexiblePendulum", {"phi0": 0.2}),
                                         ("PDLowPass", {"phi_o": 0.1})])
@pytest.mark.parametrize("h", [-1e-3, 0.0, math.nan, math.inf])
def test_6_a_bad_step_size_is_refused_and_the_instance_goes_on(open_fmu, name, start, h):
    inst = open_fmu(name, **start)
    assert inst.step(0.0, H) == 0
    assert inst.step(H, h) == 3                       # fmi2Error, nothing changed
    assert "step size must be positive and finite" in inst.messages(3)
    assert inst.step(H, H) == 0                       # the same instance steps on
    assert inst.outputs() == twin_outputs(open_fmu, name, 2, **start)


def test_6_a_tiny_substep_hits_the_cap_fast_and_is_reported(open_fmu):
    inst = open_fmu("FlexiblePendulum", phi0=0.2, step=1e-12)
    t0 = time.perf_counter()
    assert inst.step(0.0, H) == 2                     # fmi2Discard, instead of 180 s of work
    assert time.perf_counter() - t0 < 5.0
    assert "more than the cap of 100000 per doStep" in inst.messages(2)
    assert inst.step(0.0, 1e-8) == 0                  # a step within the cap is taken


def test_6_an_adaptive_method_stops_at_the_cap(open_fmu):
    inst = open_fmu("FlexiblePendulum", phi0=0.2, integrator="dopri5", rtol=1e-13, atol=1e-300,
                    step=1e-9)
    t0 = time.perf_counter()
    status = inst.step(0.0, 0.5)
    assert time.perf_counter() - t0 < 60.0
    if status != 0:                                   # the cap was reached: said so
        assert status == 2 and "the substep cap of 100000" in inst.messages(3)


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_6_do_step_after_terminate_is_refused(open_fmu, name):
    inst = open_fmu(name)
    assert inst.step(0.0, H) == 0
    inst.fmu.terminate()
    assert inst.step(H, H) == 3
    assert "fmi2DoStep is not allowed in state Terminated" in inst.messages(3)
    inst.close = inst.fmu.freeInstance                # terminated already


# ------------------------------------------------------------------ 8: what runs is what ships
def _doubled_controller(fmus, tmp_path) -> Path:
    """A copy of the controller FMU whose code is changed: its F_c is doubled."""
    src, dst = Path(fmus["PDLowPass"]), tmp_path / "PDLowPass.fmu"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "resources/controller_fmu/fmu.py":
                data += (b"\n_flexpend_test_force = PDLowPass._force\n"
                         b"PDLowPass._force = lambda self: 2.0 * _flexpend_test_force(self)\n")
            zout.writestr(item, data)
    return dst


def test_8_a_modified_copy_runs_its_own_code_beside_the_original(fmus, fmu_dirs, tmp_path):
    """Both copies in this process, which also imported the checkout's packages (conftest):
    each FMU runs the code it ships."""
    from fmpy import extract

    from conftest import FmuInstance

    a = FmuInstance(fmu_dirs["PDLowPass"], {"phi_o": 0.1})
    b = FmuInstance(extract(str(_doubled_controller(fmus, tmp_path)), str(tmp_path / "b")),
                    {"phi_o": 0.1})
    try:
        assert a.step(0.0, H) == 0 and b.step(0.0, H) == 0
        fa, fb = a.get("F_c")[0], b.get("F_c")[0]
        assert fa != 0.0 and fb == 2.0 * fa
    finally:
        a.close()
        b.close()
    import controller_fmu.fmu
    assert controller_fmu.fmu.__file__.startswith(str(HERE.parent))   # the host's own, untouched
    assert not hasattr(controller_fmu.fmu, "_flexpend_test_force")


def test_8_the_master_runs_the_code_inside_the_fmu(fmus, tmp_path):
    """``flexpend run``'s master (orchestration.cosim.master, in this process where the checkout's
    packages are imported) runs the controller FMU it is given, not the checkout's code."""
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene

    # held inputs, so that the first step's inputs are the same in both runs
    scene = load_scene("flexible_pd_lowpass", [
        "stop_time=0.02", "output_interval=0.001", "master.step=0.001", "master.extrapolation=0",
        "master.input_derivatives=false"])
    paths = {"plant": fmus["FlexiblePendulum"]}
    normal = run_scene(scene, {**paths, "controller": fmus["PDLowPass"]}, progress=False).result
    doubled = run_scene(scene, {**paths, "controller": str(_doubled_controller(fmus, tmp_path))},
                        progress=False).result
    assert normal["F_c"][1] != 0.0
    assert doubled["F_c"][1] == 2.0 * normal["F_c"][1]


def test_8_an_fmu_leaves_the_hosts_sys_path_alone(open_fmu, fmu_dirs):
    before = list(sys.path)
    for _ in range(5):
        open_fmu("PDLowPass")
    assert sys.path == before
    assert not any(str(d) in p for p in sys.path for d in fmu_dirs.values())


# ------------------------------------------------------------------ the fuzz
@pytest.mark.slow
@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_fuzzed_fmi_call_sequences_keep_the_invariants(fmu_dirs, name):
    """A few hundred hypothesis-generated call sequences per FMU (invalid value references,
    wrong types, bad steps, corrupted states, terminate and reset anywhere), in a child process:
    it survives, outputs are finite or the status is not OK, restores continue bit-identically."""
    examples = os.environ.get("FLEXPEND_FUZZ_EXAMPLES", "300")
    proc = subprocess.run([sys.executable, str(HERE / "fmu_fuzz_worker.py"), fmu_dirs[name],
                           examples], capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-4000:])
    assert f"ok {examples} examples" in proc.stdout


# ------------------------------------------------------------------ issue 23: one guard
BAD_CALLS = [
    ("unknown reference", lambda i: i.fmu.getReal([999])),
    ("wrong type", lambda i: i.fmu.getInteger(i.vr("kp"))),
    ("an output set", lambda i: i.fmu.setReal(i.vr("F_c"), [1.0])),
    ("a fixed parameter set", lambda i: i.fmu.setReal(i.vr("kp"), [1.0])),
    ("NULL arrays", lambda i: i.fmu.fmi2GetReal(i.fmu.component, None, 2, None)),
    ("out of order", lambda i: i.fmu.exitInitializationMode()),
]


@pytest.mark.parametrize("what, call", BAD_CALLS, ids=[b[0] for b in BAD_CALLS])
def test_23_the_loader_and_the_native_fmus_answer_with_the_same_guard(open_fmu, native_dirs,
                                                                       what, call):
    """Issue 23, 5: the pythonfmu loader checks calls with the native FMUs' guard and the same
    generated table: the same bad call gets the same status and the same message from both."""
    from conftest import FmuInstance
    py = open_fmu("PDLowPass")
    nat = FmuInstance(native_dirs["PDLowPass"], {}, "PDLowPass")
    try:
        for inst in (py, nat):
            assert status_of(call, inst) == 3
        assert py.logs[-1][1:] == nat.logs[-1][1:], (py.logs[-1], nat.logs[-1])
        assert py.step(0.0, H) == 0 and nat.step(0.0, H) == 0          # both go on
    finally:
        nat.close()


# ------------------------------------------------------------------ the exit of a Python host
LIFECYCLE = r"""
import sys
sys.path.insert(0, ".")
from conftest import FmuInstance
inst = FmuInstance({dir!r}, {{}})
assert inst.step(0.0, 1e-3) == 0
inst.close()
print("done")
"""


def _our_errors(log: str, name: str) -> list:
    """valgrind's error blocks whose stack passes through pythonfmu's library or this FMU's
    loader (the dynamic loader's own false reports, in ``strncmp``, are left out)."""
    blocks = [b for b in re.split(r"\n==\d+== *\n", log)
              if "Invalid" in b or "uninitialised" in b or "free'd" in b]
    mark = (f"{name}_pythonfmu.so", f"linux64/{name}.so", "finalizePythonInterpreter")
    return [b for b in blocks if any(m in b for m in mark)]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("valgrind") is None, reason="needs valgrind")
@pytest.mark.parametrize("name", ["PDLowPass", "FlexiblePendulum"])
def test_a_python_host_exits_without_touching_freed_memory(fmu_dirs, name):
    """pythonfmu 0.7.0 releases its interpreter thread's owner twice at exit (its static's C++
    destructor, then its ELF destructor on the destroyed static): a write into freed memory that
    glibc sometimes reports as "corrupted double-linked list" when the host exits. The loader
    releases it first, at exit; valgrind then finds no access to freed memory in pythonfmu's
    library or the loader (it found one in finalizePythonInterpreter before)."""
    env = {**os.environ, "PYTHONMALLOC": "malloc", "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run(["valgrind", "--error-limit=no", sys.executable, "-c",
                           LIFECYCLE.format(dir=str(fmu_dirs[name]))], capture_output=True,
                          text=True, timeout=900, cwd=str(HERE), env=env)
    assert proc.returncode == 0 and proc.stdout.strip() == "done", proc.stderr[-3000:]
    assert _our_errors(proc.stderr, name) == [], _our_errors(proc.stderr, name)[:2]
