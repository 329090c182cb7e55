"""Work-precision benchmark: the error of the tip angle against wall time, for every way the
project can simulate a scene, side by side with scipy's solve_ivp and with the FMI overhead floor.

    python bench/work_precision.py                 # full run (about half an hour)
    python bench/work_precision.py --quick         # a few minutes: fewer points, fewer runs
    python bench/work_precision.py --runs 5 --scene rigid_pd --family "GS"
    python bench/work_precision.py --set plant.phi_limit=3   # an extra scene key on every
                                                             # point and the reference
    python bench/work_precision.py --workers 2     # the points on a dask LocalCluster

* **Error**: the largest absolute error of ``phi_o`` over the scene's output grid, against the
  monolithic reference (DOP853 at rtol = atol = 1e-12), see ``bench/common.py``. A run that fails
  (a ``CoSimulationError``, e.g. an FMU refusing a step because the plant diverged past its
  ``phi_limit``, or a ``solve_ivp`` failure) is recorded with ``error = inf`` and drawn as failed.
* **Time**: the median of ``--runs`` timed runs after one untimed warm-up (``median_time``); the
  co-simulation's time is the master's initialisation and stepping, ``solve_ivp``'s the call.
  A run that fails is not repeated: its time is that of the failed warm-up. A point whose warm-up
  shows that ``--runs`` runs would take over 20 s (10 s with ``--quick``) gets fewer runs (at
  least one); the record says how many.
* **Scenes**: ``flexible_pd_lowpass`` (the paper's filtered scene: 10 s from pi/6, 4 modes) and
  ``rigid_pd``. Communication steps above the scene's output interval (0.01 s) run with an output
  interval equal to the step (the error is then measured on that coarser grid).
* **Families** (the tables ``coupling_families``, ``integrator_families`` ... below; every point
  is a list of scene overrides, so a new scene option is one more entry):
  - coupling: Gauss-Seidel and Jacobi, extrapolation 0, 1, 2, and quadratic extrapolation with
    ``master.input_derivatives`` (the polynomial passed to the FMUs), over ``master.step``;
  - Gauss-Seidel quadratic with the extrapolation built from the FMUs' output derivatives
    (``master.output_derivatives``, with input derivatives), and the Hermite coupling
    (``master.coupling = "hermite"``, the plant first), over ``master.step``;
  - the adaptive master over ``master.tolerance`` (linear held, and the scenes' own coupling);
  - the implicit master (``master.algorithm = implicit``, Newton and IQN-ILS; quadratic
    interpolation passed as input derivatives) over ``master.step``, up to steps where every
    explicit coupling diverges;
  - the model-exchange master (``master.interface = model-exchange``: the FMUs' states as one
    ODE, Radau and BDF with the FMUs' directional derivatives) over ``master.rtol``;
  - every plant integrator of ``plant_fmu.integrators.REGISTRY`` over ``plant.step`` (fixed-step
    methods) or ``plant.rtol`` (adaptive ones, ``plant.atol = 1e-3 plant.rtol``), all at one
    coupling (``INTEGRATOR_MASTER``); ``exponential`` integrates the linearised plant
    (``plant.fidelity = linear``) and is labelled so;
  - ``solve_ivp`` RK45, DOP853, Radau, LSODA on the monolithic model over rtol (atol = 1e-3 rtol);
  - the same master loop over two trivial FMUs of the same flavour (the FMI overhead floor), per
    communication step: a time without an error, drawn as vertical lines.
* **FMUs**: ``--fmus native`` (the default: the native FMI 2.0 pair, which the master steps in
  its compiled loop) or ``--fmus python``; the integrators only the pythonfmu plant has
  (``PYTHONFMU_ONLY``: radau, genalpha) run on the pythonfmu pair, and their curves say so.

Results: ``bench/results/work_precision[_quick].{csv,json,png}``; the terminal shows one line per
point, then where each family sits on the Pareto front (error against time) of its scene.

``--workers N`` (a dask LocalCluster) or ``--scheduler ADDRESS`` runs the points as tasks
(``orchestration.sweeps.executor``), each on one core: the errors are the serial run's, number for
number; the times are measured with N points running side by side, so they stand for one core
only where N cores are free (on a shared machine, take the serial run's times).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import (RESULTS, ROOT, CoSim, load_scene, median_time, monolithic,  # noqa: E402
                    phi_error, product_fmus, reference, trivial_fmus,
                    trivial_native_fmus)

from orchestration.scene.keys import ConfigError  # noqa: E402
from orchestration.cosim.slave import CoSimulationError  # noqa: E402
from plant_fmu.integrators import REGISTRY  # noqa: E402

SCENES = ("flexible_pd_lowpass", "rigid_pd")

#: values of each sweep, (full, quick)
COMM_STEPS = ([1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2], [1e-3, 5e-3, 2e-2])
TOLERANCES = ([1e-2, 1e-3, 1e-4, 1e-5], [1e-2, 1e-3])
PLANT_STEPS = ([1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5, 2e-5, 1e-5], [1e-3, 2.5e-4])
PLANT_RTOLS = ([1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9], [1e-2, 1e-4])
IVP_RTOLS = ([1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10], [1e-3, 1e-6])
#: Radau stops earlier: on the flexible scene it is already at 1e-10 rad with rtol = 1e-6 and
#: takes tens of seconds per run below 1e-8
IVP_RTOLS_RADAU = ([1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8], [1e-3, 1e-6])
#: a point whose warm-up shows that --runs runs would take longer than this gets fewer (>= 1)
MAX_POINT_SECONDS = (20.0, 10.0)

#: the couplings swept over master.step: (algorithm, extrapolation order, input derivatives)
COUPLINGS = [(alg, p, False) for alg in ("gauss-seidel", "jacobi") for p in (0, 1, 2)] + \
    [(alg, 2, True) for alg in ("gauss-seidel", "jacobi")]

#: the coupling at which the plant integrators are compared (the best-order coupling that every
#: integrator takes, at the scenes' 1 ms step); its coupling error is the floor under their curves
INTEGRATOR_MASTER = ["master.algorithm=gauss-seidel", "master.extrapolation=2", "master.step=1e-3",
                     "master.input_derivatives=false"]

EXTRAPOLATION = {0: "ZOH", 1: "linear", 2: "quadratic"}
ALGORITHM = {"gauss-seidel": "GS", "jacobi": "Jacobi"}


@dataclass
class Family:
    """One curve: fixed scene overrides, and a sweep of ``values`` over the scene keys ``sweep``
    (key, factor): every key gets ``factor * value``."""
    name: str
    group: str                  # coupling | adaptive master | plant integrator | solve_ivp | FMI floor
    kind: str                   # cosim | monolithic | trivial
    sweep: list                 # [(key, factor)]; for monolithic: [("rtol", 1.0)]
    values: tuple               # (full, quick)
    overrides: list = field(default_factory=list)
    method: str = ""            # integrator, solve_ivp method or algorithm, for the record
    flavour: str = ""           # the FMUs: "" those of --fmus, "python" the pythonfmu ones always

    @property
    def param(self):
        return self.sweep[0][0]


def coupling_families():
    out = []
    for alg, p, du in COUPLINGS:
        ov = [f"master.algorithm={alg}", f"master.extrapolation={p}",
              f"master.input_derivatives={'true' if du else 'false'}"]
        out.append(Family(f"{ALGORITHM[alg]} {EXTRAPOLATION[p]}" + (" + du/dt" if du else ""),
                          "coupling", "cosim", [("master.step", 1.0)], COMM_STEPS, ov,
                          method=alg))
    return out


#: the model-exchange master's relative tolerances (atol = 1e-2 rtol times each nominal)
ME_RTOLS = ([1e-4, 1e-5, 1e-6, 1e-7, 1e-8], [1e-4, 1e-7])


def output_derivative_families():
    """Gauss-Seidel with quadratic extrapolation built from the FMUs' output derivatives
    (``master.output_derivatives``; it needs the polynomial passed as input derivatives)."""
    return [Family("GS quadratic from dy/dt + du/dt", "coupling", "cosim",
                   [("master.step", 1.0)], COMM_STEPS,
                   ["master.algorithm=gauss-seidel", "master.extrapolation=2",
                    "master.input_derivatives=true", "master.output_derivatives=true"],
                   method="gauss-seidel"),
            # the Hermite coupling (master.coupling = "hermite"), the plant first
            Family("GS Hermite, plant first", "coupling", "cosim", [("master.step", 1.0)],
                   COMM_STEPS, ["master.algorithm=gauss-seidel", "master.coupling=hermite",
                                "master.first=plant", "master.input_derivatives=true"],
                   method="gauss-seidel")]


def model_exchange_families():
    """The model-exchange master (the FMUs' states as one ODE) over ``master.rtol``."""
    return [Family(f"ME master ({solver})", "model exchange", "cosim",
                   [("master.rtol", 1.0), ("master.atol", 1e-2)], ME_RTOLS,
                   ["master.interface=model-exchange", f"master.solver={solver}"],
                   method=solver) for solver in ("radau", "bdf")]


def adaptive_families():
    return [Family("adaptive GS linear", "adaptive master", "cosim", [("master.tolerance", 1.0)],
                   TOLERANCES, ["master.adaptive=true", "master.algorithm=gauss-seidel",
                                "master.extrapolation=1", "master.input_derivatives=false"],
                   method="gauss-seidel"),
            # the scenes' own coupling (quadratic, passed as input derivatives), adaptive
            Family("adaptive GS quadratic derivatives", "adaptive master", "cosim",
                   [("master.tolerance", 1.0)], TOLERANCES,
                   ["master.adaptive=true", "master.algorithm=gauss-seidel",
                    "master.extrapolation=2", "master.input_derivatives=true"],
                   method="gauss-seidel")]


#: the implicit master's communication steps, (full, quick): beyond the explicit couplings' limits
IMPLICIT_STEPS = ([*COMM_STEPS[0], 5e-2, 1e-1], [1e-3, 2e-2, 1e-1])


def implicit_families():
    """The strongly coupled master over ``master.step`` (``orchestration/cosim/implicit.py``)."""
    return [Family(f"implicit ({name})", "implicit master", "cosim", [("master.step", 1.0)],
                   IMPLICIT_STEPS, ["master.algorithm=implicit", f"master.implicit_jacobian={j}",
                                    "master.extrapolation=2", "master.input_derivatives=true"],
                   method="implicit") for j, name in (("newton", "Newton"), ("iqn-ils", "IQN-ILS"))]


#: the plant integrators only the pythonfmu FlexiblePendulum has (the native one refuses them at
#: initialisation, naming the ones it has: plant_fmu/native/plant_model.c); their curves always run on
#: the pythonfmu pair, and say so
PYTHONFMU_ONLY = ("radau", "genalpha")


def integrator_families():
    out = []
    for name, cls in REGISTRY.items():
        base = [*INTEGRATOR_MASTER, f"plant.integrator={name}"]
        if name == "exponential":       # exact for any step: one point, on the linearised plant
            fam = Family("exponential (linear model)", "plant integrator", "cosim",
                         [("plant.step", 1.0)], ([1e-3], [1e-3]),
                         [*base, "plant.fidelity=linear"], method=name)
        elif getattr(cls, "OPTIONS", {}).get("adaptive"):
            fam = Family(f"{name} (adaptive)", "plant integrator", "cosim",
                         [("plant.rtol", 1.0), ("plant.atol", 1e-3)], PLANT_RTOLS, base,
                         method=name)
        else:
            fam = Family(name, "plant integrator", "cosim", [("plant.step", 1.0)],
                         PLANT_STEPS, base, method=name)
        if name in PYTHONFMU_ONLY:
            fam.name, fam.flavour = f"{fam.name}, pythonfmu", "python"
        out.append(fam)
    return out


def ivp_families():
    return [Family(f"solve_ivp {m}", "solve_ivp", "monolithic", [("rtol", 1.0)],
                   IVP_RTOLS_RADAU if m == "Radau" else IVP_RTOLS, method=m)
            for m in ("RK45", "DOP853", "Radau", "LSODA")]


def floor_families():
    return [Family("trivial FMUs (FMI floor)", "FMI floor", "trivial", [("master.step", 1.0)],
                   COMM_STEPS, ["master.algorithm=gauss-seidel", "master.extrapolation=0",
                                "master.input_derivatives=false"], method="gauss-seidel")]


def all_families():
    return [*coupling_families(), *output_derivative_families(), *adaptive_families(),
            *implicit_families(),
            *model_exchange_families(), *integrator_families(), *ivp_families(),
            *floor_families()]


def fmt(v: float) -> str:
    """``2e-4``, ``0.01``, ``2.5e-4``: short and exact enough for the sweeps' values."""
    if v == 0 or not math.isfinite(v) or 1e-2 <= abs(v) < 1e3:
        return f"{v:g}"
    m, e = f"{v:.2e}".split("e")
    return f"{m.rstrip('0').rstrip('.')}e{int(e)}"


def short(param: str) -> str:
    """``master.step`` -> ``step``, for table cells (the family says which component)."""
    return param.split(".")[-1]


# ---------------------------------------------------------------------------------------------
# running one point

class Runner:
    """Runs points. ``fmus``/``trivial``: the product's and the trivial FMUs (``{"plant": path,
    "controller": path}``); ``python_fmus``: the pythonfmu pair, for the families that need it
    (``Family.flavour``); ``refs``: references already solved, by :meth:`scene_for`'s key."""

    def __init__(self, runs: int, extra: list, max_seconds: float, fmus=None, trivial=None,
                 refs=None, python_fmus=None):
        self.runs = runs
        self.max_seconds = max_seconds
        self.extra = extra
        self.fmus = fmus or product_fmus()
        self.trivial = trivial or trivial_fmus()
        self.python_fmus = python_fmus
        self._refs = dict(refs or {})
        self._cosims = {}

    def scene_for(self, scene_name, fam: Family, value):
        """``(scene of the point, its overrides, the scene of its reference)``: the reference is
        the scene itself (with ``--set``) on the point's output grid, without the family's
        master/plant-solver overrides (``plant.fidelity = linear`` included: the linear-model
        point is measured against the nonlinear reference)."""
        ov = [*fam.overrides]
        for key, factor in fam.sweep:
            if key != "rtol":
                ov.append(f"{key}={factor * value!r}")
        grid = []
        base = load_scene(scene_name, self.extra)
        for key, factor in fam.sweep:      # coarse communication steps: a coarser output grid
            if key == "master.step" and factor * value > base.output.output_interval:
                grid.append(f"output_interval={factor * value!r}")
        ov = [*ov, *grid, *self.extra]
        # the reference is monolithic: its scene only needs a master step that fits its grid
        ref_ov = [*self.extra, *grid, *(f"master.step={g.split('=')[1]}" for g in grid)]
        return load_scene(scene_name, ov), ov, (scene_name, ref_ov)

    def ref_key(self, scene_name, fam: Family, value):
        """The key of the point's reference (None for the trivial FMUs, which have none)."""
        if fam.kind == "trivial":
            return None
        name, ov = self.scene_for(scene_name, fam, value)[2]
        return (name, tuple(ov))

    def ref(self, key):
        name, ov = key
        k = (name, tuple(ov))
        if k not in self._refs:
            self._refs[k] = reference(load_scene(name, ov))
        return self._refs[k]

    def point(self, scene_name, fam: Family, value):
        """:meth:`run`, with a sweep value the scene refuses recorded as a failed point."""
        try:
            return self.run(scene_name, fam, value)
        except ConfigError as exc:
            return dict(scene=scene_name, group=fam.group, family=fam.name, kind=fam.kind,
                        method=fam.method, param=fam.param, value=value, settings="",
                        median_s=math.nan, all_s=[], error=math.inf, ok=False, runs=0,
                        message=f"ConfigError: {exc}", stats={})

    def run(self, scene_name, fam: Family, value):
        """The record of one point."""
        scene, ov, ref_key = self.scene_for(scene_name, fam, value)
        rec = dict(scene=scene_name, group=fam.group, family=fam.name, kind=fam.kind,
                   method=fam.method, param=fam.param, value=value, settings=" ".join(ov),
                   median_s=math.nan, all_s=[], error=math.inf, ok=False, runs=0, message="",
                   stats={})
        if fam.kind == "monolithic":
            ref = self.ref(ref_key)
            fn = self._guard(lambda: self._monolithic(scene, fam.method, value))
        else:
            ref = None if fam.kind == "trivial" else self.ref(ref_key)
            if fam.kind == "trivial":
                fmus = self.trivial
            elif fam.flavour == "python":
                if self.python_fmus is None:
                    self.python_fmus = product_fmus("python")
                fmus = self.python_fmus
            else:
                fmus = self.fmus
            cosim = CoSim(scene, fmus, trivial=fam.kind == "trivial")
            fn = self._guard(lambda: self._cosim(cosim))
        med, times, value_out = median_time(fn, self.runs, self.max_seconds)
        failed = isinstance(value_out, _Failure)
        rec["all_s"] = [value_out.seconds] if failed else times
        rec["median_s"] = value_out.seconds if failed else med
        rec["runs"] = len(rec["all_s"])
        if failed:
            rec["message"] = value_out.message
            return rec
        if fam.kind == "trivial":
            rec["ok"], rec["error"] = True, math.nan
            rec["stats"] = value_out[1]
            return rec
        if fam.kind == "monolithic":
            phi, nfev = value_out
            rec["stats"] = {"nfev": nfev}
            if phi is None:
                rec["message"] = "solve_ivp failed"
                return rec
            err = float(abs(phi - ref["phi_o"]).max()) if len(phi) == len(ref) else math.inf
        else:
            result, stats = value_out
            rec["stats"] = stats
            err = phi_error(result, ref)
        rec["error"] = err
        rec["ok"] = math.isfinite(err)
        if not rec["ok"]:
            rec["message"] = "non-finite phi_o (diverged)"
        return rec

    @staticmethod
    def _guard(fn):
        """``fn`` that turns a failure into a value, and after a failure returns it again without
        running (a failed point is not repeated)."""
        failure = []

        def guarded():
            if failure:
                return failure[0].seconds, failure[0]
            t0 = time.perf_counter()
            try:
                return fn()
            except (CoSimulationError, ArithmeticError, RuntimeError, ValueError) as exc:
                msg = " ".join(f"{type(exc).__name__}: {exc}".split())
                failure.append(_Failure(time.perf_counter() - t0, msg[:300]))
                return failure[0].seconds, failure[0]
        return guarded

    @staticmethod
    def _cosim(cosim):
        result, stats = cosim.run()
        return stats.wall_time, (result, {"steps": stats.steps, "rejected": stats.rejected,
                                          "iterations": stats.iterations})

    @staticmethod
    def _monolithic(scene, method, rtol):
        seconds, phi, nfev = monolithic(scene, method, rtol)
        return seconds, (phi, nfev)


@dataclass
class _Failure:
    seconds: float
    message: str


# ---------------------------------------------------------------------------------------------
# the points as tasks (orchestration.sweeps.executor): here one after the other, or on dask workers

#: a worker's Runner, made at its first point (keeps its loaded FMUs' extraction and references)
_RUNNER: dict = {}


def _families_by_name():
    return {f.name: f for f in all_families()}


def _reference_task(key):
    """``(key, reference)``, or ``(key, None)`` for a reference scene the scene refuses (its
    points then fail with that message, as in :meth:`Runner.point`)."""
    name, ov = key
    try:
        return key, reference(load_scene(name, list(ov)))
    except ConfigError:
        return key, None


def _point_task(item):
    """One point: ``(scene, family name, value, setup, {reference key: reference})``."""
    scene, family, value, setup, refs = item
    from orchestration.sweeps.executor import worker_file
    k = (setup["runs"], tuple(setup["extra"]), setup["max_seconds"])
    if _RUNNER.get("key") != k:
        def local(fmus):
            return {role: worker_file(ship, path) for role, (ship, path) in fmus.items()}
        _RUNNER.update(key=k, runner=Runner(setup["runs"], list(setup["extra"]),
                                            setup["max_seconds"], local(setup["fmus"]),
                                            local(setup["trivial"]),
                                            python_fmus=local(setup["python_fmus"])))
    runner = _RUNNER["runner"]
    runner._refs.update(refs)
    return runner.point(scene, _families_by_name()[family], value)


# ---------------------------------------------------------------------------------------------
# Pareto front and report

THRESHOLDS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7)


