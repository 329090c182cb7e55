"""Cantilever finite elements against the analytic Euler-Bernoulli beam, and the invariants."""
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from plant_fmu.beam import (analytic_frequencies, analytic_mode_shape, beam_model,
                            fe_mass_matrix_check)
from plant_fmu.params import PlantParams

P = PlantParams(n_modes=8)


def test_first_four_frequencies_match_analytic_at_default_mesh():
    fe = beam_model(P).frequencies[:4]
    exact = analytic_frequencies(P, 4)
    np.testing.assert_allclose(fe, exact, rtol=1e-3)
    # and the acceptance values of docs/model.md section 6
    np.testing.assert_allclose(fe, [26.33, 165.02, 462.07, 905.47], rtol=1e-3)


def test_analytic_frequencies_use_the_classical_roots():
    # beta_1 L = 1.875104, beta_2 L = 4.694091 (clamped-free beam, any textbook)
    bl = np.sqrt(analytic_frequencies(P, 2) / np.sqrt(P.EI / (P.rhoA * P.L**4)))
    np.testing.assert_allclose(bl, [1.8751040687, 4.6940911330], rtol=1e-9)


@pytest.mark.parametrize("mode", [1, 2, 3, 4])
def test_mesh_convergence_is_fourth_order(mode):
    """Hermite cubics with consistent mass: frequency error ~ h^4 (here measured, slope >= 3.8)."""
    exact = analytic_frequencies(P, mode)[-1]
    meshes = np.array([8, 16, 32])
    err = [abs(beam_model(P.replace(n_elements=int(ne), n_modes=mode)).frequencies[-1] - exact)
           / exact for ne in meshes]
    slopes = -np.diff(np.log(err)) / np.diff(np.log(meshes))
    assert np.all(slopes > 3.8), (err, slopes)
    assert err[-1] < err[0]


def test_rigid_invariants_closed_form():
    b = beam_model(P)
    rA, L = P.rhoA, P.L
    assert b.I0 == pytest.approx(P.m + rA * L, rel=1e-15)
    assert b.I1 == pytest.approx(rA * L**2 / 2, rel=1e-15)
    assert b.I2 == pytest.approx(rA * L**3 / 3, rel=1e-15)
    assert rA == pytest.approx(15.6, rel=1e-12)  # docs/model.md: rho * EA / E


def test_I4_is_identity_for_mass_normalised_modes():
    np.testing.assert_allclose(fe_mass_matrix_check(P), np.eye(P.n_modes), atol=1e-12)


@pytest.mark.parametrize("j", [1, 2, 3, 4])
def test_I3_I5_tip_values_match_analytic_mode_shapes(j):
    """The FE integrals of the modes against quadratures of the analytic shapes."""
    b = beam_model(P)
    shape = analytic_mode_shape(P, j)
    norm = scipy.integrate.quad(lambda s: P.rhoA * shape(s) ** 2, 0, P.L, limit=200)[0]
    assert norm == pytest.approx(1.0, rel=1e-10)  # the analytic shape is mass-normalised
    I3 = scipy.integrate.quad(lambda s: P.rhoA * shape(s), 0, P.L, limit=200)[0]
    I5 = scipy.integrate.quad(lambda s: P.rhoA * s * shape(s), 0, P.L, limit=200)[0]
    assert b.I3[j - 1] == pytest.approx(I3, rel=2e-4)
    assert b.I5[j - 1] == pytest.approx(I5, rel=2e-4)
    assert b.tip_deflection[j - 1] == pytest.approx(float(shape(P.L)), rel=2e-4)
    h = 1e-6
    slope = (shape(P.L) - shape(P.L - h)) / h
    assert b.tip_slope[j - 1] == pytest.approx(float(slope), rel=1e-3)


def test_I3_first_mode_classical_value():
    # For a mass-normalised cantilever, int W1 ds / sqrt(L int W1^2 ds) = 0.7830 (modal participation)
    b = beam_model(P)
    assert b.I3[0] / np.sqrt(P.rhoA * P.L) == pytest.approx(0.7830, abs=1e-4)


def test_gravity_preload_lowers_first_mode_to_26_04():
    from plant_fmu.dynamics import plant_model
    pp = P.replace(gravity_preload=True, n_modes=4)
    K0 = plant_model(pp).linearize()[2]
    w = np.sqrt(np.linalg.eigvalsh(K0[2:, 2:]))
    assert w[0] == pytest.approx(26.04, abs=0.01)
    # Kg = int rhoA g (L - s) N'^T N' ds: symmetric, positive definite
    Kg = beam_model(pp).Kg
    np.testing.assert_allclose(Kg, Kg.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(Kg) > 0)
    assert not beam_model(P).Kg.any()  # off by default


