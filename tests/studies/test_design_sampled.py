"""flexpend design for a sampled controller: the stacked evaluator's roots are the sampled
loop's (its s-plane equivalents, against sampled_poles plant by plant, whose filter comes from
python-control's c2d, not from the controller's difference equation), the design scores the
candidates by them, and the Tustin filter's cutoffs stay below pi / T."""
import math

import numpy as np
import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.scene.keys import ConfigError
from orchestration.studies.design import (NYQUIST_FRACTION, RobustLoop, UncertaintySet,
                                          design_filter, design_settings)
from orchestration.studies.sampled import sampled_poles
from plant_fmu.params import PlantParams

SET = UncertaintySet(PlantParams(), (2, 8), (5e-4, 2e-3), 0.1, 0.2)


def _decay(p, c):
    """The sampled loop's decay rate ``-log(max |z|) / T`` (``sampled_poles``)."""
    sp = sampled_poles((p, c), c.sample_period, c.delay, c.discretization)
    return -math.log(sp.spectral_radius) / c.sample_period


@pytest.mark.parametrize("tau_fraction,discretization", [(0.0, "tustin"), (0.5, "tustin"),
                                                         (1.0, "zoh")])
def test_stacked_sampled_worst_case_is_the_sampled_loop_s_plant_by_plant(tau_fraction,
                                                                         discretization):
    T = 0.004
    c = ControllerParams(filter_order=2, cutoff=120.0, filter_damping=0.3, sample_period=T,
                         delay=tau_fraction * T, discretization=discretization)
    plants = SET.plants(2)[::3]
    w = RobustLoop(plants).worst(c)
    each = [_decay(p, c) for p in plants]
    assert w.decay == pytest.approx(min(each), rel=1e-9, abs=1e-9)
    assert _decay(w.decay_plant, c) == pytest.approx(w.decay, rel=1e-9, abs=1e-9)
    # the worst damping ratio is that of an s-plane equivalent of the worst plant's poles
    sp = sampled_poles((w.damping_plant, c), T, c.delay, discretization)
    s = sp.s[np.isfinite(sp.s.real)]
    assert w.damping == pytest.approx((-s.real / np.abs(s)).min(), rel=1e-8, abs=1e-10)


def test_a_sampled_design_scores_its_choice_by_the_sampled_loop():
    T, tau = 0.004, 0.002
    base = ControllerParams(sample_period=T, delay=tau)
    s = design_settings({"design.levels": 2, "design.check_levels": 2, "design.n_cutoffs": 9,
                         "design.n_dampings": 4})
    r = design_filter(PlantParams(), base, s)
    ch = r.chosen
    assert (ch.sample_period, ch.delay, ch.discretization) == (T, tau, "tustin")
    # the Tustin filter's cutoffs stop below pi / T (default design.cutoff_max = 1000 > 785)
    top = NYQUIST_FRACTION * math.pi / T
    assert max(row[1] for row in r.grid) == pytest.approx(top)
    assert ch.cutoff * T < math.pi
    # its worst case, plant by plant with sampled_poles (check_levels = levels: the search set)
    each = [_decay(p, ch) for p in SET.plants(2)]
    assert r.worst.decay == pytest.approx(min(each), rel=1e-9)
    assert r.worst.decay >= max(row[3] for row in r.grid) - 1e-3 * abs(r.worst.decay)
    assert r.to_json()["sampled"] == {"T": T, "tau": tau, "discretization": "tustin"}


def test_no_cutoff_below_the_nyquist_limit_is_a_config_error():
    base = ControllerParams(cutoff=50.0, sample_period=0.02)
    s = design_settings({"design.cutoff_min": 200.0})
    with pytest.raises(ConfigError, match="design.cutoff_min = 200 rad/s"):
        design_filter(PlantParams(), base, s)
