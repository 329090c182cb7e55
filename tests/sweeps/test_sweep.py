"""flexpend sweep: the same table on worker processes and on dask as serially, seeded samples,
failed and lost runs,
resuming, and one-line errors for bad specs (orchestration/sweeps/, orchestration/sweeps/executor.py).

The runs are short (3 s of the filtered scene from 0.05 rad, where the summary's fits are
reliable) so that the file stays a few seconds long."""
import math

import numpy as np
import pytest
import scipy.stats

from orchestration.cli import main
from orchestration.studies.design import UncertaintySet, worst_cases
from orchestration.sweeps.executor import DaskExecutor, Executor, ProcessExecutor, TaskLost
from orchestration.job import run_scene
from orchestration.scene.schema import load_scene
from orchestration.sweeps.engine import Journal, read_table, run_sweep, sweep_stats, write_table
from orchestration.sweeps.plan import plan_sweep
from plant_fmu.params import PlantParams

SHORT = ["stop_time=3", "initial.phi=0.05"]
TIMES = ("wall_time", "cosim_time")


@pytest.fixture(scope="module")
def paths(fmus):
    return {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}


@pytest.fixture(scope="module")
def cluster(paths):
    """A LocalCluster of 2 worker processes with the FMUs sent to them."""
    with DaskExecutor(workers=2, files=list(paths.values())) as ex:
        yield ex


@pytest.fixture(scope="module")
def processes():
    """Two worker processes on this machine (the local executor)."""
    with ProcessExecutor(2) as ex:
        yield ex


class Counting(Executor):
    """The serial executor, counting the tasks it runs."""

    def __init__(self):
        self.tasks = 0

    def map(self, fn, items, batch=1):
        for i, value in super().map(fn, items, batch):
            self.tasks += 1
            yield i, value


def untimed(rows):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


@pytest.mark.slow
def test_grid_on_two_workers_equals_serial_and_a_direct_run(paths, cluster, processes,
                                                            tmp_path):
    plan = plan_sweep("flexible_pd_lowpass", grids=["controller.kp=500:700:2"],
                      values=["master.extrapolation=0,1"], overrides=SHORT)
    assert [p.params for p in plan.points] == [
        {"controller.kp": kp, "master.extrapolation": e} for kp in (500.0, 700.0) for e in (0, 1)]
    serial = run_sweep(plan, paths, tmp_path / "serial", progress=False)
    assert cluster.workers == 2
    dask = run_sweep(plan, paths, tmp_path / "dask", cluster, progress=False)
    assert serial.table.suffix == ".parquet"
    assert untimed(read_table(serial.table)) == untimed(read_table(dask.table))
    # the local executor, at any number of workers and any batch, value for value
    local = run_sweep(plan, paths, tmp_path / "local", processes, progress=False)
    assert untimed(read_table(local.table)) == untimed(read_table(serial.table))
    with ProcessExecutor(1) as one:
        alone = run_sweep(plan, paths, tmp_path / "alone", one, batch=3, progress=False)
    assert untimed(read_table(alone.table)) == untimed(read_table(serial.table))
    assert all(r["status"] == "ok" for r in dask.rows)
    # a row holds what the run's own summary says (run_scene called directly here, with BLAS
    # on one thread as every task has it: two threads change the fits' 13th digit)
    from threadpoolctl import threadpool_limits
    scene = load_scene("flexible_pd_lowpass", SHORT + ["controller.kp=700",
                                                       "master.extrapolation=1"])
    with threadpool_limits(limits=1, user_api="blas"):
        r = run_scene(scene, paths, progress=False).summary
    row = dask.rows[3]
    assert row["slow_frequency"] == r["slow"]["frequency"]
    assert row["slow_rate"] == r["slow"]["rate"] and row["slow_rate_linear"] == \
        r["slow"]["linear"]["rate"]
    assert row["bending_rate"] == r["bending"]["rate"]
    assert row["max_abs_F_c"] == r["max_abs_F_c"]
    assert row["steps"] == r["steps"] == round(3 / scene.master.step)
    reliable = [m["rate"] for m in (r["slow"], r["bending"]) if m["reliable"]]
    assert reliable and row["decay_rate"] == -max(reliable)
    assert (tmp_path / "dask" / "sweep.png").stat().st_size > 10_000      # the heat map


