"""FlexiblePendulum: a thin adapter over the pure model, whole-state save/restore, clean failures."""
import math

import numpy as np
import pytest

from plant_fmu.dynamics import linear_plant_model, plant_model
from plant_fmu.integrators import make_stepper
from plant_fmu.params import PlantParams

H = 1e-3
SENSORS = ("x_o", "phi_o", "omega_o")


def force(t):
    """A test force on the cart: a push, a pull and a ripple near the first bending mode."""
    return (30.0 if t < 0.05 else -30.0 if t < 0.1 else 0.0) + 4.0 * math.sin(150.0 * t)


def finite(values):
    return all(math.isfinite(v) for v in values)


@pytest.mark.parametrize("fidelity, integrator, n_modes", [
    ("nonlinear", "rk4", 4), ("nonlinear", "dopri5", 2), ("linear", "exponential", 3),
], ids=["rk4-n4", "dopri5-n2", "linear-exponential-n3"])
def test_fmu_equals_the_pure_model_and_stepper(open_fmu, fidelity, integrator, n_modes):
    """The FMU adds nothing to the model: same stepper, same held input -> identical outputs."""
    plant = open_fmu("FlexiblePendulum", fidelity=fidelity, integrator=integrator,
                     n_modes=n_modes, phi0=0.05, x_dot0=0.1)
    p = PlantParams(n_modes=n_modes)
    model = linear_plant_model(p) if fidelity == "linear" else plant_model(p)
    st = make_stepper(integrator, model, 0.0, model.initial_state(phi=0.05, x_dot=0.1),
                      h=2.5e-4, rtol=1e-6, atol=1e-9)
    for k in range(200):
        t = k * H
        plant.set(F_c=force(t))
        assert plant.step(t, H) == 0
        st.u = force(t)
        assert st.advance(t + H) == (True, None)
        o = model.outputs(t + H, st.y)
        got = dict(zip(("x_o", "x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1",
                        "energy"), plant.outputs()))
        assert got["x_o"] == o["x_o"] and got["x_dot"] == o["x_dot"]
        assert got["phi_o"] == o["phi_o"] and got["omega_o"] == o["omega_o"]
        assert got["tip_deflection"] == o["tip_deflection"]
        assert got["eta_1"] == o["eta"][0]
        assert got["energy"] == o["energy"]


def test_initial_outputs_follow_the_initial_values(open_fmu):
    plant = open_fmu("FlexiblePendulum", initialize=False, phi0=0.2, x0=0.3, phi_dot0=-0.5,
                     x_dot0=0.7)
    plant.fmu.enterInitializationMode()
    # readable in initialisation mode (InitialUnknowns), before exitInitializationMode
    assert plant.get("phi_o", "x_o", "omega_o", "x_dot") == [0.2, 0.3, -0.5, 0.7]
    plant.fmu.exitInitializationMode()
    x_o, x_dot, phi_o, omega_o, tip, eta_1, energy, phi, *etas = plant.outputs()
    assert (x_o, x_dot, phi_o, omega_o, tip, eta_1, phi) == (0.3, 0.7, 0.2, -0.5, 0.0, 0.0, 0.2)
    assert etas == [0.0] * 7
    m = plant_model(PlantParams())
    assert energy == m.energy(m.initial_state(phi=0.2, x=0.3, phi_dot=-0.5, x_dot=0.7))


def test_rigid_pendulum_has_zero_modal_outputs(open_fmu):
    plant = open_fmu("FlexiblePendulum", n_modes=0, phi0=0.1)
    for k in range(50):
        plant.set(F_c=force(k * H))
        assert plant.step(k * H, H) == 0
    assert plant.get("tip_deflection", "eta_1", "eta_2") == [0.0, 0.0, 0.0]
    assert plant.get("phi_o")[0] > 0.1                      # it falls (open loop)
    assert plant.get("phi") == plant.get("phi_o")           # rigid: frame angle = tip angle


def test_modal_and_frame_outputs_are_the_state(open_fmu):
    """phi and eta_1..eta_8 are the state's entries; the tip angle follows from them (docs/model.md:
    phi_o = phi + atan(N'(L) eta))."""
    plant = open_fmu("FlexiblePendulum", n_modes=3, phi0=0.1)
    for k in range(40):
        plant.set(F_c=force(k * H))
        assert plant.step(k * H, H) == 0
    phi, e1, e2, e3, e4, phi_o = plant.get("phi", "eta_1", "eta_2", "eta_3", "eta_4", "phi_o")
    slope = plant_model(PlantParams(n_modes=3)).tip_slope
    assert e4 == 0.0 and e1 != 0.0 and e3 != 0.0
    assert phi_o == pytest.approx(phi + math.atan(slope @ [e1, e2, e3]), rel=1e-14)


def test_a_step_from_another_time_is_refused(open_fmu):
    plant = open_fmu("FlexiblePendulum")
    assert plant.step(0.0, H) == 0
    assert plant.step(0.5, H) == 2
    assert "doStep called at t = 0.5 but the FMU is at t = 0.001" in plant.messages()
    assert plant.step(H, H) == 0                            # the right time still works


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_the_start_time_of_setup_experiment_is_the_fmu_time(open_fmu, name):
    inst = open_fmu(name, start_time=2.5)
    assert inst.step(2.5, H) == 0 and inst.step(2.5 + H, H) == 0
    assert inst.step(0.0, H) == 2


