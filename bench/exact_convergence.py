"""The exact rung as a reference: its convergence in the mesh, the step and the coupling, its
stated numerical error, and its cost, on the undamped filtered scene (docs/exact.md).

    python3 bench/exact_convergence.py [--quick] [--before REV] [--runs 3] [--json FILE]

The scene is ``flexible_pd_lowpass`` without structural damping (``plant.zeta = 0``: the beam's
every mode rings undamped, the hardest case for a step and a coupling; its linear loop's second
bending mode even grows, +0.168 +- 425 rad/s), over 3 s, from 0.05, 0.2 and pi/6 rad.

* **The refined reference** at each angle: the monolithic exact loop (plant and filter stepped as
  one system by Radau IIA, the filter in the same stages) at 48 elements and 0.125 ms, checked
  against a second method, generalized alpha at 32 elements and 6.25 us (``--cross-check``,
  7 min; measured: within 6.4e-6, 1.3e-5, 1.2e-5 rad).
* **A. The plant**: the monolithic loop (no coupling) by Radau IIA at 2, 1, 0.5 ms and by
  generalized alpha (the previous integrator) at 0.25, 0.1, 0.05 ms, on 16, 24 and 32 elements:
  the largest ``|phi_o|`` error against the reference.
* **B. The coupling**: the co-simulation through the native FMUs and the product's master
  (Gauss-Seidel, quadratic extrapolation as input derivatives): the previous design, a 2 ms
  communication step with the beam substepped finer and finer (Radau at 1, 0.5, 0.25 ms), against
  the exact rung's coupling now, at its own step (``plant.exact_step`` = 2, 1, 0.5, 0.25 ms).
* **C. The stated numerical error**: what a run at ``plant.exact_step = h`` states (its
  difference from the run at ``2 h``) against its measured error, as a ratio.
* **D. The cost** per simulated second through the product (CPU seconds of the run, medians of
  ``--runs`` after a warm-up, interleaved): the exact rung now (24 elements, 1 ms, with and
  without its step-doubling estimate) and, with ``--before REV``, the commit ``REV`` checked out
  into a temporary git worktree (the previous default: generalized alpha at 0.25 ms under a 2 ms
  communication step, 24 elements), each in a fresh process.

The results go to stdout (and ``--json``); the references are cached in
``bench/results/exact_refs`` (ignored by git).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.exact_loop import exact_run  # noqa: E402

ANGLES = (0.05, 0.2, math.pi / 6)
STOP = 3.0
CACHE = ROOT / "bench" / "results" / "exact_refs"
REF = (48, 1.25e-4)                       # elements, Radau step
CROSS = (32, 6.25e-6)                     # elements, generalized-alpha step


def scene(phi0: float, stop: float = STOP, **keys):
    return load_scene("flexible_pd_lowpass", {"initial.phi": phi0, "stop_time": stop,
                                              "plant.zeta": 0.0, "plant.fidelity": "exact",
                                              **keys})


def reference(phi0: float, method: str = "radau", ne: int = REF[0], h: float = REF[1]):
    """The monolithic loop's phi_o on the 2 ms grid (cached)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"{method}_{phi0:.6f}_{ne}_{h:g}_{STOP:g}.npy"
    if path.exists():
        return np.load(path)
    out = exact_run(scene(phi0), ne, h, kernel=True, method=method)
    np.save(path, out)
    return out


def cosim(phi0: float, ne: int, h: float, H: float, stop: float = STOP):
    """phi_o of the co-simulation through the native FMUs at communication step ``H`` with the
    beam stepped by Radau at ``h`` (``H = h``: the product's coupling)."""
    from orchestration import simulate
    from orchestration.cosim.master import Master
    from orchestration.cosim.slave import Slave
    from orchestration.export import flavour_fmus
    from orchestration.job import RECORD, controller_start_values, plant_start_values

    sc = scene(phi0, stop, **{"plant.n_elements": ne, "plant.exact_step": h})
    if H == h:
        return simulate(sc).result["phi_o"]
    fmus = flavour_fmus("native")
    values = plant_start_values(sc)
    values["step"] = h
    slaves = {"plant": Slave(fmus["plant"], "plant", values),
              "controller": Slave(fmus["controller"], "controller", controller_start_values(sc))}
    try:
        master = Master(slaves, sc.connections, RECORD, replace(sc.master, step=H))
        res, _ = master.run(0.0, stop, sc.output.output_interval)
    finally:
        for s in slaves.values():
            s.close()
    return res["phi_o"]


