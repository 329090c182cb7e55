"""PDLowPass: the exact discretisation of the pure model, feedthrough only without a filter,
saturation, variable steps and clean failures."""
import math

import numpy as np
import pytest

from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel

H = 1e-3


def sensors(t):
    return (0.3 * t, 0.1 * math.sin(12.0 * t) + 0.01 * math.sin(150.0 * t),
            1.2 * math.cos(12.0 * t) + 1.5 * math.cos(150.0 * t))       # x_o, phi_o, omega_o


@pytest.mark.parametrize("params", [
    {}, {"filter_order": 1, "cutoff": 130.0}, {"filter_order": 0},
    {"kx": 2.0, "filter_damping": 0.7, "cutoff": 90.0}, {"force_limit": 20.0},
], ids=["order2", "order1", "order0", "kx-order2", "saturated"])
def test_fmu_equals_the_model_stepped_exactly(open_fmu, params):
    """Each doStep is the model's exact zero-order-hold step; F_c is the model's output."""
    ctrl = open_fmu("PDLowPass", **params)
    model = PDLowPassModel(ControllerParams(**params))
    xc = model.initial_state()
    for k in range(300):
        y = sensors(k * H)
        ctrl.set(x_o=y[0], phi_o=y[1], omega_o=y[2])
        # before the step: F_c of the current state (and, without a filter, of these inputs)
        assert ctrl.get("F_c")[0] == pytest.approx(model.output(xc, y), rel=1e-13, abs=1e-12)
        assert ctrl.step(k * H, H) == 0
        xc = model.step(xc, y, H)
        assert ctrl.get("F_c")[0] == pytest.approx(model.output(xc, y), rel=1e-13, abs=1e-12)
    if "force_limit" in params:
        assert abs(ctrl.get("F_c")[0]) == 20.0          # the sensors drive it into saturation


def test_feedthrough_only_without_a_filter(open_fmu):
    direct = open_fmu("PDLowPass", filter_order=0, kx=1.0, instance_name="order0")
    filtered = open_fmu("PDLowPass", instance_name="order2")
    for inst in (direct, filtered):
        inst.set(phi_o=0.1, omega_o=2.0, x_o=3.0)
    assert direct.get("F_c") == [-(500 * 0.1 + 5 * 2.0 + 1.0 * 3.0)]     # at once
    assert filtered.get("F_c") == [0.0]                                     # filter at rest
    filtered.set(phi_o=-5.0)
    assert filtered.get("F_c") == [0.0]                                     # no feedthrough


def test_variable_steps_use_the_discretisation_of_each_step(open_fmu):
    ctrl = open_fmu("PDLowPass")
    model = PDLowPassModel(ControllerParams())
    xc, t, y = model.initial_state(), 0.0, (0.0, 0.05, 0.0)
    ctrl.set(x_o=y[0], phi_o=y[1], omega_o=y[2])
    for h in (1e-3, 5e-4, 2e-3, 1e-3, 1.3e-2):
        assert ctrl.step(t, h) == 0
        t += h
        xc = model.step(xc, y, h)
        assert ctrl.get("F_c")[0] == pytest.approx(model.output(xc, y), rel=1e-13)
    # the step response settles to the DC value -kp*phi_o (unit DC gain); the default filter's
    # slowest pole decays at zf wc = 9.73/s: 3 s take it below 1e-12 of the step
    for k in range(3000):
        assert ctrl.step(t, 1e-3) == 0
        t += 1e-3
    assert ctrl.get("F_c")[0] == pytest.approx(-500 * 0.05, rel=1e-9)


@pytest.mark.parametrize("order", [0, 2])
def test_nonfinite_input_is_discarded_and_F_c_stays_finite(open_fmu, order):
    ctrl = open_fmu("PDLowPass", filter_order=order)
    ctrl.set(phi_o=0.1)
    assert ctrl.step(0.0, H) == 0
    f = ctrl.get("F_c")[0]
    ctrl.set(omega_o=math.nan)
    assert ctrl.step(H, H) == 2
    assert "non-finite input at t = 0.001: omega_o = nan" in ctrl.messages(2)
    assert ctrl.get("F_c") == [f]                        # held, never NaN
    ctrl.set(omega_o=0.0)
    assert ctrl.step(H, H) == 0                          # retry with a finite input


def test_overflowing_filter_is_discarded(open_fmu):
    ctrl = open_fmu("PDLowPass")
    ctrl.set(phi_o=1e306)
    assert ctrl.step(0.0, H) == 2
    assert "the filter state overflows" in ctrl.messages(2)
    assert ctrl.get("F_c") == [0.0]


@pytest.mark.parametrize("name, value, words", [
    ("filter_order", 3, "filter_order = 3 is out of range"),
    ("cutoff", -1.0, "cutoff = -1.0 is out of range"),
    ("force_limit", 0.0, "force_limit = 0.0 is out of range"),
    ("kp", math.inf, "kp = inf is out of range"),
])
def test_bad_parameter_is_an_error_naming_it(open_fmu, name, value, words):
    ctrl = open_fmu("PDLowPass", **{name: value})
    assert ctrl.init_status == 3                                # exitInitializationMode: error
    errors = [m for s, _, m in ctrl.logs if s == 3]
    assert errors and errors[0].startswith(f"bad parameter: {words}")   # status fmi2Error
    assert ctrl.step(0.0, H) == 2 and words in ctrl.logs[-1][2]
    assert ctrl.get("F_c") == [0.0]


def test_polynomial_sensor_inputs_are_integrated_exactly(open_fmu):
    """With the sensors' derivatives given (dphi_o, d2phi_o, ...), each doStep is the model's
    exact step for polynomial inputs (discretize_polynomial), not the held one."""
    params = {"kx": 2.0, "filter_damping": 0.7, "cutoff": 90.0}
    ctrl = open_fmu("PDLowPass", **params)
    model = PDLowPassModel(ControllerParams(**params))
    xc = model.initial_state()
    Ad, G = model.discretize_polynomial(H)
    for k in range(100):
        y = np.array(sensors(k * H))
        dy = np.array([0.3, 1.2 * math.cos(12 * k * H), -14.4 * math.sin(12 * k * H)])
        d2y = np.array([0.0, -14.4 * math.sin(12 * k * H), -172.8 * math.cos(12 * k * H)])
        ctrl.set(x_o=y[0], phi_o=y[1], omega_o=y[2], dx_o=dy[0], dphi_o=dy[1], domega_o=dy[2],
                 d2x_o=d2y[0], d2phi_o=d2y[1], d2omega_o=d2y[2])
        assert ctrl.step(k * H, H) == 0
        e = [model.error_signal(v) for v in (y, dy, d2y)]
        xc = Ad @ xc + G @ e
        assert ctrl.get("F_c")[0] == pytest.approx(model.output(xc, y), rel=1e-12, abs=1e-12)
    held = model.output(model.step(model.initial_state(), sensors(0.0), H), sensors(0.0))
    assert held != pytest.approx(model.output(Ad @ model.initial_state() + G @ [
        model.error_signal(v) for v in (sensors(0.0), [0.3, 1.2, 0.0], [0.0, 0.0, -172.8])],
        sensors(0.0)))                              # the derivatives do change the step