def pareto(records):
    """Non-dominated points (less time and less error), by increasing time."""
    pts = sorted((r for r in records if r["ok"] and math.isfinite(r["error"])),
                 key=lambda r: (r["median_s"], r["error"]))
    front, best = [], math.inf
    for r in pts:
        if r["error"] < best:
            front.append(r)
            best = r["error"]
    return front


def summarise(records, scene):
    """Per family of ``scene``: points on the scene's front, own front, fastest point under each
    error threshold, failures."""
    rs = [r for r in records if r["scene"] == scene and r["kind"] != "trivial"]
    front = pareto(rs)
    on_front = {id(r) for r in front}
    fams = {}
    for r in rs:
        fams.setdefault(r["family"], []).append(r)
    summary = []
    for name, pts in fams.items():
        ok = [r for r in pts if r["ok"]]
        fastest = {}
        for thr in THRESHOLDS:
            good = [r for r in ok if r["error"] <= thr]
            if good:
                r = min(good, key=lambda r: r["median_s"])
                fastest[f"{thr:g}"] = {"seconds": r["median_s"], "error": r["error"],
                                       "param": r["param"], "value": r["value"]}
        summary.append({
            "family": name, "group": pts[0]["group"], "points": len(pts),
            "failed": [f"{r['param']}={fmt(r['value'])}" for r in pts if not r["ok"]],
            "on_front": [{"param": r["param"], "value": r["value"], "seconds": r["median_s"],
                          "error": r["error"]} for r in pts if id(r) in on_front],
            "own_front": [{"param": r["param"], "value": r["value"], "seconds": r["median_s"],
                           "error": r["error"]} for r in pareto(pts)],
            "best_error": min((r["error"] for r in ok), default=math.inf),
            "fastest_under": fastest,
        })
    return {"front": [{"family": r["family"], "param": r["param"], "value": r["value"],
                       "seconds": r["median_s"], "error": r["error"]} for r in front],
            "families": summary}


