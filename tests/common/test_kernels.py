"""The compiled C kernels against the readable numpy/scipy specification (two implementations).

Plant (``plant_fmu/native/fp_plant.c``): the right-hand side, outputs and energy of the nonlinear
and the linearised model at random states, inputs and parameter sets (n_modes 0..8, with and
without the gravity preload, either damping law) to 1e-12 relative; the linearised right-hand side
also against a 40-digit solution of ``M0 qdd = f``; the fixed-substep loops and the adaptive
Dormand-Prince loop against the steppers' Python loops. Filter
(``controller_fmu/native/fp_filter.c``): the matrix exponential and the exact discretisation
against scipy's ``expm`` (and a 60-digit one), orders 0, 1 and 2, held and polynomial inputs,
over steps and cutoffs.
"""
import ctypes
import math

import mpmath
import numpy as np
import pytest
import scipy.linalg

from controller_fmu.kernel import FilterKernel, expm
from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
from plant_fmu import kernel as pk
from plant_fmu.dynamics import LinearPlantModel, PlantModel
from plant_fmu.integrators import make_stepper
from plant_fmu.integrators.rk import RK4, DormandPrince54, ExplicitEuler
from plant_fmu.params import PlantParams

RTOL = 1e-12
CASES = [(n, pre) for n in range(9) for pre in (False, True)]
IDS = [f"n{n}{'-preload' if pre else ''}" for n, pre in CASES]


def random_params(rng, n, preload, damping="modal") -> PlantParams:
    """A random but physical parameter set (each value within a factor of about 2 of Table 1),
    under the damping law ``damping``."""
    f = lambda: math.exp(rng.uniform(-0.7, 0.7))  # noqa: E731
    return PlantParams(m=1.0 * f(), L=1.0 * f(), rho=7.8e3 * f(), EA=4.2e8 * f(), EI=875 * f(),
                       zeta=0.001 * f(), g=9.81 * f(), n_modes=n, n_elements=max(n, 12),
                       gravity_preload=preload, damping=damping)


def random_state(rng, m):
    n = m.n
    return rng.standard_normal(m.nx) * np.r_[1, 2, 0.02 * np.ones(n), 1, 3, 5 * np.ones(n)]


