"""The exact rung's integrator, Radau IIA (plant_fmu.exact.RadauIIA and the C kernel's
fp_radau_*): its constants against the method's definition, its stability function on a linear
oscillator against the (2, 3) Pade approximant of exp (order 5, L-stable), its order on the
nonlinear beam, the C kernel against the numpy specification, and the closed loop (the filter in
the same stages) against a second method (generalized alpha at a fine step)."""
import math

import numpy as np
import pytest

from controller_fmu.pd_lowpass import PDLowPassModel
from orchestration.scene.schema import load_scene
from orchestration.studies.exact_loop import ExactLoop
from plant_fmu import exact as ex
from plant_fmu.exact import ExactPlant, RadauIIA, StageForce
from plant_fmu.kernel import ExactKernel
from plant_fmu.params import PlantParams


# ---------------------------------------------------------------------- the method's data
def test_constants_are_radau_iia():
    """The nodes are the roots of the Radau polynomial (c3 = 1), ``A`` satisfies the
    collocation conditions sum_j a_ij c_j^(k-1) = c_i^k / k (k = 1..3), the last row is the
    weights (stiffly accurate) and ``T`` block-diagonalises ``A^-1`` with the eigenvalues
    ``gamma`` and ``mu``; ``RADAU_DEND`` is the derivative at 1 of the quadratic through the
    stages."""
    c, A = ex.RADAU_C, ex.RADAU_A
    # Radau right polynomial: d^2/dx^2 [x^2 (x - 1)^3] vanishes at c1, c2; c3 = 1
    poly = np.polynomial.Polynomial([0, 0, 1]) * np.polynomial.Polynomial([-1, 1]) ** 3
    assert np.allclose(poly.deriv(2)(c[:2]), 0.0, atol=1e-12) and c[2] == 1.0
    for k in (1, 2, 3):
        assert np.allclose(A @ c ** (k - 1), c ** k / k, rtol=0, atol=1e-15)
    b = np.linalg.solve(np.vander(c, 3, increasing=True).T, 1.0 / np.arange(1, 4))
    assert np.allclose(A[2], b, atol=1e-15)
    L = ex.RADAU_TI @ np.linalg.inv(A) @ ex.RADAU_T
    mu = ex.RADAU_MU
    block = np.array([[ex.RADAU_GAMMA, 0, 0], [0, mu.real, -mu.imag], [0, mu.imag, mu.real]])
    assert np.allclose(L, block, atol=1e-12)
    assert np.allclose(ex.RADAU_TI @ ex.RADAU_T, np.eye(3), atol=1e-14)
    W = np.array([[1.0, 2.0], [-3.0, 0.5], [0.25, 4.0]])        # two components
    coef = np.polyfit(c, W, 2)
    assert np.allclose(ex.RADAU_DEND @ W, 2 * coef[0] + coef[1], atol=1e-12)


class _Oscillator:
    """``m qdd + c qd + k q = u``: a BeamSystem's interface for RadauIIA (one coordinate)."""

    def __init__(self, m, c, k):
        self.M = np.array([[m]])
        self.c, self.k = c, k
        self.nq = 1

    def forces(self, q, qd, u=0.0, tangent=True):
        f = np.array([u - self.c * qd[0] - self.k * q[0]])
        if not tangent:
            return f, None, None
        return f, np.array([[self.k]]), np.array([[self.c]])


def _pade23(z):
    """The stability function of three-stage Radau IIA, the (2, 3) Pade approximant of exp."""
    return (1 + 2 * z / 5 + z * z / 20) / (1 - 3 * z / 5 + 3 * z * z / 20 - z ** 3 / 60)


