"""The exact Jacobians and output time derivatives of the compiled kernels (issue 24).

Plant (``fp_jacobian``, ``fp_jvp``, ``fp_output_jacobian``, ``fp_output_derivatives``):
- against the numpy specification (``jacobian_numpy``, ``output_jacobian_numpy``,
  ``output_derivatives_numpy``; ``tests/plant/test_lagrange.py`` checks those against sympy);
- against central differences of the kernel's own right-hand side and outputs;
- the output derivatives against central differences in time along an accurate trajectory
  driven by a polynomial force (scipy's DOP853 at rtol 1e-13 on the kernel's rhs), and the
  energy's first derivative (the kernel: the power balance) against the gradient of the energy
  times dx/dt.
States: random, deformed (tip slopes up to ~1 rad), moving (mode rates ~ their frequency times
their amplitude), tilted (|phi| up to 1.2 rad), n_modes 0..8, nonlinear with and without the
gravity preload and linear.

Tolerances of a central difference are derived from its step: the truncation error of the step
h is estimated from the same difference at 2h (Richardson: for a second-order difference
D(2h) - D(h) ~ 3 (D(h) - exact), for the fourth-order one ~ 15 (D(h) - exact)), the rounding
error is eps times the magnitude of the terms summed, divided by h; the check allows 10 times
their sum. A wrong derivative misses by O(1) of the entry, far outside.

Controller (``fpf_linearize``, ``fpf_output_derivatives``): against the state space of
``PDLowPassModel`` (``pd_lowpass.py``) and python-control's realisation of the same transfer
function, and the output derivatives against the exact continuous response (the filter's matrix
exponential driven by a polynomial error signal), differentiated by central differences.
"""
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from plant_fmu.dynamics import linear_plant_model, plant_model
from plant_fmu.kernel import OUT
from plant_fmu.params import PlantParams

EPS = np.finfo(float).eps
VARIANTS = [("nonlinear", False), ("nonlinear", True), ("linear", False), ("linear", True)]


def _model(n, fidelity, preload):
    p = PlantParams(n_modes=n, gravity_preload=preload)
    return linear_plant_model(p) if fidelity == "linear" else plant_model(p)


def _random_states(m, count, seed):
    """Deformed, moving, tilted states: |phi| <= 1.2, tip deflections up to ~0.1 L in all,
    mode rates of the order of their frequency times their amplitude."""
    rng = np.random.default_rng(seed)
    n, nq = m.n, m.nq
    nl = m._nl if hasattr(m, "_nl") else m
    omega = np.sqrt(nl.Kdiag)
    for _ in range(count):
        x = np.zeros(m.nx)
        x[0] = rng.uniform(-1, 1)
        x[1] = rng.uniform(-1.2, 1.2)
        if n:
            x[2:nq] = 0.1 * rng.standard_normal(n) / np.sqrt(n) / np.abs(nl.tip_defl)
            x[nq + 2:] = omega * x[2:nq] * rng.standard_normal(n)
        x[nq] = rng.standard_normal()
        x[nq + 1] = 3.0 * rng.standard_normal()
        yield x, 50.0 * rng.standard_normal()


def _central(fun, x, k, h):
    e = np.zeros_like(x)
    e[k] = h
    return (fun(x + e) - fun(x - e)) / (2.0 * h)


def _check_fd(exact, fun, x, terms, label):
    """Each column k of ``exact`` (d fun / d x_k) against central differences with the step
    h_k = eps^(1/3) max(1, |x_k|); ``terms[i]``: the magnitude of what row i sums (rounding)."""
    for k in range(x.size):
        h = EPS ** (1 / 3) * max(1.0, abs(x[k]))
        d1, d2 = _central(fun, x, k, h), _central(fun, x, k, 2 * h)
        tol = 10.0 * (np.abs(d2 - d1) / 3.0 + 64 * EPS * terms / h) + 1e-300
        err = np.abs(exact[:, k] - d1)
        bad = np.nonzero(err > tol)[0]
        assert bad.size == 0, (f"{label}: column {k}, rows {bad}: exact {exact[bad, k]}, "
                               f"differences {d1[bad]}, tolerance {tol[bad]}")


