"""The worker of ``bench/bench_sweep.py`` for one checkout: where the time of a sweep run goes, and
how many runs a sweep makes per second. It imports ``orchestration`` from wherever ``sys.path``
finds it first (the caller sets ``PYTHONPATH`` to the checkout measured) and nothing else of the
benchmarks, so that an older checkout is measured with its own code.

    PYTHONPATH=CHECKOUT python bench/sweep_run_profile.py split --runs 16 --warmup 3
    PYTHONPATH=. python bench/sweep_run_profile.py split --runs 16 --columns max_abs_x,max_abs_F_c
    PYTHONPATH=CHECKOUT python bench/sweep_run_profile.py sweep --runs 64 --workers 2 --reps 3

Prints one JSON object.

* **split**: the per-run function of a sweep (``orchestration.sweeps.engine.run_task``) on the
  runs of ``--sample design`` (the 10 s filtered scene), one after the other in this process with
  BLAS on one thread (as every task), after ``--warmup`` untimed runs. Each run's time is split
  into the co-simulation (the master's ``RunStats.wall_time``: initialisation and stepping), the
  fits (``fit_mode`` calls of the summary), the linear analysis (closed-loop and plant
  eigenvalues of the summary and the row), the FMU load and instantiation (``Slave`` objects made,
  or taken from a pool) and the rest; medians over the runs, and the medians of each run's total
  over its own stepping, with and without the fits.
* **sweep**: ``run_sweep`` of ``--runs`` design samples into a fresh folder (no plot), serially
  or on a LocalCluster of ``--workers`` processes (started and warmed up by one sweep first,
  untimed; ``--batch`` runs per task); runs per second per core (``runs / seconds / workers``),
  median over ``--reps``.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

SCENE = "flexible_pd_lowpass"
PARTS = ("stepping", "fits", "analysis", "load", "other")


def design_plan(runs: int, seed: int = 0):
    from orchestration.sweeps.plan import plan_sweep
    return plan_sweep(SCENE, samples=["design"], n_samples=runs, seed=seed)


def design_tasks(runs: int, columns=None) -> list:
    """The sweep's tasks (``engine.run_task``'s argument) of ``runs`` design samples: each
    run's scene, its FMUs and the model sources' digest (hashed once); with ``columns`` (a
    tuple of the table's columns, ``flexpend sweep --columns``) those columns only."""
    import orchestration.sweeps.engine as engine
    from orchestration.sweeps.executor import file_name

    plan = design_plan(runs)
    fmus = engine.fmus_for(plan)
    digest = engine.model_sources_digest()
    return [(p.scene, False, {r: (file_name(x), str(x))
                              for r, x in fmus[p.scene.master.fmus].items()}, digest,
             *([columns] if columns is not None else []))
            for p in plan.points]


class Clock:
    """Time spent in wrapped functions, by part; a call inside a call of the same part counts
    once (a pool's ``acquire`` that makes a ``Slave``)."""

    def __init__(self):
        self.acc, self._depth = {}, {}

    def wrap(self, owner, name: str, part: str):
        f = getattr(owner, name, None)
        if f is None:
            return

        @functools.wraps(f)
        def timed(*a, **k):
            self._depth[part] = self._depth.get(part, 0) + 1
            t0 = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self._depth[part] -= 1
                if not self._depth[part]:
                    self.acc[part] = self.acc.get(part, 0.0) + time.perf_counter() - t0
        setattr(owner, name, timed)


def split(runs: int, warmup: int, columns=None) -> dict:
    """The parts of each run's time (module docstring); with ``columns`` (``--columns``, a
    comma-separated list), each design run twice, alternately: the sweep of every column
    (``rows``, ``median_s``) and the sweep of those columns (``columns_rows``,
    ``columns_median_s``; ``steps``, ``cosim_time``, ``wall_time`` are added for the split)."""
    from threadpoolctl import threadpool_limits

    import orchestration.job as job
    import orchestration.sweeps.engine as engine
    try:
        import orchestration.studies.summary as summary
    except ImportError:                      # before the studies package (bench_sweep's f884ad8)
        import orchestration.report.summary as summary

    clock = Clock()
    clock.wrap(summary, "fit_mode", "fits")
    for name in ("linear_modes", "first_bending_frequency"):
        clock.wrap(summary, name, "analysis")
    clock.wrap(engine, "linear_decay_rate", "analysis")
    for name in ("Slave", "ModelExchangeUnit"):
        clock.wrap(job, name, "load")
    try:
        from orchestration.cosim.pool import SlavePool
        clock.wrap(SlavePool, "acquire", "load")
    except ImportError:                      # before the pool
        pass
    variants = [design_tasks(runs + warmup)]
    if columns:
        asked = tuple(dict.fromkeys([*columns.split(","), "steps", "cosim_time", "wall_time"]))
        variants.append(design_tasks(runs + warmup, asked))
    rows = [[] for _ in variants]
    with threadpool_limits(limits=1, user_api="blas"):
        for i in range(runs + warmup):
            for v, tasks in enumerate(variants):     # side by side, run by run
                clock.acc.clear()
                row = engine.run_task(tasks[i])
                assert row["status"] in ("ok", "failed"), row.get("message")
                if i < warmup:
                    continue
                part = {"total": row["wall_time"], "stepping": row["cosim_time"], **clock.acc}
                part["other"] = part["total"] - sum(part.get(k, 0.0) for k in PARTS[:-1])
                rows[v].append(part)
    out = {"runs": len(rows[0]), "steps": row["steps"], "rows": rows[0],
           "median_s": medians(rows[0])}
    if columns:
        out.update(columns=columns, columns_rows=rows[1], columns_median_s=medians(rows[1]))
    return out


def medians(rows) -> dict:
    """Medians of the parts of the runs ``rows`` (split's), of their totals without the fits,
    and of each run's total over its own stepping (robust to a load that changes between runs),
    with and without the fits."""
    med = {k: statistics.median(r.get(k, 0.0) for r in rows) for k in ("total", *PARTS)}
    med["without_fits"] = statistics.median(r["total"] - r.get("fits", 0.0) for r in rows)
    med["x_stepping"] = statistics.median(r["total"] / r["stepping"] for r in rows)
    med["x_stepping_without_fits"] = statistics.median((r["total"] - r.get("fits", 0.0))
                                                       / r["stepping"] for r in rows)
    return med


def sweep(runs: int, workers: int, reps: int, batch: int = 1) -> dict:
    from orchestration.sweeps.engine import fmus_for, run_sweep
    from orchestration.sweeps.executor import DaskExecutor, Executor

    plan = design_plan(runs)
    fmus = fmus_for(plan)
    files = [f for pair in fmus.values() for f in pair.values()]
    out = {"runs": runs, "workers": workers, "batch": batch}
    ex = Executor() if workers == 0 else DaskExecutor(workers=workers, files=files)
    cores = max(1, workers)
    with ex:
        times, stepping = [], []
        for rep in range(reps + 1):                 # the first: warm-up (imports, FMU loads)
            with tempfile.TemporaryDirectory(prefix="flexpend_bench_sweep_") as d:
                res = run_sweep(plan, fmus, d, ex, batch=batch, progress=False, plot=False)
            bad = [r for r in res.rows if r["status"] not in ("ok", "failed")]
            assert not bad, bad[0].get("message")
            if rep:
                times.append(res.seconds)
                stepping += [r["cosim_time"] for r in res.rows if r.get("cosim_time")]
    sec = statistics.median(times)
    step = statistics.median(stepping)
    out.update(seconds=sec, all_seconds=times, runs_per_s_per_core=runs / sec / cores,
               stepping_median_s=step, limit_runs_per_s=1.0 / step)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("split", "sweep"))
    ap.add_argument("--runs", type=int, default=16)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--workers", type=int, default=0, help="0: serial")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--batch", type=int, default=1, help="runs per task (on dask)")
    ap.add_argument("--columns", default=None,
                    help="split: also the sweep of these columns only (flexpend sweep "
                         "--columns), run by run beside the sweep of every column")
    args = ap.parse_args(argv)
    import orchestration
    where = os.path.dirname(os.path.dirname(os.path.abspath(orchestration.__file__)))
    out = split(args.runs, args.warmup, args.columns) if args.what == "split" else \
        sweep(args.runs, args.workers, args.reps, args.batch)
    out["checkout"] = where
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
