"""Runs in a child process of ``tests/common/test_fmu_robustness.py`` (a crash of the host must not
take pytest down): drives one FMU through fmpy's FMU2Slave with hypothesis-generated FMI call
sequences and checks, after every call, the invariants of issue 16:

* the process survives (the parent sees the exit status);
* every value a getter returns with status OK or warning is finite;
* a restored FMU state gives a bit-identical continuation (the outputs right after the restore
  equal those at the time the state was taken, and one step of 1 ms from it equals the first such
  step ever taken from it).

    python fmu_fuzz_worker.py UNZIPDIR EXAMPLES

Exit status 0 when every example held; 1 with the failing sequence on stderr.
"""
from __future__ import annotations

import json
import math
import sys

from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, calloc, free)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

UNZIPDIR, EXAMPLES = sys.argv[1], int(sys.argv[2])
MD = read_model_description(UNZIPDIR)
VARS = list(MD.modelVariables)
N = len(VARS)
OUTPUTS = [v.valueReference for v in VARS if v.causality == "output"]
MESSAGES = []


def _log(env, name, status, category, message):
    MESSAGES.append((status, category, message))


CALLBACKS = fmi2CallbackFunctions()
CALLBACKS.logger = fmi2CallbackLoggerTYPE(_log)
CALLBACKS.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
CALLBACKS.freeMemory = fmi2CallbackFreeMemoryTYPE(free)


def call(f, *args):
    """(status, result) of one FMI call; fmpy raises above warning."""
    try:
        return 0, f(*args)
    except FMICallException as exc:
        return exc.status, None


def new_instance():
    fmu = FMU2Slave(guid=MD.guid, unzipDirectory=UNZIPDIR,
                    modelIdentifier=MD.coSimulation.modelIdentifier, instanceName="fuzz")
    fmu.instantiate(callbacks=CALLBACKS, loggingOn=False)
    return fmu


#: value references inside and beyond the table (the plant's reach 72, damping: the pythonfmu
#: FMUs keep the table's positions, leaving out its Model-Exchange variables and time)
vr_ = st.integers(min_value=0, max_value=max(v.valueReference for v in VARS) + 3)
reals = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                  st.sampled_from([0.0, 0.1, -0.3, 1e-12, 1e300, -1e308]))
steps = st.sampled_from([1e-3, 1e-3, 1e-3, 5e-4, 0.0, -1e-3, math.nan, math.inf, 1e-12, 0.05])
corruptions = st.sampled_from(["none", "truncate", "flip", "nan", "n_modes", "model", "version",
                               "huge"])
action = st.one_of(
    st.tuples(st.just("setReal"), vr_, reals),
    st.tuples(st.just("setInteger"), vr_, st.integers(-3, 30)),
    st.tuples(st.just("setBoolean"), vr_, st.booleans()),
    st.tuples(st.just("setString"), vr_, st.sampled_from(["rk4", "linear", "bogus", ""])),
    st.tuples(st.just("getReal"), st.lists(vr_, min_size=1, max_size=4)),
    st.tuples(st.just("getInteger"), vr_),
    st.tuples(st.just("doStep"), steps),
    st.tuples(st.just("doStep"), steps),
    st.tuples(st.just("getState"),),
    st.tuples(st.just("setState"), st.integers(0, 3)),
    st.tuples(st.just("serialize"), st.integers(0, 3), corruptions),
    st.tuples(st.just("terminate"),),
    st.tuples(st.just("reset"),),
    st.tuples(st.just("init"),),
)


