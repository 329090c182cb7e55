"""The equations of motion derived symbolically (sympy) by Lagrange, against the numeric rhs.

The derivation starts from the kinematics of docs/model.md section 2, not from its energies:
``r(s) = (x, 0) + s b1 + w(s) b2`` with ``b1 = (-sin phi, cos phi)``, ``b2 = (-cos phi, -sin phi)``
and ``w = sum N_j(s) eta_j``. The kinetic energy ``1/2 m xd^2 + 1/2 int rhoA |rd|^2 ds`` and the
gravity potential ``g int rhoA y ds`` are expanded as polynomials in ``s`` and the shape values
``N_j``; each moment is then replaced by its invariant (``int rhoA = rhoA L``, ``int rhoA s = I1``,
``int rhoA s^2 = I2``, ``int rhoA N_j = I3_j``, ``int rhoA N_j N_k = I4_jk``, ``int rhoA s N_j =
I5_j``). Strain energy ``1/2 eta^T K eta``, Rayleigh dissipation ``1/2 etad^T D etad``, the
generalised force ``[F_c, 0, ...]`` of a force on the cart, and for the gravity preload the
foreshortening potential ``-1/2 cos(phi) eta^T Kg eta`` complete the Lagrangian.
"""
import numpy as np
import pytest
import sympy as sp

from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams


def _derive(n: int, preload: bool):
    """Symbolic M(q) and f(q, qd, F) of ``M qdd = f``, as numeric functions of the beam data."""
    t = sp.Symbol("t")
    x, phi = sp.Function("x")(t), sp.Function("phi")(t)
    eta = [sp.Function(f"eta{j}")(t) for j in range(n)]
    q = [x, phi, *eta]
    s = sp.Symbol("s")
    N = sp.symbols(f"N0:{n}")
    m, mb, I1, I2, g, F = sp.symbols("m mb I1 I2 g F")
    I3 = sp.symbols(f"I3_0:{n}")
    I5 = sp.symbols(f"I5_0:{n}")
    I4 = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"I4_{min(i, j)}{max(i, j)}"))
    K = sp.symbols(f"K0:{n}")
    D = sp.symbols(f"D0:{n}")
    Kg = sp.Matrix(n, n, lambda i, j: sp.Symbol(f"Kg_{min(i, j)}{max(i, j)}"))

    w = sum((N[j] * eta[j] for j in range(n)), sp.Integer(0))
    b1 = sp.Matrix([-sp.sin(phi), sp.cos(phi)])
    b2 = sp.Matrix([-sp.cos(phi), -sp.sin(phi)])
    r = sp.Matrix([x, 0]) + s * b1 + w * b2
    rd = r.diff(t)

    def integrate(expr):
        """int rhoA (polynomial in s and N_j) ds, moment by moment."""
        poly = sp.Poly(sp.expand(expr), s, *N)
        total = sp.Integer(0)
        for powers, coeff in poly.terms():
            ps, pn = powers[0], powers[1:]
            idx = [j for j, p in enumerate(pn) for _ in range(p)]
            if not idx:
                moment = {0: mb, 1: I1, 2: I2}[ps]
            elif len(idx) == 1 and ps == 0:
                moment = I3[idx[0]]
            elif len(idx) == 1 and ps == 1:
                moment = I5[idx[0]]
            elif len(idx) == 2 and ps == 0:
                moment = I4[idx[0], idx[1]]
            else:
                raise AssertionError(f"unexpected moment s^{ps} N{idx}")
            total += coeff * moment
        return total

    T = sp.Rational(1, 2) * m * x.diff(t) ** 2 + sp.Rational(1, 2) * integrate(rd.dot(rd))
    V = g * integrate(r[1]) + sum(sp.Rational(1, 2) * K[j] * eta[j] ** 2 for j in range(n))
    if preload:
        e = sp.Matrix(eta)
        V += -sp.Rational(1, 2) * sp.cos(phi) * (e.T * Kg * e)[0, 0]
    R = sum(sp.Rational(1, 2) * D[j] * eta[j].diff(t) ** 2 for j in range(n))
    L = T - V
    Q = [F] + [0] * (n + 1)

    qs = sp.symbols(f"q0:{n + 2}")
    vs = sp.symbols(f"v0:{n + 2}")
    acc = sp.symbols(f"a0:{n + 2}")
    sub = {}
    for qi, qsym, vsym, asym in zip(q, qs, vs, acc):
        sub[qi.diff(t, 2)] = asym
        sub[qi.diff(t)] = vsym
    sub_q = dict(zip(q, qs))
    eqs = []
    for i, qi in enumerate(q):
        lhs = sp.diff(L, qi.diff(t)).diff(t) - sp.diff(L, qi) + sp.diff(R, qi.diff(t)) - Q[i]
        eqs.append(lhs.subs(sub).subs(sub_q))
    # eqs = M a - f  ->  M = d eqs / d a,  f = -(eqs at a = 0)
    M = sp.Matrix([[sp.diff(e, a) for a in acc] for e in eqs])
    f = sp.Matrix([-e.subs({a: 0 for a in acc}) for e in eqs])
    T_num = T.subs(sub).subs(sub_q)
    upper = lambda A: [A[i, j] for i in range(n) for j in range(i, n)]  # noqa: E731
    params = [m, mb, I1, I2, g, F, *I3, *I5, *K, *D, *upper(I4), *upper(Kg)]
    args = [*qs, *vs, *params]
    energy = T_num + V.subs(sub_q)
    # The Jacobian's ingredients, differentiated by sympy: df/d(q, qd, F) and dM/dq_k
    z = [*qs, *vs]
    dfdz = f.jacobian([*z, F])
    dMdq = [M.diff(qk) for qk in qs]
    # The tip angle phi_o = phi + atan(N'(L) eta) and its rate omega_o = d/dt phi_o (by the
    # chain rule on q(t)), with the tip slopes and deflections as symbols
    ts = sp.symbols(f"ts0:{n}")
    td = sp.symbols(f"td0:{n}")
    phi_o = phi + sp.atan(sum((ts[j] * eta[j] for j in range(n)), sp.Integer(0)))
    omega_o = phi_o.diff(t)
    outs_t = sp.Matrix([x, x.diff(t), phi_o, omega_o, phi,
                        sum((td[j] * eta[j] for j in range(n)), sp.Integer(0)), T + V, *eta])
    outs = outs_t.subs(sub).subs(sub_q)
    out_args = [*z, *params, *ts, *td]
    # their first and second time derivatives along q(t), with the accelerations acc and the
    # jerks jerk as symbols (tests/common/test_jacobian.py gives them their values)
    jerk = sp.symbols(f"j0:{n + 2}")
    sub3 = {qi.diff(t, 3): js for qi, js in zip(q, jerk)}
    d_outs = [outs_t.diff(t, k).subs(sub3).subs(sub).subs(sub_q) for k in (1, 2)]
    lam = lambda e: sp.lambdify(args, e, "numpy")  # noqa: E731
    return (lam(M), lam(f), lam(energy), n,
            {"dfdz": lam(dfdz), "dMdq": [lam(d) for d in dMdq], "M": M, "f": f, "args": args,
             "F": F,
             "outputs": sp.lambdify(out_args, outs, "numpy"),
             "doutputs": sp.lambdify(out_args, outs.jacobian(z), "numpy"),
             "time_derivatives": sp.lambdify([*out_args, *acc, *jerk], d_outs, "numpy")})


