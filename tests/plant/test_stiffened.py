"""The stiffened floating frame (``fidelity = "stiffened"``): derived by sympy from the kinematics of
the inextensible beam, against the numpy specification and the C kernel.

The derivation starts from the kinematics, not from the energies of
:class:`plant_fmu.dynamics.StiffenedPlantModel`: ``r(s) = (x, 0) + (s - u(s)) b1 + w(s) b2`` with
``b1 = (-sin phi, cos phi)``, ``b2 = (-cos phi, -sin phi)``, ``w = sum N_j(s) eta_j`` and the
foreshortening ``u(s) = 1/2 sum G_jk(s) eta_j eta_k`` (``G_jk(s) = int_0^s N_j' N_k'``). The
kinetic energy ``1/2 m xd^2 + 1/2 int rhoA |rd|^2 ds`` and the gravity potential ``g int rhoA y``
are expanded as polynomials in ``s``, ``N_j`` and ``G_jk``, and each monomial's integral
``int rhoA (...) ds`` becomes one symbol (its value: the sum over the model's mass points, which
the numpy model never forms). Strain energy ``1/2 eta^T K eta``, Rayleigh dissipation and the force
on the cart complete the Lagrangian; sympy forms Lagrange's equations, the numpy model Kane's.
The moments without ``G`` are the invariants, and ``int rhoA G`` in the weight is ``Kg / g`` (the
model: the nonlinear model with the preload plus the foreshortening's kinetic energy over its
points).
"""
import math
import shutil
import subprocess

import numpy as np
import pytest
import sympy as sp

from plant_fmu.beam import analytic_mode_shape, beam_model, mass_points
from plant_fmu.dynamics import model_for, plant_model, stiffened_plant_model
from plant_fmu.params import PlantParams


def _derive(n: int):
    """Symbolic ``M(q)``, ``f(q, qd, F)`` and ``T + V``, as numeric functions of the state, the
    force and the moments ``int rhoA (monomial of s, N_j, G_jk)`` (:func:`_moments` gives their
    values; the list of monomials is the fourth item)."""
    t, s = sp.symbols("t s")
    x, phi = sp.Function("x")(t), sp.Function("phi")(t)
    eta = [sp.Function(f"eta{j}")(t) for j in range(n)]
    q = [x, phi, *eta]
    N = sp.symbols(f"N0:{n}")
    G = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"G_{min(i, j)}{max(i, j)}"))
    gsyms = sorted(set(G), key=str)
    m, g, F = sp.symbols("m g F")
    K, D = sp.symbols(f"K0:{n}"), sp.symbols(f"D0:{n}")
    e = sp.Matrix(eta)
    w = sum((N[j] * eta[j] for j in range(n)), sp.Integer(0))
    u = sp.Rational(1, 2) * (e.T * G * e)[0, 0]
    b1 = sp.Matrix([-sp.sin(phi), sp.cos(phi)])
    b2 = sp.Matrix([-sp.cos(phi), -sp.sin(phi)])
    r = sp.Matrix([x, 0]) + (s - u) * b1 + w * b2
    rd = r.diff(t)
    moments = {}

    def integrate(expr, tag):
        """int rhoA (polynomial in s, N_j, G_jk) ds: one symbol per monomial (and ``tag``: the
        kinetic and the potential energy's moments may be computed differently)."""
        poly = sp.Poly(sp.expand(expr), s, *N, *gsyms)
        total = sp.Integer(0)
        for powers, coeff in poly.terms():
            key = (tag, powers)
            if key not in moments:
                moments[key] = sp.Symbol(f"mom{len(moments)}")
            total += coeff * moments[key]
        return total

    T = sp.Rational(1, 2) * m * x.diff(t) ** 2 + sp.Rational(1, 2) * integrate(rd.dot(rd), "T")
    V = g * integrate(r[1], "V") + sum(sp.Rational(1, 2) * K[j] * eta[j] ** 2 for j in range(n))
    R = sum(sp.Rational(1, 2) * D[j] * eta[j].diff(t) ** 2 for j in range(n))
    L = T - V
    Q = [F] + [0] * (n + 1)
    qs, vs, acc = (sp.symbols(f"{c}0:{n + 2}") for c in "qva")
    sub = {}
    for qi, qsym, vsym, asym in zip(q, qs, vs, acc):
        sub[qi.diff(t, 2)] = asym
        sub[qi.diff(t)] = vsym
    sub_q = dict(zip(q, qs))
    eqs = [(sp.diff(L, qi.diff(t)).diff(t) - sp.diff(L, qi) + sp.diff(R, qi.diff(t)) - Q[i])
           .subs(sub).subs(sub_q) for i, qi in enumerate(q)]
    M = sp.Matrix([[sp.diff(ei, a) for a in acc] for ei in eqs])
    f = sp.Matrix([-ei.subs({a: 0 for a in acc}) for ei in eqs])
    energy = (T + V).subs(sub).subs(sub_q)
    keys = list(moments)
    args = [*qs, *vs, m, g, F, *K, *D, *(moments[k] for k in keys)]
    lam = lambda ex: sp.lambdify(args, ex, "numpy")  # noqa: E731
    gidx = [tuple(int(c) for c in str(k).split("_")[1]) for k in gsyms]
    return lam(M), lam(f), lam(energy), (keys, gidx)


