"""The exact rung's C kernel (``fp_exact_*`` through plant_fmu.kernel.ExactKernel) against its
numpy specification (plant_fmu/exact.py): forces, tangents, mass, start, one step and a closed
loop of 1000 steps to round-off; bad inputs and failing Newton solves return an error code and
never a non-finite state."""
import math

import numpy as np
import pytest

from controller_fmu.pd_lowpass import PDLowPassModel
from orchestration.scene.schema import load_scene
from orchestration.studies.exact_loop import ExactLoop
from plant_fmu.exact import AffineForce, ExactPlant, GeneralizedAlpha
from plant_fmu.kernel import (FP_BADARG, FP_NOCONVERGE, FP_NONFINITE, ExactKernel,
                              ExactStepError)
from plant_fmu.params import PlantParams

RTOL = 1e-12





def plant(ne: int, zeta: float = 0.001) -> ExactPlant:
    """The exact beam (its own damping law: Kelvin-Voigt)."""
    return ExactPlant(PlantParams().replace(n_modes=1, n_elements=ne, zeta=zeta,
                                            damping="kelvin-voigt"))


def random_state(pl: ExactPlant, rng, phi=0.4):
    """A deformed, moving state: the straight beam at ``phi`` plus random nodal perturbations."""
    x = pl.initial_state(phi=phi, x=0.1, phi_dot=1.5, x_dot=-0.3)
    nq = pl.nq
    return (x[:nq] + 1e-6 * rng.standard_normal(nq), x[nq:] + 1e-3 * rng.standard_normal(nq))


def rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(1.0, np.max(np.abs(b)))


# ne = 1: the closed loop's force row lies inside the band; 3 and 8: outside (Sherman-Morrison)
@pytest.mark.parametrize("ne", (1, 3, 8))
@pytest.mark.parametrize("zeta", (0.0, 0.02))
def test_forces_tangents_and_mass_are_the_specs(ne, zeta):
    pl = plant(ne, zeta)
    k = ExactKernel(pl, 1e-3)
    rng = np.random.default_rng(ne)
    for _ in range(3):
        q, qd = random_state(pl, rng)
        u = 100.0 * rng.standard_normal()
        f, K, C = pl.system.forces(q, qd, u)
        fc, Kc, Cc = k.forces(q, qd, u)
        # the axial force EA (|r'| - 1) is formed from |r'| ~ 1: its round-off floor is
        # EA ulp(1) (4.2e8 x 2.2e-16 = 9e-8 N), whatever the strain; a few of those at most
        floor = 16 * pl.params.EA * np.finfo(float).eps
        assert np.max(np.abs(fc - f)) <= RTOL * np.max(np.abs(f)) + floor
        assert rel(Kc, K) <= RTOL and rel(Cc, C) <= RTOL
        assert k.forces(q, qd, u, tangent=False)[1] is None
        assert np.array_equal(k.forces(q, qd, u, tangent=False)[0], fc)
    assert rel(k.mass(), pl.system.M) <= RTOL


