"""What dask.distributed buys a sweep on this machine: a 64-run ``flexpend sweep`` on a
LocalCluster against the serial path, and dask's overhead per task.

    python bench/bench_sweep.py [--workers 2] [--reps 3] [--stop-time 2]

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
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, product_fmus  # noqa: E402

from orchestration.sweeps.executor import DaskExecutor, Executor  # noqa: E402
from orchestration.sweeps.plan import plan_sweep
from orchestration.sweeps.engine import run_sweep  # noqa: E402

SCENE = "flexible_pd_lowpass"
GRID = ["controller.kp=400:600:8", "controller.cutoff=80:120:8"]
TIMES = ("wall_time", "cosim_time")


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
    args = ap.parse_args(argv)
    fmus = product_fmus()
    plan = plan_sweep(SCENE, grids=GRID, overrides=[f"stop_time={args.stop_time!r}"])
    short = plan_sweep(SCENE, grids=GRID, overrides=["stop_time=0.05"])
    out = {"command": "python bench/bench_sweep.py " + " ".join(sys.argv[1:] if argv is None
                                                                 else argv),
           "python": platform.python_version(), "cpus": os.cpu_count(),
           "load_average_start": list(os.getloadavg()), "runs": len(plan.points),
           "stop_time": args.stop_time, "workers": args.workers}
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
    out["load_average_end"] = list(os.getloadavg())
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