N_MODES = 2
RK4 = dict(A=[[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]],
           B=[1 / 6, 1 / 3, 1 / 3, 1 / 6], C=[0, 0.5, 0.5, 1])


@pytest.fixture(scope="module")
def derived():
    return _derive(N_MODES)


def _moments(p, model, keys, gidx):
    """The value of each moment ``int rhoA s^a prod N_j^b prod G_jk^c``: without ``G``, the
    invariants (``rhoA L, I1, I2, I3, I5``; ``I4 = I``); with ``G``, in the kinetic energy, the
    sum over the model's mass points; ``int rhoA G = Kg / g`` in the potential (the preload's)."""
    n, pts, b = model.n, model.points, model.beam
    Fa = beam_model(p.replace(gravity_preload=True, g=1.0)).Kg
    out = []
    for tag, key in keys:
        ps, pn, pg = key[0], key[1:1 + n], key[1 + n:]
        idx = [j for j, k in enumerate(pn) for _ in range(k)]
        if not any(pg):
            out.append({(0, 0): p.rhoA * p.L, (1, 0): b.I1, (2, 0): b.I2}[ps, 0] if not idx else
                       (b.I3, b.I5)[ps][idx[0]] if len(idx) == 1 else float(idx[0] == idx[1]))
        elif tag == "V":
            assert ps == 0 and not idx and sum(pg) == 1
            out.append(Fa[gidx[pg.index(1)]])
        else:
            v = pts.m * pts.s ** ps
            for j, k in enumerate(pn):
                v = v * pts.N[:, j] ** k
            for (i, j), k in zip(gidx, pg):
                v = v * pts.G[:, i, j] ** k
            out.append(float(np.sum(v)))
    return out


def _values(p, model, sym, F):
    keys, gidx = sym
    b = model.beam
    return [p.m, p.g, F, *np.diag(b.K), *np.diag(b.D), *_moments(p, model, keys, gidx)]


def _random_states(n, count, seed):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q = np.r_[rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi), 1e-2 * rng.standard_normal(n)]
        v = np.r_[rng.standard_normal(), 3 * rng.standard_normal(), 10 * rng.standard_normal(n)]
        yield q, v, 100 * rng.standard_normal()