def test_variable_communication_steps(open_fmu):
    plant = open_fmu("FlexiblePendulum", phi0=0.01)
    t = 0.0
    for h in (1e-3, 2e-3, 5e-4, 1.7e-3, 1e-2):
        assert plant.step(t, h) == 0
        t += h
    assert finite(plant.outputs())


# ------------------------------------------------------------------ failures
def test_nonfinite_input_is_discarded_and_the_step_can_be_retried(open_fmu):
    plant = open_fmu("FlexiblePendulum", phi0=0.05)
    assert plant.step(0.0, H) == 0
    before = plant.outputs()
    for bad in (math.nan, math.inf):
        plant.set(F_c=bad)
        assert plant.step(H, H) == 2                            # fmi2Discard
        assert plant.outputs() == before                        # state unchanged, no NaN
    assert "non-finite input F_c = nan" in plant.messages(2)
    assert "non-finite input F_c = inf" in plant.messages(2)
    plant.set(F_c=1.0)
    assert plant.step(H, H) == 0                                # a retry succeeds
    assert plant.outputs() != before and finite(plant.outputs())


def test_divergence_of_phi_is_discarded_with_its_cause(open_fmu):
    plant = open_fmu("FlexiblePendulum", phi0=0.5, n_modes=1)   # falls, open loop
    t, status = 0.0, 0
    while status == 0 and t < 2.0:
        last = plant.outputs()
        status = plant.step(t, 0.01)
        t += 0.01
    assert status == 2
    msg = plant.messages(3)
    assert "divergence" in msg and "phi_limit = 1.5707963267948966" in msg
    assert plant.outputs() == last and finite(last)             # the last accepted state
    assert plant.step(t, 0.01) == 2                             # refuses until restored
    assert "restore a saved FMU state" in plant.messages(3)


def test_divergence_of_the_energy_is_discarded_with_its_cause(open_fmu):
    plant = open_fmu("FlexiblePendulum", energy_limit=100.0)    # 76.5 at rest
    plant.set(F_c=500.0)
    statuses = [plant.step(k * H, H) for k in range(200)]
    assert 2 in statuses
    assert "energy_limit = 100.0" in plant.messages(3)
    assert finite(plant.outputs())
    assert plant.get("energy")[0] <= 100.0


def test_failed_integrator_is_discarded_with_its_cause(open_fmu):
    """Explicit Euler far beyond its stability limit over one long step: the stepper itself
    fails (its state overflows within the step), and the FMU says so."""
    plant = open_fmu("FlexiblePendulum", integrator="euler", step=1e-2, phi0=0.1)
    before = plant.outputs()
    assert plant.step(0.0, 20.0) == 2
    assert "integrator 'euler' failed between t = 0.0 and 20.0" in plant.messages(3)
    assert plant.outputs() == before and finite(before)
    assert plant.step(20.0, 1e-3) == 2                      # refuses until a state is restored


def test_blow_up_is_caught_before_any_output_overflows(open_fmu):
    """With both divergence bounds off, the state's norm still bounds the outputs."""
    plant = open_fmu("FlexiblePendulum", integrator="euler", step=1e-2, phi0=0.1,
                     phi_limit=math.inf, energy_limit=math.inf)
    t, status = 0.0, 0
    while status == 0 and t < 100.0:
        status = plant.step(t, 0.05)
        t += 0.05
    assert status == 2
    assert "exceeds 1e100 (numerical blow-up)" in plant.messages(3)
    assert finite(plant.outputs())


@pytest.mark.parametrize("name, value, words", [
    ("n_modes", -1, "n_modes = -1 is out of range"),
    ("EI", 0.0, "EI = 0.0 is out of range"),
    ("zeta", 1.5, "zeta = 1.5 is out of range"),
    ("integrator", "leapfrog", "integrator = 'leapfrog' is unknown; known: "),
    ("fidelity", "quadratic", "fidelity = 'quadratic' is not allowed"),
    ("damping", "viscous", "damping = 'viscous' is not allowed; allowed: modal, kelvin-voigt"),
    ("step", -1e-3, "step = -0.001 is out of range"),
    ("phi0", math.nan, "phi0 = nan is out of range"),
    ("integrator", "exponential", "it needs fidelity = 'linear'"),
])
def test_bad_parameter_is_an_error_naming_it(open_fmu, name, value, words):
    plant = open_fmu("FlexiblePendulum", **{name: value})
    assert plant.init_status == 3                               # exitInitializationMode: error
    errors = [m for s, _, m in plant.logs if s == 3]            # logged with status fmi2Error
    assert errors and words in errors[0] and errors[0].startswith("bad parameter")
    assert plant.step(0.0, H) == 2                              # and doStep is discarded
    assert words in plant.logs[-1][2]
    assert finite(plant.outputs())


def test_parameters_are_fixed_after_initialisation(open_fmu):
    from fmpy.fmi1 import FMICallException

    plant = open_fmu("FlexiblePendulum", phi0=0.1)
    with pytest.raises(FMICallException) as exc:
        plant.set(n_modes=2)
    assert exc.value.status == 3                                # fmi2Error, instance alive
    assert "parameter n_modes is fixed" in plant.messages(3)
    assert plant.step(0.0, H) == 0


def test_nonfinite_input_derivative_is_discarded(open_fmu):
    plant = open_fmu("FlexiblePendulum", phi0=0.05)
    assert plant.step(0.0, H) == 0
    before = plant.outputs()
    plant.set(F_c=1.0, dF_c=math.nan)
    assert plant.step(H, H) == 2
    assert plant.outputs() == before
    assert "non-finite input dF_c = nan" in plant.messages(2)