@pytest.mark.parametrize("ne", (1, 3, 8))
@pytest.mark.parametrize("law", ("held", "loop"))
def test_start_and_one_step_are_the_specs(ne, law):
    pl = plant(ne)
    rng = np.random.default_rng(10 + ne)
    force = 25.0 if law == "held" else AffineForce(3.0, 0.4, 1.0, 60.0, 6.0)
    for h in (1e-4, 1e-3):
        k, ga = ExactKernel(pl, h), GeneralizedAlpha(pl.system, h)
        q, qd = random_state(pl, rng)
        s_np, s_c = ga.start(q, qd, force), k.start(q, qd, force)
        assert np.array_equal(s_c[0], q) and np.array_equal(s_c[1], qd)
        assert np.array_equal(s_c[2], s_c[3])
        # the accelerations M^-1 f of a random state are huge (the slopes' masses are small):
        # the C ones satisfy the specification's equations to its round-off floor
        f = pl.system.forces(q, qd, force if np.isscalar(force) else force(q, qd)[0], False)[0]
        assert np.max(np.abs(pl.system.M @ s_c[2] - f)) <= (RTOL * np.max(np.abs(f))
                                                             + 16 * pl.params.EA * 2.2e-16)
        # the same start for both: one step compared on its own, to 1e-12 or, where the
        # specification itself is more sensitive than that, to its own spread under 1-ulp
        # perturbations of its input (the axial stiffness makes the step's velocities carry the
        # residual's round-off floor: up to ~1e-11 relative at h = 1e-4)
        t_np, t_c = ga.step(s_np, force), k.step(s_np, force)
        # the same Newton iterations: the tangent (with the force row) is the specification's
        assert k.newton_iterations == ga.newton_iterations
        spread = np.zeros(4)
        for seed in range(3):
            signs = np.random.default_rng(seed)
            s_ulp = tuple(v * (1 + np.finfo(float).eps * signs.choice([-1, 1], v.size))
                          for v in s_np)
            spread = np.maximum(spread, [rel(a, b) for a, b in zip(ga.step(s_ulp, force), t_np)])
        for a, b, sp in zip(t_c, t_np, spread):
            assert rel(a, b) <= max(RTOL, 4 * sp)
        # the state moved: the comparison is not of two copies of the input
        assert rel(t_np[1], s_np[1]) > 1e-6


def test_many_steps_in_one_call_equal_single_steps():
    pl = plant(4)
    k = ExactKernel(pl, 1e-3)
    x = pl.initial_state(phi=0.3)
    s = k.start(x[:pl.nq], x[pl.nq:], 5.0)
    one = s
    for _ in range(20):
        one = k.step(one, 5.0)
    many = k.steps(s, 5.0, 20)
    for a, b in zip(many, one):
        assert np.array_equal(a, b)


def test_closed_loop_1000_steps_with_the_numpy_controller():
    """The filtered paper loop (PD + designed low-pass, in numpy) from pi/6 with 4 elements at
    h = 1 ms: 1000 steps, the force law rebuilt each step from the controller's filter state."""
    sc = load_scene("flexible_pd_lowpass", {"initial.phi": math.pi / 6,
                                            "plant.damping": "kelvin-voigt"})
    pl = ExactPlant(sc.plant.params.replace(n_elements=4))
    x0 = pl.initial_state(phi=math.pi / 6)
    out = {}
    for kernel in (False, True):
        loop = ExactLoop(pl, PDLowPassModel(sc.controller), 1e-3, kernel=kernel)
        t, out[kernel] = loop.run(x0, 1.0, 0.01)
    assert t.size == 101
    swing = np.max(np.abs(out[False]))
    assert swing > 0.5
    assert np.max(np.abs(out[True] - out[False])) <= 1e-11 * swing


def _taken_state(k, pl):
    x = pl.initial_state(phi=0.5, phi_dot=2.0)
    return k.start(x[:pl.nq], x[pl.nq:], 0.0)


@pytest.mark.parametrize("force", (math.nan, math.inf, AffineForce(0.0, math.nan),
                                   AffineForce(0.0, 1.0, 1.0, math.inf, 0.0)))
def test_a_force_that_is_not_finite_is_refused(force):
    pl = plant(3)
    k = ExactKernel(pl, 1e-3)
    s = _taken_state(k, pl)
    with pytest.raises(ExactStepError) as err:
        k.steps(s, force, 5)
    assert err.value.code == FP_BADARG
    for a, b in zip(err.value.state, s):
        assert np.array_equal(a, b)
    with pytest.raises(ExactStepError):
        k.start(s[0], s[1], force)


