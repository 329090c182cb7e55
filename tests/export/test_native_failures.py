"""The native FMUs' failure paths and states: every non-OK status with its message, a bad
parameter, input or step refused with the state unchanged, divergence and blow-up discarded, the
FMU state bit-identical through get, set and serialisation, and issue 23's attack on the core
(crafted states with their checksum recomputed, steps beyond the cap or below the time
resolution, non-finite invariants, null arrays).

Independent values: the values of the states themselves (a restored state must continue
bit-identically) and the limits the modelDescription states.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest


# ---------------------------------------------------------------------- failure paths
def test_bad_parameter_is_an_error_at_exit_initialization(open_native):
    from fmpy.fmi1 import FMICallException
    for start, word in (({"n_modes": 9}, "n_modes"), ({"EI": -1.0}, "EI"),
                        ({"integrator": "radau"}, "supported: dopri5, euler, exponential, rk4"),
                        ({"n_elements": 101}, "n_elements"),
                        ({"integrator": "exponential"}, "fidelity = 'linear'"),
                        ({"damping": "viscous"}, "bad parameter: damping = 'viscous' is not "
                                                 "allowed; allowed: modal, kelvin-voigt"),
                        ({"damping": "Kelvin-Voigt"}, "damping = 'Kelvin-Voigt' is not")):
        inst = open_native("FlexiblePendulum", initialize=False, **start)
        inst.fmu.enterInitializationMode()
        with pytest.raises(FMICallException) as exc:
            inst.fmu.exitInitializationMode()
        assert exc.value.status == 3
        assert word in inst.messages(3)
        assert inst.step(0.0, 1e-3) == 3              # the instance is in its error state
    ctrl = open_native("PDLowPass", initialize=False, filter_damping=0.0)
    ctrl.fmu.enterInitializationMode()
    with pytest.raises(FMICallException):
        ctrl.fmu.exitInitializationMode()
    assert "filter_damping = 0 is out of range" in ctrl.messages(3)


def test_nan_input_is_discarded_with_the_state_unchanged(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.2)
    inst.set(F_c=1.0)
    assert inst.step(0.0, 1e-3) == 0
    before = inst.outputs()
    inst.set(F_c=math.nan)
    assert inst.step(1e-3, 1e-3) == 2
    assert "non-finite input F_c" in inst.messages(2)
    assert inst.outputs() == before
    inst.set(F_c=1.0)
    assert inst.step(1e-3, 1e-3) == 0                   # a retry may follow
    ctrl = open_native("PDLowPass")
    ctrl.set(phi_o=math.inf)
    assert ctrl.step(0.0, 1e-3) == 2 and "phi_o = inf" in ctrl.messages(2)


def test_bad_step_size_is_discarded(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.2)
    for h in (-1e-3, 0.0, math.nan, math.inf):
        assert inst.step(0.0, h) == 2
    assert "must be positive and finite" in inst.messages(2)
    assert inst.step(0.0, 1e-3) == 0


def test_divergence_is_discarded_and_refuses_until_a_state_is_restored(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.3, phi_limit=0.31)
    state = inst.fmu.getFMUstate()
    codes = [inst.step(k * 1e-3, 1e-3) for k in range(200)]
    k = codes.index(2)
    assert all(c == 0 for c in codes[:k])
    assert "|phi| =" in inst.messages(2) and "phi_limit = 0.31" in inst.messages(2)
    assert all(math.isfinite(v) for v in inst.outputs())
    assert abs(inst.get("phi")[0]) <= 0.31                # the last accepted state
    assert inst.step(k * 1e-3, 1e-3) == 2                 # refused
    assert "restore a saved FMU state" in inst.messages(2)
    inst.fmu.setFMUstate(state)
    assert inst.step(0.0, 1e-3) == 0


def test_blow_up_is_discarded(open_native):
    """Explicit Euler on the stiff modes at a large substep blows up: Discard, never NaN."""
    inst = open_native("FlexiblePendulum", integrator="euler", step=2e-3, n_modes=8,
                       phi_limit=math.inf, energy_limit=math.inf, phi0=0.1)
    codes = [inst.step(k * 2e-3, 2e-3) for k in range(2000)]
    assert 2 in codes
    assert "non-finite state" in inst.messages(2) or "exceeds 1e100" in inst.messages(2)
    assert all(math.isfinite(v) for v in inst.outputs())


def test_invalid_value_reference_and_calls_out_of_order_are_errors(open_native):
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", initialize=False)
    assert inst.step(0.0, 1e-3) == 3                      # doStep before initialisation
    assert "fmi2DoStep is not allowed in state Instantiated" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.getReal([1])                             # dF_c: not in the native FMU
    assert "no variable with value reference 1" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.getReal([999])
    with pytest.raises(FMICallException):
        inst.fmu.getInteger([inst.vr("phi0")[0]])          # a Real read as Integer
    inst.initialize()
    with pytest.raises(FMICallException):
        inst.set(n_modes=2)                               # a fixed parameter after init
    assert "parameter n_modes is fixed" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.setReal(inst.vr("phi_o"), [1.0])         # an output
    with pytest.raises(FMICallException):
        inst.fmu.exitInitializationMode()                 # twice
    assert inst.step(0.5, 1e-3) == 3                      # not the FMU's time
    assert "but the FMU is at t = 0" in inst.messages(3)


def test_substep_cap_discards_the_step_and_says_so(open_native):
    from orchestration.export.native_fmus import MAX_SUBSTEPS
    inst = open_native("FlexiblePendulum", phi0=0.2, step=1e-9)
    before = inst.outputs()
    assert inst.step(0.0, 2.0) == 2                       # 2e9 substeps
    msg = inst.messages(2)
    assert f"more than the cap of {MAX_SUBSTEPS} per doStep" in msg and "2000000000" in msg
    assert inst.outputs() == before
    assert inst.step(0.0, 1e-4) == 0                      # 1e5 substeps: within the cap


def test_corrupt_serialised_state_is_an_error(open_native):
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", phi0=0.2)
    data = bytearray(inst.fmu.serializeFMUstate(inst.fmu.getFMUstate()))
    for where in (0, 5, 100, len(data) // 2, len(data) - 1):
        bad = bytearray(data)
        bad[where] ^= 0x40
        with pytest.raises(FMICallException):
            inst.fmu.deSerializeFMUstate(bytes(bad))
    with pytest.raises(FMICallException):
        inst.fmu.deSerializeFMUstate(bytes(data[:-8]))
    log = inst.messages(3)
    assert "corrupt" in log and "format version" in log and "bytes" in log
    other = open_native("PDLowPass")
    with pytest.raises(FMICallException):
        other.fmu.deSerializeFMUstate(bytes(data))
    assert "belongs to another model" in other.messages(3)


def test_every_non_ok_status_comes_with_a_message(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.3, phi_limit=0.31)
    inst.set(F_c=math.nan)
    inst.step(0.0, 1e-3)
    inst.set(F_c=0.0)
    for k in range(200):
        if inst.step(k * 1e-3, 1e-3):
            break
    statuses = [s for s, _, _ in inst.logs]
    assert 2 in statuses and all(m for s, _, m in inst.logs if s > 0)
    assert all(cat for _, cat, _ in inst.logs)            # never a NULL category


# ---------------------------------------------------------------------- FMU state
@pytest.mark.parametrize("integrator", ["rk4", "dopri5", "symplectic_euler"])
def test_state_get_set_and_serialisation_are_bit_identical(open_native, integrator):
    def run(inst, k0, n):
        out = []
        for k in range(k0, k0 + n):
            inst.set(F_c=10 * math.sin(0.05 * k))
            inst.fmu.setRealInputDerivatives(inst.vr("F_c"), [1], [0.5 * math.cos(0.05 * k)])
            assert inst.step(k * 1e-3, 1e-3) == 0
            out.append(inst.outputs())
        return out

    a = open_native("FlexiblePendulum", phi0=0.4, integrator=integrator)
    run(a, 0, 50)
    state = a.fmu.getFMUstate()
    data = a.fmu.serializeFMUstate(state)
    first = run(a, 50, 50)
    a.fmu.setFMUstate(state)
    assert run(a, 50, 50) == first
    b = open_native("FlexiblePendulum")                    # another instance, other parameters
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    assert run(b, 50, 50) == first
    a.fmu.freeFMUstate(state)


#: The input each native FMU is driven by in the state tests below.
_INPUT = {"FlexiblePendulum": "F_c", "PDLowPass": "phi_o"}


def _driven(inst, name, k0: int, n: int) -> list:
    """Steps ``k0 .. k0 + n - 1`` of 1 ms of ``inst`` (the FMU ``name``) under a sine input:
    the outputs after each."""
    out = []
    for k in range(k0, k0 + n):
        inst.set(**{_INPUT[name]: 0.3 * math.sin(0.05 * k)})
        assert inst.step(k * 1e-3, 1e-3) == 0
        out.append(inst.outputs())
    return out


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_a_state_passed_back_to_get_fmu_state_is_overwritten_in_place(open_native, name):
    """fmi2GetFMUstate with an existing state overwrites it (no new allocation): the same
    pointer, the same bytes as a fresh state of the same instant, the same continuation."""
    import ctypes
    from fmpy.fmi2 import fmi2FMUstate

    inst = open_native(name)

    def run(k0, n):
        return _driven(inst, name, k0, n)

    old = inst.fmu.getFMUstate()                           # taken at t = 0, to be overwritten
    run(0, 30)
    reused = fmi2FMUstate(old.value)
    assert inst.fmu.fmi2GetFMUstate(inst.fmu.component, ctypes.byref(reused)) == 0
    assert reused.value == old.value
    fresh = inst.fmu.getFMUstate()
    assert inst.fmu.serializeFMUstate(reused) == inst.fmu.serializeFMUstate(fresh)
    first = run(30, 30)
    inst.fmu.setFMUstate(reused)
    assert run(30, 30) == first
    inst.fmu.freeFMUstate(reused)
    inst.fmu.freeFMUstate(fresh)


def _state_taken(open_native, name, start):
    """An instance of ``name`` with ``start`` stepped 20 times, its state then taken and
    serialised, and the 20 steps that follow: ``(instance, state, bytes, those outputs)``."""
    inst = open_native(name, **start)
    _driven(inst, name, 0, 20)
    state = inst.fmu.getFMUstate()
    data = inst.fmu.serializeFMUstate(state)
    return inst, state, data, _driven(inst, name, 20, 20)


@pytest.mark.parametrize("name, start, other", [
    ("FlexiblePendulum", {"fidelity": "linear", "integrator": "exponential", "phi0": 0.1},
     {"fidelity": "linear", "integrator": "exponential", "EI": 3.0}),
    ("PDLowPass", {"cutoff": 30.0}, {"cutoff": 50.0, "kp": 2.0}),
])
def test_a_restore_keeps_the_cached_discretisations_only_for_equal_parameters(
        open_native, name, start, other):
    """A restore carries the live model's cached discretisations over (fpm_model_keep) only when
    what they derive from is bitwise equal: restored into the instance that took the state, into
    a fresh one (nothing cached) and into one that stepped with other parameters at the same step
    (a cache that must not be kept), the continuation is bit for bit the same."""
    def run(inst, k0, n):
        return _driven(inst, name, k0, n)

    a, state, data, first = _state_taken(open_native, name, start)
    a.fmu.setFMUstate(state)
    assert run(a, 20, 20) == first
    fresh = open_native(name)
    fresh.fmu.setFMUstate(fresh.fmu.deSerializeFMUstate(data))
    assert run(fresh, 20, 20) == first
    c = open_native(name, **other)
    run(c, 0, 20)
    c.fmu.setFMUstate(c.fmu.deSerializeFMUstate(data))
    assert run(c, 20, 20) == first
    a.fmu.freeFMUstate(state)


@pytest.mark.parametrize("start, other, differs", [
    ({"integrator": "rk4"}, {"EI": 3.0}, True),
    ({"integrator": "dopri5", "phi0": 0.3}, {"integrator": "dopri5", "phi0": 0.2}, True),
    ({"integrator": "symplectic_euler", "n_modes": 2},
     {"integrator": "symplectic_euler", "n_modes": 3}, True),
    ({"fidelity": "linear", "integrator": "exponential"},
     {"fidelity": "linear", "integrator": "exponential", "step": 5e-4}, True),
    ({"damping": "kelvin-voigt", "zeta": 0.02}, {"zeta": 0.02}, True),
    ({"phi0": 0.5}, {"phi0": 0.3, "phi_limit": 0.45}, True),
    ({"energy_limit": 1e6}, {"energy_limit": 2e6}, False),
])
def test_a_restore_takes_the_derived_quantities_over_only_from_equal_parameters(
        open_native, start, other, differs):
    """A co-simulation restore takes the live model's derived quantities (modal data, plant,
    linear model, limits) instead of rebuilding them only when the live model is initialised
    from bitwise equal parameters. A state restored into an instance running other parameters
    (rebuilt) continues bit for bit as in the instance that took it and as in a fresh one;
    restored there again (equal parameters now: taken over), the same; and that instance's own
    state, restored after it, continues its own run (rebuilt again). A phi_limit taken over
    from the live model would refuse the state of phi0 = 0.5."""
    name = "FlexiblePendulum"

    def run(inst, k0, n):
        return _driven(inst, name, k0, n)

    a, state, data, first = _state_taken(open_native, name, start)
    for _ in range(2):                                     # the instance that took it
        a.fmu.setFMUstate(state)
        assert run(a, 20, 20) == first
    b = open_native(name, **other)
    run(b, 0, 20)
    own_state = b.fmu.getFMUstate()
    own = run(b, 20, 20)
    assert (own != first) == differs
    for _ in range(2):                                     # rebuilt, then taken over
        b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
        assert run(b, 20, 20) == first
    b.fmu.setFMUstate(own_state)
    assert run(b, 20, 20) == own
    fresh = open_native(name)
    fresh.fmu.setFMUstate(fresh.fmu.deSerializeFMUstate(data))
    assert run(fresh, 20, 20) == first
    a.fmu.freeFMUstate(state)
    b.fmu.freeFMUstate(own_state)


def test_a_restore_into_a_model_prepared_before_a_parameter_change_rebuilds_it(open_native):
    """An instance in initialization mode whose outputs were read (its model prepared from the
    parameters then) and whose parameter was set after, back to the value of the instance that
    took the state: its parameters are equal, its derived quantities are not, and it is not
    initialised, so a restore rebuilds them: the continuation is bit for bit the same."""
    name = "FlexiblePendulum"

    def run(inst, k0, n):
        return _driven(inst, name, k0, n)

    a = open_native(name, phi0=0.3)
    ei = a.get("EI")[0]
    run(a, 0, 20)
    data = a.fmu.serializeFMUstate(a.fmu.getFMUstate())
    first = run(a, 20, 20)
    c = open_native(name, initialize=False, phi0=0.3, EI=3.0 * ei)
    c.fmu.enterInitializationMode()
    c.outputs()                                            # prepared from EI = 3 ei
    c.set(EI=ei)
    c.fmu.setFMUstate(c.fmu.deSerializeFMUstate(data))
    assert run(c, 20, 20) == first


def test_an_in_memory_state_whose_bytes_were_overwritten_is_refused(open_native):
    """An in-memory state carries a checksum of its bytes (the FNV-1a trailer is written only
    when it is serialised): a byte overwritten in memory makes restoring or serialising it an
    error that says so, and the instance is unchanged."""
    import ctypes
    from fmpy.fmi1 import FMICallException

    inst = open_native("FlexiblePendulum", phi0=0.2)
    state = inst.fmu.getFMUstate()
    n = len(inst.fmu.serializeFMUstate(state))
    raw = ctypes.string_at(state.value, 64 + n)
    at = state.value + raw.index(b"FPMS") + n // 2        # a byte of the payload, in memory
    before = inst.outputs()
    original = ctypes.string_at(at, 1)[0]
    ctypes.memset(at, original ^ 0x40, 1)
    with pytest.raises(FMICallException):
        inst.fmu.setFMUstate(state)
    with pytest.raises(FMICallException):
        inst.fmu.serializeFMUstate(state)
    assert "corrupt" in inst.messages(3) and "memory was overwritten" in inst.messages(3)
    assert inst.outputs() == before
    ctypes.memset(at, original, 1)                         # restored: accepted again
    inst.fmu.setFMUstate(state)
    inst.fmu.freeFMUstate(state)


def test_a_state_carries_the_damping_law(open_native):
    """The damping law is a parameter of the state: one saved under the Kelvin-Voigt law and
    restored into an instance opened with the modal law continues as the Kelvin-Voigt run to
    the last bit, and the modal run is another."""
    def run(inst, k0, n):
        out = []
        for k in range(k0, k0 + n):
            inst.set(F_c=10 * math.sin(0.05 * k))
            assert inst.step(k * 1e-3, 1e-3) == 0
            out.append(inst.outputs())
        return np.array(out)

    start = dict(phi0=0.4, zeta=0.02, n_modes=4)
    a = open_native("FlexiblePendulum", damping="kelvin-voigt", **start)
    run(a, 0, 50)
    state = a.fmu.getFMUstate()
    data = a.fmu.serializeFMUstate(state)
    first = run(a, 50, 50)
    b = open_native("FlexiblePendulum", **start)
    modal = run(b, 0, 100)[50:]
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    assert np.array_equal(run(b, 50, 50), first)
    assert np.max(np.abs(modal - first)) > 1e-6
    a.fmu.freeFMUstate(state)


# ---------------------------------------------------------------------- issue 23: the core
def _fnv(data: bytes) -> int:
    h = 14695981039346656037
    for b in data:
        h = ((h ^ b) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def _refix(blob: bytearray) -> bytes:
    """Recompute a state's trailer, as anyone can (an FNV-1a, no key)."""
    import struct
    blob[-8:] = struct.pack("<Q", _fnv(bytes(blob[:-8])))
    return bytes(blob)


