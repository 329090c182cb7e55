"""The sampled-data loop (orchestration/studies/sampled.py) against independent constructions:
the continuous loop as T -> 0 at the order the theory gives, the rigid pendulum's critical sample
period from its own equations, python-control's zero-order hold, a full period's delay as z^-1,
and a fractional delay composed of fine zero-order-hold steps."""
import math

import numpy as np
import pytest
import scipy.signal
from scipy.optimize import linear_sum_assignment

from controller_fmu.spec import model_for
from orchestration.studies.analysis import _drift_free, closed_loop_matrix, linearisation
from orchestration.studies.sampled import (
    DEFAULT_DISCRETIZATION,
    plant_discretisation,
    sampled_loop,
    sampled_poles,
    stable_intervals,
)
from orchestration.scene.schema import load_scene
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams


def _loop(name, **controller):
    scene = load_scene(name)
    return linearisation(scene).params, scene.controller.replace(**controller)


def _match(a, b):
    """``b`` reordered to pair each of ``a`` with its nearest (an optimal assignment)."""
    _, idx = linear_sum_assignment(np.abs(np.asarray(a)[:, None] - np.asarray(b)[None, :]))
    return np.asarray(b)[idx]


def _plant_without_drift(p):
    """The plant's (A, B, C) without the cart's position and velocity (kx = 0: not fed back)."""
    A, B, C, _ = plant_model(p).state_space()
    nq = p.n_modes + 2
    keep = [i for i in range(A.shape[0]) if i not in (0, nq)]
    return A[np.ix_(keep, keep)], B[keep], C[:, keep]


@pytest.mark.parametrize("name,discretization,factor", [
    ("rigid_pd", "tustin", 0.5), ("rigid_pd", "zoh", 0.5),
    ("flexible_pd_lowpass", "tustin", 0.5), ("flexible_pd_lowpass", "zoh", 1.0)])
def test_sampled_poles_tend_to_the_continuous_ones_at_first_order(name, discretization, factor):
    """With tau = 0 the sample-and-hold lags by T/2 (the held force is, to first order, the
    force of half a period ago), so the s-plane equivalents of the poles are the continuous
    loop's with a delay T/2 on the force: first order in T, ``s(T) = s0 + factor T s'(0) +
    O(T^2)`` where ``s'(0)`` is the sensitivity of the continuous pole to a delay on the force,
    ``s' = -s0 (w^H B K v) / (w^H v)`` (differentiating ``det(sI - A0 - B K e^{-s theta})``).
    The Tustin filter adds no first-order lag (``factor = 1/2``), the filter's zero-order-hold
    equivalent half a period more (``factor = 1``); with no filter both are the same. The order
    is measured from three periods halving, and the coefficient compared with the theory's."""
    p, c = _loop(name)
    Acl = _drift_free(closed_loop_matrix(p, c), p)
    lam, V = np.linalg.eig(Acl)
    W = np.linalg.inv(V)                                    # rows: left eigenvectors, W V = I
    A, B, C = _plant_without_drift(p)
    m = model_for(c)
    Bbig = np.vstack([B, np.zeros((m.nx, 1))])
    Kbig = np.hstack([m.D @ C, m.C])                        # F = Kbig [x; xf]
    sens = np.array([-lam[i] * (W[i] @ Bbig @ Kbig @ V[:, i]) for i in range(len(lam))])
    Ts = (1e-5, 5e-6, 2.5e-6)
    errs, coefs = [], []
    for T in Ts:
        s = _match(lam, sampled_poles((p, c), T, 0.0, discretization).s)
        errs.append(np.abs(s - lam).max())
        coefs.append((s - lam) / T)
    orders = [math.log(errs[i] / errs[i + 1]) / math.log(Ts[i] / Ts[i + 1]) for i in range(2)]
    assert orders == pytest.approx([1.0, 1.0], abs=0.02)
    assert np.abs(coefs[-1] - factor * sens).max() < 0.01 * np.abs(sens).max()


