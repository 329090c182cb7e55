"""The co-simulation's stability boundaries: the transition matrix of one communication step
(orchestration/studies/stability.py) against independent computations, and the real (native) FMUs on
the master at three points just inside and three just outside each predicted boundary, for held
inputs and for polynomial ones (input derivatives, Taylor extrapolation from output derivatives).

Observation: the co-simulation's output samples (one per communication step) of a small motion
(initial.phi = 1e-3) are realised as a linear system (block-Hankel matrix, Kung's method); its
largest pole is the observed growth factor per step. With ``plant.fidelity = linear`` the samples
are exactly those of a linear system, so the observed factor must equal the predicted spectral
radius to rounding, and the verdict (grow or decay) must be the predicted one at every point. The
points are 0.9, 0.95, 0.98 and 1.02, 1.05, 1.1 times the critical value; there the predicted
spectral radius differs from 1 by at least 1.7e-5 per step (the weakest boundary, Jacobi with the
zero-order hold, where the rigid mode crosses), far above what rounding moves it (< 1e-9 in these
runs). The nonlinear plant is used at one boundary where the crossing mode grows fast: the
nonlinear terms at phi ~ 1e-3 are ~1e-6 of the motion, so only the verdict is compared there.
"""
import math

import numpy as np
import pytest
from conftest import hand_stepped

from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
from orchestration.studies.analysis import max_real_part
from orchestration.job import run_scene
from orchestration.scene.schema import load_scene, scene_from_config
from orchestration.studies.stability import (FIXED_STEP_METHODS, METHODS, POLYNOMIAL_METHODS,
                                             controller_polynomial_step_map, critical_step,
                                             critical_value,
                                             highest_mode, integrator_step_limit,
                                             observed_spectral_radius,
                                             plant_polynomial_step_map, plant_step_map,
                                             scene_transition_matrix, spectral_radius,
                                             transition_matrix)
from plant_fmu.dynamics import linear_plant_model
from plant_fmu.integrators import make_stepper
from plant_fmu.params import PlantParams

FACTORS = (0.9, 0.95, 0.98, 1.02, 1.05, 1.1)
#: the paper's flexible plant (4 modes) and the controller's default filter (2nd order, 150 rad/s)
BASE = {"plant.n_modes": 4, "controller.filter_order": 2, "controller.cutoff": 150.0,
        "controller.filter_damping": 0.5, "controller.kp": 500.0, "controller.kd": 5.0,
        "initial.phi": 1e-3, "plant.phi_limit": math.inf, "plant.energy_limit": math.inf,
        # the transition matrices model held inputs (the step average of the polynomial)
        "master.input_derivatives": False}
OBSERVED = ["phi_o", "omega_o", "F_c", "phi", "eta_1", "eta_2", "eta_3", "eta_4"]
N_STEPS = 60


@pytest.fixture(scope="module")
def paths(native):
    """The native FMUs (the scenes' default, master.fmus = "native"; they give output
    derivatives)."""
    return {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}


def _scene(**values):
    H = values["master.step"]
    n = values.pop("n_steps", N_STEPS)
    return scene_from_config("stability", {**BASE, "output_interval": H, "stop_time": n * H,
                                           **values})


def _observe(scene, paths):
    """Observed growth factor per communication step (the start-up steps, whose map differs,
    left out); ``inf`` if the co-simulation diverged. The plant step's preflight is skipped: the
    substep-limit points beyond it are what is observed here."""
    r = run_scene(scene, paths, progress=False, check_step=False)
    if r.summary["stopped"] is not None:
        return math.inf
    skip = scene.master.extrapolation + 2
    Y = np.column_stack([r.result[c] for c in OBSERVED])[skip:]
    rtol = 1e-8 if scene.plant.fidelity == "linear" else 1e-6
    return observed_spectral_radius(Y, rtol=rtol)