@pytest.mark.parametrize("wh", (0.05, 0.4, 1.5, 8.0, 300.0))
def test_one_step_of_an_oscillator_is_the_pade_approximant(wh):
    """On ``q'' + w^2 q = 0`` a step's amplification matrix has the eigenvalues R(+-i w h) of the
    (2, 3) Pade approximant: |R| < 1 (L-stable: -> 0 as w h grows) and the phase error
    ``arg R(i w h) - w h`` of order ``(w h)^6``."""
    w, h = 1.0, wh
    osc = _Oscillator(1.0, 0.0, w * w)
    rad = RadauIIA(osc, h, tol=1e-14)
    G = np.zeros((2, 2))
    for j, (q, v) in enumerate(((1.0, 0.0), (0.0, w))):
        st = rad.start(np.array([q]), np.array([v]), 0.0)
        st = rad.step(st, 0.0)
        G[:, j] = st[0][0], st[1][0] / w
    lam = np.linalg.eigvals(G)
    R = _pade23(1j * w * h)
    assert np.allclose(sorted(lam, key=lambda z: z.imag), sorted([R, R.conjugate()],
                                                                 key=lambda z: z.imag),
                       rtol=1e-9, atol=1e-12)
    assert abs(R) < 1.0
    if wh < 0.5:       # the phase error is O((w h)^7), the amplitude's O((w h)^6)
        half = _pade23(0.5j * w * h)
        ratio = abs(np.angle(R) - wh) / abs(np.angle(half) - 0.5 * wh)
        assert 2 ** 6.8 < ratio < 2 ** 7.2
        assert 2 ** 5.8 < (1 - abs(R)) / (1 - abs(half)) < 2 ** 6.2


def _beam_open_loop(h, t_end=0.2, method="radau", ne=2):
    """The tip angle after ``t_end`` of a damped 2-element beam driven by a smooth force."""
    p = PlantParams().replace(n_elements=ne, n_modes=1, zeta=0.05, damping="kelvin-voigt")
    pl = ExactPlant(p)
    x0 = pl.initial_state(phi=0.3, phi_dot=0.5)
    rad = RadauIIA(pl.system, h, tol=1e-13)
    st = rad.start(x0[:pl.nq], x0[pl.nq:], 0.0)
    for k in range(int(round(t_end / h))):
        st = rad.step(st, StageForce.polynomial(20 * math.sin(8 * k * h), 160 * math.cos(8 * k * h),
                                                -1280 * math.sin(8 * k * h), h))
    return pl.tip_angle(np.concatenate(st[:2]))[0]


def test_order_on_the_nonlinear_beam():
    """On a smooth, damped motion of the nonlinear beam the tip angle converges at the method's
    stage order, 3, not its classical 5: the stiff axial modes (8000 rad/s, h omega = 4 to 16
    here), left to L-stability, reduce the order of any Runge-Kutta method to its stage order
    (order reduction, Hairer & Wanner II, IV.15); the non-stiff modes' phase keeps order 5 (the
    oscillator above). Measured against the step quartered twice more; the error at 1 ms is
    already below 1e-8 rad."""
    hs = (2e-3, 1e-3, 5e-4)
    ref = _beam_open_loop(1.25e-4)
    err = [abs(_beam_open_loop(h) - ref) for h in hs]
    orders = [math.log2(a / b) for a, b in zip(err, err[1:])]
    assert 2.8 <= min(orders) and max(orders) <= 3.5, (err, orders)
    assert err[1] < 1e-8


