"""The sampled loop's margins (issue 38; orchestration.studies.sampled.sampled_margins, on the
closed-loop eigenvalues) against two other routes: python-control's ``stability_margins`` of the
discrete loop transfer ``L(z) = K(z) P(z)``, built here from the plant's exact hold (with the
delay's state) and the filter's difference equation; and the theory as ``T -> 0``: the hold
delays by ``T / 2`` on average, so the delay margin tends to the continuous loop's minus
``T / 2``, and the gain margin's lower end (the PD's least gain, set by the slow dynamics) to
the continuous one."""
from __future__ import annotations

import numpy as np
import pytest

from controller_fmu.spec import model_for
from orchestration.studies.analysis import margins
from orchestration.studies.sampled import (_params, _reduced_plant, filter_discretisation,
                                           plant_discretisation, sampled_margins)


def _loop_transfer(scene, T, tau):
    import control
    p, c = _params(scene)
    A, B, C = _reduced_plant(p, c)
    Phi, G_prev, G_new = plant_discretisation(A, B, T, tau)
    ge = model_for(c).gains @ C
    n = A.shape[0]
    if tau > 0:                      # the force before the delay runs out: one more state
        Ap = np.block([[Phi, G_prev], [np.zeros((1, n + 1))]])
        Bp = np.vstack([G_new, [[1.0]]])
        Cp = np.hstack([ge, [[0.0]]])
    else:
        Ap, Bp, Cp = Phi, G_new, ge
    P = control.ss(Ap, Bp, Cp, 0, T)
    Ad, Bd, Cd, Dd = filter_discretisation(c, T)
    K = control.ss(Ad, Bd, Cd, Dd, T) if Ad.size else control.ss([], [], [], Dd, T)
    return control.series(P, K)


@pytest.mark.parametrize("T,tau", [(0.005, 0.0), (0.004, 0.004)])
def test_the_margins_are_python_controls_of_the_discrete_loop(T, tau):
    import warnings

    import control
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # its fallback to the frequency response
        gm, pm, _, _, wp, _ = control.stability_margins(_loop_transfer("rigid_pd", T, tau),
                                                        returnall=True)
    m = sampled_margins("rigid_pd", T, tau)
    assert m["phase_margin_deg"] == pytest.approx(min(pm), rel=1e-6)
    assert m["phase_margin_freq"] == pytest.approx(wp[np.argmin(pm)], rel=1e-6)
    if len(gm):
        assert m["gain_margin_upper"] == pytest.approx(max(g for g in gm if g > 1), rel=1e-6)


def test_as_T_shrinks_the_delay_margin_is_the_continuous_ones_less_half_a_sample():
    p, c = _params("rigid_pd")
    cont = margins(p, c)
    for T in (1e-4, 2e-4):
        m = sampled_margins("rigid_pd", T, 0.0)
        assert m["delay_margin_s"] == pytest.approx(cont["delay_margin_s"] - T / 2, rel=2e-3)
        assert m["gain_margin_lower"] == pytest.approx(cont["gain_margin_lower"], rel=1e-6)


def test_an_unstable_sampled_loop_has_no_margins():
    m = sampled_margins("rigid_pd", 0.021, 0.0)
    assert m["nominal_stable"] is False and m["phase_margin_deg"] is None and m["note"]