def err(a, b) -> float:
    n = min(len(a), len(b))
    return float(np.max(np.abs(np.asarray(a[:n]) - np.asarray(b[:n]))))


def table_plant(refs, quick):
    rows = []
    meshes = (24,) if quick else (16, 24, 32)
    for ne in meshes:
        for method, steps in (("radau", (2e-3, 1e-3, 5e-4)), ("genalpha", (2.5e-4, 1e-4, 5e-5))):
            if quick and method == "genalpha":
                steps = (2.5e-4,)
            for h in steps:
                e = [err(exact_run(scene(a), ne, h, kernel=True, method=method), refs[a])
                     for a in ANGLES]
                rows.append({"method": method, "elements": ne, "step": h, "error": e})
                print(f"  A  {method:8s} {ne:3d} el  h = {h * 1e3:5.3g} ms   "
                      + "  ".join(f"{x:.2e}" for x in e), flush=True)
    return rows


def table_coupling(refs, quick):
    rows = []
    cases = ([("2 ms coupling", 24, h, 2e-3) for h in (1e-3, 5e-4, 2.5e-4)]
             + [("2 ms coupling", 32, 2.5e-4, 2e-3)]
             + [("own step", 24, h, h) for h in (2e-3, 1e-3, 5e-4, 2.5e-4)]
             + [("own step", 32, h, h) for h in (5e-4, 2.5e-4)])
    if quick:
        cases = [c for c in cases if c[1] == 24 and c[2] >= 5e-4]
    for label, ne, h, H in cases:
        e = [err(cosim(a, ne, h, H), refs[a]) for a in ANGLES]
        rows.append({"coupling": label, "elements": ne, "step": h, "communication_step": H,
                     "error": e})
        print(f"  B  {label:13s} {ne:3d} el  h = {h * 1e3:5.3g} ms  H = {H * 1e3:4.3g} ms   "
              + "  ".join(f"{x:.2e}" for x in e), flush=True)
    return rows


_BEFORE_RUN = """
import json, sys
sys.path.insert(0, {root!r})
from orchestration import simulate
keys = {{"plant.fidelity": "exact", "plant.zeta": 0.0, "stop_time": {stop!r},
        "initial.phi": {phi0!r}, "plant.n_elements": {ne!r}, "plant.step": {h!r},
        "master.step": {H!r}}}
print(json.dumps(simulate("flexible_pd_lowpass", keys).result["phi_o"].tolist()))
"""


def table_before(refs, root: Path, quick):
    """The previous exact rung (generalized alpha in the FMU, coupled at master.step) refined
    under the 2 ms coupling: the aliasing this design removes."""
    rows = []
    cases = [(24, 2.5e-4, 2e-3), (32, 2.5e-5, 2e-3), (32, 2.5e-5, 1e-3)]
    for ne, h, H in cases[:1] if quick else cases:
        e = []
        for a in ANGLES:
            code = _BEFORE_RUN.format(root=str(root), stop=STOP, phi0=a, ne=ne, h=h, H=H)
            out = subprocess.run([sys.executable, "-c", code], cwd=str(root), check=True,
                                 capture_output=True, text=True)
            e.append(err(np.array(json.loads(out.stdout.strip().splitlines()[-1])), refs[a]))
        rows.append({"elements": ne, "step": h, "communication_step": H, "error": e})
        print(f"  B' before: genalpha {ne:3d} el  h = {h * 1e3:5.3g} ms  H = {H * 1e3:4.3g} ms   "
              + "  ".join(f"{x:.2e}" for x in e), flush=True)
    return rows


def table_stated(refs, quick):
    from orchestration import simulate

    rows = []
    for h in ((1e-3,) if quick else (2e-3, 1e-3, 5e-4)):
        for a in ANGLES:
            keys = {"plant.exact_step": h}
            if h > 1e-3:
                keys["output_interval"] = 2 * h
            run = simulate(scene(a, **keys))
            ref = refs[a] if h <= 1e-3 else refs[a][::2]
            e = err(run.result["phi_o"], ref)
            stated = run.summary["numerical_error"]["phi_o"]
            rows.append({"step": h, "angle": a, "error": e, "stated": stated,
                         "ratio": stated / e})
            print(f"  C  h = {h * 1e3:4.3g} ms  phi0 = {a:.3f}  error {e:.2e}  stated {stated:.2e}"
                  f"  stated / error {stated / e:.2f}", flush=True)
    return rows


