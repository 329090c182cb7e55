"""flexpend design: the robust filter, its worst case checked by a second method, and the scene
default it sets."""
import json
import subprocess
import sys

import numpy as np
import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.studies.analysis import max_real_part
from orchestration.studies.design import (DESIGN_DEFAULTS, RobustLoop, UncertaintySet,
                                          design_filter, design_settings)
from orchestration.scene.schema import load_scene
from plant_fmu.params import PlantParams

#: The uncertainty set of issue 6: n_modes 2..8, zeta 0.05 %..0.2 %, EI +-10 %, m +-20 %.
SET = UncertaintySet(PlantParams(), (2, 8), (5e-4, 2e-3), 0.1, 0.2)


def test_uncertainty_grid_spans_the_set():
    ax = SET.axes(3)
    assert ax["n_modes"] == list(range(2, 9))
    assert ax["zeta"] == pytest.approx([5e-4, 1e-3, 2e-3])
    assert ax["EI"] == pytest.approx([787.5, 875.0, 962.5])
    assert ax["m"] == pytest.approx([0.8, 1.0, 1.2])
    assert len(SET.plants(3)) == 7 * 27


def test_stacked_worst_case_equals_plant_by_plant_eigenvalues():
    """The batched evaluator against analysis.max_real_part, one plant at a time."""
    c = ControllerParams(filter_order=1, cutoff=120.0)
    plants = SET.plants(2)
    w = RobustLoop(plants).worst(c)
    each = [-max_real_part(p, c) for p in plants]
    assert w.decay == pytest.approx(min(each), abs=1e-9)
    assert -max_real_part(w.decay_plant, c) == pytest.approx(w.decay, abs=1e-9)


def test_scene_filter_is_stable_over_the_whole_uncertainty_set():
    """The filtered scene's filter, plant by plant on a 6-level grid (every corner, 1512 plants,
    not the design's grids) and 300 random draws inside the set."""
    c = load_scene("flexible_pd_lowpass").controller
    plants = SET.plants(6)
    rng = np.random.default_rng(6)
    for _ in range(300):
        plants.append(PlantParams(n_modes=int(rng.integers(2, 9)),
                                  zeta=float(np.exp(rng.uniform(np.log(5e-4), np.log(2e-3)))),
                                  EI=875.0 * rng.uniform(0.9, 1.1), m=rng.uniform(0.8, 1.2)))
    worst = max(max_real_part(p, c) for p in plants)
    assert worst < 0
    # and the no-filter PD is not: the set is not trivially stable
    assert max(max_real_part(p, c.replace(filter_order=0)) for p in SET.plants(2)) > 0


def test_coarse_design_is_at_least_as_good_as_its_grid():
    s = design_settings({"design.levels": 2, "design.check_levels": 2, "design.n_cutoffs": 9,
                         "design.n_dampings": 4})
    r = design_filter(PlantParams(), ControllerParams(), s)
    best_grid = max(row[3] for row in r.grid)
    # the refined and rounded choice, re-measured on the search set
    again = RobustLoop(SET.plants(2)).worst(r.chosen).decay
    assert again >= best_grid - 1e-3 * abs(best_grid)
    assert r.worst.decay == pytest.approx(again)       # check_levels = levels: same set
    assert r.chosen.filter_order in (1, 2) and r.worst.stable


@pytest.mark.slow
def test_scene_default_is_the_design_choice(tmp_path):
    """flexpend design with its defaults chooses the filter the filtered scene holds (and the
    controller's default); given the scene's previous filter (150, 0.5), it beats it."""
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", "design", "--json",
                           "--set", "controller.cutoff=150", "--set", "controller.filter_damping=0.5",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    scene = load_scene("flexible_pd_lowpass")
    for key, value in out["filter"].items():
        assert scene.get(key) == pytest.approx(value), key
    assert out["worst_case"]["stable"] and out["worst_case"]["plants"] == 7 * 125
    # the chosen filter beats the other order and the scene's previous filter (150, 0.5)
    assert out["worst_case"]["decay_rate"] >= max(
        v["worst_case"]["decay_rate"] for v in out["best_per_order"].values())
    assert out["worst_case"]["decay_rate"] > out["baselines"]["given"]["worst_case"]["decay_rate"]
    assert not out["baselines"]["no filter"]["worst_case"]["stable"]
    for name in ("design_bode.png", "design_root_locus.png", "design_worst_case.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    sweep = np.genfromtxt(tmp_path / "design_sweep.csv", delimiter=",", names=True)
    assert len(sweep) == DESIGN_DEFAULTS["design.n_cutoffs"]


@pytest.mark.parametrize("item,fragment", [
    ("design.criterion=fast", "design.criterion = 'fast' is not allowed; allowed: decay, damping"),
    ("design.levels=1", "design.levels = 1 is out of range"),
    ("design.cutoff_min=2000", "design.cutoff_min = 2000.0 exceeds design.cutoff_max"),
    ("design.level=3", "unknown key 'design.level'; did you mean 'design.levels'?"),
])
def test_design_bad_input_one_line_exit_2(item, fragment, tmp_path, capsys):
    from orchestration.cli import main
    assert main(["design", "--set", item, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert fragment in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
