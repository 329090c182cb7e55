"""A sweep's verdicts: "undetermined" (no fit decides, too short a run, or stopped early) is counted
and shown apart from "unstable" in the terminal, the table and the plot; a short run says what
the linearised loop says instead; the plot gives each quantity an axis of its own, with its unit,
and a legend of the series it drew (orchestration/sweeps/, orchestration/report/text.py)."""
import json

import numpy as np
import pytest

from orchestration.api import analyze
from orchestration.cli import main
from orchestration.report.text import verdict_lines
from orchestration.sweeps.engine import read_table, sweep_stats
from orchestration.sweeps.plan import plan_sweep
from orchestration.sweeps.plot import sweep_figure

KPS = (500.0, 700.0)


def test_short_runs_have_no_verdict_and_say_the_linearised_loop_is_stable(fmus, tmp_path,
                                                                          capsys):
    # 0.5 s from pi/6: fewer than 3 periods of any oscillation in the linear range, no fit
    args = ["sweep", "flexible_pd_lowpass", "--values",
            "controller.kp=" + ",".join(f"{kp:g}" for kp in KPS), "--set", "stop_time=0.5",
            "--serial", "--out", str(tmp_path)]
    assert main(args) == 0
    out = capsys.readouterr().out
    # the linearised loops of the same runs, from flexpend analyze
    assert all(analyze(overrides=[f"controller.kp={kp}"]).stable for kp in KPS)
    assert ("verdicts of the 2 finished runs: 0 stable, 0 unstable, 2 undetermined (2 whose fits "
            "do not decide)") in out, out
    assert "undetermined: the 2 runs whose fits do not decide" in out
    assert out.count("the linearised loop is stable in both") == 1
    assert "stable: 0 of 2" not in out and "0.0 %" not in out
    record = json.loads((tmp_path / "sweep.json").read_text())
    stats = record["stats"]
    assert (stats["stable"], stats["unstable"], stats["undetermined"], stats["no_fit"],
            stats["no_fit_linear_stable"], stats["stable_fraction"]) == (0, 0, 2, 2, 2, None)
    rows = read_table(record["table"])
    assert [r["verdict"] for r in rows] == ["undetermined"] * 2
    assert [r["stable"] for r in rows] == [None] * 2
    assert [r["linear_stable"] for r in rows] == [True] * 2
    assert all("periods" in (r["bending_note"] or "") for r in rows)


def rows_of_each_kind():
    """Four runs of a 1-D grid: stable, undetermined (no fit decides), unstable, stopped."""
    base = {"status": "ok", "slow_rate": None, "slow_rate_linear": None, "bending_rate": None,
            "bending_rate_linear": None, "decay_rate": None, "linear_decay_rate": None}
    return [
        {**base, "run": 0, "stable": True, "verdict": "stable", "decay_rate": 0.6,
         "linear_decay_rate": 0.59, "slow_rate": -0.6, "slow_rate_linear": -0.59,
         "bending_rate_linear": -1.9},
        {**base, "run": 1, "stable": None, "verdict": "undetermined", "linear_decay_rate": 0.58,
         "bending_rate_linear": -1.95},
        {**base, "run": 2, "stable": False, "verdict": "unstable", "decay_rate": -0.1,
         "linear_decay_rate": -0.12, "slow_rate": 0.1, "slow_rate_linear": 0.12},
        {**base, "run": 3, "status": "failed", "stable": None, "verdict": "undetermined"},
    ]


def test_stats_count_no_verdict_apart_from_unstable():
    s = sweep_stats(rows_of_each_kind())
    assert (s["stable"], s["unstable"], s["undetermined"], s["no_fit"], s["failed"]) == \
        (1, 1, 2, 1, 1)
    assert s["stable_fraction"] == 0.5                 # of the two runs with a verdict
    assert (s["linear_stable"], s["linear_unstable"], s["no_fit_linear_stable"]) == (2, 1, 1)
    lines = verdict_lines(s)
    assert lines[0] == ("  verdicts of the 4 finished runs: 1 stable (50.0 % of those with a "
                        "verdict), 1 unstable, 2 undetermined (1 whose fits do not decide; 1 "
                        "stopped early)")
    assert lines[1].endswith("the linearised loop is stable")