# ---------------------------------------------------------------------- the matrix itself
@pytest.mark.parametrize("method", METHODS)
def test_plant_step_map_is_the_steppers_map(method):
    """The plant's map over one communication step (off the substep grid: 4 substeps and a
    shortened one) equals the real stepper's, probed column by column on the linear plant."""
    p = PlantParams(n_modes=2)
    m = linear_plant_model(p)
    H, h = 1.1e-3, 2.5e-4
    Phi, Gamma = plant_step_map(method, m.A, m.B, m.nq, H, h)
    opts = {"adaptive": False} if method in ("dopri5", "radau") else {}
    cols = []
    for i in range(m.nx + 1):
        y0, u = np.zeros(m.nx), 0.0
        if i < m.nx:
            y0[i] = 1.0
        else:
            u = 1.0
        st = make_stepper(method, m, 0.0, y0, u=u, h=h, **opts)
        assert st.advance(H) == (True, None)
        cols.append(st.y)
    probed = np.array(cols).T
    np.testing.assert_allclose(np.hstack([Phi, Gamma]), probed, rtol=0,
                               atol=1e-12 * np.abs(probed).max())


@pytest.mark.parametrize("method", FIXED_STEP_METHODS)
def test_polynomial_plant_map_is_the_steppers_map(method):
    """The plant's map for a polynomial input (FMI's input derivatives) equals the real stepper
    given ``set_input(u, du, d2u)`` (the RK stages at their stage times), or, for the methods
    that hold an input, given the polynomial's average over the step (as the plant FMU's
    do_step): probed column by column, off the substep grid."""
    p = PlantParams(n_modes=2)
    m = linear_plant_model(p)
    H, h = 1.1e-3, 2.5e-4
    Phi, Gamma = plant_polynomial_step_map(method, m.A, m.B, m.nq, H, h)
    cols = []
    for i in range(m.nx + 3):
        y0, u = np.zeros(m.nx), np.zeros(3)
        if i < m.nx:
            y0[i] = 1.0
        else:
            u[i - m.nx] = 1.0
        st = make_stepper(method, m, 0.0, y0, h=h)
        if method in POLYNOMIAL_METHODS:
            st.set_input(*u, t=0.0)
        else:
            st.u = u[0] + H * (0.5 * u[1] + H * u[2] / 6.0)
        assert st.advance(H) == (True, None)
        cols.append(st.y)
    probed = np.array(cols).T
    np.testing.assert_allclose(np.hstack([Phi, Gamma]), probed, rtol=0,
                               atol=1e-12 * np.abs(probed).max())
    with pytest.raises(ValueError, match="dopri5"):
        plant_polynomial_step_map("dopri5", m.A, m.B, m.nq, H, h)


def test_controller_polynomial_map_is_the_filter_driven_by_the_polynomial():
    """The controller's map for polynomial sensors against the filter's ODE driven by the
    polynomial error signal, integrated by scipy to 1e-12."""
    from scipy.integrate import solve_ivp
    c = ControllerParams(kx=3.0)
    ctrl = PDLowPassModel(c)
    H = 7e-3
    Ad, G = controller_polynomial_step_map(c, H)
    xc0, y = np.array([0.3, -2.0]), np.array([[0.1, 0.2, -0.5], [1.0, -3.0, 2.0],
                                               [20.0, 5.0, -7.0]])   # y, y', y''
    e = ctrl.gains[0] @ y.T
    sol = solve_ivp(lambda s, xc: ctrl.Af @ xc + ctrl.Bf[:, 0] * (e[0] + e[1] * s
                                                                  + e[2] * s * s / 2),
                    (0, H), xc0, rtol=1e-12, atol=1e-14, method="DOP853")
    np.testing.assert_allclose(Ad @ xc0 + G @ y.ravel(), sol.y[:, -1], rtol=1e-9)


@pytest.mark.parametrize("method", ["rk4", "genalpha"])
@pytest.mark.parametrize("algorithm,first,e,ind,outd", [
    ("jacobi", "controller", 1, True, True), ("gauss-seidel", "plant", 2, False, False),
    ("gauss-seidel", "controller", 2, True, False), ("implicit", "controller", 1, False, False)])