def print_summary(scene, s, floor):
    print(f"\nPareto front of {scene} (time, error, family, setting):")
    for p in s["front"]:
        print(f"  {p['seconds']:9.4f} s  {p['error']:9.2e}  {p['family']:<28} "
              f"{p['param']}={fmt(p['value'])}")
    if floor:
        print("  FMI floor (trivial FMUs): " + ", ".join(
            f"h={fmt(r['value'])}: {r['median_s']:.3g} s" for r in floor))
    print(f"\nFamilies of {scene}: points on the front; fastest point with error <= threshold "
          "(seconds @ setting); failed points")
    head = "| family | on front | " + " | ".join(f"<= {t:g}" for t in THRESHOLDS) + \
        " | best error | failed |"
    print(head)
    print("|" + "---|" * (len(THRESHOLDS) + 4))
    for f in s["families"]:
        cells = []
        for t in THRESHOLDS:
            c = f["fastest_under"].get(f"{t:g}")
            cells.append(f"{c['seconds']:.3g} s @ {short(c['param'])}={fmt(c['value'])}"
                         if c else "-")
        failed = ", ".join(f["failed"]) if f["failed"] else "-"
        print(f"| {f['family']} | {len(f['on_front'])}/{f['points']} | " + " | ".join(cells) +
              f" | {f['best_error']:.2e} | {failed} |")