@pytest.fixture(scope="module", params=[(1, False), (2, False), (2, True)],
                ids=["n1", "n2", "n2-preload"])
def case(request):
    n, preload = request.param
    p = PlantParams(n_modes=n, gravity_preload=preload)
    return p, plant_model(p), _derive(n, preload)


def _param_values(p, model, F):
    b = model.beam
    n = p.n_modes
    I4 = np.eye(n)
    Kg = b.Kg if p.gravity_preload else np.zeros((n, n))
    upper = lambda A: [A[i, j] for i in range(n) for j in range(i, n)]  # noqa: E731
    return [p.m, p.rhoA * p.L, b.I1, b.I2, p.g, F, *b.I3, *b.I5, *np.diag(b.K), *np.diag(b.D),
            *upper(I4), *upper(Kg)]


def _random_states(model, count=20, seed=7):
    rng = np.random.default_rng(seed)
    n = model.n
    for _ in range(count):
        q = np.r_[rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi), 1e-2 * rng.standard_normal(n)]
        v = np.r_[rng.standard_normal(), rng.standard_normal(), 10 * rng.standard_normal(n)]
        yield q, v, 100 * rng.standard_normal()


def test_rhs_matches_symbolic_lagrange_equations(case):
    p, model, (M_f, f_f, _, n, _) = case
    for q, v, F in _random_states(model):
        args = [*q, *v, *_param_values(p, model, F)]
        qdd = np.linalg.solve(np.array(M_f(*args), dtype=float), np.array(f_f(*args), dtype=float).ravel())
        expected = np.r_[v, qdd]
        got = model.rhs(0.0, np.r_[q, v], F)
        assert np.linalg.norm(got - expected) <= 1e-9 * np.linalg.norm(expected)
        got_np = model.rhs_numpy(0.0, np.r_[q, v], F)
        assert np.linalg.norm(got_np - expected) <= 1e-9 * np.linalg.norm(expected)