def test_a_stack_of_steps_is_the_matrices_one_by_one(method, algorithm, first, e, ind, outd):
    """``transition_matrix`` of a 1-d array of steps (the scan's path: the substep's powers and
    the filter's exponentials formed once for the stack) equals its matrices computed one step
    at a time, on and off the substep grid, start-up steps included."""
    p, c = PlantParams(n_modes=2), ControllerParams()
    Hs = np.array([1e-4, 1.1e-3, 5e-3, 2.31e-2])
    for step_index in (None, 0):
        stack = transition_matrix(p, c, Hs, algorithm=algorithm, first=first, extrapolation=e,
                                  input_derivatives=ind, output_derivatives=outd,
                                  integrator=method, step_index=step_index)
        for k, H in enumerate(Hs):
            one = transition_matrix(p, c, float(H), algorithm=algorithm, first=first,
                                    extrapolation=e, input_derivatives=ind,
                                    output_derivatives=outd, integrator=method,
                                    step_index=step_index)
            np.testing.assert_allclose(stack[k], one, rtol=0, atol=1e-13 * np.abs(one).max())


def test_stability_functions_at_known_limits():
    """Textbook limits on the imaginary axis and for a damped mode."""
    assert integrator_step_limit("rk4", 1j) == pytest.approx(2 * math.sqrt(2), rel=1e-6)
    assert integrator_step_limit("symplectic_euler", 1j) == pytest.approx(2.0, rel=1e-6)
    zeta = 0.01     # |1 + h lam| = 1 at h = 2 zeta / w for explicit Euler
    assert integrator_step_limit("euler", complex(-zeta, math.sqrt(1 - zeta ** 2))) == \
        pytest.approx(2 * zeta, rel=1e-6)
    assert integrator_step_limit("euler", 1j) == 0.0
    for method in ("genalpha", "radau", "exponential"):        # A-stable
        assert integrator_step_limit(method, complex(-0.001, 1.0)) is None


@pytest.mark.parametrize("filter_order", [2, 0])
@pytest.mark.parametrize("algorithm,first", [("jacobi", "controller"),
                                             ("gauss-seidel", "controller"),
                                             ("gauss-seidel", "plant")])
@pytest.mark.parametrize("p_extra", [0, 2])
def test_small_step_limit_is_the_continuous_loop(filter_order, algorithm, first, p_extra):
    """log(rho)/H tends to the largest real part of the continuous closed loop (analysis.py),
    the error falling with H (the filtered loop: -0.263; the PD alone: +1.64, unstable)."""
    p, c = PlantParams(n_modes=4), ControllerParams(filter_order=filter_order)
    exact = max_real_part(p, c)
    errs = []
    for H in (1e-4, 5e-5):
        rho = spectral_radius(transition_matrix(p, c, H, algorithm=algorithm, first=first,
                                                extrapolation=p_extra))
        errs.append(abs(math.log(rho) / H - exact))
    assert errs[1] < 0.02 * abs(exact), (exact, errs)
    assert errs[1] < 0.6 * errs[0] or errs[1] < 1e-6 * abs(exact), errs


@pytest.mark.parametrize("p_extra", [0, 1, 2])
def test_gauss_seidel_orders_have_one_spectrum(p_extra):
    """Controller-first and plant-first compose the same two maps in the two cyclic orders, so
    their characteristic polynomials agree (the loop is a product of commuting scalar weights and
    the two FMUs' maps): the same eigenvalues, up to the zeros of the sample registers (defective,
    so rounding scatters them to ~1e-2; only those above 0.2 are compared)."""
    p, c = PlantParams(n_modes=3), ControllerParams()
    for H in (2e-3, 2.3e-2):
        ev = [np.sort_complex(np.linalg.eigvals(transition_matrix(
            p, c, H, algorithm="gauss-seidel", first=f, extrapolation=p_extra)))
            for f in ("controller", "plant")]
        big = [e[np.abs(e) > 0.2] for e in ev]
        np.testing.assert_allclose(big[0], big[1], atol=1e-9)



def _assert_hand_stepped(scene, paths):
    """The master with the real FMUs on ``scene`` (its plant step's preflight skipped) against
    its transition matrices stepped by hand (``hand_stepped``): every sample of phi_o, omega_o,
    x and F_c, to 1e-10 of each column's largest value."""
    res = run_scene(scene, paths, progress=False, check_step=False).result
    hand = hand_stepped(scene, len(res))
    for j, col in enumerate(("phi_o", "omega_o", "x", "F_c")):
        scale = np.abs(res[col]).max()
        np.testing.assert_allclose(res[col], hand[:, j], rtol=0, atol=1e-10 * scale,
                                   err_msg=col)


