"""FMU state: it holds the whole internal state (integrator, filter, time, inputs), so that a run
restored from a saved state repeats bit for bit: run 1 s, save, run 1 s, restore, run it again."""
import json

import numpy as np
import pytest

H = 1e-3
N = 1000                        # one second of 1 ms steps


def closed_loop(plant, ctrl, k0, n):
    """``n`` Jacobi steps from ``t = k0*H``: both FMUs step on the outputs of the last point."""
    rows = []
    for k in range(k0, k0 + n):
        t = k * H
        x_o, phi_o, omega_o = plant.get("x_o", "phi_o", "omega_o")
        ctrl.set(x_o=x_o, phi_o=phi_o, omega_o=omega_o)
        plant.set(F_c=ctrl.get("F_c")[0])
        assert plant.step(t, H) == 0 and ctrl.step(t, H) == 0
        rows.append(plant.outputs() + ctrl.get("F_c"))
    return np.array(rows)


def save(inst, how):
    state = inst.fmu.getFMUstate()
    if how == "memory":
        return state
    data = inst.fmu.serializeFMUstate(state)
    inst.fmu.freeFMUstate(state)
    json.loads(bytes(data))                          # portable: plain JSON
    return bytes(data)


def restore(inst, saved, how):
    state = saved if how == "memory" else inst.fmu.deSerializeFMUstate(saved)
    inst.fmu.setFMUstate(state)
    if how != "memory":
        inst.fmu.freeFMUstate(state)


CASES = [
    ("rk4", "nonlinear", 4, "memory"),
    ("rk4", "nonlinear", 4, "serialized"),
    ("dopri5", "nonlinear", 4, "serialized"),       # adaptive step size and its error history
    ("radau", "nonlinear", 2, "memory"),            # Newton matrices, step size, collocation
    ("genalpha", "nonlinear", 4, "serialized"),     # acceleration state
    ("exponential", "linear", 4, "memory"),
]


@pytest.mark.parametrize("integrator, fidelity, n_modes, how", CASES,
                         ids=[f"{c[0]}-n{c[2]}-{c[3]}" for c in CASES])
def test_restored_second_is_bit_identical(open_fmu, integrator, fidelity, n_modes, how):
    plant = open_fmu("FlexiblePendulum", integrator=integrator, fidelity=fidelity,
                     n_modes=n_modes, phi0=0.3, rtol=1e-6, atol=1e-9)
    ctrl = open_fmu("PDLowPass")
    closed_loop(plant, ctrl, 0, N)
    saved = [save(plant, how), save(ctrl, how)]
    first = closed_loop(plant, ctrl, N, N)
    restore(plant, saved[0], how)
    restore(ctrl, saved[1], how)
    again = closed_loop(plant, ctrl, N, N)
    assert np.array_equal(first, again)
    assert np.all(np.isfinite(first))
    assert abs(first[-1, 2]) < 0.3                  # the loop is stable: it did something
    if how == "memory":
        plant.fmu.freeFMUstate(saved[0])
        ctrl.fmu.freeFMUstate(saved[1])


def test_serialized_state_moves_to_a_fresh_instance(open_fmu):
    """A serialized state carries the parameters too: restored into an instance set up with other
    parameters, it continues exactly as the original."""
    plant = open_fmu("FlexiblePendulum", phi0=0.3, n_modes=3, instance_name="original")
    ctrl = open_fmu("PDLowPass", filter_order=1, cutoff=130.0, instance_name="original")
    closed_loop(plant, ctrl, 0, 300)
    saved = [save(plant, "serialized"), save(ctrl, "serialized")]
    first = closed_loop(plant, ctrl, 300, 300)

    plant2 = open_fmu("FlexiblePendulum", n_modes=1, instance_name="copy")
    ctrl2 = open_fmu("PDLowPass", instance_name="copy")
    restore(plant2, saved[0], "serialized")
    restore(ctrl2, saved[1], "serialized")
    assert np.array_equal(closed_loop(plant2, ctrl2, 300, 300), first)


def test_state_restores_after_a_failure(open_fmu):
    """Rollback is the way out of a failed step: after the divergence, restoring the saved state
    lets the slave step again (here with a force that keeps it upright)."""
    plant = open_fmu("FlexiblePendulum", phi0=0.2, n_modes=1)
    for k in range(100):
        assert plant.step(k * H, H) == 0
    saved = plant.fmu.getFMUstate()
    outputs = plant.outputs()
    status, k = 0, 100
    while status == 0:
        status = plant.step(k * H, H)
        k += 1
    assert status == 2 and plant.step(k * H, H) == 2
    plant.fmu.setFMUstate(saved)
    assert plant.outputs() == outputs
    assert plant.step(100 * H, H) == 0
    plant.fmu.freeFMUstate(saved)


def test_state_keeps_the_controller_filter_and_time(open_fmu):
    ctrl = open_fmu("PDLowPass")
    ctrl.set(phi_o=0.1, omega_o=0.0)
    for k in range(10):
        assert ctrl.step(k * H, H) == 0
    saved = ctrl.fmu.getFMUstate()
    f10 = ctrl.get("F_c")[0]
    assert ctrl.step(10 * H, H) == 0
    assert ctrl.get("F_c")[0] != f10
    ctrl.fmu.setFMUstate(saved)
    assert ctrl.get("F_c")[0] == f10
    assert ctrl.step(11 * H, H) == 2                 # its time went back to 10 ms too
    assert ctrl.step(10 * H, H) == 0
    ctrl.fmu.freeFMUstate(saved)


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_a_corrupt_serialised_state_is_an_error_not_a_crash(open_fmu, name):
    from fmpy.fmi1 import FMICallException

    inst = open_fmu(name)
    with pytest.raises(FMICallException) as exc:
        inst.fmu.deSerializeFMUstate(b"{not json")
    assert exc.value.status == 3                     # fmi2Error, and the instance is unchanged
    assert f"not a valid {name} state (JSONDecodeError" in inst.messages(3)
    assert inst.step(0.0, H) == 0
    assert all(np.isfinite(inst.outputs()))


@pytest.mark.parametrize("how", ["memory", "serialized"])
def test_a_state_carries_the_damping_law(open_fmu, how):
    """The damping law is a parameter of the state: one saved under the Kelvin-Voigt law and
    restored into an instance opened with the modal law continues as the Kelvin-Voigt run to
    the last bit, and the modal run is another."""
    start = dict(phi0=0.3, zeta=0.02, n_modes=4)
    plant = open_fmu("FlexiblePendulum", damping="kelvin-voigt", **start)
    ctrl = open_fmu("PDLowPass")
    closed_loop(plant, ctrl, 0, 100)
    saved = [save(plant, how), save(ctrl, how)]
    first = closed_loop(plant, ctrl, 100, 100)
    other, ctrl2 = open_fmu("FlexiblePendulum", **start), open_fmu("PDLowPass")
    modal = closed_loop(other, ctrl2, 0, 200)[100:]
    if how == "memory":        # a state in memory belongs to its instance
        other, ctrl2 = plant, ctrl
    restore(other, saved[0], how)
    restore(ctrl2, saved[1], how)
    assert np.array_equal(closed_loop(other, ctrl2, 100, 100), first)
    assert np.max(np.abs(modal - first)) > 1e-6
