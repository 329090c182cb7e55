"""Every method on the nonlinear plant (n_modes = 4) against scipy's DOP853 at rtol = 1e-12.

The force is a zero-order-hold history over five communication steps of 10 ms, as the FMU sees
it: the steppers advance from one communication point to the next with ``u`` held constant. The
reference integrates each interval separately with the same constant force.
"""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from plant_fmu.dynamics import linear_plant_model, plant_model
from plant_fmu.integrators import make_stepper
from plant_fmu.params import PlantParams

H = 0.01
FORCES = [2.0, -1.0, 3.0, 0.5, -2.0]


def reference(model, x0):
    y, out = np.array(x0, dtype=float), []
    for k, u in enumerate(FORCES):
        sol = solve_ivp(model.rhs, (k * H, (k + 1) * H), y, method="DOP853", rtol=1e-12,
                        atol=1e-14, args=(u,))
        assert sol.success
        y = sol.y[:, -1]
        out.append(y)
    return np.array(out)


@pytest.fixture(scope="module")
def plant():
    p = PlantParams(n_modes=4)
    model = plant_model(p)
    x0 = model.initial_state(phi=0.05, phi_dot=-0.2)
    x0[2:6] = [2e-3, -4e-4, 1e-4, -3e-5]          # every mode deformed
    return p, model, x0, reference(model, x0)


def drive(name, model, x0, h, **kw):
    s = make_stepper(name, model, 0.0, x0, h=h, **kw)
    out = []
    for k, u in enumerate(FORCES):
        s.u = u
        ok, msg = s.advance((k + 1) * H)
        assert ok, msg
        assert s.t == (k + 1) * H
        out.append(s.y.copy())
    return np.array(out), s


def error(out, ref):
    """The largest deviation over the communication points (the state's scale is ~0.2)."""
    return float(np.abs(out - ref).max())


# (name, options, order, substeps per communication step); the substeps put h * omega_4 (905
# rad/s, the fourth cantilever mode) in the asymptotic range of each method.
CASES = [
    ("euler", {}, 1, [1600, 3200, 6400]),
    ("symplectic_euler", {}, 1, [400, 800, 1600]),
    ("rk4", {}, 4, [100, 200, 400]),
    ("dopri5", {"adaptive": False}, 5, [50, 100, 200]),
    ("radau", {"adaptive": False, "rtol": 1e-10, "atol": 1e-10}, 5, [50, 100, 200]),
    ("genalpha", {"rho_inf": 0.8, "rtol": 1e-10, "atol": 1e-10}, 2, [200, 400, 800]),
    ("genalpha", {"rho_inf": 0.0, "rtol": 1e-10, "atol": 1e-10}, 2, [200, 400, 800]),
    ("genalpha", {"rho_inf": 0.8, "rtol": 1e-10, "atol": 1e-10, "residual": "mass"}, 2,
     [200, 400, 800]),
]


@pytest.mark.parametrize("name,kw,p,nsub", CASES,
                         ids=[c[0] + str(c[1].get("rho_inf", "")) + c[1].get("residual", "")
                              for c in CASES])
def test_every_method_converges_to_dop853_at_its_order(plant, name, kw, p, nsub):
    _, model, x0, ref = plant
    hs = [H / n for n in nsub]
    errs = [error(drive(name, model, x0, h, **kw)[0], ref) for h in hs]
    order = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert errs[-1] < errs[0] and errs[-1] > 1e-11, errs
    assert order >= p - 0.2, (order, errs)


@pytest.mark.parametrize("name", ["dopri5", "radau"])
def test_adaptive_methods_on_the_plant_meet_their_tolerance(plant, name):
    _, model, x0, ref = plant
    errs = []
    for rtol in (1e-5, 1e-7, 1e-9):
        out, s = drive(name, model, x0, 1e-4, rtol=rtol, atol=rtol * 1e-2)
        errs.append(error(out, ref))
        assert errs[-1] < 300 * rtol, (rtol, errs)
        assert s.nrejected < s.nsteps
    assert errs[0] > errs[1] > errs[2]


def test_genalpha_mass_and_acceleration_residuals_agree(plant):
    """The two Newton residuals have the same root: results agree to the Newton tolerance."""
    _, model, x0, _ = plant
    kw = dict(h=H / 100, rtol=1e-10, atol=1e-12)
    a = drive("genalpha", model, x0, **kw)[0]
    b, s = drive("genalpha", model, x0, residual="mass", **kw)
    assert np.abs(a - b).max() < 1e-8 * np.abs(a).max()
    assert s.njev >= 1


