"""The stiffened floating frame (``fidelity = "stiffened"``): derived by sympy from the kinematics of
the inextensible beam, against the numpy specification and the C kernel.

The derivation starts from the kinematics, not from the energies of
:class:`plant_fmu.dynamics.StiffenedPlantModel`: ``r(s) = (x, 0) + (s - u(s)) b1 + w(s) b2`` with
``b1 = (-sin phi, cos phi)``, ``b2 = (-cos phi, -sin phi)``, ``w = sum N_j(s) eta_j`` and the
foreshortening ``u(s) = 1/2 sum G_jk(s) eta_j eta_k`` (``G_jk(s) = int_0^s N_j' N_k'``). The
kinetic energy ``1/2 m xd^2 + 1/2 int rhoA |rd|^2 ds`` and the gravity potential ``g int rhoA y``
are expanded in powers of the modal amplitude (``eta -> eps eta``) and kept to ``eps^2``, as
polynomials in ``s``, ``N_j`` and ``G_jk``; each moment is then replaced by its invariant (those
of ``tests/test_lagrange.py``, and ``int rhoA G_jk = Fa_jk``, ``int rhoA s G_jk = Fb_jk``).
Strain energy ``1/2 eta^T K eta``, Rayleigh dissipation and the force on the cart complete it.
"""
import math

import numpy as np
import pytest
import sympy as sp

from plant_fmu.beam import analytic_mode_shape, beam_model
from plant_fmu.dynamics import model_for, plant_model, stiffened_plant_model
from plant_fmu.params import PlantParams


def _derive(n: int):
    """Symbolic ``M(q)``, ``f(q, qd, F)`` and ``T + V`` as numeric functions of the beam data."""
    t, s, eps = sp.symbols("t s eps")
    x, phi = sp.Function("x")(t), sp.Function("phi")(t)
    eta = [sp.Function(f"eta{j}")(t) for j in range(n)]
    q = [x, phi, *eta]
    N = sp.symbols(f"N0:{n}")
    G = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"G_{min(i, j)}{max(i, j)}"))
    gsyms = sorted(set(G), key=str)
    m, mb, I1, I2, g, F = sp.symbols("m mb I1 I2 g F")
    I3, I5 = sp.symbols(f"I3_0:{n}"), sp.symbols(f"I5_0:{n}")
    K, D = sp.symbols(f"K0:{n}"), sp.symbols(f"D0:{n}")
    Fa = {gs: sp.Symbol("Fa" + str(gs)[1:]) for gs in gsyms}
    Fb = {gs: sp.Symbol("Fb" + str(gs)[1:]) for gs in gsyms}

    e = sp.Matrix(eta) * eps
    w = sum((N[j] * e[j] for j in range(n)), sp.Integer(0))
    u = sp.Rational(1, 2) * (e.T * G * e)[0, 0]
    b1 = sp.Matrix([-sp.sin(phi), sp.cos(phi)])
    b2 = sp.Matrix([-sp.cos(phi), -sp.sin(phi)])
    r = sp.Matrix([x, 0]) + (s - u) * b1 + w * b2
    rd = r.diff(t)

    def second_order(expr):
        poly = sp.Poly(sp.expand(expr), eps)
        return sum((c * eps**k for (k,), c in poly.terms() if k <= 2), sp.Integer(0)).subs(eps, 1)

    def integrate(expr):
        """int rhoA (polynomial in s, N_j, G_jk) ds, moment by moment."""
        poly = sp.Poly(second_order(expr), s, *N, *gsyms)
        total = sp.Integer(0)
        for powers, coeff in poly.terms():
            ps, pn, pg = powers[0], powers[1:1 + n], powers[1 + n:]
            idx = [j for j, p in enumerate(pn) for _ in range(p)]
            gi = [gsyms[j] for j, p in enumerate(pg) for _ in range(p)]
            if not idx and not gi:
                moment = {0: mb, 1: I1, 2: I2}[ps]
            elif len(idx) == 1 and not gi and ps <= 1:
                moment = (I3, I5)[ps][idx[0]]
            elif len(idx) == 2 and not gi and ps == 0:
                moment = 1 if idx[0] == idx[1] else 0          # mass-normalised modes
            elif not idx and len(gi) == 1 and ps <= 1:
                moment = (Fa, Fb)[ps][gi[0]]
            else:
                raise AssertionError(f"unexpected moment s^{ps} N{idx} {gi}")
            total += coeff * moment
        return total

    T = sp.Rational(1, 2) * m * x.diff(t) ** 2 + sp.Rational(1, 2) * integrate(rd.dot(rd))
    V = g * integrate(r[1]) + sum(sp.Rational(1, 2) * K[j] * eta[j] ** 2 for j in range(n))
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
    params = [m, mb, I1, I2, g, F, *I3, *I5, *K, *D, *(Fa[k] for k in gsyms),
              *(Fb[k] for k in gsyms)]
    args = [*qs, *vs, *params]
    lam = lambda ex: sp.lambdify(args, ex, "numpy")  # noqa: E731
    return lam(M), lam(f), lam(energy), gsyms


N_MODES = 2


@pytest.fixture(scope="module")
def derived():
    return _derive(N_MODES)


def _values(p, model, gsyms, F):
    b = model.beam
    ij = [tuple(int(c) for c in str(k).split("_")[1]) for k in gsyms]
    return [p.m, p.rhoA * p.L, b.I1, b.I2, p.g, F, *b.I3, *b.I5, *np.diag(b.K), *np.diag(b.D),
            *(b.Fa[i, j] for i, j in ij), *(b.Fb[i, j] for i, j in ij)]