def test_rhs_mass_matrix_and_energy_match_the_derivation(derived):
    """The numpy specification and the C kernel against Lagrange's equations derived by sympy
    from the foreshortened kinematics, at random deformed, moving, tilted states."""
    M_f, f_f, E_f, sym = derived
    p = PlantParams(n_modes=N_MODES, zeta=0.01)
    model = stiffened_plant_model(p)
    for q, v, F in _random_states(N_MODES, 20, seed=3):
        args = [*q, *v, *_values(p, model, sym, F)]
        M = np.array(M_f(*args), dtype=float)
        f = np.array(f_f(*args), dtype=float).ravel()
        expected = np.r_[v, np.linalg.solve(M, f)]
        np.testing.assert_allclose(model.mass_matrix(q), M, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(model.forces(q, v, F), f, rtol=1e-12,
                                   atol=1e-12 * np.abs(f).max())
        for got in (model.rhs_numpy(0.0, np.r_[q, v], F), model.rhs(0.0, np.r_[q, v], F)):
            assert np.linalg.norm(got - expected) <= 1e-10 * np.linalg.norm(expected)
        E = float(E_f(*args))
        assert model.energy_numpy(np.r_[q, v]) == pytest.approx(E, rel=1e-12)
        assert model.energy(np.r_[q, v]) == pytest.approx(E, rel=1e-12)


def test_derivation_differs_from_the_nonlinear_model(derived):
    """The foreshortening terms are not negligible at these states: the nonlinear model with the
    preload (which has the gravity part only) misses the derivation (so the test above can
    fail)."""
    M_f, f_f, _, sym = derived
    p = PlantParams(n_modes=N_MODES, gravity_preload=True)
    pre = plant_model(p)
    worst = 0.0
    for q, v, F in _random_states(N_MODES, 5, seed=3):
        args = [*q, *v, *_values(p, stiffened_plant_model(p), sym, F)]
        qdd = np.linalg.solve(np.array(M_f(*args), dtype=float),
                              np.array(f_f(*args), dtype=float).ravel())
        worst = max(worst, np.linalg.norm(pre.rhs_numpy(0, np.r_[q, v], F)[N_MODES + 2:] - qdd)
                    / np.linalg.norm(qdd))
    assert worst > 1e-6


def test_foreshortening_against_the_analytic_modes():
    """The mass points' ``G(s) = int_0^s N'^2``: ``sum m_p G_p = int rhoA (L - s) N'^2`` and
    ``sum m_p s_p G_p = int rhoA (L^2 - s^2)/2 N'^2`` (integration by parts) of the first two
    modes against quadrature of the analytic cantilever shapes (fine mesh)."""
    from scipy.integrate import quad

    p = PlantParams(n_modes=2, n_elements=60, L=1.3, rho=5e3)
    pts = mass_points(p)
    Fa = np.einsum("p,pij->ij", pts.m, pts.G)
    Fb = np.einsum("p,pij->ij", pts.m * pts.s, pts.G)
    L, rhoA = p.L, p.rhoA
    for j in (1, 2):
        shape = analytic_mode_shape(p, j)
        h = 1e-6
        slope = lambda s: (shape(s + h) - shape(s - h)) / (2 * h)  # noqa: E731
        fa = quad(lambda s: rhoA * (L - s) * slope(s) ** 2, h, L - h, epsabs=0, limit=200)[0]
        fb = quad(lambda s: rhoA * 0.5 * (L * L - s * s) * slope(s) ** 2, h, L - h, epsabs=0,
                  limit=200)[0]
        assert Fa[j - 1, j - 1] == pytest.approx(fa, rel=1e-5)
        assert Fb[j - 1, j - 1] == pytest.approx(fb, rel=1e-5)


def test_the_second_order_truncation_loses_the_mass_matrix_where_the_full_one_holds():
    """Why the kinetic energy is kept in full: truncated to second order in eta, the rotation's
    Schur complement is ``I2 - I5.I5 + eta.(I - Fb).eta``, which turns negative at 8 modes for a
    deflection along the top eigenvector of ``Fb - I`` of ~0.3 % of L; the full mass matrix there
    stays positive definite (its smallest eigenvalue, and the rhs is finite)."""
    p = PlantParams(n_modes=8)
    model = stiffened_plant_model(p)
    pts = model.points
    Fb = np.einsum("p,pij->ij", pts.m * pts.s, pts.G)
    lam, vec = np.linalg.eigh(Fb - np.eye(8))
    resid = model.I2 - model._I5I5
    eta = vec[:, -1] * math.sqrt(2.0 * resid / lam[-1])
    assert resid + eta @ (np.eye(8) - Fb) @ eta < 0            # the truncation: indefinite
    tip = abs(float(model.tip_defl @ eta)) / p.L
    assert tip < 0.01
    q = np.r_[0.0, 0.3, eta]
    assert np.linalg.eigvalsh(model.mass_matrix(q)).min() > 0
    assert np.all(np.isfinite(model.rhs(0.0, np.r_[q, np.zeros(10)], 0.0)))


def test_first_order_modal_equations_carry_the_axial_loads_geometric_stiffness():
    """To first order in eta, the stiffened rung's modal equations differ from the nonlinear
    model's (no preload) by ``K_G eta`` with ``K_G = -(g c - s xdd) Fa + phid^2 Fb``: the
    geometric stiffness of the axial load of gravity, the cart's acceleration along the beam and
    the centrifugal load, whatever the angular acceleration. ``Fa = Kg / g``;
    ``Fb = int rhoA (L^2 - s^2)/2 N'^T N'`` by Gauss on each element (not the model's points)."""
    from plant_fmu.beam import _fe_modes_unit, _hermite_dN

    p = PlantParams(n_modes=4, L=1.2, rho=6e3)
    st, nl = stiffened_plant_model(p), plant_model(p)
    n, ne = p.n_modes, p.n_elements
    phi_u = _fe_modes_unit(ne)[1][:, :n]
    gx, gw = np.polynomial.legendre.leggauss(4)
    xi, gw = 0.5 * (gx + 1.0), 0.5 * gw
    Fb = np.zeros((n, n))
    for e in range(ne):
        dw = _hermite_dN(xi, 1.0 / ne) @ phi_u[2 * e:2 * e + 4]
        xs = (e + xi) / ne
        Fb += (dw * (gw * 0.5 * (1 - xs * xs) / ne)[:, None]).T @ dw      # dimensionless
    Fa = beam_model(p.replace(gravity_preload=True, g=1.0)).Kg
    rng = np.random.default_rng(8)
    for _ in range(5):
        eps, v = 1e-7, rng.standard_normal(n)
        phi, phid = rng.uniform(-1.5, 1.5), 3.0 * rng.standard_normal()
        a = np.r_[10.0 * rng.standard_normal(2), np.zeros(n)]            # xdd, phidd
        q, qd = np.r_[0.2, phi, eps * v], np.r_[0.3, phid, np.zeros(n)]
        res = lambda m: (m.mass_matrix(q) @ a - m.forces(q, qd, 0.0))[2:]  # noqa: E731
        c, s = math.cos(phi), math.sin(phi)
        KG = -(p.g * c - s * a[0]) * Fa + phid * phid * Fb
        want = KG @ v
        np.testing.assert_allclose((res(st) - res(nl)) / eps, want,
                                   rtol=0, atol=1e-4 * np.abs(want).max())


def test_energy_is_conserved_without_damping_and_force():
    """Lagrange's equations of a conservative system: ``T + V`` stays constant along a tight
    solution from a tilted, spinning, deformed start (the nonlinear model's energy with the same
    terms would not be)."""
    from scipy.integrate import solve_ivp

    p = PlantParams(n_modes=3, zeta=0.0)
    model = stiffened_plant_model(p)
    x0 = model.initial_state(phi=0.4, phi_dot=2.0, x_dot=-0.5)
    x0[2:5] = [3e-3, -1e-3, 2e-4]
    sol = solve_ivp(lambda t, x: model.rhs(t, x, 0.0), (0, 0.5), x0, method="DOP853",
                    rtol=1e-12, atol=1e-13, dense_output=False, t_eval=np.linspace(0, 0.5, 51))
    E = np.array([model.energy(sol.y[:, k]) for k in range(sol.t.size)])
    scale = model.I1 * p.g + 0.5 * model.I2 * 4.0
    assert np.max(np.abs(E - E[0])) < 1e-9 * scale
    # the same state under the nonlinear model with the preload leaves the stiffened energy
    pre = plant_model(p.replace(gravity_preload=True))
    sol2 = solve_ivp(lambda t, x: pre.rhs(t, x, 0.0), (0, 0.5), x0, method="DOP853",
                     rtol=1e-12, atol=1e-13)
    assert abs(model.energy(sol2.y[:, -1]) - E[0]) > 1e3 * np.max(np.abs(E - E[0]))


def test_small_amplitude_frequencies_are_the_preload_rungs():
    """At the upright rest state the foreshortening's kinetic terms are of fourth order: the
    linearisation (by differences of the rhs) is that of the preload rung, and not the default's."""
    p = PlantParams(n_modes=4)
    st = stiffened_plant_model(p)
    pre, dflt = plant_model(p.replace(gravity_preload=True)), plant_model(p)

    def eig(model):
        x0, h = np.zeros(model.nx), 1e-7
        J = np.column_stack([(model.rhs_numpy(0, x0 + h * e, 0.0)
                              - model.rhs_numpy(0, x0 - h * e, 0.0)) / (2 * h)
                             for e in np.eye(model.nx)])
        return np.sort_complex(np.linalg.eigvals(J))

    e_st, e_pre, e_def = eig(st), eig(pre), eig(dflt)
    big = np.abs(e_pre) > 1e-3            # the cart's double zero aside
    assert np.count_nonzero(big) == st.nx - 2
    np.testing.assert_allclose(e_st[big], e_pre[big], rtol=1e-6)
    assert np.max(np.abs(e_def[big] - e_pre[big]) / np.abs(e_pre[big])) > 1e-4


def test_the_analyses_linearise_the_stiffened_rung_as_the_preload_rung():
    """``analyze`` of a stiffened scene is the preload rung's linear loop (its linearisation),
    not the default rung's."""
    from orchestration import analyze

    base = {"plant.gravity_preload": False}
    st = analyze("flexible_pd_lowpass", {**base, "plant.fidelity": "stiffened",
                                         "master.fmus": "python"})
    pre = analyze("flexible_pd_lowpass", {"plant.gravity_preload": True})
    dflt = analyze("flexible_pd_lowpass", base)
    e = lambda a: np.sort_complex(np.asarray(a.eigenvalues))  # noqa: E731
    np.testing.assert_array_equal(e(st), e(pre))
    assert np.max(np.abs(e(st) - e(dflt))) > 1e-3


def test_a_stiffened_runs_summary_compares_with_analyzes_loop(native):
    """The summary's linear bending root of a stiffened run is the one ``analyze`` gives for the
    same scene (the preloaded loop: one linearisation for the summary and the analyses), not the
    un-preloaded loop's (issue 34: the summary printed 153.16 rad/s where analyze and the run
    agree on 152.26)."""
    from orchestration import analyze
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene

    sc = load_scene("flexible_pd_lowpass", {"plant.fidelity": "stiffened", "stop_time": 3.0})
    run = run_scene(sc, {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]},
                    progress=False)
    lin = run.summary["bending"]["linear"]
    assert lin is not None
    assert run.summary["linear_loop"] == ("the stiffened rung's linearisation (4 modes, "
                                          "preloaded, modal damping 0.1 %)")

    def bending(a):
        return min((z for z in a.eigenvalues if z.imag > 60),
                   key=lambda z: abs(z.imag - lin["frequency"]))

    z = bending(analyze(sc))
    assert (lin["rate"], lin["frequency"]) == (z.real, z.imag)
    plain = bending(analyze(sc, {"plant.fidelity": "nonlinear"}))
    assert abs(plain.imag - z.imag) > 0.5         # 153.19 against 152.3 rad/s