@pytest.mark.parametrize("nsub", [1, 7])
def test_exponential_is_exact_on_the_linearised_plant(plant, nsub):
    """The exponential integrates the linearised plant: exact for any substep against DOP853."""
    p, _, x0, _ = plant
    lin = linear_plant_model(p)
    ref = reference(lin, x0)
    for model in (lin, plant_model(p)):      # the nonlinear model gives its linearisation
        out, s = drive("exponential", model, x0, H / nsub)
        assert error(out, ref) < 1e-10 * np.abs(ref).max()
        assert s.nfev == 0


@pytest.mark.parametrize("max_halvings,ok", [(0, False), (3, True)])
def test_genalpha_halves_a_substep_whose_newton_iteration_fails(max_halvings, ok):
    """n_modes = 8 at h = 1 ms (h omega ~ 9 for the highest coupled mode) from a state with every
    mode deformed: the first Newton iteration diverges from the predictor; two half substeps
    converge, and the stepper carries on on its 1 ms grid."""
    model = plant_model(PlantParams(n_modes=8))
    x0 = model.initial_state(phi=0.05, phi_dot=-0.2)
    x0[2:model.nq] = 1e-3 * (-0.3) ** np.arange(8)
    s = make_stepper("genalpha", model, 0.0, x0, h=1e-3, max_halvings=max_halvings)
    res = s.advance(0.02)
    if ok:
        assert res == (True, None) and s.nrejected >= 1 and s.nsteps == 20 and s.t == 0.02
    else:
        assert not res[0] and "Newton" in res[1] and np.all(np.isfinite(s.y))


# ---------------------------------------------------------------------- polynomial inputs
#: u(t) = a + b (t - t_k) + c (t - t_k)^2 / 2 over each communication step [t_k, t_k + H]
POLY = [(2.0, 300.0, -4e4), (-1.0, -150.0, 2e4), (3.0, 0.0, 1e5)]


def poly_reference(model, x0):
    y, out = np.array(x0, dtype=float), []
    for k, (a, b, c) in enumerate(POLY):
        tk = k * H
        sol = solve_ivp(lambda t, x: model.rhs(t, x, a + (t - tk) * (b + 0.5 * (t - tk) * c)),
                        (tk, tk + H), y, method="DOP853", rtol=1e-12, atol=1e-14)
        assert sol.success
        y = sol.y[:, -1]
        out.append(y)
    return np.array(out)


def _drive_poly(model, x0, name, h, held=False):
    s = make_stepper(name, model, 0.0, x0, h=h, rtol=1e-11, atol=1e-13)
    out = []
    for k, (a, b, c) in enumerate(POLY):
        if held:
            s.u = a + b * H / 2 + c * H * H / 6              # the polynomial's step average
        else:
            s.set_input(a, b, c)
        assert s.advance((k + 1) * H) == (True, None)
        out.append(s.y.copy())
    return np.array(out)


@pytest.mark.parametrize("name,order,steps", [("rk4", 4, (2.5e-4, 1.25e-4, 6.25e-5))])
def test_polynomial_input_converges_at_the_method_order(plant, name, order, steps):
    """set_input(u, du, d2u): driven by the polynomial, the method converges to the reference
    driven by the same polynomial at its own order; holding the step average instead leaves an
    error that does not fall with the substep (a different input)."""
    _, model, x0, _ = plant
    ref = poly_reference(model, x0)
    scale = np.abs(ref).max()
    errs = [np.abs(_drive_poly(model, x0, name, h) - ref).max() / scale for h in steps]
    held = np.abs(_drive_poly(model, x0, name, steps[-1], held=True) - ref).max() / scale
    slopes = np.diff(np.log(errs)) / np.diff(np.log(steps))
    assert np.all(slopes > order - 0.2), (errs, slopes)
    assert errs[-1] < held / 10, (errs, held)


def test_adaptive_dopri5_meets_its_tolerance_with_a_polynomial_input(plant):
    _, model, x0, _ = plant
    ref = poly_reference(model, x0)
    scale = np.abs(ref).max()
    err = np.abs(_drive_poly(model, x0, "dopri5", 1e-3) - ref).max() / scale
    held = np.abs(_drive_poly(model, x0, "dopri5", 1e-3, held=True) - ref).max() / scale
    assert err < 1e-8 < held / 100, (err, held)


def test_held_only_methods_refuse_a_polynomial_input(plant):
    _, model, x0, _ = plant
    s = make_stepper("genalpha", model, 0.0, x0, h=1e-3)
    with pytest.raises(ValueError, match="held input only"):
        s.set_input(1.0, 2.0)
    s.set_input(1.0)                    # a constant is fine
    assert s.advance(1e-3) == (True, None)