def _state_offsets(name: str) -> dict:
    sys.path.insert(0, str(Path(__file__).parents[1] / "fuzz"))
    from make_corpus import layout
    return layout(name, {})


@pytest.mark.parametrize("name, item, kind, value, words", [
    ("FlexiblePendulum", "n_modes", "d", 4194304.0, "n_modes = 4194304 is out of range"),
    ("FlexiblePendulum", "n_elements", "d", 2.5, "n_elements = 2.5 is not an Integer value"),
    ("FlexiblePendulum", "initialized", "i", 0, "not initialised in a state that needs"),
    ("FlexiblePendulum", "k", "d", 2.0 ** 63, "is not a substep count"),
    ("FlexiblePendulum", "y", "d", math.nan, "the state y = nan is not finite"),
    ("FlexiblePendulum", "mode", "i", 0x7FFFFFFF, "the mode 2147483647 is not a state"),
    ("FlexiblePendulum", "phi_limit", "d", -1.0, "phi_limit = -1 is out of range"),
    ("PDLowPass", "filter_order", "d", 1048576.0, "filter_order = 1048576 is out of range"),
    ("PDLowPass", "xc0", "d", math.inf, "xc[0] = inf is not finite"),
    ("PDLowPass", "F", "d", -math.inf, "F_c = -inf is not finite"),
    ("PDLowPass", "force_limit", "d", 0.0, "force_limit = 0 is out of range"),
], ids=lambda x: x if isinstance(x, str) and " " not in x else None)
def test_23_1_a_crafted_state_with_its_checksum_recomputed_is_refused(open_native, name, item,
                                                                      kind, value, words):
    """Issue 23, 1: a state edited field by field with the trailer recomputed passes the
    checksum and is refused by the checks of the values, naming the item; the instance is
    unchanged (the old layer accepted next = 1048576 or nx = 4194304 and crashed at doStep)."""
    import struct
    from fmpy.fmi1 import FMICallException
    start = {"phi0": 0.3} if name == "FlexiblePendulum" else {"phi_o": 0.1}
    out = "phi_o" if name == "FlexiblePendulum" else "F_c"
    inst = open_native(name, **start)
    assert inst.step(0.0, 1e-3) == 0
    state = inst.fmu.getFMUstate()
    blob = bytearray(inst.fmu.serializeFMUstate(state))
    at = _state_offsets(name)[item]
    blob[at:at + (8 if kind == "d" else 4)] = struct.pack("<d" if kind == "d" else "<i", value)
    with pytest.raises(FMICallException) as exc:
        inst.fmu.deSerializeFMUstate(_refix(blob))
    assert exc.value.status == 3
    log = inst.messages(3)
    assert "corrupt" not in log and words in log and "the instance is unchanged" in log
    assert inst.step(1e-3, 1e-3) == 0
    twin = open_native(name, **start)
    assert twin.step(0.0, 1e-3) == 0 and twin.step(1e-3, 1e-3) == 0
    assert inst.get(out) == twin.get(out)
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_23_1_every_double_of_a_state_crafted_restores_to_a_legal_state_or_is_refused(
        open_native, name):
    """Each 8 bytes of the payload overwritten with a hostile double (checksum recomputed):
    the restore is refused, or what it restores steps with finite outputs or refuses the step
    with a message."""
    import struct
    from fmpy.fmi1 import FMICallException
    inst = open_native(name, **({"phi0": 0.3} if name == "FlexiblePendulum" else {"phi_o": 0.1}))
    assert inst.step(0.0, 1e-3) == 0
    state = inst.fmu.getFMUstate()
    good = bytes(inst.fmu.serializeFMUstate(state))
    outputs = [v for v in inst.vars.values() if v.causality == "output"]
    restored = 0
    for at in range(24, len(good) - 8 - 7):
        for value in (math.nan, 1e300, -1.0, 2.0 ** 62):
            blob = bytearray(good)
            blob[at:at + 8] = struct.pack("<d", value)
            try:
                back = inst.fmu.deSerializeFMUstate(_refix(blob))
            except FMICallException as exc:
                assert exc.status == 3 and inst.logs[-1][2]
                continue
            restored += 1
            inst.fmu.setFMUstate(back)
            inst.fmu.freeFMUstate(back)
            t = inst.fmu.getRealStatus(2)                    # fmi2LastSuccessfulTime
            status = inst.step(t, 1e-3)
            assert status == 0 or inst.logs[-1][0] == status
            for v in outputs:
                try:
                    assert math.isfinite(inst.fmu.getReal([v.valueReference])[0])
                except FMICallException as exc:
                    assert exc.status == 3
            inst.fmu.setFMUstate(state)
    assert restored > 0                                      # inputs may be anything
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("start, h", [({}, 1e19), ({}, 1e300), ({"step": 1e-300}, 1e-3),
                                      ({"step": 5e-324}, 1e-3)])
