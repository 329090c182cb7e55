"""The error figure (orchestration/studies/error_figure.py, bench/error_figure.py): a run on a
floating-frame rung states ``kappa * max |phi_o(run) - phi_o(companion)| + floor``, its companion
the stiffened rung with the modes that matter, through the same FMUs and master."""
import json
import math

import numpy as np
import pytest

from orchestration.scene.schema import load_scene
from orchestration.studies import error_figure as ef
from orchestration.studies.plant_step import rung_params, step_limit
from plant_fmu.beam import analytic_frequencies

DATA = json.loads(ef.FIGURE_FILE.read_text(encoding="utf-8"))
KV = {"plant.damping": "kelvin-voigt"}


def _floor(res, scene):
    """The JSON's floor evaluated here, its terms written out (independently of
    error_figure.TERMS), on the companion's result."""
    p = scene.plant.params
    D = np.max(np.abs(res["tip_deflection"])) / p.L
    W = np.max(np.abs(res["omega_o"]))
    damped = DATA["damped"]
    ringing = 0.0 if (p.damping == damped["law"] and p.zeta >= damped["zeta"]) else 1.0
    w1 = 1.8751040687119611 ** 2 * math.sqrt(p.EI / (p.rho * p.EA / p.E * p.L ** 4))
    value = {"D": D, "D_ringing": D * ringing, "D_stiffness": D * w1 ** 2 * p.L / p.g,
             "D2": D * D, "kd_W": scene.controller.kd * W, "1": 1.0}
    f = DATA["floor"]
    return f["safety"] * sum(c * value[k] for k, c in f["terms"].items())


# ---------------------------------------------------------------------- the companion
@pytest.mark.parametrize("name,keys", [("flexible_pd_lowpass", {}), ("rigid_pd", {}),
                                       ("flexible_pd_lowpass", {"plant.EI": 1500.0}),
                                       ("flexible_pd_lowpass", {"plant.L": 1.2})])
def test_the_companion_carries_the_cantilever_modes_below_its_frequency(name, keys):
    """Counted on the analytic cantilever frequencies (not the FE model the product reads):
    the paper's beam 8, rigid_pd's stiff beam 3, EI 1500 7; never fewer than the run's."""
    scene = load_scene(name, keys)
    p = scene.plant.params
    below = int(np.sum(analytic_frequencies(p, 12) <= ef.COMPANION_FREQUENCY))
    want = min(ef.COMPANION_MODES, max(below, p.n_modes, 1))
    cs = ef.companion_scene(scene)
    assert cs.plant.params.n_modes == want
    assert cs.plant.fidelity == "stiffened" and cs.plant.integrator == "rk4"
    assert (name, want) != ("rigid_pd", 8)                 # the stiff beam's modes do not matter
    big = ef.companion_scene(load_scene(name, {**keys, "plant.n_modes": 8}))
    assert big.plant.params.n_modes == 8


@pytest.mark.parametrize("keys", [{}, {"plant.EI": 1500.0}, {"plant.zeta": 0.0}])
def test_the_companion_steps_within_a_margin_of_rk4s_limit(keys):
    """plant.step of the companion: within STEP_MARGIN of RK4's stability limit on its plant and
    a whole fraction of the communication step; the scene's own step when that is within it
    (the paper's modal scene at 8 modes: 2.5e-4 s of a 3.13e-4 s limit)."""
    scene = load_scene("flexible_pd_lowpass", keys)
    cs = ef.companion_scene(scene)
    h = cs.plant.step
    limit = step_limit("rk4", rung_params(cs.plant.params, "stiffened"))[0]
    assert h <= ef.STEP_MARGIN * limit
    k = scene.master.step / h
    assert abs(k - round(k)) < 1e-9
    if scene.plant.step <= ef.STEP_MARGIN * limit:
        assert h == scene.plant.step
    else:
        assert h > ef.STEP_MARGIN * limit * (1 - 1 / k) - 1e-15     # the largest such fraction
    from orchestration.job import check_plant_step
    assert check_plant_step(cs) is None                     # neither refused nor warned