@pytest.mark.parametrize("h, max_iter", ((1.0, 30), (0.1, 30), (1e-3, 1)))
def test_newton_that_does_not_converge_returns_a_code_and_the_last_good_state(h, max_iter):
    """A huge step (the rotating beam's geometry far from linear over it) or one Newton
    iteration allowed: the numpy specification fails too, and the kernel says so with
    FP_NOCONVERGE and the state it was given, all finite."""
    pl = plant(4)
    k = ExactKernel(pl, h, max_iter=max_iter)
    ga = GeneralizedAlpha(pl.system, h, max_iter=max_iter)
    s = _taken_state(k, pl)
    with pytest.raises(RuntimeError, match="did not converge"):
        ga.step(s, 0.0)
    with pytest.raises(ExactStepError) as err:
        k.steps(s, 0.0, 3)
    assert err.value.code == FP_NOCONVERGE
    assert all(np.isfinite(a).all() for a in err.value.state)
    for a, b in zip(err.value.state, s):
        assert np.array_equal(a, b)


def test_a_state_that_is_not_finite_stops_with_a_code():
    pl = plant(3)
    k = ExactKernel(pl, 1e-3)
    q, qd, qdd, a = _taken_state(k, pl)
    qd = qd.copy()
    qd[5] = math.nan
    with pytest.raises(ExactStepError) as err:
        k.step((q, qd, qdd, a), 0.0)
    assert err.value.code in (FP_NONFINITE, FP_BADARG)
    with pytest.raises(ExactStepError):
        k.start(q, qd, 0.0)


def test_bad_parameters_are_refused():
    pl = plant(3)
    with pytest.raises(ValueError, match="rho_inf"):
        ExactKernel(pl, 1e-3, rho_inf=1.5)
    for h, it in ((0.0, 30), (math.nan, 30), (1e-3, 0)):
        with pytest.raises(ValueError, match="out of range"):
            ExactKernel(pl, h, max_iter=it)


@pytest.mark.parametrize("ne", (1, 3, 8))
def test_outputs_are_the_specs(ne):
    """fp_exact_outputs (the native FMU's outputs at the exact rung) against ExactPlant's tip
    angle and rate, tip deflection and energy, and the root tangent's angle, at deformed, moving
    states. The angles and rates to the last bit (the same libm operations on both sides); the
    tip deflection to round-off of its terms (it is a dot product of the tip's offset, of size
    L, with the unit normal: a difference of numbers near 1 whose result is near 1e-3, so the
    order of the two products and whether numpy fuses them (it may, by version) moves its last
    bits by hundreds of its own ulps, never by more than a few ulps of the terms); the energy to
    round-off of its size (the strain energy sums EA eps^2 with EA = 4.2e8)."""
    pl = plant(ne)
    k = ExactKernel(pl, 1e-4)
    rng = np.random.default_rng(ne)
    for _ in range(5):
        q, qd = random_state(pl, rng)
        q = q + 1e-3 * rng.standard_normal(pl.nq)            # bent and stretched
        x = np.concatenate([q, qd])
        o = k.outputs((q, qd))
        e = pl.system.embed(q)
        spec = [q[0], qd[0], *pl.tip_angle(x), math.atan2(-e[2], e[3]), pl.tip_deflection(x)]
        assert np.array_equal(o[:5], spec[:5])
        terms = np.max(np.abs(e[-4:-2] - e[0:2]))
        assert abs(o[5] - spec[5]) <= 4 * np.finfo(float).eps * terms
        assert abs(o[6] - pl.energy(x)) <= RTOL * abs(pl.energy(x))


def test_a_tangent_of_zero_length_is_not_finite_without_a_division_by_zero():
    """A tip slope (or an element's) of zero length has no angle and no strain: the outputs and
    the forces say FP_NONFINITE (the kernel never divides by zero: UBSan's check in the fuzz
    test)."""
    pl = plant(3)
    k = ExactKernel(pl, 1e-4)
    x = pl.initial_state(phi=0.2)
    q, qd = x[:pl.nq].copy(), x[pl.nq:]
    q[-2:] = 0.0
    with pytest.raises(ExactStepError) as err:
        k.outputs((q, qd))
    assert err.value.code == FP_NONFINITE
    q[3:] = 0.0                                              # every node at the root, no slope
    with pytest.raises(ExactStepError) as err:
        k.forces(q, qd)
    assert err.value.code == FP_NONFINITE