def test_mass_matrix_and_energy_match_symbolic(case):
    p, model, (M_f, _, E_f, n, _) = case
    for q, v, F in _random_states(model, count=10, seed=11):
        args = [*q, *v, *_param_values(p, model, F)]
        np.testing.assert_allclose(model.mass_matrix(q), np.array(M_f(*args), dtype=float),
                                   rtol=1e-12, atol=1e-12)
        assert model.energy(np.r_[q, v]) == pytest.approx(float(E_f(*args)), rel=1e-12)


def _symbolic_jacobian(p, model, sym, q, v, F):
    """``(J, b)`` of the right-hand side from sympy's derivatives of ``M`` and ``f``:
    ``d qdd/dz = M^-1 (df/dz - (dM/dz) qdd)``."""
    M_f, f_f, _, n, d = sym
    args = [*q, *v, *_param_values(p, model, F)]
    M = np.array(M_f(*args), dtype=float)
    qdd = np.linalg.solve(M, np.array(f_f(*args), dtype=float).ravel())
    nq = n + 2
    dfdz = np.array(d["dfdz"](*args), dtype=float)            # nq x (2 nq + 1)
    rhs = dfdz.copy()
    for k in range(nq):
        rhs[:, k] -= np.array(d["dMdq"][k](*args), dtype=float) @ qdd
    da = np.linalg.solve(M, rhs)
    J = np.zeros((2 * nq, 2 * nq))
    J[:nq, nq:] = np.eye(nq)
    J[nq:] = da[:, :2 * nq]
    b = np.r_[np.zeros(nq), da[:, 2 * nq]]
    return J, b


def test_jacobian_matches_symbolic_derivatives(case):
    """The hand-differentiated Jacobian of the numpy model (the kernel's specification) against
    sympy's derivatives of the Lagrange equations, at random deformed, moving, tilted states."""
    p, model, sym = case
    for q, v, F in _random_states(model, count=10, seed=13):
        J_sym, b_sym = _symbolic_jacobian(p, model, sym, q, v, F)
        J, b = model.jacobian_numpy(np.r_[q, v], F)
        np.testing.assert_allclose(J, J_sym, rtol=0, atol=1e-10 * np.abs(J_sym).max())
        np.testing.assert_allclose(b, b_sym, rtol=0, atol=1e-12 * np.abs(b_sym).max())


def test_output_jacobian_matches_symbolic_derivatives(case):
    """The outputs (omega_o derived by sympy as d/dt phi_o) and their Jacobian against the
    numpy model's and the kernel's."""
    p, model, sym = case
    d = sym[4]
    extra = [*model.tip_slope, *model.tip_defl]
    for q, v, F in _random_states(model, count=10, seed=17):
        x = np.r_[q, v]
        args = [*q, *v, *_param_values(p, model, F), *extra]
        outs = np.array(d["outputs"](*args), dtype=float).ravel()
        o = model.outputs(0.0, x)
        got = np.r_[o["x_o"], o["x_dot"], o["phi_o"], o["omega_o"], x[1], o["tip_deflection"],
                    o["energy"], o["eta"]]
        np.testing.assert_allclose(got, outs, rtol=1e-12, atol=1e-12)
        C_sym = np.array(d["doutputs"](*args), dtype=float)
        C = model.output_jacobian_numpy(x)
        np.testing.assert_allclose(C, C_sym, rtol=0, atol=1e-11 * np.abs(C_sym).max())


def test_jacobian_of_the_fully_symbolic_accelerations():
    """n = 1: the accelerations solved symbolically (qdd = M^-1 f, no identity used) and
    differentiated by sympy, against the numpy model's Jacobian."""
    p = PlantParams(n_modes=1, gravity_preload=True)
    model = plant_model(p)
    d = _derive(1, True)[4]
    args, nq = d["args"], 3
    qdd = d["M"].LUsolve(d["f"])
    z = args[:2 * nq]
    rhs = sp.Matrix([*z[nq:], *qdd])
    J_f = sp.lambdify(args, rhs.jacobian([*z, d["F"]]), "numpy")
    for q, v, F in _random_states(model, count=5, seed=19):
        J_all = np.array(J_f(*q, *v, *_param_values(p, model, F)), dtype=float)
        J, b = model.jacobian_numpy(np.r_[q, v], F)
        np.testing.assert_allclose(J, J_all[:, :2 * nq], rtol=0, atol=1e-10 * np.abs(J).max())
        np.testing.assert_allclose(b, J_all[:, 2 * nq], rtol=0, atol=1e-12 * np.abs(b).max())