def test_design_check_grid_on_dask_and_processes_equals_serial(cluster, processes):
    from controller_fmu.pd_lowpass import ControllerParams
    plants = UncertaintySet(PlantParams()).plants(3)
    ctrls = [ControllerParams(filter_order=2, cutoff=97.3, filter_damping=0.1),
             ControllerParams(filter_order=1, cutoff=115.0), ControllerParams(filter_order=0)]
    serial = worst_cases(plants, ctrls)
    for ex in (Executor(), cluster, processes):
        for a, b in zip(serial, worst_cases(plants, ctrls, ex, chunks=5)):
            assert (a.decay, a.decay_plant, a.decay_root) == (b.decay, b.decay_plant, b.decay_root)
            assert (a.damping, a.damping_plant, a.n_plants) == (b.damping, b.damping_plant,
                                                                b.n_plants)
    assert serial[0].n_plants == 7 * 27 and serial[2].decay < 0 < serial[0].decay


def test_seeded_sample_is_reproducible_and_draws_the_design_set(paths, tmp_path):
    def draws(seed, n=5, sample=("design",)):
        plan = plan_sweep("flexible_pd_lowpass", samples=list(sample), n_samples=n, seed=seed,
                          overrides=SHORT)
        return plan, [p.params for p in plan.points]

    plan, a = draws(7)
    assert draws(7)[1] == a and draws(8)[1] != a
    assert draws(7, n=3)[1] == a[:3]                # the first k of n samples are the k samples
    # one key of the set alone gets the same values as with the whole set
    assert [p["plant.zeta"] for p in draws(7, sample=["plant.zeta=design"])[1]] == \
        [p["plant.zeta"] for p in a]
    # the rows of a run hold the drawn values, and a second run gives the same table
    one = run_sweep(plan, paths, tmp_path / "one", progress=False)
    two = run_sweep(plan, paths, tmp_path / "two", progress=False)
    assert untimed(one.rows) == untimed(two.rows)
    assert [{k: r[k] for k in a[0]} for r in one.rows] == a
    assert (tmp_path / "one" / "sweep.png").stat().st_size > 10_000      # the histogram
    # the distribution is the set's: n_modes uniform on 2..8, zeta log-uniform on
    # [5e-4, 2e-3], EI and m uniform within +-10 % and +-20 % of the nominal (KS tests)
    big = UncertaintySet(PlantParams()).sample(np.random.default_rng(1), 4000)
    counts = np.bincount(big["n_modes"], minlength=9)[2:]
    assert counts.sum() == 4000 and scipy.stats.chisquare(counts).pvalue > 1e-3
    for values, lo, hi, log in ((big["zeta"], 5e-4, 2e-3, True), (big["EI"], 787.5, 962.5, False),
                                (big["m"], 0.8, 1.2, False)):
        x = np.log(values) if log else np.asarray(values)
        a_, b_ = (math.log(lo), math.log(hi)) if log else (lo, hi)
        assert x.min() >= a_ - 1e-12 and x.max() <= b_ + 1e-12
        assert scipy.stats.kstest(x, "uniform", args=(a_, b_ - a_)).pvalue > 1e-3