def _rigid_critical_period(p: PlantParams, kp: float, kd: float, tau_steps: int = 0) -> float:
    """The rigid inverted pendulum on a cart from its own equations, under the sampled PD on phi
    (zero-order hold, no delay), discretised by scipy.signal.cont2discrete; the largest T before a
    root of the closed loop's characteristic polynomial leaves the unit circle, by bisection.

    A uniform beam (mass mb, length L) hinged on a cart (mass m), linearised upright:
    ``(m + mb) xdd - mb L/2 phidd = F``, ``-mb L/2 xdd + mb L^2/3 phidd - mb g L/2 phi = 0``
    (phi counter-clockwise, the tip moving to -x). The cart's position and velocity do not enter:
    the loop is (phi, phidot) driven by F."""
    mb = p.rho * p.EA / p.E * p.L
    M0 = np.array([[p.m + mb, -mb * p.L / 2], [-mb * p.L / 2, mb * p.L ** 2 / 3]])
    Minv = np.linalg.inv(M0)
    a = Minv[1, 1] * mb * p.g * p.L / 2                     # phidd = a phi + b F
    b = Minv[1, 0]
    Ac = np.array([[0.0, 1.0], [a, 0.0]])
    Bc = np.array([[0.0], [b]])

    def radius(T):
        Ad, Bd, *_ = scipy.signal.cont2discrete((Ac, Bc, np.eye(2), np.zeros((2, 1))), T, "zoh")
        Acl = Ad - Bd @ np.array([[kp, kd]])
        poly = np.poly(Acl)                                 # z^2 - tr z + det
        return np.abs(np.roots(poly)).max()

    T, step = 1e-4, 1.01
    assert radius(T) < 1
    while radius(T * step) < 1:
        T *= step
    lo, hi = T, T * step
    while hi - lo > 1e-12 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if radius(mid) < 1 else (lo, mid)
    return lo


def test_rigid_pd_critical_period_is_the_exact_zoh_loop_s():
    p, c = _loop("rigid_pd")
    expected = _rigid_critical_period(p, c.kp, c.kd)
    got = stable_intervals("rigid_pd", tau_fraction=0.0)
    assert got.critical == pytest.approx(expected, rel=1e-7)
    # the first interval is the stable one; just inside and outside its end the verdict agrees
    assert sampled_poles((p, c), expected * (1 - 1e-5)).stable
    assert not sampled_poles((p, c), expected * (1 + 1e-5)).stable


@pytest.mark.parametrize("name", ["rigid_pd", "flexible_pd_lowpass"])
def test_plant_part_without_delay_is_python_controls_zoh(name):
    import control

    p, _ = _loop(name)
    A, B, C, D = plant_model(p).state_space()
    for T in (1e-3, 7e-3):
        Phi, G_prev, G_new = plant_discretisation(A, B, T, 0.0)
        ref = control.c2d(control.ss(A, B, C, D), T, "zoh")
        np.testing.assert_allclose(Phi, ref.A, rtol=1e-12, atol=1e-12 * np.abs(ref.A).max())
        np.testing.assert_allclose(G_new, ref.B, rtol=1e-12, atol=1e-12 * np.abs(ref.B).max())
        assert not np.any(G_prev)


def _delayed_loop_poles(p, c, T, discretization, extra_delay: bool):
    """The closed loop's poles assembled by python-control: the plant's zero-order hold, the
    filter's difference equation times the PD gains, a unit delay z^-1 in series with the plant
    when ``extra_delay``, connected by ``control.feedback`` (positive: the controller's output
    is the force, ``F = -H_d (kx x_o + kp phi_o + kd omega_o)``)."""
    import control

    if c.kx == 0.0:
        A, B, C = _plant_without_drift(p)
    else:
        A, B, C, _ = plant_model(p).state_space()
    G = control.c2d(control.ss(A, B, C, np.zeros((3, 1))), T, "zoh")
    m = model_for(c)
    g = np.array([[c.kx, c.kp, c.kd]])
    if m.nx:
        H = control.ss(m.Af, m.Bf, m.Cf, m.Df)
        kw = {"prewarp_frequency": c.cutoff} if discretization == "tustin" else {}
        Hd = control.c2d(H, T, discretization, **kw)
        K = control.ss(Hd.A, Hd.B @ g, -Hd.C, -Hd.D @ g, T)
    else:
        K = control.ss([], [], [], -g, T)
    if extra_delay:
        G = control.series(control.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]], T), G)
    return np.linalg.eigvals(np.asarray(control.feedback(G, K, sign=1).A))


@pytest.mark.parametrize("name,kx,discretization", [
    ("rigid_pd", 0.0, "tustin"), ("flexible_pd_lowpass", 0.0, "tustin"),
    ("flexible_pd_lowpass", 0.0, "zoh"), ("flexible_pd_lowpass", -20.0, "tustin")])