def close(a, b, rtol=RTOL):
    """Relative to the largest entry (the scale of the vector), as in the existing tests."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * max(np.abs(b).max(), 1e-300))


@pytest.fixture(params=CASES, ids=IDS)
def models(request):
    """``(nonlinear, linear, rng)`` for three random parameter sets per case, the first two under
    the modal damping law, the third under the Kelvin-Voigt law (fresh models: the cache of
    plant_model is not involved)."""
    n, pre = request.param
    rng = np.random.default_rng(100 * n + pre)
    out = []
    for law in ("modal", "modal", "kelvin-voigt"):
        p = random_params(rng, n, pre, law)
        out.append((PlantModel(p), LinearPlantModel(p)))
    return out, rng


# ---------------------------------------------------------------------- evaluations
def test_rhs_equals_numpy(models):
    pairs, rng = models
    for nl, lin in pairs:
        for _ in range(10):
            x, u = random_state(rng, nl), rng.standard_normal() * 100
            close(nl.rhs(0.0, x, u), nl.rhs_numpy(0.0, x, u))
            close(lin.rhs(0.0, x, u), lin.rhs_numpy(0.0, x, u))


def test_energy_and_tip_equal_numpy(models):
    pairs, rng = models
    for nl, lin in pairs:
        for _ in range(10):
            x = random_state(rng, nl)
            for m in (nl, lin):
                assert m.energy(x) == pytest.approx(m.energy_numpy(x), rel=RTOL, abs=RTOL)
                close(m.tip_angle(x), m.tip_angle_numpy(x))


def test_outputs_equal_numpy(models):
    pairs, rng = models
    for nl, lin in pairs:
        for m in (nl, lin):
            x = random_state(rng, nl)
            out = m.kernel.outputs(x, energy=True)
            nq, n = m.nq, m.n
            phi_o, omega_o = m.tip_angle_numpy(x)
            expect = {"x_o": x[0], "x_dot": x[nq], "phi": x[1], "phi_o": phi_o,
                      "omega_o": omega_o, "energy": m.energy_numpy(x),
                      "tip_deflection": float(m.tip_defl @ x[2:nq]) if n else 0.0}
            for name, value in expect.items():
                assert out[pk.OUT[name]] == pytest.approx(value, rel=RTOL, abs=RTOL), name
            np.testing.assert_array_equal(out[pk.OUT["eta"]:], x[2:nq])


@pytest.mark.parametrize("n", [4, 8])
def test_linear_rhs_against_a_40_digit_solution(n):
    """The C kernel solves ``M0 qdd = f`` by its Schur complement: checked against mpmath's LU
    solution at 40 digits (the product with the state-space ``A``, through the inverse of the
    ill-conditioned M0, is less accurate)."""
    mpmath.mp.dps = 40
    lin = LinearPlantModel(PlantParams(n_modes=n, gravity_preload=True))
    M0, K0, D0 = (mpmath.matrix(a.tolist()) for a in (lin.M0, lin.K0, lin.D0))
    rng = np.random.default_rng(n)
    for _ in range(5):
        x, u = random_state(rng, lin), rng.standard_normal() * 100
        q, qd = mpmath.matrix(x[:lin.nq].tolist()), mpmath.matrix(x[lin.nq:].tolist())
        f = -(K0 * q) - (D0 * qd)
        f[0] += u
        qdd = mpmath.lu_solve(M0, f)
        exact = np.r_[x[lin.nq:], [float(v) for v in qdd]]
        close(lin.rhs(0.0, x, u), exact)


def test_builtin_tableaus_are_the_python_ones():
    """The tableaus compiled into the kernel (for the native FMUs) are bit for bit the Python
    classes' (which the Python steppers pass)."""
    lib = pk.library()
    lib.fp_builtin_tableau.restype = ctypes.POINTER(pk._Tableau)
    for code, cls in ((0, ExplicitEuler), (1, RK4), (2, DormandPrince54)):
        t = lib.fp_builtin_tableau(code).contents
        s = t.stages
        assert s == cls.B.size and bool(t.fsal) == cls.FSAL

        def arr(ptr, size):
            return np.ctypeslib.as_array(ctypes.cast(ptr, ctypes.POINTER(ctypes.c_double)),
                                         (size,)).copy()

        np.testing.assert_array_equal(arr(t.A, s * s).reshape(s, s), cls.A)
        np.testing.assert_array_equal(arr(t.B, s), cls.B)
        np.testing.assert_array_equal(arr(t.C, s), cls.C)
        if cls.E is None:
            assert not t.E
        else:
            np.testing.assert_array_equal(arr(t.E, s), cls.E)
    assert not lib.fp_builtin_tableau(3)


def test_bad_plant_data_are_refused():
    with pytest.raises(ValueError, match="out of range"):
        pk.PlantKernel(n=1, linear=False, preload=False, I0=1.0, I1=math.nan, I2=1.0, g=9.81,
                       I3=[1.0], I5=[1.0], K=[1.0], D=[0.0], Kg=[[0.0]], tip_slope=[1.0],
                       tip_defl=[1.0])


# ---------------------------------------------------------------------- the loops
class _PythonOnly:
    """The plant without its compiled loops: the steppers run their Python loops, on the numpy
    right-hand side (or the compiled one: ``compiled_rhs``)."""

    def __init__(self, m, compiled_rhs=False):
        self.rhs = m.rhs if compiled_rhs else m.rhs_numpy
        self.nq, self.nx = m.nq, m.nx


@pytest.mark.parametrize("method", ["euler", "symplectic_euler", "rk4"])
@pytest.mark.parametrize("linear", [False, True], ids=["nonlinear", "linear"])
def test_fixed_substep_loop_equals_the_python_loop(method, linear):
    """The compiled loop against the stepper's Python loop on the numpy right-hand side, at
    random parameters, with held and polynomial inputs, on and off the substep grid."""
    rng = np.random.default_rng(7)
    for n, pre in ((0, False), (3, True), (8, False)):
        p = random_params(rng, n, pre)
        m = LinearPlantModel(p) if linear else PlantModel(p)
        # h omega_n = 0.2 on the highest mode: inside every method's stability region (Euler's
        # growth is slow there), where round-off is not amplified from substep to substep
        w_max = float(m.beam.frequencies.max()) if n else 1.0
        h = min(1e-4, 0.2 / w_max)
        y0 = m.initial_state(phi=0.3, phi_dot=-0.5)
        y0[2:m.nq] = 1e-3 * rng.standard_normal(n)
        a = make_stepper(method, m, 0.0, y0, h=h)
        b = make_stepper(method, _PythonOnly(m), 0.0, y0, h=h)
        for k, t_end in enumerate((1e-3, 2e-3, 2.65e-3, 3.7e-3)):   # 2.65, 3.7: off the grid
            u = tuple(rng.standard_normal(3) * (50.0, 1e4, 1e6)) if k % 2 else (20.0, 0.0, 0.0)
            for s in (a, b):
                s.set_input(*u, t=a.t)
            assert a.advance(t_end) == b.advance(t_end) == (True, None)
            close(a.y, b.y)
            assert (a.t, a.nfev, a.nsteps) == (b.t, b.nfev, b.nsteps)