def test_23_2_a_step_too_long_for_the_cap_is_refused_not_skipped(open_native, start, h):
    """Issue 23, 2: the substep count is computed in floating point and checked before any
    conversion: a step of 1e19 or 1e300 (2^63 substeps or more), or a plant step of 1e-300 or
    5e-324 (which hung the second doStep), is discarded with the count, the state unchanged."""
    inst = open_native("FlexiblePendulum", phi0=0.2, **start)
    before = inst.outputs()
    for _ in range(2):
        assert inst.step(0.0, h) == 2
        assert "more than the cap of" in inst.messages(2)
        assert inst.outputs() == before
    assert inst.fmu.getRealStatus(2) == 0.0                  # the time did not move


def test_23_2_a_step_below_the_time_resolution_is_refused(open_native):
    inst = open_native("PDLowPass", phi_o=0.1)
    assert inst.step(0.0, 1.0) == 0
    assert inst.step(1.0, 1e-20) == 2                        # 1 + 1e-20 == 1
    assert "below the resolution of the time" in inst.messages(2)
    assert inst.step(1.0, 1e-3) == 0


@pytest.mark.parametrize("phi_dot0", [1e160, 1.7976931348623157e308])
def test_23_3_an_initial_state_with_non_finite_outputs_is_a_bad_parameter(open_native,
                                                                         phi_dot0):
    """Issue 23, 3: exitInitializationMode refused (it returned OK and energy read inf or NaN
    with status OK); no output is ever read non-finite with OK."""
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", initialize=False, phi_dot0=phi_dot0)
    assert inst.initialize() == 3
    assert "the initial state" in inst.messages(3) and "too large" in inst.messages(3)
    for v in [v for v in inst.vars.values() if v.causality == "output"]:
        with pytest.raises(FMICallException):
            inst.fmu.getReal([v.valueReference])