def test_a_full_period_delay_is_one_step_z_inverse(name, kx, discretization):
    p, c = _loop(name, kx=kx)
    for T in (2e-3, 6e-3):
        for tau, extra in ((0.0, False), (T, True)):
            expected = _delayed_loop_poles(p, c, T, discretization, extra)
            got = sampled_poles((p, c), T, tau, discretization).z
            assert len(got) == len(expected)
            np.testing.assert_allclose(_match(expected, got), expected, rtol=0,
                                       atol=1e-9 * max(1.0, np.abs(expected).max()))


def test_a_fractional_delay_is_the_composition_of_fine_holds():
    """tau = j T / N: the period stepped in N zero-order holds of T / N (scipy's), the previous
    force over the first j and the new one over the rest, gives the same one-period map."""
    p, c = _loop("flexible_pd_lowpass")
    A, B, C = _plant_without_drift(p)
    T, N = 4e-3, 8
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, C, np.zeros((3, 1))), T / N, "zoh")
    for j in (1, 3, 5):
        Phi, Gp, Gn = np.eye(len(A)), np.zeros_like(B), np.zeros_like(B)
        for i in range(N):
            Phi, Gp, Gn = Ad @ Phi, Ad @ Gp, Ad @ Gn
            if i < j:
                Gp = Gp + Bd
            else:
                Gn = Gn + Bd
        ours = plant_discretisation(A, B, T, j * T / N)
        for x, y in zip(ours, (Phi, Gp, Gn)):
            np.testing.assert_allclose(x, y, rtol=0, atol=1e-11 * np.abs(y).max())
    # and the loop at that delay: its spectral radius lies between no delay's and a full one's
    # for the filtered scene at a period where the delay matters
    rho = [sampled_poles((p, c), T, f * T).spectral_radius for f in (0.0, 0.5, 1.0)]
    assert rho[0] < rho[1] < rho[2]


def test_tustin_keeps_more_of_the_stable_range_than_zoh():
    """The zoh filter's extra half period of lag costs stable sample period (the module's
    choice of default)."""
    assert DEFAULT_DISCRETIZATION == "tustin"
    tustin = stable_intervals("flexible_pd_lowpass", tau_fraction=0.0).critical
    zoh = stable_intervals("flexible_pd_lowpass", tau_fraction=0.0, discretization="zoh").critical
    assert zoh < tustin


@pytest.mark.parametrize("kwargs,word", [
    ({"T": 0.0}, "T"), ({"T": -1e-3}, "T"), ({"T": float("nan")}, "T"),
    ({"T": 1e-3, "tau": 2e-3}, "tau"), ({"T": 1e-3, "tau": -1e-6}, "tau"),
    ({"T": 1e-3, "discretization": "euler"}, "discretization"),
    ({"T": 0.04}, "pi / cutoff")])
def test_bad_arguments_raise_value_errors_naming_them(kwargs, word):
    with pytest.raises(ValueError, match=word) as info:
        sampled_loop("flexible_pd_lowpass", **kwargs)
    assert "\n" not in str(info.value)


def test_bad_scan_arguments_raise_value_errors():
    with pytest.raises(ValueError, match="tau_fraction"):
        stable_intervals("rigid_pd", tau_fraction=1.5)
    with pytest.raises(ValueError, match="T_range"):
        stable_intervals("rigid_pd", T_range=(0.01, 0.001))
    with pytest.raises(ValueError, match="not both"):
        stable_intervals("rigid_pd", tau_fraction=0.5, tau=1e-3)


def test_stability_region_figure_marks_each_scene_s_critical_periods(tmp_path):
    from orchestration.studies.sampled import critical_periods, stability_region_figure

    path = tmp_path / "region.png"
    out = stability_region_figure(path, scenes=["rigid_pd"], n_T=12, n_fraction=3)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    expected = critical_periods("rigid_pd")
    assert out == {"rigid_pd": pytest.approx(expected, rel=1e-12)}
    # a full period's delay costs stable sample period
    assert expected["tau=T"] < expected["tau=0"]


def test_a_fixed_delay_scan_s_boundary_is_where_the_verdict_changes():
    """``tau`` in seconds: the scan starts at ``T = tau``, and just inside and outside its
    boundary the poles (computed afresh) give the two verdicts."""
    tau = 3e-3
    r = stable_intervals("flexible_pd_lowpass", tau=tau)
    assert r.scanned[0] == tau and r.tau == tau and r.tau_fraction is None
    assert r.critical is not None and r.critical > tau
    p, c = _loop("flexible_pd_lowpass")
    assert sampled_poles((p, c), r.critical * (1 - 1e-6), tau).stable
    assert not sampled_poles((p, c), r.critical * (1 + 1e-6), tau).stable