@pytest.mark.parametrize("fidelity,preload", VARIANTS)
@pytest.mark.parametrize("n", range(9))
def test_jacobian_against_numpy_and_differences(n, fidelity, preload):
    m = _model(n, fidelity, preload)
    k = m.kernel
    for x, u in _random_states(m, count=4, seed=100 + n):
        J, b = k.jacobian(x, u)
        J_np, b_np = m.jacobian_numpy(x, u)
        scale = np.abs(J_np).max(axis=1, keepdims=True) + np.abs(b_np)[:, None]
        # two ways of solving M (the kernel: Schur complement; numpy: LU): they agree to
        # ~cond(M) eps
        rtol = 64 * EPS * np.linalg.cond(m.mass_matrix(x[:m.nq]))
        assert np.all(np.abs(J - J_np) <= rtol * scale), np.abs(J - J_np).max()
        assert np.all(np.abs(b - b_np) <= rtol * scale[:, 0])
        # central differences of the kernel's rhs in the state and the force
        f = k.rhs(x, u)
        terms = np.abs(f) + np.abs(J_np) @ np.abs(x) + np.abs(b_np) * abs(u)
        _check_fd(J, lambda z, u=u: k.rhs(z, u), x, terms, f"J ({fidelity}, preload {preload})")
        _check_fd(b[:, None], lambda v, x=x: k.rhs(x, v[0]), np.array([u]), terms, "b")
        # the product without forming J
        v = np.random.default_rng(n).standard_normal(m.nx) * np.maximum(np.abs(x), 1.0)
        jv = k.jvp(x, u, v, 3.0)
        expect = J_np @ v + 3.0 * b_np
        assert np.all(np.abs(jv - expect) <= rtol * (np.abs(J_np) @ np.abs(v) + 3 * np.abs(b_np)))


def test_jacobian_is_constant_for_the_linear_model():
    m = _model(4, "linear", True)
    J0, b0 = m.kernel.jacobian(np.zeros(m.nx), 0.0)
    A, B = m.A, m.B[:, 0]
    np.testing.assert_allclose(J0, A, rtol=0, atol=1e-10 * np.abs(A).max())
    np.testing.assert_allclose(b0, B, rtol=0, atol=1e-10 * np.abs(B).max())
    for x, u in _random_states(m, 3, 5):
        J, b = m.kernel.jacobian(x, u)
        assert np.array_equal(J, J0) and np.array_equal(b, b0)


@pytest.mark.parametrize("fidelity,preload", VARIANTS)
@pytest.mark.parametrize("n", [0, 1, 2, 5, 8])
def test_output_jacobian_against_numpy_and_differences(n, fidelity, preload):
    m = _model(n, fidelity, preload)
    k = m.kernel
    for x, _ in _random_states(m, count=4, seed=200 + n):
        C = k.output_jacobian(x)
        C_np = m.output_jacobian_numpy(x)
        assert C.shape == (OUT["eta"] + n, m.nx)
        scale = np.abs(C_np).max(axis=1, keepdims=True)
        assert np.all(np.abs(C - C_np) <= 1e-14 * scale + 1e-300)
        y = k.outputs(x)
        terms = np.abs(y) + np.abs(C_np) @ np.abs(x)
        _check_fd(C, k.outputs, x, terms, f"C ({fidelity}, preload {preload})")


@pytest.mark.parametrize("fidelity,preload", VARIANTS)
@pytest.mark.parametrize("n", [0, 1, 3, 8])
def test_output_derivatives_against_numpy(n, fidelity, preload):
    m = _model(n, fidelity, preload)
    for x, u in _random_states(m, count=5, seed=300 + n):
        du = 1e3 * math.sin(u)
        d1, d2 = m.kernel.output_derivatives(x, u, du)
        e1, e2 = m.output_derivatives_numpy(x, u, du)
        # the scale of row k: the terms of C f and of f^T H f + C (J f + b du)
        f = m.rhs_numpy(0.0, x, u)
        J, b = m.jacobian_numpy(x, u)
        C = m.output_jacobian_numpy(x)
        s1 = np.abs(C) @ np.abs(f)
        s2 = np.abs(C) @ (np.abs(J) @ np.abs(f) + np.abs(b) * abs(du)) + np.abs(e2)
        rtol = 256 * EPS * np.linalg.cond(m.mass_matrix(x[:m.nq]))
        # the energy's d1: the kernel's power balance against the numpy gradient . f: the
        # power balance is exact (Lagrange's equations) up to the cancellation in grad E . f
        assert np.all(np.abs(d1 - e1) <= rtol * s1 + 1e-300), (d1 - e1, s1)
        assert np.all(np.abs(d2 - e2) <= rtol * s2 + 1e-300), (d2 - e2, s2)