def _random_states(n, count, seed):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        q = np.r_[rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi), 1e-2 * rng.standard_normal(n)]
        v = np.r_[rng.standard_normal(), 3 * rng.standard_normal(), 10 * rng.standard_normal(n)]
        yield q, v, 100 * rng.standard_normal()


def test_rhs_mass_matrix_and_energy_match_the_derivation(derived):
    """The numpy specification and the C kernel against Lagrange's equations derived by sympy
    from the foreshortened kinematics, at random deformed, moving, tilted states."""
    M_f, f_f, E_f, gsyms = derived
    p = PlantParams(n_modes=N_MODES, zeta=0.01)
    model = stiffened_plant_model(p)
    for q, v, F in _random_states(N_MODES, 20, seed=3):
        args = [*q, *v, *_values(p, model, gsyms, F)]
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
    M_f, f_f, _, gsyms = derived
    p = PlantParams(n_modes=N_MODES, gravity_preload=True)
    pre = plant_model(p)
    worst = 0.0
    for q, v, F in _random_states(N_MODES, 5, seed=3):
        args = [*q, *v, *_values(p, stiffened_plant_model(p), gsyms, F)]
        qdd = np.linalg.solve(np.array(M_f(*args), dtype=float),
                              np.array(f_f(*args), dtype=float).ravel())
        worst = max(worst, np.linalg.norm(pre.rhs_numpy(0, np.r_[q, v], F)[N_MODES + 2:] - qdd)
                    / np.linalg.norm(qdd))
    assert worst > 1e-6


def test_foreshortening_invariants_against_the_analytic_modes():
    """``Fa = int rhoA (L - s) N'^2`` and ``Fb = int rhoA (L^2 - s^2)/2 N'^2`` of the first two
    modes against quadrature of the analytic cantilever shapes (fine mesh)."""
    from scipy.integrate import quad

    p = PlantParams(n_modes=2, n_elements=60, L=1.3, rho=5e3)
    b = beam_model(p)
    L, rhoA = p.L, p.rhoA
    for j in (1, 2):
        shape = analytic_mode_shape(p, j)
        h = 1e-6
        slope = lambda s: (shape(s + h) - shape(s - h)) / (2 * h)  # noqa: E731
        fa = quad(lambda s: rhoA * (L - s) * slope(s) ** 2, h, L - h, epsabs=0, limit=200)[0]
        fb = quad(lambda s: rhoA * 0.5 * (L * L - s * s) * slope(s) ** 2, h, L - h, epsabs=0,
                  limit=200)[0]
        assert b.Fa[j - 1, j - 1] == pytest.approx(fa, rel=1e-5)
        assert b.Fb[j - 1, j - 1] == pytest.approx(fb, rel=1e-5)


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
    specification; the kernel refuses the exact Jacobians and output derivatives by name."""
    p = PlantParams(n_modes=n, n_elements=12, zeta=0.02)
    model = stiffened_plant_model(p)
    k = model.kernel
    for q, v, F in _random_states(n, 10, seed=5 + n):
        x = np.r_[q, v]
        ref = model.rhs_numpy(0.0, x, F)
        assert np.max(np.abs(k.rhs(x, F) - ref)) <= 1e-12 * np.max(np.abs(ref))
        assert k.energy(x) == pytest.approx(model.energy_numpy(x), rel=1e-13, abs=1e-13)
        out = k.outputs(x)
        assert out[2:4] == pytest.approx(model.tip_angle_numpy(x), rel=1e-14, abs=1e-15)
    for call in (lambda: k.jacobian(x, 0.0), lambda: k.jvp(x, 0.0, x),
                 lambda: k.output_jacobian(x), lambda: k.output_derivatives(x, 0.0)):
        with pytest.raises(ValueError, match="fidelity = 'stiffened'"):
            call()


def test_both_fmu_flavours_run_the_stiffened_rung_as_the_reference(native, fmus):
    """A co-simulation of the filtered scene at ``fidelity = "stiffened"`` with the native pair
    and with the pythonfmu pair: the same outputs (the same kernel; the native FMU's Fb from its
    tables), and the monolithic reference's to the co-simulation's accuracy, which is far below
    the stiffened rung's difference from the nonlinear rung with the preload."""
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    from orchestration.studies.reference import simulate_reference

    sets = {"initial.phi": math.pi / 6, "stop_time": 0.4, "plant.zeta": 0.0}
    sc = load_scene("flexible_pd_lowpass", {**sets, "plant.fidelity": "stiffened"})
    plant = lambda paths: {"plant": paths["FlexiblePendulum"],  # noqa: E731
                           "controller": paths["PDLowPass"]}
    a = run_scene(sc, plant(native), progress=False)
    b = run_scene(sc, plant(fmus), progress=False)
    assert a.summary["stopped"] is None and b.summary["stopped"] is None
    for c in a.result.dtype.names:
        assert np.max(np.abs(a.result[c] - b.result[c])) <= 1e-10 * max(
            1.0, float(np.max(np.abs(b.result[c])))), c
    ref = simulate_reference(sc)["phi_o"]
    pre = simulate_reference(load_scene("flexible_pd_lowpass",
                                        {**sets, "plant.gravity_preload": True}))["phi_o"]
    cosim = np.max(np.abs(a.result["phi_o"] - ref))
    assert cosim < 1e-4
    assert np.max(np.abs(pre - ref)) > 3 * cosim
