"""Model-Exchange FMU states (issue 24, review): a restore takes back every state legal Model
Exchange calls can reach, even one past the divergence bounds, and refuses one that only a
crafted file can hold (a communication step's input in a Model-Exchange instance)."""
from __future__ import annotations

import ctypes
import struct

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Model

NX = 20


@pytest.fixture
def plant(native):
    path = native["FlexiblePendulum"]
    md = read_model_description(path)
    d = extract(path)
    f = FMU2Model(guid=md.guid, unzipDirectory=d, modelIdentifier=md.modelExchange.modelIdentifier,
                  instanceName="plant")
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.newDiscreteStates()
    f.enterContinuousTimeMode()
    yield f, md
    f.terminate()
    f.freeInstance()


def _states(f):
    x = (ctypes.c_double * NX)()
    f.getContinuousStates(x, NX)
    return list(x)


def _set(f, xs):
    f.setContinuousStates((ctypes.c_double * NX)(*xs), NX)


def _derivatives(f):
    dx = (ctypes.c_double * NX)()
    f.getDerivatives(dx, NX)
    return np.array(dx)


def test_a_state_past_phi_limit_that_the_importer_set_restores(plant):
    """An integrator's trial point beyond phi_limit (pi/2) is a legal Model-Exchange state: its
    FMU state saves, serialises and restores, and the derivatives after the restore are those
    before it, bit for bit."""
    f, _ = plant
    xs = _states(f)
    xs[1], xs[11] = 1.6, 3.0
    _set(f, xs)
    want = _derivatives(f)
    state = f.getFMUstate()
    copy = f.deSerializeFMUstate(f.serializeFMUstate(state))
    _set(f, [0.0] * NX)
    f.setFMUstate(copy)
    assert _states(f)[1] == 1.6
    assert np.array_equal(_derivatives(f), want)
    f.freeFMUstate(state)
    f.freeFMUstate(copy)


def _fnv(data: bytes) -> int:
    h = 14695981039346656037
    for c in data:
        h = ((h ^ c) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def test_a_crafted_model_exchange_state_with_a_steps_input_is_refused(plant):
    """The plant's saved state ends with the flag 'a doStep was taken' (then the checksum, an
    FNV-1a anyone can recompute). Set in a Model-Exchange state, it would make the directional
    derivatives read a communication step's stale input: the restore refuses it and the
    instance is unchanged."""
    f, md = plant
    xs = _states(f)
    xs[1], xs[11] = 0.5, 2.0
    _set(f, xs)
    der = [u.variable.valueReference for u in md.derivatives]
    sts = [u.variable.derivative.valueReference for u in md.derivatives]
    before = f.getDirectionalDerivative([der[11]], [sts[1]], [1.0])
    state = f.getFMUstate()
    data = bytearray(f.serializeFMUstate(state))
    f.freeFMUstate(state)
    n = len(data)
    assert struct.unpack("<i", data[n - 12:n - 8])[0] == 0        # stepped = 0 as saved
    data[n - 12:n - 8] = struct.pack("<i", 1)
    data[n - 8:] = struct.pack("<Q", _fnv(bytes(data[:n - 8])))
    with pytest.raises(FMICallException):
        crafted = f.deSerializeFMUstate(bytes(data))
        f.setFMUstate(crafted)
    assert f.getDirectionalDerivative([der[11]], [sts[1]], [1.0]) == before
