"""The sampled controller (issue 38; controller_fmu/sampled.py, the C kernel's fpf_sampled):
the filter's difference equation by three routes (the numpy specification, the C kernel,
python-control's c2d), against closed forms (the zero-order-hold equivalent is exact for a held
input: its step response is the continuous one at the ticks; the prewarped bilinear map keeps
the DC gain and the gain at the cutoff), and the co-simulation semantics (samples at the ticks,
the force after the delay, a step across an instant refused)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controller_fmu.kernel import FilterKernel
from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.sampled import SampledController, filter_difference_equation

CASES = [(order, d, T) for order in (0, 1, 2) for d in ("tustin", "zoh")
         for T in (1e-4, 4e-3, 0.03)]


@pytest.mark.parametrize("order,disc,T", CASES)
def test_the_kernel_and_python_control_give_the_specifications_difference_equation(order, disc,
                                                                                   T):
    import control
    p = ControllerParams(filter_order=order, sample_period=T, discretization=disc)
    spec = filter_difference_equation(p)
    kern = FilterKernel(p).sampled(T, disc)
    for a, b in zip(spec, kern):
        assert a.shape == b.shape
        assert np.allclose(a, b, rtol=1e-13, atol=1e-15 * max(1.0, np.abs(a).max(initial=0)))
    if order:
        from controller_fmu.pd_lowpass import PDLowPassModel
        m = PDLowPassModel(p)
        H = control.ss(m.Af, m.Bf, m.Cf, m.Df)
        Hd = (control.c2d(H, T, "tustin", prewarp_frequency=p.cutoff) if disc == "tustin"
              else control.c2d(H, T, "zoh"))
        # the same transfer function (a realisation may differ): compare on the unit circle
        for w in np.linspace(0.1, 0.99, 5) * math.pi / T:
            z = np.exp(1j * w * T)
            Ad, Bd, Cd, Dd = spec
            mine = (Cd @ np.linalg.solve(z * np.eye(order) - Ad, Bd) + Dd).item()
            assert abs(mine - complex(Hd(z))) <= 1e-10 * max(1.0, abs(mine))


@pytest.mark.parametrize("order", [1, 2])
def test_the_zoh_filter_steps_as_the_continuous_filter_at_the_ticks(order):
    """For a held (step) error signal the zero-order-hold equivalent is exact: the sampled
    filter's output at t_k is the continuous step response at t_k, in closed form."""
    T = 4e-3
    p = ControllerParams(filter_order=order, sample_period=T, discretization="zoh", kp=1.0,
                         kd=0.0)
    c = SampledController(p)
    F = []
    for k in range(40):
        F.append(c.step(k * T, T, [0.0, 1.0, 0.0]))    # the force of tick k (no delay)
    wc, z = p.cutoff, p.filter_damping
    t = np.arange(40) * T
    if order == 1:
        closed = 1.0 - np.exp(-wc * t)
    else:
        wd = wc * math.sqrt(1.0 - z * z)
        closed = 1.0 - np.exp(-z * wc * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z)
                                             * np.sin(wd * t))
    assert np.allclose(F, -closed, rtol=0, atol=1e-13)


@pytest.mark.parametrize("order", [1, 2])
def test_the_prewarped_tustin_filter_keeps_the_dc_gain_and_the_gain_at_the_cutoff(order):
    T = 0.02                                 # coarse: cutoff T = 1.95 rad, far from continuous
    p = ControllerParams(filter_order=order, sample_period=T)
    Ad, Bd, Cd, Dd = filter_difference_equation(p)

    def Hd(z):
        return (Cd @ np.linalg.solve(z * np.eye(order) - Ad, Bd) + Dd).item()

    wc, zf = p.cutoff, p.filter_damping
    H_cut = 1 / (1j + 1) if order == 1 else 1 / (2j * zf)      # H(j wc), closed form
    assert Hd(1.0) == pytest.approx(1.0, rel=1e-13)
    assert Hd(np.exp(1j * wc * T)) == pytest.approx(H_cut, rel=1e-12)


def test_the_force_acts_after_the_delay_and_is_held():
    T, tau = 0.01, 0.004
    p = ControllerParams(filter_order=0, sample_period=T, delay=tau, kp=2.0, kd=0.0)
    c = SampledController(p)
    assert c.output([0, 0.5, 0]) == 0.0                  # before the delay: the force before
    assert c.step(0.0, tau, [0, 0.5, 0]) == -1.0         # sampled at 0, acting from 0.004 on
    assert c.next_event() == pytest.approx(T)
    assert c.output([0, 9.0, 0]) == -1.0                 # held: no feedthrough with a delay
    assert c.step(tau, T - tau, [0, 9.0, 0]) == -1.0     # not a tick: the sensors are not read
    assert c.step(T, tau, [0, 0.25, 0]) == -0.5          # the tick at T, acting at T + tau


def test_with_no_delay_the_force_at_a_tick_is_a_feedthrough_of_the_sensors_set_there():
    p = ControllerParams(filter_order=0, sample_period=0.01, kp=3.0, kd=0.0)
    c = SampledController(p)
    assert c.output([0, 1.0, 0]) == -3.0 and c.output([0, 2.0, 0]) == -6.0
    c.step(0.0, 0.005, [0, 2.0, 0])
    assert c.output([0, 5.0, 0]) == -6.0                 # between ticks: held


@pytest.mark.parametrize("t,h", [(0.0, 0.011), (0.0, 0.0041)])
def test_a_step_across_a_tick_or_the_delays_end_is_refused_and_changes_nothing(t, h):
    p = ControllerParams(filter_order=2, sample_period=0.01, delay=0.004)
    c = SampledController(p)
    with pytest.raises(ValueError, match="crosses"):
        c.step(t, h, [0, 1.0, 0])
    assert c.k == 0 and c.pending is None and c.t == 0.0 and not c.xf.any()


def test_the_parameters_are_checked_together():
    with pytest.raises(ValueError, match="delay"):
        ControllerParams(sample_period=0.01, delay=0.02)
    with pytest.raises(ValueError, match="pi / cutoff"):
        ControllerParams(sample_period=1.001 * math.pi / 97.3)
    ControllerParams(sample_period=1.001 * math.pi / 97.3, discretization="zoh")
    with pytest.raises(ValueError, match="discretization"):
        ControllerParams(sample_period=0.01, discretization="euler")