#: the couplings of the hand-stepped comparison: (extrapolation, input derivatives, output
#: derivatives, plant integrator); the scenes' default is (2, True, False, "rk4")
COUPLINGS = [(0, False, False, "rk4"), (1, False, False, "rk4"), (2, False, False, "rk4"),
             (1, True, False, "rk4"), (2, True, False, "rk4"), (1, True, True, "rk4"),
             (2, True, True, "rk4"), (2, True, False, "symplectic_euler"),
             (2, True, False, "euler"), (2, True, True, "exponential")]


@pytest.mark.parametrize("filter_order", [2, 0])
@pytest.mark.parametrize("algorithm,first", [("jacobi", "controller"),
                                             ("gauss-seidel", "controller"),
                                             ("gauss-seidel", "plant")])
@pytest.mark.parametrize("p_extra,in_der,out_der,method", COUPLINGS,
                         ids=[f"p{c[0]}{'-in' if c[1] else ''}{'-out' if c[2] else ''}-{c[3]}"
                              for c in COUPLINGS])
def test_hand_stepped_map_matches_the_master_step_for_step(paths, filter_order, algorithm, first,
                                                           p_extra, in_der, out_der, method):
    """The linear map stepped by hand (start-up steps with fewer samples included) against the
    master with the real FMUs and the linear plant: every sample of phi_o, omega_o, x and F_c, at
    a step off the plant's substep grid (4 substeps of 2.5e-4 and one of 1e-4), for held and
    polynomial inputs (input derivatives) and Taylor extrapolation (output derivatives)."""
    H = 1.1e-3
    scene = _scene(**{"master.step": H, "master.algorithm": algorithm, "master.first": first,
                      "master.extrapolation": p_extra, "master.input_derivatives": in_der,
                      "master.output_derivatives": out_der, "plant.integrator": method,
                      "plant.fidelity": "linear", "plant.n_modes": 2,
                      "controller.filter_order": filter_order, "controller.kx": 3.0,
                      "n_steps": 25})
    # explicit Euler is beyond its limit on the damped modes (the plant step's preflight would
    # refuse it): the map is compared, stable or not
    _assert_hand_stepped(scene, paths)


@pytest.mark.parametrize("filter_order", [2, 0])
@pytest.mark.parametrize("first", ["plant", "controller"])
@pytest.mark.parametrize("method", ["rk4", "exponential"])
def test_hand_stepped_hermite_map_matches_the_master_step_for_step(paths, filter_order, first,
                                                                   method):
    """The Hermite coupling's map (``coupling = "hermite"``) stepped by hand from the master's
    consistent initial outputs against the master with the real FMUs and the linear plant, as
    above: either FMU first, a filter or none (feedthrough), a polynomial plant method and one
    that holds its input's average."""
    H = 1.1e-3
    scene = _scene(**{"master.step": H, "master.algorithm": "gauss-seidel",
                      "master.first": first, "master.coupling": "hermite",
                      "master.input_derivatives": True, "plant.integrator": method,
                      "plant.fidelity": "linear", "plant.n_modes": 2,
                      "controller.filter_order": filter_order, "controller.kx": 3.0,
                      "n_steps": 25})
    _assert_hand_stepped(scene, paths)


# ---------------------------------------------------------------------- co-simulation step limits
#: (algorithm, first, extrapolation, plant fidelity): boundaries in H at the default cutoff
STEP_LIMITS = [("jacobi", "controller", 0, "linear"),        # the rigid mode crosses, ~3.3 ms
               ("jacobi", "controller", 1, "linear"),        # the 1st bending mode, ~18 ms
               ("gauss-seidel", "plant", 2, "linear"),       # the 1st bending mode, ~20 ms
               ("jacobi", "controller", 1, "nonlinear")]


@pytest.fixture(scope="module")
def step_limits():
    out = {}
    p, c = PlantParams(n_modes=4), ControllerParams(cutoff=150.0, filter_damping=0.5)
    for alg, first, e, _ in STEP_LIMITS:
        f = lambda H, a=alg, fi=first, x=e: spectral_radius(  # noqa: E731
            transition_matrix(p, c, H, algorithm=a, first=fi, extrapolation=x))
        out[alg, first, e] = critical_value(f, 1e-3, 4e-2, n=60)
    return out


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("alg,first,e,fidelity", STEP_LIMITS,
                         ids=["jacobi-zoh", "jacobi-linear", "gs-plant-first-quadratic",
                              "jacobi-linear-nonlinear-plant"])
