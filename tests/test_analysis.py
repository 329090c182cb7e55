"""Margins of the loop broken at the force, checked against closed-loop eigenvalues."""
import numpy as np
import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.studies.analysis import analyze, closed_loop_matrix, loop_transfer, max_real_part
from plant_fmu.params import PlantParams

CASES = [(PlantParams(n_modes=0), ControllerParams(filter_order=0)),
         (PlantParams(n_modes=4), ControllerParams()),
         (PlantParams(n_modes=4), ControllerParams(filter_order=1, cutoff=130)),
         (PlantParams(n_modes=8), ControllerParams())]
IDS = ["rigid-pd", "n4-2nd", "n4-1st", "n8-2nd"]


@pytest.mark.parametrize("p,c", CASES, ids=IDS)
def test_gain_margins_are_the_stability_boundaries_of_the_closed_loop(p, c):
    m = analyze(p, c).margins
    assert m["nominal_stable"]
    for key in ("gain_margin_upper", "gain_margin_lower"):
        k = m[key]
        if k in (0.0, np.inf):
            continue
        inside = k * (0.999 if key.endswith("upper") else 1.001)
        outside = k * (1.001 if key.endswith("upper") else 0.999)
        assert max_real_part(p, c, inside) < 0 < max_real_part(p, c, outside)
        # at the boundary, a closed-loop pole sits at j * (crossover frequency)
        eig = np.linalg.eigvals(closed_loop_matrix(p, c, k))
        w = m[key + "_freq"]
        assert np.min(np.abs(eig - 1j * w)) < 1e-5 * max(1.0, w)


def test_rigid_lower_gain_margin_closed_form():
    """Rigid PD with its gain scaled by k: a real root crosses zero when the static stiffness
    vanishes. Eliminating xdd = -k kp phi / I0 from the phi row gives the stationary condition
    k kp I1 / I0 = g I1, so k_low = g I0 / kp."""
    from plant_fmu.beam import beam_model
    p, c = CASES[0]
    k_low = p.g * beam_model(p).I0 / c.kp
    assert analyze(p, c).margins["gain_margin_lower"] == pytest.approx(k_low, rel=1e-9)


def test_phase_margin_is_a_gain_crossover():
    p, c = CASES[1]
    m = analyze(p, c).margins
    L = loop_transfer(p, c)
    for w, ph in m["gain_crossovers"]:
        val = complex(L(1j * w))
        assert abs(val) == pytest.approx(1.0, abs=1e-9)
        assert ph == pytest.approx((np.degrees(np.angle(val)) + 360) % 360 - 180, abs=1e-9)


def test_unstable_loop_has_no_gain_margins_and_eigs_agree():
    a = analyze(PlantParams(n_modes=4), ControllerParams(filter_order=0))
    assert not a.stable and a.margins["gain_margin_upper"] is None
    assert a.max_real_part == pytest.approx(1.643, abs=0.01)


def test_damping_ratios_of_modes():
    a = analyze(*CASES[1])
    for re, im, wn, zeta in a.modes():
        assert wn == pytest.approx(abs(complex(re, im)))
        if wn > 0:
            assert zeta == pytest.approx(-re / wn)


def test_cart_feedback_keeps_cart_roots_in_the_verdict():
    # kx != 0: the cart is fed back; with the "wrong" sign kx > 0 the cart is unstable
    c = ControllerParams(filter_order=0, kx=1.0)
    assert max_real_part(PlantParams(n_modes=0), c) > 0