def corrupt(data: bytes, how: str) -> bytes:
    if how == "truncate":
        return data[: len(data) // 2]
    if how == "flip":
        i = len(data) // 3
        return data[:i] + bytes([data[i] ^ 0x5A]) + data[i + 1:]
    if how in ("nan", "n_modes", "model", "version", "huge"):
        try:
            s = json.loads(data)
        except ValueError:
            return data
        if how == "nan":
            key = "y" if s.get("y") else ("x" if "x" in s else "t")
            if isinstance(s.get(key), list) and s[key]:
                s[key][0] = math.nan
            else:
                s[key] = math.nan
        elif how == "n_modes" and "n_modes" in s.get("params", {}) and s.get("initialized"):
            # (before exitInitializationMode a parameter may hold any value the host set: the
            # FMU checks it there, so such a state with n_modes = -1 is a legal one)
            s["params"]["n_modes"] = -1
        elif how == "model":
            s["model"] = "PDLowPass" if s.get("model") != "PDLowPass" else "FlexiblePendulum"
        elif how == "version":
            s["version"] = 99
        elif how == "huge" and isinstance(s.get("params"), dict):
            k = next(iter(s["params"]))
            s["params"][k] = 1e308
        return json.dumps(s).encode()
    return data


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(st.lists(action, min_size=1, max_size=25))
def sequence(actions):
    fmu = new_instance()
    states = []               # (state, outputs at save, first 1 ms step from it, time at save)
    t = 0.0
    call(fmu.setupExperiment, None, 0.0)
    try:
        for a in actions:
            kind = a[0]
            if kind == "init":
                call(fmu.enterInitializationMode)
                call(fmu.exitInitializationMode)
            elif kind.startswith("set") and kind != "setState":
                f = getattr(fmu, kind)
                call(f, [a[1]], [a[2]])
            elif kind == "getReal":
                s, vals = call(fmu.getReal, a[1])
                if s <= 1:
                    assert all(math.isfinite(v) for v in vals), (a, vals)
            elif kind == "getInteger":
                call(fmu.getInteger, [a[1]])
            elif kind == "doStep":
                s, _ = call(fmu.doStep, t, a[1])
                if s <= 1:
                    t += a[1]
                    s2, vals = call(fmu.getReal, OUTPUTS)
                    assert s2 > 1 or all(math.isfinite(v) for v in vals), (a, vals)
            elif kind == "getState":
                s, state = call(fmu.getFMUstate)
                if s <= 1:
                    s2, outs = call(fmu.getReal, OUTPUTS)
                    states.append([state, outs if s2 <= 1 else None, None, t])
            elif kind == "setState" and states:
                entry = states[a[1] % len(states)]
                s, _ = call(fmu.setFMUstate, entry[0])
                if s <= 1:
                    t = entry[3]
                    s2, outs = call(fmu.getReal, OUTPUTS)
                    if entry[1] is not None and s2 <= 1:
                        assert outs == entry[1], ("restore not bit-identical", outs, entry[1])
                    s3, _ = call(fmu.doStep, t, 1e-3)
                    if s3 <= 1:
                        s4, after = call(fmu.getReal, OUTPUTS)
                        if entry[2] is None:
                            entry[2] = after
                        else:
                            assert after == entry[2], ("continuation differs", after, entry[2])
                        # back to the saved state, so the sequence goes on from there
                        call(fmu.setFMUstate, entry[0])
            elif kind == "serialize" and states:
                entry = states[a[1] % len(states)]
                s, data = call(fmu.serializeFMUstate, entry[0])
                if s <= 1:
                    bad = corrupt(bytes(data), a[2])
                    s2, state = call(fmu.deSerializeFMUstate, bad)
                    if s2 <= 1:
                        if a[2] in ("nan", "n_modes", "model", "version", "truncate") \
                                and bad != bytes(data):
                            raise AssertionError(f"a corrupt state ({a[2]}) was accepted")
                        if bad == bytes(data):     # the same state, so the same continuation
                            states.append([state, entry[1], entry[2], entry[3]])
                        else:
                            call(fmu.freeFMUstate, state)
            elif kind == "terminate":
                call(fmu.terminate)
            elif kind == "reset":
                call(fmu.reset)
                t = 0.0
                call(fmu.setupExperiment, None, 0.0)
    finally:
        for entry in states:
            call(fmu.freeFMUstate, entry[0])
        fmu.freeInstance()


if __name__ == "__main__":
    try:
        sequence()
    except AssertionError as exc:
        print(f"invariant broken: {exc}", file=sys.stderr)
        sys.exit(1)
    print(f"ok {EXAMPLES} examples")