def test_failing_run_is_a_failed_row_and_the_others_complete(paths, tmp_path):
    # kp = 1e5 drives the beam past plant.phi_limit within 0.05 s: the FMU refuses the step
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=500,1e5,600"],
                      overrides=SHORT)
    res = run_sweep(plan, paths, tmp_path, progress=False)
    assert [r["status"] for r in res.rows] == ["ok", "failed", "ok"]
    bad = res.rows[1]
    assert "the beam tilted past plant.phi_limit" in bad["message"]
    assert "phi_limit" in bad["fmu_message"] and "plant: doStep" in bad["fmu_message"]
    assert bad["stable"] is None and 0 < bad["stopped_at"] < 0.05 and bad["wall_time"] > 0
    assert res.rows[0]["stable"] is True and res.rows[2]["stable"] is True
    stats = sweep_stats(res.rows)
    assert (stats["ok"], stats["failed"], stats["stable"], stats["undetermined"]) == (2, 1, 2, 1)
    assert (tmp_path / "sweep.png").stat().st_size > 10_000              # the line plot


def test_resume_runs_only_the_missing_rows(paths, tmp_path):
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=500,1e5,550,600"],
                      overrides=SHORT)
    first = run_sweep(plan, paths, tmp_path, progress=False)
    journal = tmp_path / "runs.jsonl"
    lines = journal.read_text().splitlines()
    assert len(lines) == 4
    # interrupted after two runs, the second half-written when the process was killed
    journal.write_text(lines[0] + "\n" + lines[1] + "\n" + lines[2][:40])
    ex = Counting()
    again = run_sweep(plan, paths, tmp_path, ex, progress=False)
    assert (ex.tasks, again.ran, again.skipped) == (2, 2, 2)
    assert untimed(again.rows) == untimed(first.rows)
    assert [r["wall_time"] for r in again.rows][:2] == [r["wall_time"] for r in first.rows][:2]
    assert len(Journal(tmp_path).read()) == 4
    ex = Counting()
    run_sweep(plan, paths, tmp_path, ex, progress=False)
    assert ex.tasks == 0                       # all done; the failed run counts as done...
    run_sweep(plan, paths, tmp_path, ex, progress=False, retry_failed=True)
    assert ex.tasks == 1                       # ...unless asked to retry it
    # the CSV table (no pyarrow) holds the same values as the Parquet one
    for kind in ("csv", "parquet"):
        (tmp_path / kind).mkdir()
        assert write_table(again.rows, tmp_path / kind, kind == "parquet").suffix == f".{kind}"
    assert read_table(tmp_path / "csv" / "sweep.csv") == \
        read_table(tmp_path / "parquet" / "sweep.parquet") == again.rows


@pytest.mark.slow
def test_lost_worker_keeps_the_other_results(tmp_path):
    import dask

    # no retry, and one task at a time on the worker (no innocent task dies with it)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0,
                          "distributed.scheduler.worker-saturation": 1.0}):
        with DaskExecutor(workers=1) as ex:
            out = dict(ex.map(_die_on_three, range(6)))
    assert isinstance(out[3], TaskLost) and "KilledWorker" in out[3].message
    assert {i: v for i, v in out.items() if i != 3} == {0: 0, 1: 1, 2: 4, 4: 16, 5: 25}


def _die_on_three(i):
    if i == 3:
        import os
        os._exit(1)                 # a crash inside an FMU takes its worker process with it
    return i * i