def test_fixed_substep_loop_stops_at_a_non_finite_state():
    """Euler far beyond its stability limit overflows: the stepper fails with a message and
    keeps the last finite state, like the Python loop (on the same right-hand side: where a
    state overflows depends on the order of the operations)."""
    m = PlantModel(PlantParams(n_modes=4))
    y0 = m.initial_state(phi=0.1)
    for method in ("euler", "symplectic_euler"):
        a = make_stepper(method, m, 0.0, y0, h=1e-2)
        b = make_stepper(method, _PythonOnly(m, compiled_rhs=True), 0.0, y0, h=1e-2)
        ok_a, msg_a = a.advance(100.0)
        ok_b, msg_b = b.advance(100.0)
        assert not ok_a and not ok_b and "non-finite state" in msg_a
        assert msg_a == msg_b
        assert np.all(np.isfinite(a.y))
        assert a.t == b.t and a.nsteps == b.nsteps and a.nfev == b.nfev


@pytest.mark.parametrize("linear", [False, True], ids=["nonlinear", "linear"])
def test_adaptive_loop_equals_the_python_loop(linear):
    """The compiled Dormand-Prince loop against ``DormandPrince54._step_adaptive``: the same
    accepted and rejected steps (counters), the same states to round-off, with held and
    polynomial inputs, scalar and per-component atol.

    Both run on the compiled right-hand side (tested against numpy above). The step-size
    control reads an error estimate ``sum_i K_i E_i`` that cancels to about 1e-9 of its terms at
    rtol = 1e-7, so round-off in the stages moves the proposed steps by ~1e-7 relative and the
    states by up to a few 1e-12 at n_modes = 8. "Round-off" is therefore measured: a third run,
    the Python loop from the initial state times (1 + 2^-52), gives the spread one ulp causes,
    and C and Python must agree to 1e-12 or to four times that spread. Equal counters show the
    same decisions."""
    rng = np.random.default_rng(11)
    for n, pre, atol in ((0, False, 1e-9), (4, True, 1e-9), (8, False, None)):
        p = random_params(rng, n, pre)
        m = LinearPlantModel(p) if linear else PlantModel(p)
        atol = np.full(m.nx, 1e-8) * np.r_[np.ones(m.nq), 10 * np.ones(m.nq)] if atol is None \
            else atol
        y0 = m.initial_state(phi=0.4, phi_dot=0.2)
        y0[2:m.nq] = 1e-3 * rng.standard_normal(n)
        kw = dict(h=1e-4, rtol=1e-7, atol=atol)
        a = make_stepper("dopri5", m, 0.0, y0, **kw)
        b = make_stepper("dopri5", _PythonOnly(m, compiled_rhs=True), 0.0, y0, **kw)
        ulp = make_stepper("dopri5", _PythonOnly(m, compiled_rhs=True), 0.0,
                           y0 * (1.0 + 2.0 ** -52), **kw)
        # one step (Stepper.step), short enough to be accepted at once (a rejection moves the
        # step by the round-off of the error estimate)
        c1 = make_stepper("dopri5", m, 0.0, y0, **{**kw, "h": 1e-6})
        c2 = make_stepper("dopri5", _PythonOnly(m, compiled_rhs=True), 0.0, y0, **{**kw, "h": 1e-6})
        assert c1.step() == c2.step() == (True, None)
        close(c1.y, c2.y)
        assert (c1.t, c1.nfev, c1.nsteps) == (c2.t, c2.nfev, c2.nsteps) == (1e-6, 7, 1)
        assert c1._h_abs == pytest.approx(c2._h_abs, rel=1e-6)
        for k in range(1, 6):
            u = tuple(rng.standard_normal(3) * (50.0, 1e4, 1e6)) if k % 2 else (5.0, 0.0, 0.0)
            for s in (a, b, ulp):
                s.set_input(*u)
            assert a.advance(k * 1e-3) == b.advance(k * 1e-3) == ulp.advance(k * 1e-3) \
                == (True, None)
            spread = np.abs(ulp.y - b.y).max() / np.abs(b.y).max()
            close(a.y, b.y, rtol=max(RTOL, 4.0 * spread))
            # the same decisions as the Python loop, or as the Python loop started one ulp away
            # (an accept/reject decision sitting on the round-off of the error norm goes either
            # way: then the ulp run shows it)
            counts = [(s.t, s.nfev, s.nsteps, s.nrejected) for s in (a, b, ulp)]
            assert counts[0] in counts[1:]
        assert a.nrejected > 0 or n == 0          # the error control was exercised