def test_model_for_and_refusals():
    p = PlantParams(n_modes=2)
    assert model_for(p, "stiffened") is stiffened_plant_model(p)
    with pytest.raises(ValueError, match="fidelity = 'exact'"):
        model_for(p, "exact")
    with pytest.raises(ValueError, match="stiffened"):
        stiffened_plant_model(p).jacobian_numpy(np.zeros(8), 0.0)
    assert math.isfinite(stiffened_plant_model(PlantParams(n_modes=0)).energy(np.r_[0, .1, 0, 0]))


@pytest.mark.parametrize("n", [0, 1, 4, 8])
def test_kernel_matches_numpy_to_round_off(n):
    """``fp_rhs``, ``fp_energy`` and the outputs of the stiffened model against the numpy
    specification (to round-off: the relative error of solving M, ``cond(M) eps``); the kernel refuses the exact Jacobians and output derivatives by name."""
    p = PlantParams(n_modes=n, n_elements=12, zeta=0.02)
    model = stiffened_plant_model(p)
    k = model.kernel
    for q, v, F in _random_states(n, 10, seed=5 + n):
        x = np.r_[q, v]
        ref = model.rhs_numpy(0.0, x, F)
        # Cholesky (kernel) against LU (numpy) of the same M: round-off times its condition
        tol = 10 * np.linalg.cond(model.mass_matrix(q)) * np.finfo(float).eps
        assert np.max(np.abs(k.rhs(x, F) - ref)) <= tol * np.max(np.abs(ref))
        assert k.energy(x) == pytest.approx(model.energy_numpy(x), rel=1e-13, abs=1e-13)
        out = k.outputs(x)
        assert out[2:4] == pytest.approx(model.tip_angle_numpy(x), rel=1e-14, abs=1e-15)
    for call in (lambda: k.jacobian(x, 0.0), lambda: k.jvp(x, 0.0, x),
                 lambda: k.output_jacobian(x), lambda: k.output_derivatives(x, 0.0)):
        with pytest.raises(ValueError, match="fidelity = 'stiffened'"):
            call()