def test_cosimulation_step_limit(paths, step_limits, alg, first, e, fidelity, factor):
    Hc = step_limits[alg, first, e]
    assert Hc is not None
    scene = _scene(**{"master.step": factor * Hc, "master.algorithm": alg, "master.first": first,
                      "master.extrapolation": e, "plant.fidelity": fidelity})
    predicted = spectral_radius(scene_transition_matrix(scene))
    assert (predicted < 1) == (factor < 1), predicted      # a clean boundary at this margin
    observed = _observe(scene, paths)
    assert (observed < 1) == (predicted < 1), (predicted, observed)
    if fidelity == "linear":
        assert observed == pytest.approx(predicted, abs=1e-3 * abs(predicted - 1)), \
            (predicted, observed)


#: boundaries of polynomial couplings on the filtered scene (flexible_pd_lowpass, its filter 97.3
#: rad/s, damping 0.1): (algorithm, first, extrapolation, output derivatives), all with input
#: derivatives; the first is the scenes' default coupling (14.6 ms), the third the largest step
POLYNOMIAL_LIMITS = [("gauss-seidel", "controller", 2, False),
                     ("gauss-seidel", "controller", 2, True),
                     ("gauss-seidel", "controller", 1, False),
                     ("gauss-seidel", "plant", 1, True)]


def _filtered(H, alg, first, e, out_der, coupling="polynomial"):
    sets = {"initial.phi": 1e-3, "plant.phi_limit": "inf", "plant.energy_limit": "inf",
            "plant.fidelity": "linear", "master.step": H, "output_interval": H,
            "stop_time": N_STEPS * H, "master.algorithm": alg, "master.first": first,
            "master.extrapolation": e, "master.input_derivatives": "true",
            "master.output_derivatives": str(out_der).lower(), "master.coupling": coupling}
    return load_scene("flexible_pd_lowpass", [f"{k}={v}" for k, v in sets.items()])


def _assert_growth_is_predicted(scene, paths, stable: bool):
    """The scene's predicted spectral radius is on the ``stable`` side of 1, and the native
    FMUs' observed growth factor per step is on the same side and equals it (to 1e-3 of its
    distance from 1)."""
    predicted = spectral_radius(scene_transition_matrix(scene))
    assert (predicted < 1) == stable, predicted       # a clean boundary at this margin
    observed = _observe(scene, paths)
    assert (observed < 1) == (predicted < 1), (predicted, observed)
    assert observed == pytest.approx(predicted, abs=1e-3 * abs(predicted - 1)), \
        (predicted, observed)


@pytest.fixture(scope="module")
def polynomial_limits():
    sc = load_scene("flexible_pd_lowpass")
    return {(alg, first, e, o): critical_step(
        sc.plant.params, sc.controller, algorithm=alg, first=first, extrapolation=e,
        input_derivatives=True, output_derivatives=o) for alg, first, e, o in POLYNOMIAL_LIMITS}


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("alg,first,e,out_der", POLYNOMIAL_LIMITS,
                         ids=["default-gs-quadratic", "gs-quadratic-taylor", "gs-linear",
                              "gs-plant-first-linear-taylor"])
def test_polynomial_coupling_step_limit(paths, polynomial_limits, alg, first, e, out_der,
                                        factor):
    """The native FMUs on the master at three steps on each side of the predicted largest stable
    step of a coupling with input (and output) derivatives: the observed growth factor is the
    predicted spectral radius, and the verdict flips at the boundary."""
    Hc = polynomial_limits[alg, first, e, out_der]
    _assert_growth_is_predicted(_filtered(factor * Hc, alg, first, e, out_der), paths,
                                factor < 1)