# ---------------------------------------------------------------------------------------------
# the figure

GROUP_STYLE = {"coupling": "-", "adaptive master": "-", "plant integrator": "--",
               "solve_ivp": ":", "model exchange": (0, (5, 1, 1, 1))}


def plot(records, scenes, path, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fams = list(dict.fromkeys(r["family"] for r in records if r["kind"] != "trivial"))
    colors = {}
    others = iter(["tab:purple", "tab:brown", "tab:pink", "tab:cyan", "tab:olive", "navy",
                   "darkgoldenrod", "teal", "crimson", "magenta", "lime", "sienna"])
    greys = iter(["0.0", "0.35", "0.55", "0.75"])
    for f in fams:
        g = next(r for r in records if r["family"] == f)
        if g["group"] == "coupling":     # colour = extrapolation, line style = algorithm
            colors[f] = ("tab:red" if "du/dt" in f else "tab:orange" if "quadratic" in f
                         else "tab:green" if "linear" in f else "tab:blue")
        elif g["group"] == "solve_ivp":
            colors[f] = next(greys, "0.5")
        else:
            colors[f] = next(others, "tab:gray")
    markers = "osD^v<>pPhX*dH8"
    fig, axes = plt.subplots(1, len(scenes), figsize=(8.5 * len(scenes), 8), squeeze=False)
    handles = {}
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in records if r["scene"] == scene]
        finite = [r["error"] for r in rs if r["ok"] and math.isfinite(r["error"])]
        times = [r["median_s"] for r in rs if math.isfinite(r["median_s"])]
        if not times:
            continue
        top = 10 ** math.ceil(math.log10(max(finite))) * 10 if finite else 1.0
        bottom = 10 ** math.floor(math.log10(max(min(finite), 1e-14))) / 3 if finite else 1e-12
        fail_y = top / 2
        for i, fam in enumerate(fams):
            pts = sorted((r for r in rs if r["family"] == fam), key=lambda r: r["value"])
            if not pts:
                continue
            group = pts[0]["group"]
            ok = [r for r in pts if r["ok"]]
            bad = [r for r in pts if not r["ok"]]
            ls = GROUP_STYLE.get(group, "-")
            if pts[0]["method"] == "jacobi" and group == "coupling":
                ls = "-."
            if ok:
                (h,) = ax.plot([r["median_s"] for r in ok], [r["error"] for r in ok],
                               linestyle=ls, marker=markers[i % len(markers)], color=colors[fam],
                               ms=5, lw=1.3, label=fam)
                handles[fam] = h
            if bad:
                ax.plot([r["median_s"] for r in bad], [fail_y] * len(bad), "x",
                        color=colors[fam], ms=8, mew=2)
                if fam not in handles:
                    handles[fam] = ax.plot([], [], linestyle=ls, marker="x", color=colors[fam],
                                           label=fam + " (all failed)")[0]
        ax.axhline(fail_y, color="0.6", lw=0.8)
        ax.text(min(times), fail_y * 1.15, "failed (x): diverged / FMU refused a step / "
                "solver failure", fontsize=8, color="0.35")
        floor = sorted((r for r in rs if r["kind"] == "trivial" and r["ok"]),
                       key=lambda r: r["value"])
        for r in floor:
            ax.axvline(r["median_s"], color="0.5", lw=0.8, ls=":")
            ax.text(r["median_s"], bottom * 1.3, f" floor h={fmt(r['value'])}", rotation=90,
                    fontsize=7, color="0.35", va="bottom")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(bottom, top)
        ax.set_xlabel("wall time per run, s (median)")
        ax.set_ylabel("max |phi_o - phi_o,ref| over the run, rad")
        ax.set_title(scene)
        ax.grid(True, which="major", alpha=0.3)
    import textwrap
    # a one-scene chart is narrow: fewer legend columns, shorter title lines
    fig.suptitle("\n".join(textwrap.wrap(title, min(150, 90 * len(scenes)))), fontsize=9)
    ncol = min(5, len(handles), 3 * len(scenes))
    fig.legend(list(handles.values()), list(handles), loc="lower center",
               ncol=ncol, fontsize=8, frameon=False)
    nrows = math.ceil(len(handles) / ncol)
    fig.tight_layout(rect=(0, 0.03 + 0.025 * nrows, 1, 0.97))
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# command line

