"""Where a warm ``flexpend run`` (the three scenes of the paper) spends its time, before and after.

    python bench/bench_run_profile.py [--before REV] [--runs 5] [--json FILE]

This checkout, or with ``--before`` the commits ``REV`` and ``HEAD`` each checked out into a
fresh temporary git worktree (removed at the end), runs ``flexpend run --out TMP`` in a new
process ``--runs`` times after one warm-up run (the FMUs and the compiled loop are built then:
in a fresh worktree, that first run is the cold start, reported too); the processes of the two
checkouts alternate, so that the load of the machine falls on both alike. Warm also means the
checkout's bytecode cached (``__pycache__``, written by the first run): ``PYTHONDONTWRITEBYTECODE``
is dropped from the children's environment, where it would make every process compile the
project's modules from source (about 0.1 s of CPU). Each process times its own phases in CPU seconds (the machines are shared:
under load, wall time stretches and CPU time much less), each phase's time exclusive of the
phases nested in it:

* ``imports``: every ``import`` statement (``builtins.__import__``), wherever it runs;
* ``stepping``: the masters' ``run`` (the co-simulation, compiled or Python loop);
* ``summary (fits)``: ``summarize`` (the fitted modes, the verdict, the validity);
* ``figures``: drawing the figures (:mod:`orchestration.report.figures`) and writing them;
* ``CSV``: writing the results' CSV files;
* ``FMUs up to date``: finding the FMUs built and up to date;
* ``other``: the rest of the process's CPU time (the interpreter's start, reading the scenes,
  opening the FMUs, the text).

Printed: the medians per phase and of the whole process's CPU and wall time, side by side, and
those of ``python3 -c "import numpy, scipy, matplotlib, fmpy"`` timed in the same loop, with
the ratio of each ``flexpend run`` to it.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: The child: ``python -c _CHILD ROOT OUT``; prints one JSON line of seconds per phase.
_CHILD = r'''
import builtins, json, os, sys, time
root, out = sys.argv[1:3]
sys.path.insert(0, root)
totals, stack = {}, []

def timed(category, fn):
    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        stack.append(0.0)                      # time of the phases nested in this one
        try:
            return fn(*args, **kwargs)
        finally:
            dt = time.process_time() - t0
            nested = stack.pop()
            totals[category] = totals.get(category, 0.0) + dt - nested
            if stack:
                stack[-1] += dt
    wrapper.__wrapped__ = fn
    return wrapper

builtins.__import__ = timed("imports", builtins.__import__)
import orchestration.cli as cli
import orchestration.job as job
from orchestration.cosim import master, model_exchange
from orchestration.report import figures
for cls in (master.Master, model_exchange.ModelExchangeMaster):
    cls.run = timed("stepping", cls.run)
job.summarize = timed("summary (fits)", job.summarize)
job.save_figure = timed("figures", job.save_figure)
for name in ("time_histories", "snapshots", "paper_overview", "mode_shapes", "root_map"):
    setattr(figures, name, timed("figures", getattr(figures, name)))
job.write_csv = timed("CSV", job.write_csv)
job.flavour_fmus = timed("FMUs up to date", job.flavour_fmus)
with open(os.devnull, "w") as null:
    sys.stdout, sys.stderr = null, null
    code = cli.main(["run", "--out", out])
    sys.stdout, sys.stderr = sys.__stdout__, sys.__stderr__
assert code == 0, code
print(json.dumps(totals))
'''
PHASES = ("imports", "stepping", "summary (fits)", "figures", "CSV", "FMUs up to date", "other")
IMPORTS = "import numpy, scipy, matplotlib, fmpy"


def _env() -> dict:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    env.pop("FLEXPEND_HOME", None)        # each checkout builds into its own build/
    # warm: the checkout's modules compiled once (as an installed package's are, and as Python
    # caches them by default), not compiled from source again in every process
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")          # as flexpend sets it, for the imports' process too
    return env


def _child(args, cwd=None) -> tuple[float, float, str]:
    """Run ``args``: (wall seconds, CPU seconds of the process, its stdout)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(args, cwd=cwd, capture_output=True, text=True, env=_env())
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))} failed:\n{proc.stdout}\n{proc.stderr}")
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return wall, cpu, proc.stdout