def test_adaptive_loop_in_chunks_equals_one_call():
    """The cap on accepted steps leaves a state from which another call continues exactly as
    one longer call does (what a native FMU needs to cap its work per step)."""
    m = PlantModel(PlantParams(n_modes=4))
    kern = m.kernel
    tab = kern.tableau(DormandPrince54.A, DormandPrince54.B, DormandPrince54.C,
                       DormandPrince54.E, True)
    y0 = m.initial_state(phi=0.5)
    f0 = m.rhs(0.0, y0, 3.0)
    opts = dict(rtol=1e-8, atol=1e-10, max_step=math.inf, min_step=0.0)
    u = (3.0, 100.0, -1e4, 0.0)
    whole = kern.dopri_advance(tab, y0, f0, 0.0, 0.01, u, h_abs=1e-4, **opts)
    assert whole[0] == pk.FP_OK and whole[1] == 0.01
    t, y, f, h_abs, calls, steps = 0.0, y0, f0, 1e-4, 0, 0
    while t < 0.01:
        rc, t, y, f, h_abs, _, nsteps, *_ = kern.dopri_advance(tab, y, f, t, 0.01, u, h_abs=h_abs,
                                                               max_steps=3, **opts)
        assert rc in (pk.FP_OK, pk.FP_CAP) and nsteps <= 3
        calls += 1
        steps += nsteps
    assert steps == whole[6] and calls >= steps // 3
    np.testing.assert_array_equal(y, whole[2])


def test_adaptive_loop_reports_a_step_underflow():
    """A minimum step that the error control cannot respect stops the loop with the message of
    the Python loop, at the same time."""
    m = PlantModel(PlantParams(n_modes=4))
    y0 = m.initial_state(phi=0.5)
    a = make_stepper("dopri5", m, 0.0, y0, h=1e-3, rtol=1e-12, atol=1e-14, min_step=1e-4)
    b = make_stepper("dopri5", _PythonOnly(m), 0.0, y0, h=1e-3, rtol=1e-12, atol=1e-14,
                     min_step=1e-4)
    ra, rb = a.advance(0.01), b.advance(0.01)
    assert ra[0] is False and "step size underflow" in ra[1]
    assert ra == rb


# ---------------------------------------------------------------------- the filter
def test_expm_against_scipy_and_50_digits():
    """The kernel's matrix exponential on random matrices (norms 1e-4 to ~100): within 1e-13 of
    the largest entry of a 50-digit exponential (mpmath), and within 1e-11 of scipy's (whose own
    error reaches 5e-12 on these; the kernel's stays below 1e-14)."""
    mpmath.mp.dps = 50
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 5, 8):
        for scale in (1e-4, 0.01, 0.3, 1.0, 3.0, 30.0):
            A = rng.standard_normal((n, n)) * scale
            E, R = expm(A), scipy.linalg.expm(A)
            X = np.array(mpmath.expm(mpmath.matrix(A.tolist())).tolist(), dtype=float)
            np.testing.assert_allclose(E, X, rtol=0, atol=1e-13 * np.abs(X).max())
            np.testing.assert_allclose(E, R, rtol=0, atol=1e-11 * np.abs(X).max())
    np.testing.assert_array_equal(expm(np.zeros((3, 3))), np.eye(3))
    with pytest.raises(ValueError, match="non-finite"):
        expm(np.array([[math.nan]]))


STEPS = [1e-5, 1e-4, 1e-3, 5e-3, 2e-2]
CUTOFFS = [1.0, 30.0, 97.3, 150.0, 1000.0]


@pytest.mark.parametrize("order", [1, 2])
@pytest.mark.parametrize("poly", [False, True], ids=["held", "polynomial"])
def test_filter_discretisation_against_scipy(order, poly):
    """``(Ad, G)`` of the kernel against PDLowPassModel.discretize (held) and
    discretize_polynomial (scipy's expm), each column to 1e-12 of its largest entry."""
    for wc in CUTOFFS:
        for zf in (0.1, 0.5, 2.0):
            c = ControllerParams(filter_order=order, cutoff=wc, filter_damping=zf)
            model, kern = PDLowPassModel(c), FilterKernel(c)
            for h in STEPS:
                Ad, G = kern.discretize(h, poly=poly)
                if poly:
                    Ad_s, G_s = model.discretize_polynomial(h)
                else:
                    Ad_s, Bd_s = model.discretize(h)
                    G_s = Bd_s[:, None]
                for got, ref in ((Ad, Ad_s), (G, G_s)):
                    scale = np.abs(np.hstack([Ad_s, G_s])).max()
                    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * scale,
                                               err_msg=f"wc={wc} zf={zf} h={h}")