def test_preload_matches_quadrature_of_analytic_first_mode():
    pp = P.replace(gravity_preload=True, n_modes=1)
    shape = analytic_mode_shape(pp, 1)
    h = 1e-6
    d = lambda s: (shape(s + h) - shape(s - h)) / (2 * h)  # noqa: E731
    kg = scipy.integrate.quad(lambda s: pp.rhoA * pp.g * (pp.L - s) * d(s) ** 2, h, pp.L - h,
                              limit=200)[0]
    assert beam_model(pp).Kg[0, 0] == pytest.approx(kg, rel=1e-4)


def test_fe_eigenproblem_against_40_digits():
    """The finite-element eigenvalues (numpy, reduced by the Cholesky factor of K) against a
    40-digit solution of the same K v = lam M v, and the modes M-orthonormal: the low modes to
    1e-10 at 24 elements (scipy's eigh(K, M) is off by 1.5e-9 there)."""
    import mpmath

    from plant_fmu import beam

    mpmath.mp.dps = 40
    ne = 24
    le = 1.0 / ne
    K = np.zeros((2 * ne + 2, 2 * ne + 2))
    M = np.zeros_like(K)
    ke, me = beam._element_matrices(le, 875.0, 15.6)
    for e in range(ne):
        K[2 * e:2 * e + 4, 2 * e:2 * e + 4] += ke
        M[2 * e:2 * e + 4, 2 * e:2 * e + 4] += me
    K, M = K[2:, 2:], M[2:, 2:]
    lam, vec = beam._eigh_generalized(K, M)
    Li = mpmath.cholesky(mpmath.matrix(M.tolist())) ** -1
    exact = np.sort([float(v) for v in mpmath.eigsy(Li * mpmath.matrix(K.tolist()) * Li.T,
                                                     eigvals_only=True)])
    np.testing.assert_allclose(lam[:ne], exact[:ne], rtol=1e-10)
    V = vec[:, :ne]                                   # the modes a model can keep
    np.testing.assert_allclose(V.T @ M @ V, np.eye(ne), atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_scaled_unit_modes_equal_the_modes_solved_for_the_beam(seed):
    """The modal data are the unit beam's (L = EI = rhoA = 1), scaled (beam.Scales): the native
    FMUs carry the unit tables and scale them. Against the FE eigenproblem assembled and solved
    for the beam itself, at random L, EI, rhoA, g and meshes."""
    from plant_fmu.beam import _eigh_generalized, _element_matrices, _hermite_dN

    rng = np.random.default_rng(seed)
    f = lambda: float(np.exp(rng.uniform(-1.5, 1.5)))  # noqa: E731
    ne = int(rng.integers(3, 40))
    p = P.replace(L=f(), EI=875 * f(), rho=7.8e3 * f(), g=9.81 * f(), n_elements=ne,
                  n_modes=min(ne, 6), gravity_preload=True)
    b = beam_model(p)
    L, EI, rhoA, n = p.L, p.EI, p.rhoA, p.n_modes
    le = L / ne
    K = np.zeros((2 * ne + 2,) * 2)
    M = np.zeros_like(K)
    ke, me = _element_matrices(le, EI, rhoA)
    for e in range(ne):
        K[2 * e:2 * e + 4, 2 * e:2 * e + 4] += ke
        M[2 * e:2 * e + 4, 2 * e:2 * e + 4] += me
    lam, vec = _eigh_generalized(K[2:, 2:], M[2:, 2:])
    modes = np.zeros((2 * ne + 2, lam.size))
    modes[2:] = vec
    modes *= np.where(modes[-2] < 0, -1.0, 1.0)
    phi = modes[:, :n]
    np.testing.assert_allclose(b.frequencies ** 2, lam[:n], rtol=1e-10)
    np.testing.assert_allclose(b.tip_deflection, phi[-2], rtol=1e-8)
    np.testing.assert_allclose(b.tip_slope, phi[-1], rtol=1e-8)
    # invariants of the directly solved modes, by Gauss quadrature of the Hermite interpolants
    gx, gw = np.polynomial.legendre.leggauss(4)
    xi, gw = 0.5 * (gx + 1.0), 0.5 * gw
    H = np.stack([1 - 3 * xi**2 + 2 * xi**3, le * (xi - 2 * xi**2 + xi**3), 3 * xi**2 - 2 * xi**3,
                  le * (-xi**2 + xi**3)], axis=-1)
    dH = _hermite_dN(xi, le)
    I3, I5, Kg = np.zeros(n), np.zeros(n), np.zeros((n, n))
    for e in range(ne):
        ve = phi[2 * e:2 * e + 4]
        s = e * le + le * xi
        I3 += rhoA * le * (gw @ (H @ ve))
        I5 += rhoA * le * ((gw * s) @ (H @ ve))
        dw = dH @ ve
        Kg += (dw * (gw * rhoA * p.g * (L - s) * le)[:, None]).T @ dw
    scale = np.abs(I3).max()
    np.testing.assert_allclose(b.I3, I3, rtol=1e-8, atol=1e-10 * scale)
    np.testing.assert_allclose(b.I5, I5, rtol=1e-8, atol=1e-10 * scale * L)
    np.testing.assert_allclose(b.Kg, Kg, rtol=1e-8, atol=1e-10 * np.abs(Kg).max())


def _damped_cantilever(p: PlantParams, beta: float):
    """The clamped finite-element cantilever of ``p`` (every dof of the mesh), undamped and with
    the material (Kelvin-Voigt) damping ``C = beta K``: ``(omega_j, damped eigenvalues)`` in
    ascending frequency, from the eigenvalues of the first-order systems."""
    from plant_fmu.beam import _element_matrices

    ne = p.n_elements
    nd = 2 * (ne + 1)
    K, M = np.zeros((nd, nd)), np.zeros((nd, nd))
    ke, me = _element_matrices(p.L / ne, p.EI, p.rhoA)
    for e in range(ne):
        K[2 * e:2 * e + 4, 2 * e:2 * e + 4] += ke
        M[2 * e:2 * e + 4, 2 * e:2 * e + 4] += me
    K, M = K[2:, 2:], M[2:, 2:]                    # clamped at s = 0
    n = K.shape[0]

    def eig(C):
        A = np.block([[np.zeros((n, n)), np.eye(n)],
                      [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
        lam = np.linalg.eigvals(A)
        lam = lam[lam.imag > 0]
        return lam[np.argsort(np.abs(lam))]

    # the undamped frequencies from M v = mu K v (scipy's LAPACK, reduced by K's Cholesky
    # factor): the low modes are its largest mu, to a relative accuracy of ~eps whatever the
    # mesh; the first-order system's eigenvalues resolve them only to ~eps omega_max^2 /
    # omega_j^2 (1.2e-10 on mode 1 with some CPUs' LAPACK kernels), enough for the damping
    # ratios (1e-6) but not for the frequencies (1e-10)
    mu = scipy.linalg.eigh(M, K, eigvals_only=True)[::-1]
    return 1.0 / np.sqrt(mu), eig(beta * K)


@pytest.mark.parametrize("preload", [False, True])
def test_kelvin_voigt_damps_mode_j_by_zeta_omega_j_over_omega_1(preload):
    """docs/model.md section 7: the material damping ``beta EI w''''_t``,
    ``beta = 2 zeta / omega_1``, gives mode ``j`` the ratio ``zeta omega_j / omega_1``: the eigenvalues of the finite-element
    cantilever with ``C = beta K`` against the undamped ones, and the model's ``D`` (its ratios
    ``D_jj / (2 omega_j)``) the same; the modal law gives every mode ``zeta``. The self-weight's
    geometric stiffness is not damped: the preload leaves ``D`` as it is."""
    zeta = 0.002
    p = PlantParams(n_modes=6, n_elements=16, zeta=zeta, damping="kelvin-voigt",
                    gravity_preload=preload)
    omega, lam = _damped_cantilever(p, 2 * zeta / _damped_cantilever(p, 0.0)[0][0])
    ratio = -lam.real / np.abs(lam)                          # damping ratio of each mode
    n = p.n_modes
    np.testing.assert_allclose(ratio[:n], zeta * omega[:n] / omega[0], rtol=1e-6)
    b = beam_model(p)
    np.testing.assert_allclose(b.frequencies, omega[:n], rtol=1e-10)
    np.testing.assert_allclose(np.diag(b.D) / (2 * b.frequencies), ratio[:n], rtol=1e-6)
    assert np.count_nonzero(b.D - np.diag(np.diag(b.D))) == 0
    assert np.array_equal(b.D, beam_model(p.replace(gravity_preload=not preload)).D)
    modal = beam_model(p.replace(damping="modal"))
    np.testing.assert_allclose(np.diag(modal.D) / (2 * modal.frequencies), zeta, rtol=1e-14)
    assert ratio[1] / zeta > 6 and ratio[n - 1] / zeta > 80    # the laws differ above mode 1
