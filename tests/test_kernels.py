"""The compiled right-hand side against the readable numpy one (two implementations)."""
import numpy as np
import pytest

from plant_fmu.dynamics import plant_model
from plant_fmu.kernels import HAVE_NUMBA
from plant_fmu.params import PlantParams


def test_numba_is_in_use():
    assert HAVE_NUMBA


@pytest.mark.parametrize("n,preload", [(0, False), (1, False), (4, False), (4, True), (8, True)],
                         ids=["rigid", "n1", "n4", "n4-preload", "n8-preload"])
def test_kernel_equals_numpy_rhs(n, preload):
    m = plant_model(PlantParams(n_modes=n, gravity_preload=preload))
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = rng.standard_normal(m.nx) * np.r_[1, 2, 0.02 * np.ones(n), 1, 3, 5 * np.ones(n)]
        u = rng.standard_normal() * 100
        a, b = m.rhs(0.0, x, u), m.rhs_numpy(0.0, x, u)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())


@pytest.mark.parametrize("n,preload", [(0, False), (4, False), (8, True)],
                         ids=["rigid", "n4", "n8-preload"])
def test_energy_kernel_equals_numpy(n, preload):
    m = plant_model(PlantParams(n_modes=n, gravity_preload=preload))
    rng = np.random.default_rng(10 + n)
    for _ in range(20):
        x = rng.standard_normal(m.nx) * np.r_[1, 2, 0.02 * np.ones(n), 1, 3, 5 * np.ones(n)]
        e, e_np = m.energy(x), m.energy_numpy(x)
        assert e == pytest.approx(e_np, rel=1e-12, abs=1e-12)


class _PythonOnly:
    """The plant without its compiled substep loop: the steppers fall back to Python."""

    def __init__(self, m):
        self.rhs, self.nq, self.nx = m.rhs, m.nq, m.nx


@pytest.mark.parametrize("method", ["rk4", "euler"])
def test_compiled_substeps_equal_python_substeps(method):
    """The compiled explicit RK loop (PlantModel.erk_steps) against the stepper's Python loop:
    same states to round-off, same counters, on and off the substep grid."""
    from plant_fmu.integrators import make_stepper
    m = plant_model(PlantParams(n_modes=4))
    y0 = m.initial_state(phi=0.4, phi_dot=0.3)
    a = make_stepper(method, m, 0.0, y0, u=2.0, h=2.5e-4)
    b = make_stepper(method, _PythonOnly(m), 0.0, y0, u=2.0, h=2.5e-4)
    for t_end in (1e-3, 2e-3, 2.6e-3, 3.7e-3, 5e-3):     # 2.6 and 3.7 ms are off the grid
        a.u = b.u = 100.0 * t_end
        assert a.advance(t_end) == b.advance(t_end) == (True, None)
        np.testing.assert_allclose(a.y, b.y, rtol=1e-12, atol=1e-14)
        assert (a.t, a.nfev, a.nsteps) == (b.t, b.nfev, b.nsteps)


def test_compiled_substeps_stop_at_a_non_finite_state():
    """Euler far beyond its stability limit overflows: the stepper fails with a message and
    keeps the last finite state, like the Python loop."""
    from plant_fmu.integrators import make_stepper
    m = plant_model(PlantParams(n_modes=4))
    y0 = m.initial_state(phi=0.1)
    a = make_stepper("euler", m, 0.0, y0, h=1e-2)
    b = make_stepper("euler", _PythonOnly(m), 0.0, y0, h=1e-2)
    ok_a, msg_a = a.advance(100.0)
    ok_b, msg_b = b.advance(100.0)
    assert not ok_a and not ok_b and "non-finite state" in msg_a
    assert np.all(np.isfinite(a.y))
    assert a.t == b.t and a.nsteps == b.nsteps


def test_compiled_substeps_with_a_polynomial_input():
    """The compiled loop evaluates the polynomial input at the stage times as the Python one."""
    from plant_fmu.integrators import make_stepper
    m = plant_model(PlantParams(n_modes=4))
    y0 = m.initial_state(phi=0.4)
    a = make_stepper("rk4", m, 0.0, y0, h=2.5e-4)
    b = make_stepper("rk4", _PythonOnly(m), 0.0, y0, h=2.5e-4)
    for k, t_end in enumerate((1e-3, 2e-3, 2.6e-3, 3.7e-3)):
        t0 = a.t
        for s in (a, b):
            s.set_input(3.0 - k, 400.0 * (-1) ** k, 3e4 * k, t=t0)
        assert a.advance(t_end) == b.advance(t_end) == (True, None)
        np.testing.assert_allclose(a.y, b.y, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("n", [0, 1, 4, 8])
def test_tip_kernel_equals_numpy(n):
    m = plant_model(PlantParams(n_modes=n))
    rng = np.random.default_rng(20 + n)
    for _ in range(20):
        x = rng.standard_normal(m.nx) * np.r_[1, 2, 0.05 * np.ones(n), 1, 3, 5 * np.ones(n)]
        np.testing.assert_allclose(m.tip_angle(x), m.tip_angle_numpy(x), rtol=1e-13, atol=1e-15)