@pytest.mark.parametrize("fidelity,preload", VARIANTS)
@pytest.mark.parametrize("n", [1, 4])
def test_energy_rate_is_the_power_balance(n, fidelity, preload):
    """grad E . f = F_c x_dot - etad.D.etad (+ the skew part of Kg, zero here): the identity the
    kernel's d1 of the energy uses, checked on the kernel's own energy and rhs by central
    differences of E along f (independent of the output Jacobian)."""
    m = _model(n, fidelity, preload)
    k = m.kernel
    nl = m._nl if fidelity == "linear" else m
    for x, u in _random_states(m, count=5, seed=400 + n):
        f = k.rhs(x, u)
        eta_d = x[m.nq + 2:]
        power = u * x[m.nq] - float(nl.Ddiag @ (eta_d * eta_d))
        h = EPS ** (1 / 3) / np.linalg.norm(f / np.maximum(np.abs(x), 1.0))

        def along(t, x=x, f=f):
            return k.energy(x + t * f)

        fd = (along(h) - along(-h)) / (2 * h)
        fd2 = (along(2 * h) - along(-2 * h)) / (4 * h)
        terms = float(np.abs(m.output_jacobian_numpy(x)[OUT["energy"]]) @ np.abs(f))
        E_terms = abs(k.energy(x)) + terms
        tol = 10 * (abs(fd2 - fd) / 3 + 64 * EPS * E_terms / h)
        assert abs(power - fd) <= tol, (power, fd, tol)
        d1, _ = k.output_derivatives(x, u, 0.0)
        assert d1[OUT["energy"]] == pytest.approx(power, rel=1e-12, abs=1e-12 * terms)


def _trajectory(m, x0, poly, times):
    """The kernel's rhs integrated by DOP853 at rtol 1e-13 with the force poly(t) = u0 + u1 t +
    u2 t^2 / 2, the states at ``times`` (each reached by the integrator's steps: t_eval uses the
    dense output of order 7, far below the tolerance over these short spans)."""
    from scipy.integrate import solve_ivp

    u0, u1, u2 = poly
    scale = np.maximum(np.abs(x0), 1e-3 * max(np.abs(x0).max(), 1.0))
    sol = solve_ivp(lambda t, y: m.kernel.rhs(y, u0 + t * (u1 + 0.5 * t * u2)), (0.0, times[-1]),
                    x0, method="DOP853", rtol=1e-13, atol=1e-13 * scale, t_eval=times)
    assert sol.success
    return sol.y.T


def _stencil4(vals, h):
    """The fourth-order central difference from values at -2h, -h, (0), h, 2h."""
    return (vals[0] - 8 * vals[1] + 8 * vals[3] - vals[4]) / (12 * h)


