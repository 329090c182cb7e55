"""The compiled adaptive and implicit masters against the compiled fixed-step default, at equal
error, on the three paper scenes (issue 39, item 1: the goal is at most 3 times the default's
cost).

    python bench/bench_compiled_adaptive.py [--stop-time S] [--runs 5] [--scenes ...]

Per scene, the fixed-step default (the scene's coupling: Gauss-Seidel, quadratic extrapolation
as input derivatives, ``master.compiled = auto``: the C loop) runs at the steps of
:data:`FIXED_STEPS`; the adaptive master at the tolerances of :data:`TOLERANCES` with both
estimators (``master.max_step`` = :data:`MAX_STEP`, its output grid), and the implicit master
(``master.algorithm = implicit``, Newton and IQN-ILS, both schemes of :data:`IMPLICIT_SCHEMES`)
at :data:`IMPLICIT_STEPS`. Error: the
largest ``|phi_o - phi_o,ref|`` against the monolithic reference (bench/common.py), measured once
per configuration (a run that stops early, an implicit step that does not converge, has none).
Cost: the process CPU time of the master's run (initialisation and stepping, FMU loading
excluded), the median of ``--runs`` repetitions after one warm-up, every
configuration run in turn within each repetition (interleaved: load on the machine falls on all
alike). The ratio: a configuration's cost over the default's cost at the same error, read
log-log on the default's error-cost front (a blank where the error is outside the front). Each
row says which loop ran (``compiled`` or ``python``).
"""
from __future__ import annotations

import argparse
import math
import statistics

import numpy as np

from common import CoSim, load_scene, product_fmus  # noqa: F401 - sets up the path first

from orchestration import simulate
from orchestration.cosim.slave import CoSimulationError
from orchestration.scene.schema import PAPER_SCENES

FIXED_STEPS = (5e-4, 1e-3, 2e-3, 4e-3, 8e-3)
TOLERANCES = (1e-2, 1e-3, 1e-4)
MAX_STEP = 0.01
IMPLICIT_STEPS = (2e-3, 4e-3)
#: the implicit master's schemes timed: every output iterated, or only the controller's force
#: (the plant steps first on it: the serial scheme with master.first = "plant")
IMPLICIT_SCHEMES = {"parallel": {},
                    "serial": {"master.implicit_scheme": "serial", "master.first": "plant"}}
#: each scene's horizon (``--stop-time`` sets all): flexible_pd's bending mode grows (the paper's
#: spillover), so that after a few seconds every run is O(0.5 rad) off and no two errors compare
STOP_TIMES = {"rigid_pd": 10.0, "flexible_pd": 1.0, "flexible_pd_lowpass": 10.0}


def configurations(stop_time: float) -> list:
    """(family, label, scene keys) of every configuration timed."""
    base = {"stop_time": stop_time, "fidelity.companion": False}
    out = [("default", f"step {h * 1e3:g} ms",
            {**base, "master.step": h, "output_interval": max(h, 2e-3)}) for h in FIXED_STEPS]
    for est in ("extrapolation", "energy"):
        out += [(f"adaptive {est}", f"tolerance {tol:g}",
                 {**base, "master.adaptive": True, "master.tolerance": tol,
                  "master.error_estimator": est, "master.max_step": MAX_STEP,
                  "output_interval": MAX_STEP}) for tol in TOLERANCES]
    for scheme, sets in IMPLICIT_SCHEMES.items():
        for update in ("newton", "iqn-ils"):
            out += [(f"implicit {scheme} {update}", f"step {h * 1e3:g} ms",
                     {**base, "master.algorithm": "implicit", "master.implicit_jacobian": update,
                      "master.step": h, "output_interval": max(h, 2e-3), **sets})
                    for h in IMPLICIT_STEPS]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stop-time", type=float, default=None,
                    help="the runs' horizon (default: STOP_TIMES)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--scenes", nargs="+", default=list(PAPER_SCENES), choices=PAPER_SCENES)
    a = ap.parse_args(argv)
    fmus = product_fmus(flavour="native")
    for name in a.scenes:
        stop_time = a.stop_time or STOP_TIMES[name]
        configs = configurations(stop_time)
        errors, loops, tried, sims = [], [], [], []
        for _, _, keys in configs:
            run = simulate(name, keys, reference=True)
            # a run that stopped early (an implicit step that does not converge) has no error
            errors.append(float(np.max(np.abs(run.result["phi_o"] - run.reference["phi_o"])))
                          if run.completed else math.nan)
            loops.append(run.stats.loop)
            tried.append(run.stats.steps + run.stats.rejected)
            sets = [f"{k}={str(v).lower() if isinstance(v, bool) else v}" for k, v in keys.items()]
            sims.append(CoSim(load_scene(name, sets), fmus))
        times = [[] for _ in configs]
        for rep in range(a.runs + 1):                       # the first: the warm-up
            for i, sim in enumerate(sims):
                try:
                    sim.run()
                except CoSimulationError as exc:            # timed up to where it stopped
                    sim.stopped = exc.time
                if rep:
                    times[i].append(sim.cpu)
        cost = [statistics.median(t) for t in times]
        front = sorted((errors[i], cost[i]) for i, c in enumerate(configs) if c[0] == "default")
        le, lc = np.log([e for e, _ in front]), np.log([c for _, c in front])
        print(f"{name} (stop_time {stop_time:g} s, median of {a.runs} runs, process CPU)")
        for i, (family, label, _) in enumerate(configs):
            e = errors[i]
            ratio = ""
            if not math.isfinite(e):
                ratio = f"stopped at t = {sims[i].stopped:g} s"
            elif family != "default" and le[0] <= math.log(e) <= le[-1]:
                ratio = f"{cost[i] / math.exp(np.interp(math.log(e), le, lc)):6.2f}x"
            print(f"  {family:26s} {label:16s} {loops[i]:9s} error {e:9.3g} rad  "
                  f"{tried[i]:6d} steps  cpu {cost[i] * 1e3:9.2f} ms  {ratio}", flush=True)


if __name__ == "__main__":
    main()