def test_filter_discretisation_against_60_digits():
    """At the steps and cutoffs where the scaling and squaring works hardest (wc h up to 20, 13
    squarings), the kernel's exponential agrees with a 60-digit one to 1e-12 of each column's
    scale (the worst seen: 7e-13 at wc h = 20, zf = 2, where scipy's is 1.6e-13)."""
    mpmath.mp.dps = 60
    for wc, zf, h in ((1000.0, 0.1, 0.02), (1000.0, 2.0, 0.02), (150.0, 0.1, 0.02),
                      (97.3, 0.1, 1e-3)):
        aug = mpmath.zeros(5, 5)
        aug[0, 1], aug[1, 0], aug[1, 1], aug[1, 2] = h, -(wc * wc) * h, (-2 * zf * wc) * h, \
            (wc * wc) * h
        aug[2, 3] = aug[3, 4] = h
        E = np.array(mpmath.expm(aug).tolist(), dtype=float)
        Ad, G = FilterKernel(ControllerParams(cutoff=wc, filter_damping=zf)).discretize(h)
        exact = E[:2, :5]
        got = np.hstack([Ad, G])
        scale = np.abs(exact).max(axis=0)
        assert np.all(np.abs(got - exact) <= 1e-12 * scale), (wc, zf, h)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_filter_step_against_numpy(order):
    """One step of the kernel (state, saturated force) against ``Ad x + G e`` with scipy's
    matrices, held (e1 = e2 = 0) and polynomial inputs."""
    rng = np.random.default_rng(order)
    for wc in CUTOFFS:
        c = ControllerParams(filter_order=order, cutoff=wc, filter_damping=0.3, force_limit=40.0)
        model, kern = PDLowPassModel(c), FilterKernel(c)
        for h in STEPS:
            prep = kern.prepared(h)
            Ad_s, G_s = model.discretize_polynomial(h)
            x = rng.standard_normal(order) * 0.1
            kern.x[0:order] = list(x)
            y = rng.standard_normal(9) * np.repeat([1.0, 100.0, 1e4], 3)
            y[3:] *= rng.integers(0, 2)                        # held or polynomial
            e = [model.error_signal(y[3 * k:3 * k + 3]) for k in range(3)]
            F = kern.step(prep, *e)
            if order == 0:
                assert F == model.output((), y[:3])
                continue
            x_new = Ad_s @ x + G_s @ e
            scale = np.abs(Ad_s).max() * np.abs(x).max() + np.abs(G_s).max(axis=0) @ np.abs(e)
            np.testing.assert_allclose(list(kern.x)[:order], x_new, rtol=0, atol=1e-12 * scale)
            assert F == min(max(-kern.x[0], -40.0), 40.0)


def test_filter_step_refuses_a_non_finite_result():
    kern = FilterKernel(ControllerParams(filter_order=2))
    prep = kern.prepared(1e-3)
    assert kern.step(prep, 1e300, 0.0, 0.0) is not None
    before = list(kern.x)
    assert kern.step(prep, 1e308, 0.0, 0.0) is None        # the state would overflow
    assert kern.step(prep, math.inf) is None
    assert kern.step(prep, 0.0, math.nan) is None
    assert list(kern.x) == before


def test_one_kernel_serves_several_threads():
    """One kernel (and its buffers) serves every user of a cached model, and ctypes releases the
    GIL during a call: threads stepping FMU instances of one plant must not mix their states."""
    import threading

    m = PlantModel(PlantParams(n_modes=4))
    rng = np.random.default_rng(5)
    xs = [random_state(rng, m) for _ in range(4)]
    expected = [m.rhs_numpy(0.0, x, float(i)) for i, x in enumerate(xs)]
    bad = []

    def worker(i):
        for _ in range(3000):
            r = m.rhs(0.0, xs[i], float(i))
            if not np.allclose(r, expected[i], rtol=1e-12, atol=1e-12 * np.abs(expected[i]).max()):
                bad.append(i)
                return

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not bad