_COST = """
import sys, time, resource
sys.path.insert(0, {root!r})
from orchestration import simulate
keys = {{"plant.fidelity": "exact", "plant.zeta": 0.0, "stop_time": {stop!r}}}
simulate("flexible_pd_lowpass", {{**keys, "stop_time": 0.05}})        # warm-up: the FMUs built
{estimate}
t0 = resource.getrusage(resource.RUSAGE_SELF)
run = simulate("flexible_pd_lowpass", keys)
t1 = resource.getrusage(resource.RUSAGE_SELF)
print((t1.ru_utime - t0.ru_utime + t1.ru_stime - t0.ru_stime) / {stop!r})
"""

_NO_ESTIMATE = """
import orchestration.job as job
job._exact_numerical_error = lambda scene, fmus, run, kw: None
"""


def _cost(root: Path, stop: float, estimate: bool) -> float:
    code = _COST.format(root=str(root), stop=stop,
                        estimate="" if estimate else _NO_ESTIMATE)
    out = subprocess.run([sys.executable, "-c", code], cwd=str(root), capture_output=True,
                         text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def _worktree(folder: Path, rev: str) -> Path:
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(folder),
                    rev], check=True)
    subprocess.run([sys.executable, "-c", "from pathlib import Path; import fmu_common.kernels "
                    "as k; k.build_host_kernels(Path('.'), Path('.'))"], cwd=str(folder),
                   check=True)
    return folder


def table_cost(before: str | None, old: Path | None, runs: int, stop: float):
    """CPU s per simulated s, interleaved medians."""
    configs = {"now, with its numerical error (24 el, Radau 1 ms, coupled at 1 ms)":
               (ROOT, True),
               "now, the run alone": (ROOT, False)}
    if old is not None:
        configs[f"before ({before}: 24 el, generalized alpha 0.25 ms, 2 ms coupling)"] = \
            (old, True)
    samples = {k: [] for k in configs}
    for k, (root, est) in configs.items():                 # warm-up (builds)
        _cost(root, 0.2, est)
    for _ in range(runs):
        for k, (root, est) in configs.items():
            samples[k].append(_cost(root, stop, est))
    rows = []
    for k, v in samples.items():
        rows.append({"config": k, "cpu_per_simulated_s": float(np.median(v)), "samples": v})
        print(f"  D  {k:75s} {np.median(v):.3f} s/s  ({', '.join(f'{x:.3f}' for x in v)})",
              flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer meshes and steps")
    ap.add_argument("--cross-check", action="store_true",
                    help="also the reference by generalized alpha (32 el, 6.25 us; 7 min)")
    ap.add_argument("--before", metavar="REV", help="the cost of this commit too (a worktree)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    t0 = time.time()
    print("refined references (Radau IIA, 48 elements, 0.125 ms; monolithic)", flush=True)
    refs = {ang: reference(ang) for ang in ANGLES}
    out = {"angles": list(ANGLES), "reference": {"elements": REF[0], "step": REF[1]}}
    if a.cross_check:
        out["cross_check"] = [err(reference(ang, "genalpha", *CROSS), refs[ang])
                              for ang in ANGLES]
        print("  the reference against generalized alpha (32 el, 6.25 us): "
              + "  ".join(f"{x:.2e}" for x in out["cross_check"]), flush=True)
    print("A. the plant alone (monolithic), max |phi_o| error at 0.05, 0.2, pi/6 rad:")
    out["plant"] = table_plant(refs, a.quick)
    tmp = old = None
    try:
        if a.before:
            tmp = Path(tempfile.mkdtemp(prefix="flexpend-before-"))
            old = _worktree(tmp / "before", a.before)
        print("B. through the FMU and the master:")
        out["coupling"] = table_coupling(refs, a.quick)
        if old is not None:
            out["coupling_before"] = table_before(refs, old, a.quick)
        print("C. the stated numerical error (step doubling) against the error:")
        out["stated"] = table_stated(refs, a.quick)
        print("D. cost through the product, CPU s per simulated s (median):")
        out["cost"] = table_cost(a.before, old, a.runs, 1.0 if a.quick else 3.0)
    finally:
        if tmp is not None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(tmp / "before")], check=False)
    print(f"({time.time() - t0:.0f} s)")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