@pytest.fixture(scope="module")
def hermite_limits():
    """The first unstable interval of the Hermite coupling on the filtered scene, per first FMU:
    a narrow tongue at 14.69-14.75 ms with the plant first (the second bending mode, 426 rad/s,
    aliased to 0: 2 pi / 426.4 = 14.74 ms), 19.47-19.82 ms with the controller first."""
    from orchestration.studies import stability_intervals as iv
    from orchestration.studies.stability import STEP_RANGE, Spectra
    sc = load_scene("flexible_pd_lowpass")
    out = {}
    for first in ("plant", "controller"):
        found = iv.scan(Spectra(sc.plant.params, sc.controller,
                                [{"algorithm": "gauss-seidel", "first": first,
                                  "coupling": "hermite"}]), 0.05, min_step=STEP_RANGE[0])[0]
        out[first] = next((lo, hi) for lo, hi, stable, _ in found if not stable)
    return out


#: the points of the Hermite coupling's test: below the interval (times its lower edge) and
#: inside it (fractions of its width)
HERMITE_POINTS = [("below", 0.9), ("below", 0.95), ("below", 0.98), ("inside", 0.25),
                  ("inside", 0.5), ("inside", 0.75)]


@pytest.mark.parametrize("where,at", HERMITE_POINTS)
@pytest.mark.parametrize("first", ["plant", "controller"])
def test_hermite_coupling_step_limit(paths, hermite_limits, first, where, at):
    """The Hermite coupling on the filtered scene (``master.coupling = "hermite"``): at three
    steps below its first unstable interval and three inside it the observed growth factor is
    the predicted spectral radius, and the verdict is the predicted one."""
    lo, hi = hermite_limits[first]
    H = at * lo if where == "below" else lo + at * (hi - lo)
    _assert_growth_is_predicted(_filtered(H, "gauss-seidel", first, 2, False, "hermite"), paths,
                                where == "below")

# ---------------------------------------------------------------------- the plant's substep limit
@pytest.fixture(scope="module")
def substep_limits():
    """The plant's critical substep with 4 substeps per communication step (Gauss-Seidel,
    zero-order hold: the coupling is stable there) on the paper's 4-mode plant."""
    p, c = PlantParams(n_modes=4), ControllerParams()
    out = {}
    for method in ("rk4", "symplectic_euler"):
        f = lambda h, m=method: spectral_radius(  # noqa: E731
            transition_matrix(p, c, 4 * h, integrator=m, substep=h))
        out[method] = critical_value(f, 1e-5, 3e-3, n=60)
    return out


@pytest.mark.parametrize("method", ["rk4", "symplectic_euler"])
def test_substep_limit_is_the_stability_function_on_the_highest_mode(substep_limits, method):
    """The co-simulation's critical substep is the method's limit on the plant's highest mode
    (2511 rad/s at n_modes = 4), the coupling barely moving it."""
    lam = highest_mode(PlantParams(n_modes=4))
    assert substep_limits[method] == pytest.approx(integrator_step_limit(method, lam), rel=1e-3)


@pytest.mark.parametrize("factor", FACTORS)
@pytest.mark.parametrize("method", ["rk4", "symplectic_euler"])
def test_plant_substep_limit(paths, substep_limits, method, factor):
    h = factor * substep_limits[method]
    scene = _scene(**{"master.step": 4 * h, "plant.step": h, "plant.integrator": method,
                      "plant.fidelity": "linear"})
    predicted = spectral_radius(scene_transition_matrix(scene))
    assert (predicted < 1) == (factor < 1), predicted
    observed = _observe(scene, paths)
    assert (observed < 1) == (predicted < 1), (predicted, observed)
    assert observed == pytest.approx(predicted, abs=1e-3 * abs(predicted - 1)), \
        (predicted, observed)


def test_bad_arguments_name_the_input():
    p, c = PlantParams(n_modes=1), ControllerParams()
    with pytest.raises(ValueError, match="algorithm"):
        transition_matrix(p, c, 1e-3, algorithm="seidel")
    with pytest.raises(ValueError, match="extrapolation"):
        transition_matrix(p, c, 1e-3, extrapolation=3)
    with pytest.raises(ValueError, match="integrator = 'dopri5'"):
        transition_matrix(p, c, 1e-3, integrator="dopri5")
    with pytest.raises(ValueError, match="H = "):
        transition_matrix(p, c, -1e-3)
    with pytest.raises(TypeError, match="ControllerParams"):
        transition_matrix(p, {"kp": 1}, 1e-3)
    with pytest.raises(ValueError, match="method"):
        plant_step_map("heun", np.eye(2), np.ones((2, 1)), 1, 1e-3, 1e-4)