class _Parser(argparse.ArgumentParser):
    def error(self, message):          # one line, exit 2
        self.exit(2, f"work_precision.py: error: {message}\n")


def _die(message):
    print(f"work_precision.py: error: {message}", file=sys.stderr)
    sys.exit(2)


def _positive_int(s):
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{s!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{s!r} is not allowed; allowed: an integer >= 1")
    return v


def _git(*args):
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def _jsonable(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return v


def main(argv=None):
    ap = _Parser(description=__doc__.split("\n\n")[0],
                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fmus", choices=("native", "python"), default="native",
                    help="the FMUs of the co-simulation points (default: native, the product's "
                         "default; python: the pythonfmu flavour)")
    ap.add_argument("--quick", action="store_true",
                    help="fewer points and (unless --runs) 1 run per point: a few minutes")
    ap.add_argument("--runs", type=_positive_int, default=None,
                    help="timed runs per point after the warm-up (default 3, --quick 1); fewer for "
                         "a point whose warm-up shows they would take over 20 s (10 s quick)")
    ap.add_argument("--scene", action="append", default=None, metavar="NAME",
                    help=f"only this scene (repeatable; default: {', '.join(SCENES)})")
    ap.add_argument("--family", action="append", default=None, metavar="TEXT",
                    help="only families whose name contains TEXT (repeatable); the FMI floor "
                         "always runs")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="an extra scene override on every point and on the reference "
                         "(repeatable); family settings come first, so it overrides them")
    ap.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                    help="run the points on a dask LocalCluster of N processes (the same "
                         "errors; times measured side by side, so only with free cores)")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the points on the dask cluster of this scheduler (its workers "
                         "need this checkout at the same path)")
    ap.add_argument("--out", default=None, metavar="DIR",
                    help="output folder (default: bench/results)")
    args = ap.parse_args(argv)
    if args.workers and args.scheduler:
        _die("give --workers or --scheduler, not both")
    runs = args.runs or (1 if args.quick else 3)
    scenes = args.scene or list(SCENES)
    for s in scenes:
        try:
            load_scene(s, [])
        except (ConfigError, OSError, ValueError) as exc:
            _die(f"--scene {s!r}: {' '.join(str(exc).split())}")
    for kv in args.set:
        try:
            load_scene(scenes[0], [kv])
        except (ConfigError, ValueError) as exc:
            _die(f"--set {kv!r}: {' '.join(str(exc).split())}")
    fams = all_families()
    if args.family:
        chosen = [f for f in fams if f.kind == "trivial" or
                  any(t.lower() in f.name.lower() for t in args.family)]
        for t in args.family:
            if not any(t.lower() in f.name.lower() for f in fams if f.kind != "trivial"):
                _die(f"--family {t!r} matches no family; families: "
                     + ", ".join(f.name for f in fams))
        fams = chosen
    which = 1 if args.quick else 0
    plan = [(s, f, v) for s in scenes for f in fams for v in f.values[which]]

    results = Path(args.out) if args.out else RESULTS
    results.mkdir(parents=True, exist_ok=True)
    stem = results / ("work_precision_quick" if args.quick else "work_precision")
    command = "python bench/work_precision.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    meta = {"command": command.strip(), "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "commit": _git("rev-parse", "--short", "HEAD"),
            "uncommitted_product_files": _git("status", "--porcelain", "--", "plant_fmu",
                                              "controller_fmu", "orchestration").splitlines(),
            "python": platform.python_version(), "machine": platform.machine(),
            "cpus": os.cpu_count(), "load_average_start": list(os.getloadavg()),
            "runs": runs, "quick": args.quick, "fmus": args.fmus, "scenes": scenes, "extra_overrides": args.set,
            "integrator_master": INTEGRATOR_MASTER,
            "error": "max |phi_o - phi_o_ref| on the output grid; ref: DOP853 rtol=atol=1e-12",
            "time": "median of runs after one warm-up; a failed point is timed once; fewer runs "
                    f"where they would take over {MAX_POINT_SECONDS[which]:g} s"}
    print(f"work-precision: {len(plan)} points, {runs} runs each after a warm-up; "
          f"load average {' '.join(f'{x:.2f}' for x in meta['load_average_start'])}", flush=True)

    from orchestration.sweeps.executor import file_name, open_executor
    # the floor is the same flavour's: two trivial native FMUs (the compiled loop takes them as it
    # takes the product's), or two trivial pythonfmu FMUs
    fmus = product_fmus(args.fmus)
    trivial = trivial_native_fmus() if args.fmus == "native" else trivial_fmus()
    python_fmus = product_fmus("python")
    setup = {"runs": runs, "extra": list(args.set), "max_seconds": MAX_POINT_SECONDS[which],
             "fmus": {k: (file_name(p), str(p)) for k, p in fmus.items()},
             "trivial": {k: (file_name(p), str(p)) for k, p in trivial.items()},
             "python_fmus": {k: (file_name(p), str(p)) for k, p in python_fmus.items()}}
    runner = Runner(runs, args.set, MAX_POINT_SECONDS[which], fmus, trivial,
                    python_fmus=python_fmus)
    records = [None] * len(plan)
    t_start = time.perf_counter()
    try:
        ex = open_executor(args.workers, args.scheduler, paths=[str(Path(__file__).parent)],
                           files=[*fmus.values(), *trivial.values(), *python_fmus.values()])
    except ValueError as exc:
        _die(str(exc))
    meta["executor"] = ex.describe()
    if ex.kind != "serial":
        print(f"on {ex.describe()}: the errors are those of the serial run; the times are "
              "measured with the workers running side by side" + (f"; dask dashboard "
              f"{ex.dashboard}" if ex.dashboard else ""), flush=True)
    with ex:
        # the references first (each solved once), then every point with the ones it needs
        ref_keys = list(dict.fromkeys(k for s, f, v in plan
                                      if (k := runner.ref_key(s, f, v)) is not None))
        refs = {}
        for _, v in ex.map(_reference_task, ref_keys):
            if not isinstance(v, tuple):
                _die(f"a reference was lost with its worker: {v.message}")
            if v[1] is not None:
                refs[v[0]] = v[1]
        items = []
        for s, f, v in plan:
            k = runner.ref_key(s, f, v)
            items.append((s, f.name, v, setup, {k: refs[k]} if k in refs else {}))
        for n, (i, rec) in enumerate(ex.map(_point_task, items), 1):
            if not isinstance(rec, dict):       # a lost task (its worker died)
                scene, fam, value = plan[i]
                rec = dict(scene=scene, group=fam.group, family=fam.name, kind=fam.kind,
                           method=fam.method, param=fam.param, value=value, settings="",
                           median_s=math.nan, all_s=[], error=math.inf, ok=False, runs=0,
                           message=f"lost: {rec.message}", stats={})
            records[i] = rec
            scene, fam, value = plan[i]
            status = ("floor" if rec["kind"] == "trivial" else f"err {rec['error']:9.2e}") \
                if rec["ok"] else "FAILED"
            print(f"[{n:3d}/{len(plan)}] {scene:<20} {fam.name:<28} {fam.param}={fmt(value):<7} "
                  f"{status:<13} {rec['median_s']:8.4f} s  (x{rec['runs']}, "
                  f"{time.perf_counter() - t_start:6.0f} s elapsed)"
                  + (f"  {rec['message'][:120]}" if not rec["ok"] else ""), flush=True)

    meta["load_average_end"] = list(os.getloadavg())
    meta["total_seconds"] = time.perf_counter() - t_start
    summaries = {}
    for scene in scenes:
        summaries[scene] = summarise(records, scene)
        floor = sorted((r for r in records if r["scene"] == scene and r["kind"] == "trivial"
                        and r["ok"]), key=lambda r: r["value"])
        print_summary(scene, summaries[scene], floor)

    fields = ["scene", "group", "family", "kind", "method", "param", "value", "median_s", "error",
              "ok", "runs", "all_s", "settings", "message"]
    with open(stem.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(fields)
        for r in records:
            w.writerow([";".join(f"{x:.6g}" for x in r[k]) if k == "all_s" else
                        (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in fields])
    with open(stem.with_suffix(".json"), "w") as fh:
        json.dump(_jsonable({"meta": meta, "points": records, "pareto": summaries}), fh,
                  indent=1)
    la = meta["load_average_start"]
    plot(records, scenes, stem.with_suffix(".png"),
         f"{meta['command']}  (commit {meta['commit']}, {runs} runs, load average "
         f"{la[0]:.2f} at start)")
    print(f"\nwrote {stem}.csv, .json, .png  "
          f"({meta['total_seconds']:.0f} s; load average at end "
          f"{' '.join(f'{x:.2f}' for x in meta['load_average_end'])})")
    return 0


if __name__ == "__main__":
    # run as the module ``work_precision`` (this folder is on sys.path), so that dask pickles
    # its task functions by reference and the workers import them
    import work_precision
    sys.exit(work_precision.main())
