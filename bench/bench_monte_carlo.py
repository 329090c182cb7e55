"""The Monte Carlo of issue 39: ``flexpend sweep flexible_pd_lowpass --sample design --samples N``
from the command line, this checkout against the one before (its serial path and its dask
LocalCluster), measured side by side in one run.

    python bench/bench_monte_carlo.py [--samples 1000] [--reps 3] [--workers 2] [--before REV]
                                      [--full 10000] [--json bench/results/monte_carlo.json]
    python bench/bench_monte_carlo.py --quick       # a smoke run: 100 samples, one round

* **Sweeps, side by side.** Each round runs, one after the other in a fresh output folder, the
  whole command (a process of its own: imports, plan, executor, runs, table, plot) of:
  this checkout serially (``--serial``) and on ``--workers`` processes (its local executor), and
  the ``--before`` checkout (default c91e5e9, main before issue 39, checked out into a
  temporary git worktree removed at the end) serially and on ``--workers`` (there a dask
  LocalCluster). ``--reps`` rounds; medians of the wall times, runs per second and the
  speed-up over the same checkout's serial sweep. The tables of this checkout's two executors
  are checked equal, value for value (the wall times aside).
* **Start-up.** For this checkout's commands: the time from the command's start to its first
  finished run, less that run's own time (its row's ``wall_time``): what the command costs
  before it runs (imports, plan, the FMUs checked, the workers started).
* **The fits against the stepping** (``bench/sweep_run_profile.py split`` on both checkouts):
  a sweep run's summary fits over its stepping, medians.
* **The full Monte Carlo** (``--full N``, 0 to skip): one ``flexpend sweep ... --samples N`` of this
  checkout with the default executor (worker processes where they win), its wall time (target:
  10,000 runs in at most 120 s on 2 cores); then the same with ``--columns`` (default
  ``max_abs_x,max_abs_F_c``: no mode fit; ``--columns ''`` skips it), whose split is measured
  beside the full one's, run by run.

Wall times carry the machine's load (the rounds alternate the commands so that it falls on all
of them). Writes ``--json`` (default ``bench/results/monte_carlo.json``, git-ignored).
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
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_sweep import checkout, measure  # noqa: E402
from common import RESULTS, ROOT  # noqa: E402

SCENE = "flexible_pd_lowpass"
BEFORE = "c91e5e9"          # main before issue 39
TIMES = ("wall_time", "cosim_time")


def command(tree: Path, samples: int, executor: list, out: Path) -> list:
    return [sys.executable, "-m", "orchestration.cli", "sweep", SCENE, "--sample", "design",
            "--samples", str(samples), *executor, "--out", str(out), "-q"]


def run(tree: Path, samples: int, executor: list) -> dict:
    """One sweep command on the code of ``tree``: its wall time, the time of its first finished
    row (from the journal's growth, polled), and its rows."""
    out = Path(tempfile.mkdtemp(prefix="flexpend_mc_"))
    journal = out / "runs.jsonl"
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    proc = subprocess.Popen(command(tree, samples, executor, out), cwd=tree, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    first = None
    while proc.poll() is None:
        if first is None and journal.exists() and journal.stat().st_size:
            first = time.perf_counter() - t0
        time.sleep(0.002)
    wall = time.perf_counter() - t0
    err = proc.stderr.read()
    if proc.returncode:
        raise RuntimeError(f"{' '.join(command(tree, samples, executor, out))} failed:\n"
                           f"{err[-2000:]}")
    rows = [json.loads(line) for line in journal.read_text().splitlines()]
    shutil.rmtree(out, ignore_errors=True)
    # the journal's first row is the first run finished (on workers not always run 0)
    start = None if first is None or not rows or "wall_time" not in rows[0] else \
        first - rows[0]["wall_time"]
    rows.sort(key=lambda r: r["run"])
    return {"wall": wall, "first_row": first, "start_up": start, "rows": rows}


def untimed(rows):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--before", default=BEFORE, help="the checkout to compare with (none: skip)")
    ap.add_argument("--full", type=int, default=10000, help="runs of the full Monte Carlo (0: skip)")
    ap.add_argument("--quick", action="store_true", help="100 samples, one round, no full run")
    ap.add_argument("--json", default=str(RESULTS / "monte_carlo.json"))
    ap.add_argument("--columns", default="max_abs_x,max_abs_F_c",
                    help="the full Monte Carlo and the split again with flexpend sweep --columns "
                         "(a table of these columns only, no mode fit; '': skip)")
    a = ap.parse_args(argv)
    if a.quick:
        a.samples, a.reps, a.full = 100, 1, 0
    log = lambda text: print(text, flush=True)  # noqa: E731
    res = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                       "load_before": os.getloadavg()},
           "samples": a.samples, "reps": a.reps, "workers": a.workers}
    with checkout(a.before) as before:
        trees = {"this": ROOT} | ({"before": before} if before else {})
        configs = [(t, name, ex) for t in trees
                   for name, ex in (("serial", ["--serial"]),
                                    (f"{a.workers} workers", ["--workers", str(a.workers)]))]
        # warm-up: every checkout's FMUs built and its caches filled, untimed
        for t in trees:
            run(trees[t], 4, ["--serial"])
        times = {(t, n): [] for t, n, _ in configs}
        starts = {(t, n): [] for t, n, _ in configs}
        tables = {}
        for rep in range(a.reps):
            for t, name, ex in configs:
                r = run(trees[t], a.samples, ex)
                times[t, name].append(r["wall"])
                if r["start_up"] is not None:
                    starts[t, name].append(r["start_up"])
                tables[t, name] = untimed(r["rows"])
                log(f"round {rep + 1}: {t:6s} {name:10s} {r['wall']:7.2f} s, start-up "
                    f"{r['start_up']:.2f} s")
        same = tables["this", "serial"] == tables["this", f"{a.workers} workers"]
        res["sweeps"] = [{"checkout": t, "executor": n, "wall_median": statistics.median(v),
                          "walls": v, "runs_per_second": a.samples / statistics.median(v),
                          "speed_up": statistics.median(times[t, "serial"])
                          / statistics.median(v),
                          "start_up_median": statistics.median(starts[t, n]) if starts[t, n]
                          else None}
                         for (t, n), v in times.items()]
        res["tables_equal"] = same
        log(f"\n{a.samples} design samples of {SCENE}, {a.reps} rounds (medians):")
        log(f"  {'checkout':8s} {'executor':10s} {'wall':>8s} {'runs/s':>7s} {'speed-up':>8s} "
            f"{'start-up':>8s}")
        for s in res["sweeps"]:
            log(f"  {s['checkout']:8s} {s['executor']:10s} {s['wall_median']:7.2f}s "
                f"{s['runs_per_second']:7.1f} {s['speed_up']:7.2f}x "
                f"{s['start_up_median']:7.2f}s")
        log(f"  this checkout's tables, serial and on {a.workers} workers: "
            f"{'equal, value for value' if same else 'DIFFERENT'}")
        # the fits against the stepping
        res["split"] = {}
        for t, tree in trees.items():
            cols = ["--columns", a.columns] if a.columns and t == "this" else []
            m = measure(tree, "split", "--runs", 16 if not a.quick else 6, "--warmup", 3, *cols)
            res["split"][t] = m["median_s"]
            for label, med in ((t, m["median_s"]), (f"{t} --columns {a.columns}",
                                                    m.get("columns_median_s"))):
                if med is None:
                    continue
                log(f"  {label}: a run: stepping {1e3 * med['stepping']:.2f} ms, fits "
                    f"{1e3 * med['fits']:.2f} ms ({med['fits'] / med['stepping']:.2f} of the "
                    f"stepping), total {1e3 * med['total']:.2f} ms")
            if cols:
                res["split"]["this --columns"] = m["columns_median_s"]
    if a.full:
        r = run(ROOT, a.full, [])
        res["full"] = {"runs": a.full, "wall": r["wall"], "start_up": r["start_up"]}
        log(f"\nflexpend sweep {SCENE} --sample design --samples {a.full}: {r['wall']:.1f} s "
            f"(start-up {r['start_up']:.2f} s)")
        if a.columns:
            r = run(ROOT, a.full, ["--columns", a.columns])
            res["full_columns"] = {"runs": a.full, "columns": a.columns, "wall": r["wall"]}
            log(f"flexpend sweep {SCENE} --sample design --samples {a.full} --columns "
                f"{a.columns}: {r['wall']:.1f} s")
    res["machine"]["load_after"] = os.getloadavg()
    Path(a.json).parent.mkdir(parents=True, exist_ok=True)
    Path(a.json).write_text(json.dumps(res, indent=2))
    log(f"wrote {a.json}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
