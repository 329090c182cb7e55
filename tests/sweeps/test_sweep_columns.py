"""flexpend sweep --columns: a sweep asked for some columns computes only what they need (no mode
fit without a fit column), shows the same values as a sweep of every column, and reuses the
journal's rows that have them (orchestration/sweeps/columns.py).

The runs are the short ones of test_sweep.py (3 s of the filtered scene from 0.05 rad)."""
import pytest

import orchestration.studies.summary as summary
from orchestration.cli import main
from orchestration.sweeps import columns as cols
from orchestration.sweeps.engine import Journal, run_sweep, sweep_stats
from orchestration.sweeps.executor import Executor
from orchestration.sweeps.plan import plan_sweep
from orchestration.sweeps.plot import sweep_figure

SHORT = ["stop_time=3", "initial.phi=0.05"]
NO_FIT = "max_abs_x,max_abs_F_c,valid,linear_decay_rate"


@pytest.fixture(scope="module")
def paths(fmus):
    return {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}


class Counting(Executor):
    """The serial executor, counting the tasks it runs and keeping the last map's."""

    def __init__(self):
        self.tasks, self.items = 0, []

    def map(self, fn, items, batch=1):
        self.items = list(items)
        for i, value in super().map(fn, self.items, batch):
            self.tasks += 1
            yield i, value


@pytest.fixture()
def no_fits(monkeypatch):
    """Every call of the summary's fit fails the test."""
    def refuse(*a, **k):
        raise AssertionError("a mode was fitted")
    monkeypatch.setattr(summary, "fit_mode", refuse)


def plan(columns=None, values="controller.kp=500,1e5,600"):
    return plan_sweep("flexible_pd_lowpass", values=[values], overrides=SHORT, columns=columns)


@pytest.fixture(scope="module")
def full(paths, tmp_path_factory):
    """The sweep of every column (kp = 1e5 fails: the beam tilts past its limit)."""
    return run_sweep(plan(), paths, tmp_path_factory.mktemp("full"), progress=False).rows


def test_the_columns_asked_for_fit_nothing_and_equal_those_of_every_column(
        paths, tmp_path, full, no_fits):
    res = run_sweep(plan(NO_FIT), paths, tmp_path, progress=False)
    asked = NO_FIT.split(",")
    for row, whole in zip(res.rows, full):
        assert list(row) == ["run", "key", "controller.kp", "status", *asked, "message"]
        assert {k: row[k] for k in ("run", "key", "status", "message", *asked)} == \
            {k: whole.get(k) for k in ("run", "key", "status", "message", *asked)}
    assert [r["status"] for r in res.rows] == ["ok", "failed", "ok"]
    assert "phi_limit" in res.rows[1]["message"]
    stats = sweep_stats(res.rows, plan(NO_FIT).columns)
    assert "stable" not in stats                       # no verdict was asked for
    ok = [r for r in full if r["status"] == "ok"]
    assert stats["columns_range"]["max_abs_x"]["max"] == max(r["max_abs_x"] for r in ok)
    assert (tmp_path / "sweep.png").stat().st_size > 10_000     # the column's line plot


def test_worker_processes_give_the_serial_table(paths, tmp_path, full):
    from orchestration.sweeps.executor import ProcessExecutor
    with ProcessExecutor(2) as ex:
        res = run_sweep(plan(NO_FIT), paths, tmp_path / "p", ex, progress=False)
    serial = run_sweep(plan(NO_FIT), paths, tmp_path / "s", progress=False)
    assert res.rows == serial.rows
    assert [r["max_abs_x"] for r in res.rows] == [r["max_abs_x"] for r in full]


def test_a_fit_column_fits_and_gives_the_verdicts_of_every_column(paths, tmp_path, full):
    res = run_sweep(plan("verdict,decay_rate"), paths, tmp_path, progress=False)
    assert [(r["verdict"], r["decay_rate"]) for r in res.rows] == \
        [(r["verdict"], r["decay_rate"]) for r in full]
    stats, whole = sweep_stats(res.rows, ("verdict", "decay_rate")), sweep_stats(full)
    assert all(stats[k] == whole[k] for k in ("stable", "unstable", "undetermined", "no_fit",
                                             "worst_decay_rate", "median_decay_rate"))
    assert sweep_figure(plan("verdict,decay_rate"), res.rows) is not None