@pytest.mark.parametrize("linear,says", [((0.5, 0.6, 0.7), "stable in all 3"),
                                         ((-0.5, -0.6), "unstable in both"),
                                         ((0.5, -0.6), "stable in 1 of them, unstable in 1")])
def test_no_verdict_line_says_what_the_linearised_loop_says(linear, says):
    rows = [{"run": i, "status": "ok", "stable": None, "linear_decay_rate": v}
            for i, v in enumerate(linear)]
    assert verdict_lines(sweep_stats(rows))[1].endswith(f"the linearised loop is {says}")


def legend(ax):
    lg = ax.get_legend()
    return [] if lg is None else [t.get_text() for t in lg.get_texts()]


def test_line_plot_gives_each_quantity_its_axis_and_unit_and_no_empty_legend():
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=400,500,600,700"])
    fig = sweep_figure(plan, rows_of_each_kind())
    decay, slow, bending, strip = fig.axes
    assert decay.get_ylabel() == "largest growth rate\nσ, 1/s"
    assert slow.get_ylabel() == "slow (rigid) mode:\nσ = Re(λ), 1/s"
    assert bending.get_ylabel() == "bending mode:\nσ = Re(λ), 1/s"
    assert legend(decay) == ["co-simulation: max(fitted σ)", "linearised loop: max Re(λ)"]
    # one sign convention: the largest growth rate is the slow mode's rate where it is the
    # only one (the table's decay_rate with its sign turned), the same sign in both panels
    rows = rows_of_each_kind()
    fitted = decay.get_lines()[0].get_ydata()
    np.testing.assert_array_equal(fitted, [-0.6, np.nan, 0.1, np.nan])
    np.testing.assert_array_equal(slow.get_lines()[0].get_ydata(),
                                  [r["slow_rate"] if r["slow_rate"] is not None else np.nan
                                   for r in rows])
    assert "rates: growth rate σ = Re(λ), 1/s; negative decays" in decay.get_title()
    assert legend(slow) == ["fitted", "linearised loop"]
    assert legend(bending) == ["linearised loop"]      # no run has a fitted bending rate
    # the verdict strip: each run on its own row, "undetermined" apart from "unstable"
    assert strip.get_ylabel() == "verdict" and legend(strip) == []
    cats = [t.get_text() for t in strip.get_yticklabels()]
    assert cats == ["stable", "unstable", "undetermined", "stopped early"]
    assert [cats[int(line.get_ydata()[0])] for line in strip.get_lines()] == \
        ["stable", "undetermined", "unstable", "stopped early"]
    assert strip.get_xlabel() == "controller.kp"
    assert decay.get_title().splitlines()[1] == ("verdicts: 1 stable, 1 unstable, 2 undetermined "
                                                 "(1 whose fits do not decide, 1 stopped early)")


def test_line_plot_without_any_mode_has_no_mode_axes():
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=400,500"])
    rows = [{"run": i, "status": "ok", "stable": None, "verdict": "undetermined",
             "decay_rate": None, "linear_decay_rate": 0.6} for i in range(2)]
    decay, strip = sweep_figure(plan, rows).axes
    assert legend(decay) == ["linearised loop: max Re(λ)"]
    np.testing.assert_array_equal(decay.get_lines()[0].get_ydata(), [-0.6, -0.6])
    assert "2 undetermined (2 whose fits do not decide)" in decay.get_title()


def test_heat_map_and_histogram_count_the_verdicts():
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=400,500",
                                                     "controller.kd=4,5"])
    rows = rows_of_each_kind()
    ax = sweep_figure(plan, rows).axes[0]
    assert "verdicts: 1 stable, 1 unstable, 2 undetermined" in ax.get_title()
    assert "grey: undetermined (no fit decides)" in ax.get_title()
    assert [t.get_text() for t in ax.texts].count("no\nverdict") == 1
    plan = plan_sweep("flexible_pd_lowpass", samples=["controller.kp=uniform:400:700"],
                      n_samples=4)
    ax = sweep_figure(plan, rows).axes[0]
    assert ax.get_xlabel() == "largest growth rate σ, 1/s" and ax.get_ylabel() == "runs"
    assert "worst fitted σ = +0.1 1/s" in legend(ax) and "0: grows to the right" in legend(ax)
    assert "verdicts: 1 stable, 1 unstable, 2 undetermined" in ax.get_title()
