"""The linear model (M0, D0, K0 -> A, B, C) against finite differences of the nonlinear model."""
import numpy as np
import pytest

from plant_fmu.dynamics import linear_plant_model, plant_model
from plant_fmu.params import PlantParams


def _fd_jacobian(f, x0, h=1e-6):
    f0 = f(x0)
    J = np.empty((f0.size, x0.size))
    for i in range(x0.size):
        dx = np.zeros_like(x0)
        dx[i] = h
        J[:, i] = (f(x0 + dx) - f(x0 - dx)) / (2 * h)
    return J


@pytest.mark.parametrize("n,preload", [(0, False), (1, False), (4, False), (4, True), (8, False)],
                         ids=["rigid", "n1", "n4", "n4-preload", "n8"])
def test_A_B_match_finite_difference_jacobian_at_upright(n, preload):
    p = PlantParams(n_modes=n, gravity_preload=preload)
    m = plant_model(p)
    A, B, C, D = m.state_space()
    x0 = np.zeros(m.nx)
    J = _fd_jacobian(lambda x: m.rhs(0.0, x, 0.0), x0)
    np.testing.assert_allclose(A, J, rtol=1e-6, atol=1e-6 * np.abs(A).max())
    Bfd = (m.rhs(0.0, x0, 1e-3) - m.rhs(0.0, x0, -1e-3)) / 2e-3
    np.testing.assert_allclose(B[:, 0], Bfd, rtol=1e-9, atol=1e-12)
    assert not D.any()


@pytest.mark.parametrize("n", [0, 4])
def test_C_matches_finite_difference_of_outputs(n):
    m = plant_model(PlantParams(n_modes=n))
    C = m.state_space()[2]
    y = lambda x: np.array([x[0], *m.tip_angle(x)])  # noqa: E731
    np.testing.assert_allclose(C, _fd_jacobian(y, np.zeros(m.nx)), atol=1e-8)


def test_M0_K0_structure_of_model_md():
    p = PlantParams(n_modes=3)
    m = plant_model(p)
    b = m.beam
    M0, D0, K0 = m.linearize()
    np.testing.assert_allclose(M0[0], [b.I0, -b.I1, *(-b.I3)])
    np.testing.assert_allclose(M0[1], [-b.I1, b.I2, *b.I5])
    np.testing.assert_allclose(M0[2:, 2:], np.eye(3))
    np.testing.assert_allclose(K0[1, 1], -p.g * b.I1)
    np.testing.assert_allclose(K0[1, 2:], -p.g * b.I3)
    np.testing.assert_allclose(np.diag(K0[2:, 2:]), b.frequencies**2)
    np.testing.assert_allclose(np.diag(D0[2:, 2:]), 2 * p.zeta * b.frequencies)
    assert not K0[0].any() and not D0[:2].any()


def test_linear_model_agrees_with_nonlinear_to_second_order():
    p = PlantParams(n_modes=4)
    nl, lin = plant_model(p), linear_plant_model(p)
    rng = np.random.default_rng(1)
    d = rng.standard_normal(nl.nx)
    errs = []
    for eps in (1e-2, 1e-3):
        x = eps * d
        errs.append(np.linalg.norm(nl.rhs(0, x, 0.5) - lin.rhs(0, x, 0.5)))
    assert errs[1] < errs[0] / 50  # quadratic remainder: ratio 100 expected
    np.testing.assert_allclose(lin.jac(0, None, 0), nl.state_space()[0])


def test_rigid_model_is_the_classical_cart_pole():
    """n = 0: point-mass-free cart with a uniform rod: closed-form accelerations."""
    p = PlantParams(n_modes=0)
    m = plant_model(p)
    M, mb, L, g = p.m, p.rhoA * p.L, p.L, p.g
    phi, phid, F = 0.7, -1.3, 2.5
    x = np.array([0.0, phi, 0.3, phid])
    # Lagrange for a rod of mass mb, length L hinged on a cart, angle from vertical CCW
    # (tip moves to -x): [[M+mb, -mb L/2 c], [-mb L/2 c, mb L^2/3]] qdd = [F - mb L/2 s phid^2, mb g L/2 s]
    c, s = np.cos(phi), np.sin(phi)
    Mm = np.array([[M + mb, -mb * L / 2 * c], [-mb * L / 2 * c, mb * L**2 / 3]])
    f = np.array([F - mb * L / 2 * s * phid**2, mb * g * L / 2 * s])
    np.testing.assert_allclose(m.rhs(0, x, F)[2:], np.linalg.solve(Mm, f), rtol=1e-13)