@pytest.mark.parametrize("args,fragment", [
    (["--grid", "controller.kp=1:2"], "--grid expects KEY=START:STOP:NUM[:log]"),
    (["--grid", "controller.kpp=1:2:3"], "unknown key 'controller.kpp'; did you mean "
                                         "'controller.kp'?"),
    (["--grid", "controller.kp=1:2:0"], "NUM must be an integer 1..100000"),
    # too many runs: numpy's "Maximum allowed size exceeded", or minutes of planning, before
    (["--grid", "controller.kp=1:2:99999999999999999999"], "NUM must be an integer 1..100000"),
    (["--sample", "plant.EI=uniform:800:900", "--samples", "99999999999999999999"],
     "--samples 99999999999999999999 is not allowed; allowed: an integer 1..100000"),
    (["--grid", "controller.kp=1:2:1000", "--grid", "controller.kd=1:2:1000"],
     "the sweep has 1000000 runs; allowed: at most 100000 in one sweep"),
    (["--grid", "controller.kp=1:2:1000", "--sample", "plant.EI=uniform:800:900", "--samples",
      "1000"], "the sweep has 1000000 runs"),
    (["--grid", "controller.kp=0:2:3:log"], "a log grid needs START and STOP > 0"),
    (["--grid", "plant.n_modes=1:2:3"], "plant.n_modes takes integers; the grid gives 1.5"),
    (["--values", "master.algorithm=jacobi,"], "an empty value"),
    (["--values", "master.algorithm=jacobi,gauss"], "run 1 (master.algorithm='gauss'): "
                                                    "master.algorithm = 'gauss' is not allowed"),
    (["--grid", "plant.zeta=0.5:2:3"], "plant.zeta = 1.25 is out of range"),
    (["--sample", "plant.EI=gauss:1:2", "--samples", "3"], "--sample expects KEY=DIST"),
    (["--sample", "controller.kp=design", "--samples", "3"], "the design's uncertainty set "
                                                             "has the keys"),
    (["--sample", "design"], "--sample needs --samples N"),
    (["--values", "controller.kp=1,2", "--samples", "3"], "--samples needs --sample"),
    ([], "nothing to sweep"),
    (["--values", "controller.kp=1,2", "--set", "controller.kp=3"], "controller.kp is also "
                                                                     "swept"),
    (["--values", "controller.kp=1,2", "--set", "design.EI_spread=0.1"], "need --sample design"),
    (["--values", "controller.kp=1,2", "--workers", "0"], "--workers 0 is not allowed"),
    (["--values", "controller.kp=1,2", "--serial", "--workers", "2"], "--serial runs here"),
    (["--values", "controller.kp=1,2", "--samples", "x"], "invalid int value: 'x'"),
])
def test_bad_spec_one_line_exit_2(args, fragment, capsys, tmp_path):
    assert main(["sweep", "flexible_pd_lowpass", "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert fragment in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not any(tmp_path.iterdir())          # nothing ran, nothing written


def test_cli_sweep_prints_counts_writes_record_and_resumes(fmus, tmp_path, capsys):
    import json
    args = ["sweep", "flexible_pd_lowpass", "--values", "controller.kp=600,1e5",
            "--set", "stop_time=3", "--set", "initial.phi=0.05", "--serial", "--out",
            str(tmp_path)]
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "flexible_pd_lowpass: 2 runs: 1 ok, 1 failed; 2 ran in" in out
    assert "run 1 failed: the beam tilted past plant.phi_limit = 1.571 rad (90 deg) by t = 0.0" \
        in out
    assert "verdicts of the 2 finished runs: 1 stable (100.0 % of those with a verdict), 0 " \
           "unstable, 1 undetermined (1 stopped early)" in out
    assert "2/2 finished, 1 failed, 0 remaining" in err
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert record["stats"]["ok"] == 1 and record["grid"] == {"controller.kp": [600.0, 1e5]}
    assert record["command"].startswith("flexpend sweep flexible_pd_lowpass --values")
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert "2 already finished" in err and "; 0 ran, 2 were already done" in out


# ---------------------------------------------------------------------- a damaged sweep folder
@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 2-run sweep's folder (runs.jsonl, the table, sweep.json, sweep.png)."""
    out = tmp_path_factory.mktemp("finished")
    assert main(_SMALL + ["--out", str(out)]) == 0
    return out


_SMALL = ["sweep", "rigid_pd", "--values", "controller.kp=500,600", "--set", "stop_time=0.5",
          "--serial"]


def _rerun(finished, tmp_path, capsys, damage):
    import shutil

    out = tmp_path / "sweep"
    shutil.copytree(finished, out)
    capsys.readouterr()
    damage(out)
    code = main(_SMALL + ["--out", str(out)])
    stdout, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, stdout, err


def _row0(edit):
    """A damage that rewrites the journal's first row (a dict) with ``edit``; bytes are
    written as they are."""
    import json

    def damage(out):
        lines = (out / "runs.jsonl").read_bytes().splitlines()
        row = edit(json.loads(lines[0]))
        lines[0] = row if isinstance(row, bytes) else json.dumps(row).encode()
        (out / "runs.jsonl").write_bytes(b"\n".join(lines) + b"\n")
    return damage


@pytest.mark.parametrize("damage", [
    _row0(lambda r: json_bytes(r).replace(b'"status"', b'"st\xffatus"')),
    _row0(lambda r: {**r, "key": [1, 2]}),
    _row0(lambda r: {**r, "key": 7}),
    _row0(lambda r: {**r, "decay_rate": "fast"}),
    _row0(lambda r: {**r, "stable": "yes"}),
    _row0(lambda r: {**r, "status": None}),
    _row0(lambda r: [r]),
], ids=["invalid UTF-8", "key a list", "key a number", "decay_rate a string",
        "stable a string", "status null", "not an object"])
def test_a_damaged_journal_row_is_rerun(finished, tmp_path, capsys, damage):
    """A journal row that is not a sound row (invalid UTF-8, a key that is not a string, a
    field of the wrong type) counts as not finished: its run is rerun, the other is kept.
    Failed before with tracebacks (UnicodeDecodeError, unhashable list, a str compared with a
    float in the statistics) or by trusting the row."""
    code, stdout, err = _rerun(finished, tmp_path, capsys, damage)
    assert code == 0, err
    assert "1 already finished" in err and "; 1 ran in " in stdout, stdout
    assert ", 1 were already done" in stdout
    assert Journal(tmp_path / "sweep").read().keys() == Journal(finished).read().keys()


def json_bytes(row) -> bytes:
    import json

    return json.dumps(row).encode()


@pytest.mark.parametrize("name", ["runs.jsonl", "sweep.parquet", "sweep.csv", "sweep.json",
                                  "sweep.png"])
def test_a_folder_in_place_of_a_sweep_file_is_one_line(finished, tmp_path, capsys, name):
    """Failed before: IsADirectoryError tracebacks (runs.jsonl, the tables) or a sweep that ran
    and then could not write its record."""
    def damage(out):
        (out / name).unlink(missing_ok=True)
        (out / name).mkdir()
    code, stdout, err = _rerun(finished, tmp_path, capsys, damage)
    assert code == 2, (stdout, err)
    assert err.startswith("flexpend: error: ") and f"{name}: a folder" in err, err
    assert len(err.strip().splitlines()) == 1


def test_an_immutable_journal_is_one_line(finished, tmp_path, capsys):
    """chattr +i (root cannot write it either). Failed before: a PermissionError traceback."""
    import subprocess

    journal = tmp_path / "sweep" / "runs.jsonl"

    def damage(out):
        if subprocess.run(["chattr", "+i", str(journal)], capture_output=True).returncode:
            pytest.skip("chattr +i is not available here")
    try:
        code, stdout, err = _rerun(finished, tmp_path, capsys, damage)
    finally:
        subprocess.run(["chattr", "-i", str(journal)], capture_output=True)
    assert code == 2, (stdout, err)
    assert err.startswith("flexpend: error: ") and "runs.jsonl: cannot be written" in err
    assert len(err.strip().splitlines()) == 1


def test_a_sweep_leaves_the_companion_out_unless_it_is_set():
    """A sweep's runs state the measured bound (the companion run costs about 50 default runs);
    --set or a swept fidelity.companion keeps what the user asked."""
    from orchestration.sweeps.plan import plan_sweep

    plain = plan_sweep("rigid_pd", values=["controller.kp=400,500"])
    assert plain.scene.fidelity.companion is False
    assert all(p.scene.fidelity.companion is False for p in plain.points)
    asked = plan_sweep("rigid_pd", values=["controller.kp=400,500"],
                       overrides=["fidelity.companion=true"])
    assert all(p.scene.fidelity.companion is True for p in asked.points)
    swept = plan_sweep("rigid_pd", values=["fidelity.companion=true,false"])
    assert [p.scene.fidelity.companion for p in swept.points] == [True, False]