def run_once(root: Path, out: Path) -> dict:
    """One ``flexpend run`` of ``root`` in a new process: CPU seconds per phase, ``cpu`` and
    ``wall`` of the whole process."""
    wall, cpu, stdout = _child([sys.executable, "-c", _CHILD, str(root), str(out)], root)
    phases = json.loads(stdout.strip().splitlines()[-1])
    phases["other"] = cpu - sum(v for k, v in phases.items() if k in PHASES)
    phases.update(cpu=cpu, wall=wall)
    return phases


def imports_once() -> dict:
    wall, cpu, _ = _child([sys.executable, "-c", IMPORTS])
    return {"cpu": cpu, "wall": wall}


def profile(checkouts: dict, runs: int) -> dict:
    """``{label: {phase: median seconds}}`` for ``{label: checkout root}``, and the imports'; the
    first round warms up, and is kept as ``cold`` (its CPU and wall time): the first run of a
    fresh checkout builds its FMUs and compiled loop."""
    samples = {label: [] for label in checkouts}
    samples[IMPORTS] = []
    cold = {}
    with tempfile.TemporaryDirectory(prefix="flexpend_profile_") as tmp:
        for i in range(runs + 1):
            for label, root in checkouts.items():
                r = run_once(root, Path(tmp) / label.replace(" ", "_"))
                if i:
                    samples[label].append(r)
                else:
                    cold[label] = {"cpu": r["cpu"], "wall": r["wall"]}
            t = imports_once()
            if i:
                samples[IMPORTS].append(t)
    out = {label: {k: statistics.median(s.get(k, 0.0) for s in rows)
                   for k in (*PHASES, "cpu", "wall") if k in rows[0] or label != IMPORTS}
           for label, rows in samples.items()}
    for label, c in cold.items():
        out[label]["cold"] = c
    return out


def _worktree(folder: Path, rev: str) -> Path:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(folder),
                    rev], check=True)
    return folder


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", metavar="REV", help="also profile this commit (a temporary "
                                                    "git worktree)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    checkouts, tmp = {}, Path(tempfile.mkdtemp(prefix="flexpend_checkouts_"))
    try:
        if a.before:        # two fresh checkouts: their first runs are cold, side by side
            checkouts[f"before ({a.before})"] = _worktree(tmp / "before", a.before)
            checkouts["after (HEAD)"] = _worktree(tmp / "after", "HEAD")
        else:
            checkouts["this checkout"] = ROOT
        res = profile(checkouts, a.runs)
    finally:
        for root in checkouts.values():
            if root != ROOT:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                                str(root)], check=False)
        shutil.rmtree(tmp, ignore_errors=True)
    base = res[IMPORTS]
    labels = [k for k in res if k != IMPORTS]
    print(f"warm `flexpend run` (three scenes), median of {a.runs} processes, CPU s")
    print("| phase | " + " | ".join(labels) + " |")
    print("|---" * (len(labels) + 1) + "|")
    for ph in PHASES:
        print(f"| {ph} | " + " | ".join(f"{res[k][ph]:.3f}" for k in labels) + " |")
    for key in ("cpu", "wall"):
        print(f"| whole process, {key} | " + " | ".join(f"{res[k][key]:.3f}" for k in labels)
              + " |")
        print(f"| {key} / `python3 -c \"{IMPORTS}\"` ({base[key]:.3f} s) | "
              + " | ".join(f"{res[k][key] / base[key]:.1f}x" for k in labels) + " |")
    if a.before:
        print("| first run of a fresh checkout (cold: builds the FMUs), cpu / wall | "
              + " | ".join(f"{res[k]['cold']['cpu']:.2f} / {res[k]['cold']['wall']:.2f}"
                           for k in labels) + " |")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