@pytest.mark.parametrize("fidelity,preload", VARIANTS)
@pytest.mark.parametrize("n", [0, 2, 8])
def test_output_derivatives_along_a_trajectory(n, fidelity, preload):
    """d1 against central differences in time of the outputs, d2 against central differences of
    d1, along the trajectory of a polynomial force: both at the steps h and 2h (fourth-order
    stencils), the tolerance from their difference and the integration's tolerance."""
    m = _model(n, fidelity, preload)
    k = m.kernel
    nl = m._nl if fidelity == "linear" else m
    w_max = float(np.sqrt(nl.Kdiag).max()) if n else 10.0
    h = 0.02 / w_max                        # ~ 300 steps per period of the fastest mode
    for x0, u0 in _random_states(m, count=2, seed=500 + n):
        poly = (u0, 2e3 * np.sign(u0), -4e5)
        t_c = 10 * h
        times = t_c + h * np.array([-4, -2, -1, 0, 1, 2, 4], dtype=float)
        xs = _trajectory(m, x0, poly, times)
        us = [poly[0] + t * (poly[1] + 0.5 * t * poly[2]) for t in times]
        dus = [poly[1] + t * poly[2] for t in times]
        ys = np.array([k.outputs(x) for x in xs])
        d1s = np.array([k.output_derivatives(x, u, du)[0] for x, u, du in zip(xs, us, dus)])
        d1, d2 = k.output_derivatives(xs[3], us[3], dus[3])
        for exact, vals, label in ((d1, ys, "d1"), (d2, d1s, "d2")):
            fd_h = _stencil4(vals[[1, 2, 3, 4, 5]], h)
            fd_2h = _stencil4(vals[[0, 1, 3, 5, 6]], 2 * h)
            # rounding: the integration's relative error (~1e-13 of each state, smooth in t:
            # differences of it are far smaller) taken at 1e-12 of the values, over h
            noise = 1e-12 * np.abs(vals).max(axis=0) / h
            tol = 10 * (np.abs(fd_2h - fd_h) / 15 + noise)
            bad = np.nonzero(np.abs(exact - fd_h) > tol)[0]
            assert bad.size == 0, (f"{label} of outputs {bad}: exact {exact[bad]}, "
                                   f"differences {fd_h[bad]}, tolerance {tol[bad]}")


# ---------------------------------------------------------------------- the controller's filter
def _controller(order, **kw):
    from controller_fmu.kernel import FilterKernel
    from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel

    p = ControllerParams(filter_order=order, kx=2.5, **kw)
    return PDLowPassModel(p), FilterKernel(p)


TABLE = [1, 2, 0]          # the FMU's inputs [phi_o, omega_o, x_o] among pd_lowpass's [x_o, ...]


@pytest.mark.parametrize("order", [0, 1, 2])
def test_filter_linearisation_is_the_state_space_of_the_specification(order):
    import control

    model, k = _controller(order)
    rng = np.random.default_rng(order)
    A0, B0, C0, D0 = model.state_space()
    for _ in range(5):
        xc, e = rng.standard_normal(2) * 100, rng.standard_normal() * 100
        A, B, C, D = k.linearize(xc[:order], e)
        np.testing.assert_array_equal(A, A0)
        np.testing.assert_allclose(B, B0[:, TABLE], rtol=1e-15, atol=0)
        np.testing.assert_array_equal(C, C0)
        np.testing.assert_array_equal(D, D0[:, TABLE])
        terms = np.abs(A0) @ np.abs(xc[:order]) + np.abs(model.Bf[:, 0] * e)
        assert np.all(np.abs(k.rhs(xc[:order], e) - (A0 @ xc[:order] + model.Bf[:, 0] * e))
                      <= 4 * EPS * terms)
    # python-control's realisation of -H(s) (kp, kd, kx): the same transfer functions
    p = model.params
    wc, zf = p.cutoff, p.filter_damping
    H = {0: control.tf([1.0], [1.0]), 1: control.tf([wc], [1.0, wc]),
         2: control.tf([wc * wc], [1.0, 2 * zf * wc, wc * wc])}[order]
    A, B, C, D = k.linearize(np.zeros(order), 0.0)
    for s in (0.3j * wc, 1j * wc, 5j * wc, 0.5 * wc):
        got = (C @ np.linalg.solve(s * np.eye(order) - A, B) + D)[0] if order else D[0]
        want = -complex(H(s)) * np.array([p.kp, p.kd, p.kx])
        np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_filter_linearisation_when_saturated(order):
    """Beyond the limit F_c does not depend on the state or the inputs (slope 0); on the limit
    exactly, the slope of the identity branch (1), as fp_filter.h states."""
    model, k = _controller(order, force_limit=10.0)
    A0, B0, C0, D0 = model.state_space()
    for v, slope in ((25.0, 0.0), (-25.0, 0.0), (10.0, 1.0), (-10.0, 1.0), (9.0, 1.0)):
        xc = np.array([v, 3.0])[:order]
        A, B, C, D = k.linearize(xc, v)          # order 0: F_c = -sat(e)
        np.testing.assert_array_equal(A, A0)
        np.testing.assert_allclose(B, B0[:, TABLE], rtol=1e-15)
        np.testing.assert_array_equal(C, slope * C0)
        np.testing.assert_array_equal(D, slope * D0[:, TABLE])
        d = k.output_derivatives(xc, v, 7.0, 11.0)
        if slope == 0.0:
            assert d == (0.0, 0.0)