@pytest.mark.parametrize("flavour", ["python", "native"])
def test_both_fmu_flavours_run_the_stiffened_rung_as_the_reference(request, flavour):
    """A co-simulation of the filtered scene at ``fidelity = "stiffened"`` with either FMU pair
    meets the monolithic reference to the co-simulation's accuracy, far below the stiffened
    rung's difference from the nonlinear rung with the preload; a scene asking for it with Model
    Exchange or output derivatives (which need the Jacobians it does not have) is refused in one
    line."""
    from orchestration.job import run_scene
    from orchestration.scene.keys import ConfigError
    from orchestration.scene.schema import load_scene
    from orchestration.studies.reference import simulate_reference

    sets = {"initial.phi": math.pi / 6, "stop_time": 0.4, "plant.zeta": 0.0,
            "plant.fidelity": "stiffened"}
    for key, value in (("master.interface", "model-exchange"),
                       ("master.output_derivatives", True)):
        with pytest.raises(ConfigError, match=f"stiffened.*{key}"):
            load_scene("flexible_pd_lowpass", {**sets, key: value, "master.fmus": "native",
                                               "master.input_derivatives": 1})
    sc = load_scene("flexible_pd_lowpass", {**sets, "master.fmus": flavour})
    paths = request.getfixturevalue("fmus" if flavour == "python" else "native")
    a = run_scene(sc, {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"]},
                  progress=False)
    assert a.summary["stopped"] is None
    ref = simulate_reference(sc)["phi_o"]
    pre = simulate_reference(load_scene("flexible_pd_lowpass",
                                        {**sets, "plant.fidelity": "nonlinear",
                                         "plant.gravity_preload": True}))["phi_o"]
    cosim = np.max(np.abs(a.result["phi_o"] - ref))
    assert cosim < 1e-4
    assert np.max(np.abs(pre - ref)) > 10 * cosim


def test_closer_to_the_exact_rung_than_the_default_rung():
    """On the filtered scene without structural damping, over its first second (where the gap
    is largest from pi/6), the stiffened rung's tip angle is closer to the exact beam's (8
    elements, h = 0.1 ms, the C kernel: its own error ~1e-4 rad) than the default rung's, at the
    three angles of ``bench/fidelity_gap.py`` (which measures the full 3 s on a finer exact
    beam)."""
    from orchestration.scene.schema import load_scene
    from orchestration.studies.exact_loop import exact_run
    from orchestration.studies.reference import simulate_reference

    for phi0 in (0.05, 0.2, math.pi / 6):
        sets = {"initial.phi": phi0, "stop_time": 1.0, "plant.zeta": 0.0}
        sc = load_scene("flexible_pd_lowpass", sets)
        exact = exact_run(sc, 8, 1e-4, kernel=True)
        d_def = np.max(np.abs(simulate_reference(sc, rtol=1e-10)["phi_o"] - exact))
        st = load_scene("flexible_pd_lowpass", {**sets, "plant.fidelity": "stiffened",
                                                "master.fmus": "python"})
        d_st = np.max(np.abs(simulate_reference(st, rtol=1e-10)["phi_o"] - exact))
        print(phi0, d_def, d_st)
        assert d_st < 0.6 * d_def, (phi0, d_st, d_def)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
@pytest.mark.parametrize("n", [1, 8])
def test_the_stiffened_kernel_under_the_sanitizers(tmp_path, n):
    """``rhs_stiffened`` and its energy built with AddressSanitizer and UBSan
    (tests/native/stiffened_check.c): no memory error or undefined behaviour, the rhs and energy
    the numpy specification's, the Jacobian refused, and 40 RK4 substeps those of the Python
    kernel (the same code, so to round-off)."""
    from fmu_common import kernels

    plant = kernels.native_dir("flexpend_plant")
    exe = tmp_path / "stiffened_check"
    cmd = ["gcc", *kernels.CFLAGS, "-O1", "-g", "-fsanitize=address,undefined",
           "-fno-sanitize-recover=all", f"-I{plant}", "-o", str(exe),
           str(kernels.ROOT / "tests" / "native" / "stiffened_check.c"),
           str(plant / "fp_plant.c"), "-lm"]
    cmd.remove("-fvisibility=hidden")
    build = subprocess.run(cmd, capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    model = stiffened_plant_model(PlantParams(n_modes=n, zeta=0.01))
    pts = model.points
    x = model.initial_state(phi=0.4, phi_dot=1.5, x_dot=-0.3)
    x[2:n + 2] = 2e-3 * np.cos(np.arange(n))
    u = 37.0
    data = [model.I0, model.I1, model.I2, model.g, *model.I3, *model.I5,
            *model.Kdiag, *model.Ddiag, *model.tip_slope, *model.tip_defl, *np.ravel(model.Kg),
            *np.ravel(np.hstack([pts.s[:, None], pts.m[:, None], pts.N,
                                 pts.G.reshape(pts.s.size, n * n)])), *x, u]
    (tmp_path / "in.txt").write_text(f"{n} {pts.s.size} "
                                     + " ".join(repr(float(v)) for v in data))
    run = subprocess.run([str(exe), str(tmp_path / "in.txt")], capture_output=True, text=True,
                         timeout=120, env={"ASAN_OPTIONS": "detect_leaks=1",
                                           "UBSAN_OPTIONS": "print_stacktrace=1"})
    assert run.returncode == 0, run.stdout + run.stderr
    assert "runtime error" not in run.stderr and "Sanitizer" not in run.stderr, run.stderr
    out = np.array(run.stdout.split(), dtype=float)
    nx = model.nx
    ref = model.rhs_numpy(0.0, x, u)
    tol = 10 * np.linalg.cond(model.mass_matrix(x[:n + 2])) * np.finfo(float).eps
    assert np.max(np.abs(out[:nx] - ref)) <= tol * np.max(np.abs(ref))
    assert out[nx] == pytest.approx(model.energy_numpy(x), rel=1e-13)
    assert out[nx + 1] == 1                                   # FP_BADARG
    k = model.kernel
    y, done, rc = k.fixed_steps("rk4", k.tableau(**RK4), x, (u, 0.0, 0.0, 0.0), 0.0, 2.5e-4, 40)
    assert rc == 0 and done == 40
    np.testing.assert_allclose(out[nx + 2:], y, rtol=1e-12, atol=1e-14)