@pytest.mark.parametrize("param, value", [("L", 1e-200), ("rho", 5e-324), ("EI", 1e16)])
def test_23_3_a_parameter_outside_the_range_of_finite_invariants_is_named(open_native, param,
                                                                          value):
    """The positive parameters lie in [1e-15, 1e15] as in plant_fmu/params.py: a subnormal one
    gave a float division by zero (UBSan) in the modal scaling."""
    inst = open_native("FlexiblePendulum", initialize=False, **{param: value})
    assert inst.initialize() == 3
    assert f"bad parameter: {param} = " in inst.messages(3)


FMI3_NULL = r"""
import sys
from fmpy import read_model_description, extract
from fmpy.fmi3 import FMU3Slave
from fmpy.fmi1 import FMICallException
path = sys.argv[1]
md = read_model_description(path)
d = extract(path)
messages = []
fmu = FMU3Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier)
fmu.instantiate(loggingOn=True, logMessage=lambda *a: messages.append(a))
fmu.enterInitializationMode()
fmu.exitInitializationMode()
for fn in (fmu.fmi3GetFloat64, fmu.fmi3SetFloat64, fmu.fmi3GetInt32, fmu.fmi3GetFloat32):
    try:
        fn(fmu.component, None, 2, None, 2)
        print("OK", fn.__name__)
    except FMICallException as exc:
        print("status", exc.status)
print("messages", len(messages))
fmu.terminate()
fmu.freeInstance()
"""


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_23_4_null_arrays_with_a_count_are_an_error_in_fmi3(native3, name):
    """Issue 23, 4: fmi3GetFloat64(inst, NULL, 2, NULL, 2) was SIGSEGV (in a child process)."""
    proc = subprocess.run([sys.executable, "-c", FMI3_NULL, native3[name]], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.split("\n")
    assert lines[:4] == ["status 3"] * 4
    assert "messages 4" in proc.stdout