# ---------------------------------------------------------------------- C against numpy
@pytest.mark.parametrize("ne", (1, 3, 8))
def test_the_kernel_is_the_specification_held_and_closed_loop(ne):
    """fp_radau_step against RadauIIA.step, with a held force and with a closed-loop stage law
    (a dense Q: the force row outside the band for ne > 1), 200 steps: to round-off."""
    pl = ExactPlant(PlantParams().replace(n_elements=ne, n_modes=1, zeta=0.001,
                                        damping="kelvin-voigt"))
    h = 1e-3
    x0 = pl.initial_state(phi=0.4, phi_dot=1.0, x_dot=-0.2)
    law = StageForce((3.0, 2.0, 1.0), ((0.3, 0.05, 0.0), (0.02, 0.3, 0.05), (0.0, 0.02, 0.3)),
                     1.0, 500.0, 5.0)
    for force in (7.5, law):
        a, b = ExactKernel(pl, h, method="radau"), RadauIIA(pl.system, h)
        sa = a.start(x0[:pl.nq], x0[pl.nq:], force)
        sb = b.start(x0[:pl.nq], x0[pl.nq:], force)
        for _ in range(200):
            sa, sb = a.step(sa, force), b.step(sb, force)
        for u, v in zip(sa[:2], sb[:2]):
            assert np.max(np.abs(u - v)) <= 1e-10 * max(1.0, np.max(np.abs(v)))
        assert np.allclose(a.stage_error, b.stage_error, rtol=1e-9, atol=1e-9)
        # the same iteration, but its stopping tests compare round-off-level corrections: a
        # step may take one iteration more on one side
        assert abs(a.newton_iterations - b.newton_iterations) <= 3


def test_the_closed_loop_is_a_second_methods():
    """The filtered scene's monolithic exact loop by Radau IIA at 1 ms (the filter in the stages)
    against generalized alpha at 25 us (the filter by the trapezoidal rule), Kelvin-Voigt damping
    (both converge at their order): the same tip angle to 5e-7 rad over 0.5 s once the start's
    transient has died out (the undeformed start excites the mesh's high modes, which Radau at
    1 ms damps at once and generalized alpha at 25 us resolves until the Kelvin-Voigt damping,
    0.1 % times omega_j / omega_1, takes them: a few ms at 3000 rad/s); 2e-6 from the start."""
    sc = load_scene("flexible_pd_lowpass", {"plant.fidelity": "exact", "plant.n_elements": 6,
                                            "fidelity.max_modes": 6, "initial.phi": 0.3,
                                            "plant.damping": "kelvin-voigt"})
    pl = ExactPlant(sc.plant.params)
    x0 = pl.initial_state(phi=0.3)
    ctrl = PDLowPassModel(sc.controller)
    rad = ExactLoop(pl, ctrl, 1e-3, kernel=True, method="radau").run(x0, 0.5, 2e-3)[1]
    ga = ExactLoop(pl, ctrl, 2.5e-5, kernel=True, method="genalpha").run(x0, 0.5, 2e-3)[1]
    assert np.max(np.abs(rad - ga)) < 2e-6
    assert np.max(np.abs(rad - ga)[10:]) < 5e-7               # from 20 ms on
    assert np.ptp(rad) > 0.3


def test_a_step_that_does_not_converge_is_taken_in_halves():
    """A Radau step of the closed loop whose Newton iteration fails is taken as two halves (and
    so on, RADAU_SPLIT_MAX deep): the numpy loop and the kernel's agree, and the run is close to
    the same loop at the halved step."""
    sc = load_scene("flexible_pd_lowpass", {"plant.fidelity": "exact", "plant.n_elements": 4,
                                            "fidelity.max_modes": 4,
                                            "plant.damping": "kelvin-voigt"})
    pl = ExactPlant(sc.plant.params)
    x0 = pl.initial_state(phi=math.pi / 6)
    ctrl = PDLowPassModel(sc.controller)
    big = ExactLoop(pl, ctrl, 4e-3, kernel=True)
    a = big.run(x0, 0.2, 4e-3)[1]
    assert len(big._radau) > 1                            # some step was halved
    b = ExactLoop(pl, ctrl, 4e-3, kernel=False).run(x0, 0.2, 4e-3)[1]
    assert np.max(np.abs(a - b)) < 1e-9
    fine = ExactLoop(pl, ctrl, 1e-3, kernel=True).run(x0, 0.2, 4e-3)[1]
    assert np.max(np.abs(a - fine)) < 1e-3
