"""Energy: conserved without damping and force; dissipated by damping; fed by the force's power."""
import numpy as np
import pytest
import scipy.integrate

from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams


@pytest.mark.parametrize("n,preload", [(0, False), (2, False),
                                       pytest.param(4, False, marks=pytest.mark.slow),
                                       (2, True)],
                         ids=["rigid", "n2", "n4", "n2-preload"])
def test_energy_conserved_without_damping_and_force(n, preload):
    """5 s from phi0 = pi/6 (beam undeformed, at rest), DOP853 at rtol = atol = 1e-12: the
    pendulum falls through large angles and the modes are excited by the motion."""
    m = plant_model(PlantParams(n_modes=n, zeta=0.0, gravity_preload=preload))
    x0 = m.initial_state(phi=np.pi / 6)
    sol = scipy.integrate.solve_ivp(lambda t, x: m.rhs(t, x, 0.0), (0, 5), x0, method="DOP853",
                                    rtol=1e-12, atol=1e-12, dense_output=True)
    assert sol.success
    E0 = m.energy(x0)
    E = np.array([m.energy(sol.sol(t)) for t in np.linspace(0, 5, 201)])
    drift = np.max(np.abs(E - E0)) / abs(E0)
    assert drift < 1e-8, drift
    if n:
        assert np.max(np.abs(sol.y[2])) > 1e-4          # the beam did bend
    assert np.ptp(sol.y[1]) > 1.0                       # and the pendulum did move


def _dE_dt(m, x, u):
    """d/dt E along the motion: the derivative of E in the direction of rhs, by central
    differences with one Richardson extrapolation (error O(h^4))."""
    dx = m.rhs(0.0, x, u)
    h = 1e-3 / np.linalg.norm(dx)
    d = lambda k: (m.energy(x + k * dx) - m.energy(x - k * dx)) / (2 * k)  # noqa: E731
    return (4 * d(h / 2) - d(h)) / 3


@pytest.mark.parametrize("n", [0, 3])
def test_power_balance_at_random_states(n):
    """dE/dt = F_c xd - etad^T D etad (force power minus modal dissipation)."""
    p = PlantParams(n_modes=n, zeta=0.02)
    m = plant_model(p)
    D = np.diag(m.beam.D) if n else np.zeros(0)
    rng = np.random.default_rng(3)
    for _ in range(10):
        x = np.r_[rng.standard_normal(), rng.uniform(-1, 1), 1e-2 * rng.standard_normal(n),
                  rng.standard_normal(), rng.standard_normal(), rng.standard_normal(n)]
        F = 50 * rng.standard_normal()
        xd, etad = x[m.nq], x[m.nq + 2:]
        expected = F * xd - float(etad @ (D * etad))
        assert _dE_dt(m, x, F) == pytest.approx(expected, rel=1e-6, abs=1e-6)