def _filter_force(model, xc0, e_poly, s):
    """F_c(s) of the exact continuous response from xc0 at 0 with e(s) = e0 + e1 s + e2 s^2/2
    (pd_lowpass's exact discretisation over s, which holds for s < 0 too)."""
    e0, e1, e2 = e_poly
    if model.nx == 0:
        lim = model.params.force_limit
        return min(max(-(e0 + s * (e1 + 0.5 * s * e2)), -lim), lim)
    Ad, G = model.discretize_polynomial(float(s))
    return model.output(Ad @ xc0 + G @ np.array(e_poly), None)


@pytest.mark.parametrize("limit", [None, 40.0])
@pytest.mark.parametrize("order", [0, 1, 2])
def test_filter_output_derivatives_against_the_exact_response(order, limit):
    kw = {} if limit is None else {"force_limit": limit}
    model, k = _controller(order, **kw)
    rng = np.random.default_rng(10 + order)
    h = 1e-3 / model.params.cutoff
    for _ in range(6):
        y = rng.standard_normal((3, 3)) * [[0.05], [1.0], [50.0]]   # x_o, phi_o, omega_o; rates
        e = [model.error_signal(y[:, i]) for i in range(3)]
        xc0 = rng.standard_normal(order) * 60.0
        d1, d2 = k.output_derivatives(xc0, *e)
        F = [_filter_force(model, xc0, e, s * h) for s in (-2, -1, 0, 1, 2)]
        F2 = [_filter_force(model, xc0, e, s * h) for s in (-4, -2, 0, 2, 4)]
        for exact, fd_h, fd_2h in (
                (d1, _stencil4(F, h), _stencil4(F2, 2 * h)),
                (d2, (-F[0] + 16 * F[1] - 30 * F[2] + 16 * F[3] - F[4]) / (12 * h * h),
                 (-F2[0] + 16 * F2[1] - 30 * F2[2] + 16 * F2[3] - F2[4]) / (48 * h * h))):
            scale = max(abs(f) for f in F)
            tol = 10 * (abs(fd_2h - fd_h) / 15 + 64 * EPS * scale / h ** (1 if exact is d1
                                                                            else 2))
            assert abs(exact - fd_h) <= tol, (exact, fd_h, tol)


@pytest.mark.parametrize("limit", [None, 40.0])
@pytest.mark.parametrize("order", [0, 1, 2])
def test_filter_output_derivatives_up_to_order_4_are_powers_of_the_augmented_system(order, limit):
    """Orders 1 to 4 of ``fpf_output_derivatives`` against a second derivation: the filter and
    its input polynomial as one linear system z' = M z, z = [xc, e, e', e''] (the third
    derivative of e is 0: the sensors' polynomial is of degree 2), whose k-th derivative is
    M^k z; F_c = -xc_1 (order 0: -e), times the saturation's slope (0 beyond the limit)."""
    model, k = _controller(order, **({} if limit is None else {"force_limit": limit}))
    n = model.nx
    M = np.zeros((n + 3, n + 3))
    if n:
        M[:n, :n] = model.Af
        M[:n, n] = model.Bf[:, 0]
    M[n, n + 1] = M[n + 1, n + 2] = 1.0
    rng = np.random.default_rng(40 + order)
    for _ in range(8):
        xc = rng.standard_normal(n) * 30.0
        e = rng.standard_normal(3) * [30.0, 1e3, 1e5]
        z = np.r_[xc, e]
        slope = 1.0 if abs(z[0]) <= model.params.force_limit else 0.0
        want = [-slope * (np.linalg.matrix_power(M, j) @ z)[0] for j in (1, 2, 3, 4)]
        got = k.output_derivatives(xc, *e, orders=4)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * max(map(abs, want)))
        assert got[:2] == k.output_derivatives(xc, *e)
    with pytest.raises(ValueError, match="orders = 5"):
        k.output_derivatives(np.zeros(n), 0.0, orders=5)

