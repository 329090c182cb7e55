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
    assert len(m["gain_crossovers"]) == 3          # near the slow mode, both sides of bending
    for r in m["gain_crossovers"]:
        w, ph = r["frequency"], r["phase_change_deg"]
        val = complex(L(1j * w))
        assert abs(val) == pytest.approx(1.0, abs=1e-9)
        assert r["phase_deg"] == pytest.approx(np.degrees(np.angle(val)), abs=1e-9)
        assert ph == pytest.approx((np.degrees(np.angle(val)) + 360) % 360 - 180, abs=1e-9)
        # the phase change theta puts L e^{-j theta} at -1
        assert val * np.exp(-1j * np.radians(ph)) == pytest.approx(-1.0, abs=1e-9)
    # the phase margin is the smallest |phase change| of the listed crossovers, by definition
    smallest = min(m["gain_crossovers"], key=lambda r: abs(r["phase_change_deg"]))
    assert m["phase_margin_deg"] == abs(smallest["phase_change_deg"])
    assert m["phase_margin_freq"] == smallest["frequency"]


def _phase_shifted_loop_max_real(p, c, theta_deg):
    """The largest real part of the loop whose controller output is multiplied by
    ``e^{-j theta}`` (a pure phase change: lag for theta > 0), the cart's drift roots aside."""
    return max_real_part(p, c, np.exp(-1j * np.radians(theta_deg)))


@pytest.mark.parametrize("p,c", CASES, ids=IDS)
def test_phase_margin_is_the_stability_boundary_of_the_phase_shifted_loop(p, c):
    """Every phase change smaller than the margin, lag or lead, keeps the closed loop stable; the
    margin puts a closed-loop root at j * (its crossover frequency); a little more destabilises."""
    m = analyze(p, c).margins
    pm, w = m["phase_margin_deg"], m["phase_margin_freq"]
    sign = 1.0 if m["phase_margin_sense"] == "lag" else -1.0
    assert 0 < pm < 180
    for theta in (0.999 * pm, -0.999 * pm, 0.5 * pm, -0.5 * pm):
        assert _phase_shifted_loop_max_real(p, c, theta) < 0, theta
    assert _phase_shifted_loop_max_real(p, c, 1.001 * sign * pm) > 0
    eig = np.linalg.eigvals(closed_loop_matrix(p, c, np.exp(-1j * np.radians(sign * pm))))
    assert np.min(np.abs(eig - 1j * w)) < 1e-6 * max(1.0, w)


@pytest.mark.parametrize("p,c", CASES, ids=IDS)
def test_delay_margin_puts_a_root_on_the_axis(p, c):
    """A delay tau multiplies L(jw) by e^{-j w tau}: at the delay margin that lag equals the phase
    change of its crossover, and no crossover needs less delay."""
    m = analyze(p, c).margins
    tau, w = m["delay_margin_s"], m["delay_margin_freq"]
    assert all(r["delay_s"] >= tau for r in m["gain_crossovers"])
    eig = np.linalg.eigvals(closed_loop_matrix(p, c, np.exp(-1j * w * tau)))
    assert np.min(np.abs(eig - 1j * w)) < 1e-6 * max(1.0, w)
    L = complex(loop_transfer(p, c)(1j * w))
    assert L * np.exp(-1j * w * tau) == pytest.approx(-1.0, abs=1e-9)


@pytest.mark.parametrize("p,c", CASES + [(PlantParams(n_modes=4),
                                          ControllerParams(filter_order=0))],
                         ids=IDS + ["n4-pd-unstable"])
def test_margin_text_states_what_the_json_holds(p, c):
    """``flexpend analyze`` prints the JSON's margins with the same names and numbers; an unstable
    loop gets its note instead of a margin; nothing is printed as '-'."""
    from orchestration.report.text import analysis_lines, num

    a = analyze(p, c)
    m = a.margins
    text = "\n".join(analysis_lines(p, c, a))
    assert "(at -" not in text and " - rad/s" not in text and "x-" not in text
    if not m["nominal_stable"]:
        assert m["phase_margin_deg"] is None and m["gain_margin_upper"] is None
        assert m["note"] in text and "phase margin" not in text and "gain margin" not in text
        return
    assert (f"phase margin: {num(m['phase_margin_deg'])} deg of {m['phase_margin_sense']} at "
            f"{num(m['phase_margin_freq'])} rad/s") in text
    for r in m["gain_crossovers"]:
        sense = "lag" if r["phase_change_deg"] >= 0 else "lead"
        if len(m["gain_crossovers"]) > 1:
            assert (f"{num(r['frequency'])} rad/s: {num(abs(r['phase_change_deg']))} deg "
                    f"{sense}") in text
    assert f"delay margin: {num(1e3 * m['delay_margin_s'])} ms" in text
    assert f"x{num(m['gain_margin_lower'])}" in text
    if np.isfinite(m["gain_margin_upper"]):
        assert f"x{num(m['gain_margin_upper'])}" in text
    else:
        assert "no gain increase destabilises it" in text


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
