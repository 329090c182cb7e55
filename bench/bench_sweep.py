"""What a sweep run costs against its co-simulation, before and after a change, and what
dask.distributed buys a sweep on this machine: a 64-run ``flexpend sweep`` on a LocalCluster
against the serial path, and dask's overhead per task.

    python bench/bench_sweep.py [--before REV] [--workers 2] [--reps 3] [--stop-time 2]
    python bench/bench_sweep.py --quick          # a smoke run: the first two parts, small

* **A sweep run, before and after** (``bench/sweep_run_profile.py`` in a process per checkout:
  this one, and ``--before`` REV, default f884ad8, checked out into a temporary git worktree that
  is removed at the end; ``--before none`` skips it): the per-run function of a sweep on
  ``--sample design`` runs of the 10 s filtered scene, one after the other after a warm-up, its
  time split into stepping (the master's wall time), fits, linear analysis, FMU load and
  instantiation, and the rest; medians, and each run's total over its own stepping.
* **Runs per second per core** of ``flexpend sweep flexible_pd_lowpass --sample design`` (the
  same runs through ``run_sweep``, no plot), serially and on a LocalCluster of ``--workers``
  (one run per task, and a batch that makes four tasks a worker: 8 runs), for both checkouts, against the compiled loop's own limit: 1 / the
  runs' median stepping time.

The study of dask (with ``--quick``, skipped):

* **Sweep**: 64 runs of the filtered scene (``controller.kp`` 400..600 x ``controller.cutoff``
  80..120 rad/s, 8 x 8, ``stop_time`` 2 s), through :func:`orchestration.sweeps.engine.run_sweep` into a
  fresh folder each time: serially in this process, and on a LocalCluster of ``--workers``
  processes that is already started and warmed up (its start-up and first sweep are reported
  apart). The two alternate, ``--reps`` times each after a warm-up; medians. The tables of both
  are checked equal, value for value.
* **Ceiling**: the same side-by-side comparison for 64 tasks of pure Python arithmetic of about
  the same length, which share nothing: the speed-up the machine's free cores allow at that
  moment (on a shared machine, less than the number of workers).
* **Overhead per task**: (a) 2000 no-op tasks through the same executor, time per task (the
  scheduler's and the client's round trip, the floor of any task); (b) in the real sweep,
  ``(wall time x workers - sum of the runs' own times) / runs``: what a run costs beyond itself.
* **Batching**: 64 very short runs (``stop_time`` 0.05 s, dominated by loading the FMUs) with one
  run per task and with 8 per task (``--batch 8``).

Writes bench/results/bench_sweep.json.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, ROOT, product_fmus  # noqa: E402
from sweep_run_profile import PARTS, medians  # noqa: E402

from orchestration.sweeps.executor import DaskExecutor, Executor  # noqa: E402
from orchestration.sweeps.plan import plan_sweep
from orchestration.sweeps.engine import run_sweep  # noqa: E402

SCENE = "flexible_pd_lowpass"
GRID = ["controller.kp=400:600:8", "controller.cutoff=80:120:8"]
TIMES = ("wall_time", "cosim_time")


BEFORE = "f884ad8"          # main before issue 25


@contextmanager
def checkout(rev):
    """``rev`` checked out into a temporary git worktree (removed at the end); None: none."""
    if rev in (None, "none"):
        yield None
        return
    folder = tempfile.mkdtemp(prefix="flexpend_before_")
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", folder, rev],
                   check=True, capture_output=True)
    try:
        yield Path(folder)
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", folder],
                       capture_output=True)
        shutil.rmtree(folder, ignore_errors=True)


def measure(tree: Path, *args) -> dict:
    """``bench/sweep_run_profile.py ARGS`` run on the code of the checkout ``tree``."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cmd = [sys.executable, str(Path(__file__).resolve().parent / "sweep_run_profile.py"),
           *map(str, args)]
    p = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)} in {tree} failed:\n{p.stderr[-2000:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert Path(out["checkout"]).resolve() == tree.resolve(), (out["checkout"], tree)
    return out


def sweep_runs(args, out) -> None:
    """The profile of a sweep run and the runs per second per core, for each checkout."""
    runs, warmup, rounds, n_sweep, reps = (6, 2, 1, 16, 1) if args.quick else \
        (16, 3, args.reps, 64, args.reps)
    # (workers, batch): four tasks a worker when batched
    configs = [(0, 1), (args.workers, 1), (args.workers, max(2, n_sweep // (4 * args.workers)))]

    def label(conf):
        w, b = conf
        return "serial" if w == 0 else f"LocalCluster({w})" + (f", --batch {b}" if b > 1 else "")
    with checkout(args.before) as before:
        trees = {"before": before, "after": ROOT} if before is not None else {"after": ROOT}
        if before is not None:
            out["before"] = args.before
        pooled = {name: [] for name in trees}
        for rnd in range(rounds):               # alternating, a fresh process each time
            for name, tree in trees.items():
                got = measure(tree, "split", "--runs", runs, "--warmup", warmup)["rows"]
                pooled[name] += got
                print(f"split {name}, round {rnd + 1}: "
                      f"{statistics.median(r['total'] for r in got) * 1e3:.1f} ms a run",
                      flush=True)
        split = {name: {"median_s": medians(rows)} for name, rows in pooled.items()}
        rate = {}
        for conf in configs:
            for name, tree in trees.items():
                rate[(name, conf)] = r = measure(tree, "sweep", "--runs", n_sweep, "--workers",
                                                 conf[0], "--batch", conf[1], "--reps", reps)
                print(f"sweep {name}, {label(conf)}: {r['runs_per_s_per_core']:.1f} "
                      "runs/s/core", flush=True)
    out["run_split"] = {k: v["median_s"] for k, v in split.items()}
    out["run_split_runs"] = runs * rounds
    out["runs_per_s_per_core"] = {f"{name}, {label(conf)}": r for (name, conf), r in rate.items()}
    names = list(trees)
    print(f"\nA sweep run of the 10 s filtered scene ({runs} design samples after {warmup} "
          f"warm-up runs, {rounds} rounds, medians), ms:")
    print(f"{'':28s}" + "".join(f"{n:>10s}" for n in names))
    rows = [(k, k) for k in PARTS] + [("total", "total"), ("without the fits", "without_fits")]
    for text, key in rows:
        print(f"{text:28s}" + "".join(f"{1e3 * split[n]['median_s'][key]:10.2f}"
                                       for n in names))
    for text, key in (("total / stepping", "x_stepping"),
                       ("without fits / stepping", "x_stepping_without_fits")):
        print(f"{text:28s}" + "".join(f"{split[n]['median_s'][key]:10.2f}" for n in names))
    print(f"\nRuns per second per core, --sample design ({n_sweep} runs, median of {reps}):")
    print(f"{'':28s}" + "".join(f"{n:>10s}" for n in names) + f"{'limit':>10s}")
    for conf in configs:
        limit = rate[(names[-1], conf)]["limit_runs_per_s"]
        print(f"{label(conf):28s}" + "".join(f"{rate[(n, conf)]['runs_per_s_per_core']:10.1f}"
                                             for n in names) + f"{limit:10.1f}")
    print("(limit: 1 / the median stepping time of the runs, in the processes that ran them, "
          "after)")


def burn(seconds_hint: float) -> float:
    """Pure Python arithmetic for about ``seconds_hint`` seconds on an idle core."""
    n = int(seconds_hint * 2.5e7)
    t0 = time.perf_counter()
    s = 0
    for i in range(n):
        s += i & 7
    return time.perf_counter() - t0


def noop(i):
    return i


def sweep_time(plan, fmus, ex, batch=1):
    with tempfile.TemporaryDirectory(prefix="flexpend_bench_sweep_") as d:
        res = run_sweep(plan, fmus, d, ex, batch=batch, progress=False, plot=False)
    assert res.count("ok") == len(plan.points), [r["message"] for r in res.rows
                                                 if r["status"] != "ok"][:2]
    return res


def untimed(rows):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3, help="timed repetitions after a warm-up")
    ap.add_argument("--stop-time", type=float, default=2.0, help="length of each run, s")
    ap.add_argument("--json", default=str(RESULTS / "bench_sweep.json"))
    ap.add_argument("--before", default=BEFORE,
                    help=f"the revision compared with this checkout (default {BEFORE}; none)")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: few runs, without the study of dask")
    args = ap.parse_args(argv)
    out = {"command": "python bench/bench_sweep.py " + " ".join(sys.argv[1:] if argv is None
                                                                 else argv),
           "python": platform.python_version(), "cpus": os.cpu_count(),
           "load_average_start": list(os.getloadavg()), "workers": args.workers}
    sweep_runs(args, out)
    if args.quick:
        return finish(out, args)
    # the native pair, as `flexpend sweep` runs the scene (master.fmus = native; until
    # 2026-11-29 this study ran the pythonfmu pair)
    fmus = product_fmus("native")
    plan = plan_sweep(SCENE, grids=GRID, overrides=[f"stop_time={args.stop_time!r}"])
    short = plan_sweep(SCENE, grids=GRID, overrides=["stop_time=0.05"])
    out.update(runs=len(plan.points), stop_time=args.stop_time)
    serial = Executor()
    t0 = time.perf_counter()
    cluster = DaskExecutor(workers=args.workers, files=list(fmus.values()),
                           paths=[str(Path(__file__).resolve().parent)])
    out["cluster_start_s"] = time.perf_counter() - t0
    with cluster:
        print(f"LocalCluster of {args.workers} started in {out['cluster_start_s']:.2f} s; "
              f"load average {os.getloadavg()[0]:.2f}", flush=True)
        first = sweep_time(plan, fmus, cluster)
        out["first_dask_sweep_s"] = first.seconds            # worker imports, first FMU loads
        ref = sweep_time(plan, fmus, serial)                  # the serial warm-up
        assert untimed(ref.rows) == untimed(first.rows), "dask and serial tables differ"
        out["tables_equal"] = True
        s_times, d_times, extra = [], [], []
        for rep in range(args.reps):
            rs = sweep_time(plan, fmus, serial)
            rd = sweep_time(plan, fmus, cluster)
            s_times.append(rs.seconds)
            d_times.append(rd.seconds)
            own = sum(r["wall_time"] for r in rd.rows)
            extra.append((rd.seconds * cluster.workers - own) / len(rd.rows))
            print(f"rep {rep + 1}: serial {rs.seconds:.2f} s, dask {rd.seconds:.2f} s "
                  f"(x{rs.seconds / rd.seconds:.2f}); mean run {own / len(rd.rows):.3f} s",
                  flush=True)
        run_s = statistics.median(r["wall_time"] for r in ref.rows)
        out.update(serial_s=statistics.median(s_times), dask_s=statistics.median(d_times),
                   serial_all=s_times, dask_all=d_times, run_median_s=run_s,
                   cost_beyond_run_per_task_s=statistics.median(extra))
        out["speedup"] = out["serial_s"] / out["dask_s"]
        # the ceiling: 64 independent pure-Python tasks of the runs' length
        items = [run_s] * len(plan.points)
        list(cluster.map(burn, items[:4]))
        bs, bd = [], []
        for _ in range(args.reps):
            t = time.perf_counter()
            list(serial.map(burn, items))
            bs.append(time.perf_counter() - t)
            t = time.perf_counter()
            list(cluster.map(burn, items))
            bd.append(time.perf_counter() - t)
        out["ceiling_speedup"] = statistics.median(bs) / statistics.median(bd)
        # dask's own overhead per task: no-op tasks
        list(cluster.map(noop, range(200)))
        t = time.perf_counter()
        list(cluster.map(noop, range(2000)))
        out["noop_task_s"] = (time.perf_counter() - t) / 2000
        # short runs: one per task against 8 per task
        sweep_time(short, fmus, cluster)
        b1, b8, ss = [], [], []
        for _ in range(args.reps):
            ss.append(sweep_time(short, fmus, serial).seconds)
            b1.append(sweep_time(short, fmus, cluster).seconds)
            b8.append(sweep_time(short, fmus, cluster, batch=8).seconds)
        out.update(short_serial_s=statistics.median(ss), short_batch1_s=statistics.median(b1),
                   short_batch8_s=statistics.median(b8))
    print(f"\n64 runs of {args.stop_time:g} s (median run {out['run_median_s']:.3f} s): serial "
          f"{out['serial_s']:.2f} s, LocalCluster({args.workers}) {out['dask_s']:.2f} s: "
          f"speed-up x{out['speedup']:.2f} (ceiling now, pure-Python tasks: "
          f"x{out['ceiling_speedup']:.2f})")
    print(f"cluster start-up {out['cluster_start_s']:.2f} s, first sweep on it "
          f"{out['first_dask_sweep_s']:.2f} s (workers' imports and first FMU loads)")
    print(f"dask overhead per task: {1e3 * out['noop_task_s']:.2f} ms (no-op tasks); a run's "
          f"cost beyond itself in the sweep: {1e3 * out['cost_beyond_run_per_task_s']:.1f} ms")
    print(f"64 runs of 0.05 s: serial {out['short_serial_s']:.2f} s, one run per task "
          f"{out['short_batch1_s']:.2f} s, 8 per task {out['short_batch8_s']:.2f} s")
    return finish(out, args)


def finish(out, args) -> int:
    out["load_average_end"] = list(os.getloadavg())
    print(f"load average {out['load_average_start'][0]:.2f} at start, "
          f"{out['load_average_end'][0]:.2f} at end")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    # run as the module ``bench_sweep`` so that dask pickles burn/noop by reference
    import bench_sweep
    sys.exit(bench_sweep.main())