# ---------------------------------------------------------------------- the models' hooks
HOOKS_C = Path(__file__).parents[1] / "native" / "jacobian_hooks.c"


@pytest.fixture(scope="module")
def hooks(tmp_path_factory):
    """The test host of the hooks for each model, built against its generated fpm_vars.h."""
    return _build_hooks(tmp_path_factory.mktemp("hooks"))


def _build_hooks(out, extra=()):
    from fmu_common import kernels
    from orchestration.export.native_fmus import generate_header

    root = Path(__file__).resolve().parents[2]
    exes = {}
    for name, src, define in (("FlexiblePendulum", "plant_fmu/native/plant_model.c", "PLANT"),
                              ("PDLowPass", "controller_fmu/native/controller_model.c", "CTRL")):
        inc = out / name
        inc.mkdir()
        (inc / "fpm_vars.h").write_text(generate_header(name, "token"))
        exe = out / f"hooks_{name}"
        cmd = [kernels.find_compiler(), *kernels.CFLAGS, *extra, "-DFP_API=", "-DFPF_API=",
               f"-D{define}", f'-DMODEL_C="{root / src}"', f"-I{inc}",
               *(f"-I{root / d}" for d in ("fmu_common/native", "plant_fmu/native",
                                            "controller_fmu/native")),
               "-o", str(exe), str(HOOKS_C), str(root / "fmu_common/native/fpm_guard.c"),
               str(root / "plant_fmu/native/fp_plant.c"),
               str(root / "controller_fmu/native/fp_filter.c"), "-lm"]
        cmd = [c for c in cmd if c != "-fvisibility=hidden"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        exes[name] = exe
    return exes


def _run_hooks(exe, h, steps, args):
    proc = subprocess.run([str(exe), repr(h), str(steps), *args], check=False,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return {d["what"]: d for d in map(json.loads, proc.stdout.splitlines())}


def _me_map(n):
    """Kernel state index -> Model-Exchange index ([q of 8 modes, their rates])."""
    nq = n + 2
    return np.r_[np.arange(nq), 10 + np.arange(nq)]


@pytest.mark.parametrize("fidelity,preload,integrator", [
    ("nonlinear", False, "rk4"), ("nonlinear", True, "dopri5"), ("linear", True, "rk4"),
    ("linear", False, "exponential")])
@pytest.mark.parametrize("n", [0, 3, 8])
def test_plant_hooks_are_the_kernel_at_the_models_point(hooks, n, fidelity, preload, integrator):
    """The plant's fpm_model_jacobian and fpm_model_output_derivatives against the kernel at the
    state the model holds, with the force input_now gives: after initialisation F_c and dF_c set
    now; after doSteps the last step's polynomial at its end (the step average for the
    exponential method), also after new inputs are set and after a save and restore."""
    from plant_fmu.interface import VARIABLES

    F, dF, d2F, h, steps = 30.0, -200.0, 5e3, 2e-3, 3
    args = [f"n_modes={n}", f"fidelity={fidelity}", f"gravity_preload={int(preload)}",
            f"integrator={integrator}", "phi0=0.3", "phi_dot0=-1.0", "x_dot0=0.5", "step=1e-4",
            f"F_c={F}", f"d1:F_c={dF}", f"d2:F_c={d2F}", "after:F_c=-70", "after:d1:F_c=9"]
    out = _run_hooks(hooks["FlexiblePendulum"], h, steps, args)
    m = _model(n, fidelity, preload)
    outputs = [v.name for v in VARIABLES if v.causality == "output"]
    rows = [OUT[o] if o in OUT else (OUT["eta"] + int(o[4:]) - 1 if o.startswith("eta_") else o)
            for o in outputs]
    t0 = h * (steps - 1)
    u_step = F + h * dF + h * h * d2F / 2 if integrator != "exponential" else \
        F + h * (dF / 2 + h * d2F / 6)
    du_step = dF + h * d2F if integrator != "exponential" else 0.0
    assert t0 >= 0
    idx = _me_map(n)
    for what, (u, du) in {"init": (F, dF), "step": (u_step, du_step),
                          "restored": (u_step, du_step), "after": (u_step, du_step)}.items():
        o = out[what]
        assert o["rc"] == 0 and o["nx"] == 20 and o["nu"] == 1 and o["ny"] == len(outputs)
        x = np.array(o["state"])
        J, b = m.kernel.jacobian(x, u)
        A, B = np.zeros((20, 20)), np.zeros((20, 1))
        A[np.ix_(idx, idx)] = J
        B[idx, 0] = b
        Ck = m.kernel.output_jacobian(x)
        d1k, d2k = m.kernel.output_derivatives(x, u, du)
        C, d1, d2 = np.zeros((len(outputs), 20)), np.zeros(len(outputs)), np.zeros(len(outputs))
        for i, r in enumerate(rows):
            if r < Ck.shape[0] and not (outputs[i] == "tip_deflection" and n == 0):
                C[i, idx] = Ck[r]
                d1[i], d2[i] = d1k[r], d2k[r]
        for got, want in ((o["A"], A), (o["B"], B), (o["C"], C), (o["D"], np.zeros((15, 1))),
                          (o["d1"], d1), (o["d2"], d2)):
            want = np.asarray(want).ravel()
            np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13 * np.abs(want).max(),
                                       err_msg=what)
    # a restored state answers bit for bit as the original
    for key in ("A", "B", "C", "D", "d1", "d2", "state", "t"):
        assert out["restored"][key] == out["step"][key]


@pytest.mark.parametrize("order,limit", [(0, None), (1, None), (2, None), (2, 5.0), (0, 5.0)])
def test_controller_hooks_are_the_kernel_at_the_models_point(hooks, order, limit):
    from controller_fmu.pd_lowpass import ControllerParams

    y = {"phi_o": (0.02, -0.3, 4.0), "omega_o": (0.5, 2.0, -30.0), "x_o": (0.1, 0.2, 1.0)}
    after = {"phi_o": -0.5, "omega_o": 7.0, "x_o": 2.0}
    h, steps = 1e-3, 4
    args = [f"filter_order={order}", "kx=2.5"] + ([f"force_limit={limit}"] if limit else [])
    for k, (v, d1, d2) in y.items():
        args += [f"{k}={v}", f"d1:{k}={d1}", f"d2:{k}={d2}", f"after:{k}={after[k]}"]
    out = _run_hooks(hooks["PDLowPass"], h, steps, args)
    kw = {} if limit is None else {"force_limit": limit}
    _, k = _controller(order, **kw)
    p = ControllerParams(filter_order=order, kx=2.5, **kw)

    def e_poly(s):                             # the error signal and its rates at s from the set
        vals = {n: (v + s * (d1 + s * d2 / 2), d1 + s * d2, d2) for n, (v, d1, d2) in y.items()}
        return [p.kx * vals["x_o"][i] + p.kp * vals["phi_o"][i] + p.kd * vals["omega_o"][i]
                for i in range(3)]

    for what, e in {"init": e_poly(0.0), "step": e_poly(h), "restored": e_poly(h),
                    "after": e_poly(h)}.items():
        o = out[what]
        assert o["rc"] == 0 and o["nx"] == 2 and o["nu"] == 3 and o["ny"] == 1
        xc = np.array(o["state"])[:order]
        A0, B0, C0, D0 = k.linearize(xc, e[0])
        A, B, C = np.zeros((2, 2)), np.zeros((2, 3)), np.zeros((1, 2))
        A[:order, :order], B[:order], C[:, :order] = A0, B0, C0
        d1, d2 = k.output_derivatives(xc, *e)
        for got, want in ((o["A"], A), (o["B"], B), (o["C"], C), (o["D"], D0), (o["d1"], [d1]),
                          (o["d2"], [d2])):
            np.testing.assert_allclose(got, np.ravel(want), rtol=1e-14, atol=0, err_msg=what)
    for key in ("A", "B", "C", "D", "d1", "d2", "state", "t"):
        assert out["restored"][key] == out["step"][key]
    assert out["step"]["t"] == pytest.approx(h * steps)


@pytest.mark.parametrize("n,preload", [(1, False), (2, True)])
def test_output_derivatives_against_sympy(n, preload):
    """The outputs (T + V for the energy, not the power balance) differentiated twice in time by
    sympy along q(t) (tests/plant/test_lagrange.py's derivation from the kinematics), evaluated with
    the accelerations M^-1 f and the jerks M^-1 (df/dz [qd, qdd, dF] - (dM/dt) qdd) from sympy's
    own M, f and their derivatives."""
    from test_lagrange import _derive, _param_values

    p = PlantParams(n_modes=n, gravity_preload=preload)
    m = plant_model(p)
    M_f, f_f, _, _, d = _derive(n, preload)
    nq = n + 2
    rng = np.random.default_rng(600 + n)
    for x, u in _random_states(m, count=5, seed=600 + n):
        du = 300.0 * rng.standard_normal()
        q, v = x[:nq], x[nq:]
        args = [*q, *v, *_param_values(p, m, u)]
        M = np.array(M_f(*args), dtype=float)
        a = np.linalg.solve(M, np.array(f_f(*args), dtype=float).ravel())
        dfdz = np.array(d["dfdz"](*args), dtype=float)           # columns q, qd, F
        dMdt = sum(np.array(d["dMdq"][k](*args), dtype=float) * v[k] for k in range(nq))
        jerk = np.linalg.solve(M, dfdz @ np.r_[v, a, du] - dMdt @ a)
        d1s, d2s = (np.array(o, dtype=float).ravel() for o in d["time_derivatives"](
            *args, *m.tip_slope, *m.tip_defl, *a, *jerk))
        d1, d2 = m.kernel.output_derivatives(x, u, du)
        e1, e2 = m.output_derivatives_numpy(x, u, du)
        rows = [OUT[k] for k in ("x_o", "x_dot", "phi_o", "omega_o", "phi", "tip_deflection",
                                 "energy")] + [OUT["eta"] + j for j in range(n)]
        # scale: the largest term of each derivative (the energy's: its gradient times f)
        C = m.output_jacobian_numpy(x)
        f = m.rhs_numpy(0.0, x, u)
        J, b = m.jacobian_numpy(x, u)
        s1 = np.abs(C) @ np.abs(f)
        s2 = np.abs(C) @ (np.abs(J) @ np.abs(f) + np.abs(b) * abs(du)) + np.abs(d2)
        rtol = 256 * EPS * np.linalg.cond(M)
        for got in ((d1, d2), (e1, e2)):
            assert np.all(np.abs(got[0][rows] - d1s) <= rtol * s1[rows]), (got[0][rows], d1s)
            assert np.all(np.abs(got[1][rows] - d2s) <= rtol * s2[rows]), (got[1][rows], d2s)


@pytest.mark.skipif(not shutil.which("gcc"), reason="needs gcc")
def test_hooks_and_kernels_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    """The hooks' host (every new kernel function of both kernels, both models' hooks, a save
    and a restore) under ASan and UBSan: any memory error or undefined behaviour aborts."""
    exes = _build_hooks(tmp_path, ("-O1", "-g", "-fno-omit-frame-pointer",
                                   "-fsanitize=address,undefined", "-fno-sanitize-recover=all"))
    for n, fid, pre in ((0, "nonlinear", 0), (8, "nonlinear", 1), (8, "linear", 1)):
        out = _run_hooks(exes["FlexiblePendulum"], 1e-3, 2, [
            f"n_modes={n}", f"fidelity={fid}", f"gravity_preload={pre}", "phi0=0.4", "F_c=3",
            "d1:F_c=10", "after:F_c=1"])
        assert out["restored"]["A"] == out["step"]["A"]
    for order in (0, 1, 2):
        out = _run_hooks(exes["PDLowPass"], 1e-3, 2, [f"filter_order={order}", "phi_o=0.1",
                                                       "d1:omega_o=3", "after:x_o=1"])
        assert out["restored"]["d2"] == out["step"]["d2"]
