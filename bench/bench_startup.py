"""Start-up costs: each FMU's cold start from a fresh unpack, and ``flexpend run`` from a fresh clone.

    python bench/bench_startup.py [--runs 5]                  # FMU cold starts
    python bench/bench_startup.py --run-venv VENV             # and flexpend run, cold and warm

**FMU cold start.** In a new process per run (as an importer that unpacks an FMU and loads it):
unpack the FMU into a new folder, ``fmi2Instantiate``, initialise, one 1 ms ``doStep``; each phase
timed inside the process, after fmpy is imported; medians over ``--runs`` processes. Also the
whole ``fmpy simulate`` command of 10 ms, as a user would time it (interpreter start included).

**flexpend run.** With ``--run-venv VENV`` (a throw-away virtual environment holding the
dependencies, e.g. made by ``python3 -m venv VENV && VENV/bin/pip install -e .``): clone this
checkout's HEAD into a new folder, ``pip install -e`` it into VENV (timed: it compiles the
kernels), then ``flexpend run`` twice: cold (no FMUs built yet) and warm. The runs' own summaries
say where the time goes; the clone is left in place for inspection and removed at the end.
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

_CHILD = r'''
import json, sys, tempfile, time
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
fmu, folder = sys.argv[1:3]
t = [time.perf_counter()]
unpacked = extract(fmu, tempfile.mkdtemp(dir=folder))
md = read_model_description(unpacked)
t.append(time.perf_counter())
s = FMU2Slave(guid=md.guid, unzipDirectory=unpacked,
              modelIdentifier=md.coSimulation.modelIdentifier, instanceName="cold")
s.instantiate()
t.append(time.perf_counter())
s.setupExperiment(startTime=0.0)
s.enterInitializationMode()
s.exitInitializationMode()
t.append(time.perf_counter())
s.doStep(0.0, 1e-3)
t.append(time.perf_counter())
s.terminate()
s.freeInstance()
print(json.dumps([b - a for a, b in zip(t, t[1:])] + [t[-1] - t[0]]))
'''
PHASES = ("unpack", "instantiate", "initialise", "first step", "total")


def fmu_cold_starts(fmus: dict, runs: int) -> dict:
    out = {}
    with tempfile.TemporaryDirectory(prefix="flexpend_cold_") as tmp:
        for name, path in fmus.items():
            rows = []
            for _ in range(runs + 1):                      # the first is a warm-up of the disk
                proc = subprocess.run([sys.executable, "-c", _CHILD, str(path), tmp],
                                      capture_output=True, text=True, check=True)
                rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
            rows = rows[1:]
            out[name] = {ph: statistics.median(r[i] for r in rows) for i, ph in enumerate(PHASES)}
            fmpy_cli = Path(sys.executable).parent / "fmpy"
            walls = []
            for _ in range(runs):
                t0 = time.perf_counter()
                subprocess.run([str(fmpy_cli), "simulate", str(path), "--stop-time", "0.01",
                                "--output-file", str(Path(tmp) / "out.csv")], check=True,
                               capture_output=True, cwd=tmp)
                walls.append(time.perf_counter() - t0)
            out[name]["fmpy simulate 10 ms (process)"] = statistics.median(walls)
    return out


def flexpend_run(venv: Path) -> dict:
    """Clone, install into ``venv``, ``flexpend run`` cold and warm: seconds of each."""
    py, flexpend = venv / "bin" / "python", venv / "bin" / "flexpend"
    out = {}
    tmp = Path(tempfile.mkdtemp(prefix="flexpend_clone_"))
    try:
        clone = tmp / "flexpend"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        t0 = time.perf_counter()
        subprocess.run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                        "-e", str(clone)], check=True, cwd=tmp)
        out["pip install -e (compiles the kernels)"] = time.perf_counter() - t0
        assert not (clone / "build" / "fmus").exists()
        for label in ("flexpend run, cold (FMUs absent)", "flexpend run, warm"):
            t0 = time.perf_counter()
            proc = subprocess.run([str(flexpend), "run", "--out", str(tmp / "out")], cwd=clone,
                                  capture_output=True, text=True)
            out[label] = time.perf_counter() - t0
            if proc.returncode != 0:
                raise RuntimeError(f"{label} failed:\n{proc.stdout}\n{proc.stderr}")
            walls = [ln.strip() for ln in proc.stdout.splitlines() if "wall time" in ln]
            out[label + ": stepping (the runs' wall times)"] = "; ".join(walls)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--run-venv", type=Path, help="also time flexpend run from a fresh clone, "
                                                   "installed into this throw-away venv")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    from orchestration.export import build_fmus

    res = {"fmu_cold_start_s": fmu_cold_starts(build_fmus(), a.runs)}
    print("FMU cold start from a fresh unpack, s (median of", a.runs, "processes)")
    print("| FMU | " + " | ".join(PHASES) + " | fmpy simulate 10 ms (process) |")
    print("|---" * (len(PHASES) + 2) + "|")
    for name, r in res["fmu_cold_start_s"].items():
        print(f"| {name} | " + " | ".join(f"{r[p]:.3f}" for p in PHASES)
              + f" | {r['fmpy simulate 10 ms (process)']:.2f} |")
    if a.run_venv:
        res["flexpend_run_s"] = r = flexpend_run(a.run_venv)
        print("\nflexpend run from a fresh clone, s")
        for k, v in r.items():
            print(f"| {k} | {v if isinstance(v, str) else f'{v:.1f}'} |")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