def test_the_journal_serves_the_sweeps_whose_columns_its_rows_have(paths, tmp_path, full):
    ex = Counting()
    run_sweep(plan("max_abs_x"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 3
    run_sweep(plan("max_abs_x"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 3                               # the same columns: nothing runs
    run_sweep(plan("steps"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 6       # a new column: every run again, the failed one too
    rows = Journal(tmp_path).read()
    assert [set(r["columns"]) for r in rows.values()] == [{"steps", "max_abs_x"}] * 3
    both = run_sweep(plan("max_abs_x,steps"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 6                               # the rerun kept the old column...
    assert [(r["max_abs_x"], r["steps"]) for r in both.rows] == \
        [(r["max_abs_x"], r["steps"]) for r in full]  # ...and its values
    again = run_sweep(plan(), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 9       # every column: a row of some columns serves no longer
    assert all("slow_rate" in r and "columns" not in r for r in again.rows)
    run_sweep(plan("bending_rate"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 9       # a row of every column serves any sweep


def test_summarize_without_fits_has_the_other_fields_of_the_full_summary(paths):
    import numpy as np
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    run = run_scene(load_scene("flexible_pd_lowpass", SHORT), paths, progress=False)
    bare = summary.summarize(run.result, run.scene, None, fits=False)
    whole = summary.summarize(run.result, run.scene, None)
    assert bare["slow"] is bare["bending"] is bare["verdict"] is bare["stable"] is None
    assert whole["verdict"] == "stable" and whole["slow"]["reliable"]
    for k in ("max_abs_F_c", "max_abs_x", "completed", "validity"):
        assert bare[k] == whole[k], k
    assert np.isfinite(bare["max_abs_x"])


@pytest.mark.parametrize("spec,fragment", [
    ("bogus", "unknown column 'bogus'; allowed: stable, verdict"),
    ("max_abs_x,", "an empty column name"),
    ("max_abs_x,max_abs_x", "max_abs_x is named twice; name each column once"),
    ("status,run", "--columns names no result column; allowed: stable"),
])
def test_a_bad_column_is_a_value_error_naming_it(spec, fragment):
    with pytest.raises(ValueError, match=fragment.replace("(", r"\(")):
        cols.parse_columns(spec)
    with pytest.raises(TypeError, match="columns = 3"):
        cols.parse_columns(3)
    assert cols.parse_columns(["status", " max_abs_x"]) == ("max_abs_x",)


@pytest.mark.parametrize("args,fragment", [
    (["--columns", "bogus"], "--columns: unknown column 'bogus'; allowed:"),
    (["--columns", "max_error_phi_o"], "max_error_phi_o is the error against the monolithic "
                                       "reference: it needs --reference"),
    (["--columns", "max_abs_x", "--reference"], "ask for one of them in --columns, or leave "
                                                "--reference out"),
])
def test_cli_a_bad_column_is_one_line_exit_2(args, fragment, capsys, tmp_path):
    argv = ["sweep", "flexible_pd_lowpass", "--values", "controller.kp=500,600", "--out",
            str(tmp_path), *args]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and len(err.strip().splitlines()) == 1, err
    assert not any(tmp_path.iterdir())


def test_the_python_api_names_its_argument(tmp_path):
    from orchestration import sweep
    with pytest.raises(ValueError, match="max_error_eta_1 is the error against the monolithic "
                                         "reference: it needs reference=True"):
        sweep("flexible_pd_lowpass", values={"controller.kp": [500]}, columns=["max_error_eta_1"],
              out=tmp_path)


def test_cli_prints_the_range_of_each_column(fmus, tmp_path, capsys, no_fits):
    assert main(["sweep", "flexible_pd_lowpass", "--values", "controller.kp=500,600", "--set",
                 "stop_time=3", "--set", "initial.phi=0.05", "--serial", "--columns",
                 "max_abs_x", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "verdicts" not in out and "max_abs_x: smallest " in out and " over 2 runs" in out


def test_an_older_journal_row_without_a_verdict_has_the_verdict_of_its_stable(paths, tmp_path,
                                                                             full):
    import json
    run_sweep(plan(), paths, tmp_path, progress=False)
    journal = tmp_path / "runs.jsonl"
    rows = [json.loads(line) for line in journal.read_text().splitlines()]
    journal.write_text("".join(json.dumps({k: v for k, v in r.items() if k != "verdict"}) + "\n"
                               for r in rows))       # as an older flexpend wrote it
    ex = Counting()
    res = run_sweep(plan("verdict,max_abs_x"), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 0
    assert [r["verdict"] for r in res.rows] == ["stable", "undetermined", "stable"] == \
        [r["verdict"] if r["status"] == "ok" else "undetermined" for r in full]


def test_statistics_only_of_what_was_computed_and_no_stale_figure(paths, tmp_path):
    run_sweep(plan("max_abs_x"), paths, tmp_path, progress=False)
    assert (tmp_path / "sweep.png").exists()
    res = run_sweep(plan("valid,stable"), paths, tmp_path, progress=False)
    assert res.plot is None and not (tmp_path / "sweep.png").exists()   # no numeric column
    stats = sweep_stats(res.rows, ("valid", "stable"))
    assert "linear_stable" not in stats and "stable" in stats
    assert stats["columns_flags"] == {"valid": {"true": 2, "false": 0},
                                      "stable": {"true": 2, "false": 0}}
    bare = sweep_stats(res.rows, ("max_abs_x",))
    assert not {"invalid", "linear_stable", "stable", "no_fit"} & set(bare)


def test_a_retried_row_of_every_column_stays_one(paths, tmp_path):
    ex = Counting()
    run_sweep(plan(), paths, tmp_path, ex, progress=False)
    assert all(len(task) == 4 for task in ex.items)     # the task of every column as before
    run_sweep(plan("max_abs_x"), paths, tmp_path, ex, progress=False, retry_failed=True)
    assert ex.tasks == 4 and len(ex.items[0]) == 4      # the failed run, all columns again
    run_sweep(plan(), paths, tmp_path, ex, progress=False)
    assert ex.tasks == 4
