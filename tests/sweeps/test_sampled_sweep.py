"""A sweep over the sample period (issue 38): continuous and sampled runs side by side, each
run's linearised decay rate the loop it ran (the sampled loop's -log(max |z|) / T for a sampled
controller, the continuous loop's for sample_period = 0), which the runs' fitted rates meet."""
from __future__ import annotations

import pytest

from orchestration.sweeps.job import sweep


def test_each_runs_linear_rate_is_the_loop_it_ran(tmp_path):
    s = sweep("rigid_pd", values={"controller.sample_period": [0.0, 0.01, 0.021]},
              overrides=["stop_time=4", "initial.phi=0.01", "fidelity.companion=false"],
              serial=True, out=tmp_path / "sw")
    rows = sorted(s.rows, key=lambda r: r["controller.sample_period"])
    assert [r["controller.sample_period"] for r in rows] == [0.0, 0.01, 0.021]
    for r in rows:
        assert r["decay_rate"] == pytest.approx(r["linear_decay_rate"], abs=1e-3)
    assert rows[0]["linear_decay_rate"] > rows[1]["linear_decay_rate"] > 0 > \
        rows[2]["linear_decay_rate"]
