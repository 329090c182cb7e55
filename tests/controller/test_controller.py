"""PD + low-pass: transfer function, unit DC gain, exact discretisation with a held input."""
import numpy as np
import pytest
import scipy.integrate
import scipy.signal

from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel

FILTERS = [ControllerParams(filter_order=0), ControllerParams(filter_order=1, cutoff=130),
           ControllerParams(filter_order=2, cutoff=150, filter_damping=0.5)]
IDS = ["order0", "order1", "order2"]


@pytest.mark.parametrize("c", FILTERS, ids=IDS)
def test_state_space_realises_minus_H_times_pd(c):
    """C (sI - A)^-1 B + D equals -H(s) [kx, kp, kd] at several frequencies."""
    m = PDLowPassModel(c)
    A, B, C, D = m.state_space()
    for s in (0.0, 3j, 150j, 1e4j, 2.0 + 5j):
        G = C @ np.linalg.solve(s * np.eye(A.shape[0]) - A, B) + D if A.size else D
        expected = -m.transfer_function(s) * np.array([c.kx, c.kp, c.kd])
        np.testing.assert_allclose(G[0], expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("c", FILTERS, ids=IDS)
def test_unit_dc_gain(c):
    assert PDLowPassModel(c).transfer_function(0.0) == pytest.approx(1.0)


def test_closed_forms_of_the_filters():
    wc, zf, s = 150.0, 0.5, 40j
    assert PDLowPassModel(FILTERS[1]).transfer_function(s) == pytest.approx(130 / (s + 130))
    assert PDLowPassModel(FILTERS[2]).transfer_function(s) == pytest.approx(
        wc**2 / (s**2 + 2 * zf * wc * s + wc**2))


@pytest.mark.parametrize("c", FILTERS[1:], ids=IDS[1:])
@pytest.mark.parametrize("h", [1e-4, 1e-3, 2e-2])
def test_discretisation_matches_scipy_cont2discrete_zoh(c, h):
    m = PDLowPassModel(c)
    Ad, Bd = m.discretize(h)
    ref = scipy.signal.cont2discrete((m.Af, m.Bf, m.Cf, m.Df), h, method="zoh")
    np.testing.assert_allclose(Ad, ref[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Bd, ref[1][:, 0], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("c", FILTERS[1:], ids=IDS[1:])
def test_step_is_exact_for_held_input_against_ode_solution(c):
    """Ten steps of 20 ms with a held, changing input, against solve_ivp at tight tolerance."""
    m = PDLowPassModel(c)
    h = 0.02
    xc = m.initial_state()
    ys = [np.array([0.0, 0.1 * np.sin(k), np.cos(k)]) for k in range(10)]
    xr = xc.copy()
    for y in ys:
        xc = m.step(xc, y, h)
        e = m.error_signal(y)
        sol = scipy.integrate.solve_ivp(lambda t, z: m.Af @ z + m.Bf[:, 0] * e, (0, h), xr,
                                        rtol=1e-12, atol=1e-12, method="DOP853")
        xr = sol.y[:, -1]
    np.testing.assert_allclose(xc, xr, rtol=1e-9, atol=1e-9)


def test_order0_is_direct_feedthrough_and_saturation():
    m = PDLowPassModel(ControllerParams(filter_order=0, force_limit=20.0))
    assert m.output(m.initial_state(), [0, 0.01, 0.0]) == pytest.approx(-5.0)
    assert m.output(m.initial_state(), [0, 1.0, 0.0]) == -20.0
    assert m.output(m.initial_state(), [0, -1.0, 0.0]) == 20.0


@pytest.mark.parametrize("c", FILTERS[1:], ids=IDS[1:])
def test_polynomial_discretisation_against_ode_solution(c):
    """discretize_polynomial(h) is exact for e(s) = e0 + e1 s + e2 s^2 / 2: against a tight ODE
    solution of the filter driven by that signal; its first column is the zero-order hold."""
    m = PDLowPassModel(c)
    h, e0, e1, e2 = 2e-3, 0.7, -300.0, 4e4
    xc0 = np.array([0.3, -20.0])[:m.nx]
    Ad, G = m.discretize_polynomial(h)
    got = Ad @ xc0 + G @ [e0, e1, e2]
    sol = scipy.integrate.solve_ivp(
        lambda s, x: m.Af @ x + m.Bf[:, 0] * (e0 + e1 * s + 0.5 * e2 * s * s), (0.0, h), xc0,
        method="DOP853", rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(got, sol.y[:, -1], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(G[:, 0], m.discretize(h)[1], rtol=1e-14, atol=1e-16)
