"""The error figure's study: its kappa, floor, measured range and growth rate, fitted on a grid
of the paper scenes and checked on cases not fitted on (docs/accuracy.md).

    python3 bench/error_figure.py [--write] [--cross-check] [--json FILE]

Every case is a scene with its keys, run on each floating-frame rung (``linear``,
``nonlinear``, ``nonlinear`` with ``plant.gravity_preload``, ``stiffened``; the rigid model's two
rungs on ``rigid_pd``) through the native FMUs and the scene's master, with its companion
(:func:`orchestration.studies.error_figure.companion_scene`: the run the job makes), and
compared with a refined geometrically exact reference: the monolithic exact loop by Radau IIA at
:data:`REF` (48 elements, 0.125 ms; :func:`orchestration.studies.exact_loop.exact_run`), cached
in ``bench/results/error_figure/refs`` (ignored by git). The damping: none (``plant.zeta = 0``,
the same on both sides under either law) or Kelvin-Voigt 0.1 % on both sides (the exact rung's
law; the modal law joins when the exact rung takes it).

* **Grid** (:func:`grid`, fitted on): ``flexible_pd_lowpass`` from 0.05, 0.2, 0.35, pi/6,
  0.65 and 0.75 rad (beyond the paper's pi/6) with the PD gains ``kp``, ``kd`` scaled by 0.6, 1
  and 1.5, undamped and Kelvin-Voigt (not 0.2 there); ``rigid_pd`` (its stiff beam) from
  0.05, 0.35, pi/6, 0.65, 0.75 at the same gains, Kelvin-Voigt; 3 s each. ``flexible_pd``
  (Kelvin-Voigt, from 0.05, 0.2, pi/6, its own 2.5 s) is measured for the growth only: its loop
  grows, and is not fitted on.
* **Fit**: the floor, ``safety * sum c_k term_k`` over
  :data:`orchestration.studies.error_figure.TERMS` (:data:`FLOOR_TERMS`) on the companion's
  features, the nonnegative combination that bounds the companion's own error on every grid
  case with the smallest largest ratio (linear programming); ``kappa`` the largest
  ``error / difference`` over the grid's runs whose difference from the companion is at least
  the floor (at least 1): with it alone the figure bounds those runs' errors. The measured
  range: the companion's largest ``|phi_o|``, tip deflection and ``|omega_o|`` over the grid,
  and the softest beam (``omega_1^2 L / g``) a run on its own companion's model was measured
  on, with :data:`MARGIN`. The growth rate: how much faster than a build-up from the start
  (``t^2``) a grid run's difference from its companion grows over the second half of the run
  (:func:`orchestration.studies.error_figure.growth_rate`), at most, and at least 0 (a stable
  loop's difference never outgrew ``t^2`` on the grid; ``flexible_pd``'s growing loops are told
  by their fitted growth, the summary's verdict, first, and most also by this).
* **Off the grid** (:func:`off_grid`, never fitted on): the angles 0.1, 0.3, 0.4; ``kp`` 300 and
  700 alone; ``EI`` 600 and 1500; ``L`` 1.2; the rungs at 8 modes; ``flexible_pd`` from 0.1,
  each undamped and Kelvin-Voigt; the filters 150 rad/s / 0.5 (3 and 5 s) and 1st order
  130 rad/s; the three paper scenes at their own length (Kelvin-Voigt); under the modal law
  (the product's default, on both sides) the filtered scene from 0.1, 0.3 and pi/6, with kp 700,
  and the filtered and rigid paper scenes at their own length. Each run's stated figure
  (:func:`orchestration.studies.error_figure.assess` with the fitted model) against its measured
  error: the ratio, or why it states none.

``--write`` writes the fitted model to ``orchestration/studies/error_figure.json`` (every run
reads it), else to ``bench/results/error_figure/error_figure.json``; the cases measured go to
``bench/results/error_figure/measured.json``. ``--cross-check`` measures the reference's own
error on five cases (the same at half the step, and on 32 elements).

Run time (2-core machine shared with another job, 2026-11-28): 27 min with the references to
compute (64 of them, 14 to 60 s each), 2.5 min with them cached.
"""
from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from orchestration import simulate  # noqa: E402
from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies import error_figure as ef  # noqa: E402
from orchestration.studies.exact_loop import exact_run  # noqa: E402
from orchestration.studies.validity import rung_name  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "error_figure"
#: The refined reference: elements, Radau IIA step (s); and the cross-check's (half the step,
#: fewer elements).
REF = (48, 1.25e-4)
CROSS = (48, 6.25e-5)
MESH = (32, 1.25e-4)
PI6 = math.pi / 6
UNDAMPED = {"plant.zeta": 0.0}
KV = {"plant.damping": "kelvin-voigt"}
#: The floor's terms (of :data:`orchestration.studies.error_figure.TERMS`).
FLOOR_TERMS = ("D", "D_ringing", "kd_W", "1")
#: The floor's safety factor over the fit.
SAFETY = 1.0
#: The measured range's margin (fraction).
MARGIN = 0.1
#: The damped scenes' law and damping (the ``ringing`` feature is 0 for them).
DAMPED = {"law": "kelvin-voigt", "zeta": 0.001}
#: What the grid's couplings were (the scenes': every case runs its scene's master).
COUPLING = {"algorithm": ["gauss-seidel"], "first": ["controller"], "extrapolation": 2,
            "input_derivatives": True, "max_step": 0.002}
#: The windows of the growth rate.
WINDOWS = 8
RUNGS = ("linear", "nonlinear", "nonlinear + preload", "stiffened")


def _gains(g):
    return {} if g == 1 else {"controller.kp": 500.0 * g, "controller.kd": 5.0 * g}


def grid():
    """``[(scene, label, keys)]`` fitted on."""
    out = []
    for law, lk in (("undamped", UNDAMPED), ("kv", KV)):
        for a in (0.05, 0.2, 0.35, PI6, 0.65, 0.75):
            if law == "kv" and a == 0.2:
                continue
            for g in (0.6, 1.0, 1.5):
                out.append(("flexible_pd_lowpass", f"{law} phi {a:.3g} gain {g:g}",
                            {**lk, "initial.phi": a, "stop_time": 3.0, **_gains(g)}))
    for a in (0.05, 0.35, PI6, 0.65, 0.75):
        for g in (0.6, 1.0, 1.5):
            out.append(("rigid_pd", f"kv phi {a:.3g} gain {g:g}",
                        {**KV, "initial.phi": a, "stop_time": 3.0, **_gains(g)}))
    for a in (0.05, 0.2, PI6):
        out.append(("flexible_pd", f"kv phi {a:.3g}", {**KV, "initial.phi": a}))
    return out


def off_grid():
    """``[(scene, label, keys)]`` never fitted on."""
    f = "flexible_pd_lowpass"
    out = []
    for law, lk in (("undamped", UNDAMPED), ("kv", KV)):
        b = {"stop_time": 3.0, **lk}
        out += [(f, f"{law} phi 0.1", {**b, "initial.phi": 0.1}),
                (f, f"{law} phi 0.3", {**b, "initial.phi": 0.3}),
                (f, f"{law} phi 0.4", {**b, "initial.phi": 0.4}),
                (f, f"{law} kp 300", {**b, "controller.kp": 300.0}),
                (f, f"{law} kp 700", {**b, "controller.kp": 700.0}),
                (f, f"{law} EI 600", {**b, "plant.EI": 600.0}),
                (f, f"{law} EI 1500", {**b, "plant.EI": 1500.0}),
                (f, f"{law} L 1.2", {**b, "plant.L": 1.2}),
                (f, f"{law} 8 modes", {**b, "plant.n_modes": 8}),
                ("flexible_pd", f"{law} phi 0.1", {**lk, "initial.phi": 0.1})]
    kv = {"stop_time": 3.0, **KV}
    out += [(f, "kv filter 150/0.5", {**kv, "controller.cutoff": 150.0,
                                       "controller.filter_damping": 0.5}),
            (f, "kv filter 150/0.5, 5 s", {**kv, "controller.cutoff": 150.0,
                                            "controller.filter_damping": 0.5, "stop_time": 5.0}),
            (f, "kv filter 1st order 130", {**kv, "controller.filter_order": 1,
                                             "controller.cutoff": 130.0}),
            (f, "kv 8 modes, EI 600", {**kv, "plant.n_modes": 8, "plant.EI": 600.0}),
            (f, "kv paper scene, 10 s", {**KV}),
            ("rigid_pd", "kv paper scene, 10 s", {**KV}),
            ("flexible_pd", "kv paper scene, 2.5 s", {**KV})]
    # the product's default law, the modal one (0.1 % in every mode), on both sides: never fitted
    # on (the floor counts its high modes as ringing)
    out += [(f, f"modal phi {a:.3g}", {"initial.phi": a, "stop_time": 3.0})
            for a in (0.1, 0.3, PI6)]
    out += [(f, "modal paper scene, 10 s", {}), ("rigid_pd", "modal paper scene, 10 s", {}),
            (f, "modal kp 700", {"controller.kp": 700.0, "stop_time": 3.0})]
    return out


def reference(name, keys, ref=REF):
    """``phi_o`` of the refined exact reference on the scene's output grid (cached)."""
    k = {**keys, "plant.fidelity": "exact"}
    key = hashlib.sha1(json.dumps([name, sorted(k.items()), list(ref)]).encode()).hexdigest()
    path = RESULTS / "refs" / f"{key[:16]}.npy"
    if path.exists():
        return np.load(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = exact_run(load_scene(name, k), *ref, kernel=True)
    np.save(path, out)
    return out


def _rung_keys(rung):
    if rung == "nonlinear + preload":
        return {"plant.fidelity": "nonlinear", "plant.gravity_preload": True}
    return {"plant.fidelity": rung}


def _max(a):
    return float(np.max(a)) if len(a) else None


def measure(name, label, keys):
    """One case: the reference, the companion and the rungs' runs (without their own
    companion: ``fidelity.companion = false``; the figure is made here from the companion run
    once, as the job makes it), and what the fit and the check need."""
    t0 = time.perf_counter()
    ref = reference(name, keys)
    t_ref = time.perf_counter() - t0
    scene = load_scene(name, {**keys, "fidelity.companion": False})
    cs = ef.companion_scene(scene)
    comp = simulate(cs)
    ok = comp.completed and len(comp.result) == len(ref)
    P = ef.features(comp.result, cs, DAMPED) if len(comp.result) else None
    out = {"scene": name, "label": label, "keys": keys, "reference_time": t_ref,
           "companion": {"n_modes": cs.plant.params.n_modes, "step": cs.plant.step,
                         "completed": comp.completed,
                         "error": _max(np.abs(comp.result["phi_o"] - ref)) if ok else None,
                         "wall_time": comp.summary.get("wall_time"), "features": P,
                         "stable": comp.summary["stable"]},
           "rungs": {}}
    rungs = RUNGS if scene.plant.params.n_modes else RUNGS[:2]
    for rung in rungs:
        r = simulate(load_scene(name, {**keys, **_rung_keys(rung), "fidelity.companion": False}))
        entry = {"rung": rung_name(r.scene.plant), "completed": r.completed,
                 "stable": r.summary["stable"], "own": ef.own_companion(r.scene),
                 "wall_time": r.summary.get("wall_time")}
        if r.completed and len(r.result) == len(ref):
            entry["error"] = _max(np.abs(r.result["phi_o"] - ref))
            entry["max_abs_phi_o"] = _max(np.abs(r.result["phi_o"]))
            if ok:
                d = np.abs(r.result["phi_o"] - comp.result["phi_o"])
                entry["difference"] = _max(d)
                entry["growth"] = ef.growth_rate(r.result["time"], d, WINDOWS)
        entry["_run"], entry["_scene"] = r, r.scene
        out["rungs"][rung] = entry
    out["_companion"] = comp
    return out


def _minimax(X, E):
    """Nonnegative ``c`` with ``X c >= E`` and the smallest ``max(X c / E)``."""
    from scipy.optimize import linprog

    k = X.shape[1]
    A = np.vstack([np.hstack([-X, np.zeros((len(E), 1))]), np.hstack([X, -E[:, None]])])
    b = np.concatenate([-E, np.zeros(len(E))])
    res = linprog(np.r_[np.zeros(k), 1.0], A_ub=A, b_ub=b, bounds=[(0, None)] * (k + 1))
    if not res.success:
        raise RuntimeError(f"the floor's fit failed: {res.message}")
    return res.x[:k], float(res.x[k])


def _fitted(cases):
    """The grid cases the floor and kappa are fitted on: the loops that do not grow."""
    return [c for c in cases if c["companion"]["error"] is not None
            and c["companion"]["stable"] is not False
            and all(r["stable"] is not False for r in c["rungs"].values())]


def fit(grid_cases) -> dict:
    """The model: kappa, floor, range, growth rate (the module docstring)."""
    cases = _fitted(grid_cases)
    E = np.array([c["companion"]["error"] for c in cases])
    X = np.array([[ef.TERMS[k](c["companion"]["features"]) for k in FLOOR_TERMS]
                  for c in cases])
    coef, worst = _minimax(X, E)
    m = {"floor": {"terms": {k: float(v) for k, v in zip(FLOOR_TERMS, coef) if v > 0},
                   "safety": SAFETY, "largest_ratio": worst}}
    kappa, at = 1.0, None
    for c in cases:
        fl = ef.floor(c["companion"]["features"], m)
        for name, r in c["rungs"].items():
            if r.get("difference") and not r["own"] and r["difference"] >= fl \
                    and r["error"] / r["difference"] > kappa:
                kappa, at = r["error"] / r["difference"], f"{c['scene']} {c['label']}, {name}"
    m["kappa"] = kappa
    m["kappa_from"] = at
    feats = [c["companion"]["features"] for c in cases]
    m["range"] = {k: max(f[k] for f in feats) for k in ("A", "D", "W")}
    m["range"]["stiffness"] = min(f["stiffness"] for f in feats)
    m["range"]["margin"] = MARGIN
    rates = [r["growth"] for c in cases for r in c["rungs"].values()
             if r.get("growth") is not None and not r["own"]]
    growing = [r["growth"] for c in grid_cases if c not in cases
               for r in c["rungs"].values() if r.get("growth") is not None]
    m["growth"] = {"rate": max(0.0, max(rates)), "windows": WINDOWS,
                   "largest_measured": max(rates),
                   "growing": sorted(growing)}
    m["damped"] = DAMPED
    m["coupling"] = COUPLING
    return m


def check(cases, model_path) -> list:
    """Each case's rungs: the stated figure (or why none) against the measured error."""
    rows = []
    for c in cases:
        comp = c["_companion"]
        for rung, r in c["rungs"].items():
            f = ef.assess(r["_run"], r["_scene"], None if r["own"] else comp,
                          None if comp.completed else "it stopped", path=model_path)
            rows.append({"scene": c["scene"], "label": c["label"], "rung": rung,
                         "error": r.get("error"), "figure": f["figure"],
                         "ratio": (f["figure"] / r["error"] if f["figure"] is not None
                                   and r.get("error") else None),
                         "untrusted": f["untrusted"], "why": f["why"],
                         "companion_error": c["companion"]["error"],
                         "difference": f["difference"], "floor": f["floor"]})
    return rows


def _strip(cases):
    return [{**{k: v for k, v in c.items() if not k.startswith("_")},
             "rungs": {n: {k: v for k, v in r.items() if not k.startswith("_")}
                       for n, r in c["rungs"].items()}} for c in cases]


def table(rows, title):
    print(f"\n{title}: the stated figure / the measured error (x: no figure, why)")
    print(f"{'scene':20s} {'case':26s} {'S* err':>8s} " + " ".join(f"{r:>19s}" for r in RUNGS))
    by = {}
    for r in rows:
        by.setdefault((r["scene"], r["label"]), {})[r["rung"]] = r
    for (scene, label), rs in by.items():
        cerr = next(iter(rs.values()))["companion_error"]
        cells = []
        for rung in RUNGS:
            r = rs.get(rung)
            if r is None:
                cells.append(f"{'':>19s}")
            elif r["figure"] is None:
                cells.append(f"{'x ' + (r['untrusted'] or '?'):>19s}")
            else:
                cells.append(f"{r['error']:9.2e} {r['ratio']:5.2f}".rjust(19))
        print(f"{scene:20s} {label:26s} {(cerr or float('nan')):8.2e} " + " ".join(cells))
    ratios = [r["ratio"] for r in rows if r["ratio"] is not None]
    if ratios:
        print(f"  ratio: min {min(ratios):.2f}, median {np.median(ratios):.2f}, "
              f"max {max(ratios):.2f} over {len(ratios)} runs; "
              f"{sum(r['figure'] is None for r in rows)} without a figure")


def cross_check():
    """The reference's own error: the same at half the step, and on 32 elements, on five
    cases."""
    cases = [c for c in grid() if c[1] in ("undamped phi 0.05 gain 1", "undamped phi 0.524 gain 1",
                                           "kv phi 0.05 gain 1", "kv phi 0.524 gain 1")
             and c[0] != "rigid_pd"]
    cases += [c for c in off_grid() if c[1] == "kv EI 600"]
    out = []
    for name, label, keys in cases:
        ref = reference(name, keys)
        d = [float(np.max(np.abs(ref - reference(name, keys, other)))) for other in (CROSS, MESH)]
        out.append({"scene": name, "label": label, "half_step": d[0], "coarser_mesh": d[1]})
        print(f"  the reference against itself at {CROSS[1] * 1e3:g} ms / on {MESH[0]} elements: "
              f"{name} {label}: {d[0]:.2e} / {d[1]:.2e} rad", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--write", action="store_true", help="write orchestration/studies/"
                    "error_figure.json (every run reads it)")
    ap.add_argument("--cross-check", action="store_true")
    ap.add_argument("--json", help="also write the cases and the tables here")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    t0 = time.perf_counter()
    measured = RESULTS / "measured.json"
    print(f"grid: {len(grid())} cases; off the grid: {len(off_grid())}", flush=True)
    g = []
    for name, label, keys in grid():
        g.append(measure(name, label, keys))
        c = g[-1]
        print(f"  grid {name:20s} {label:26s} S{c['companion']['n_modes']} "
              f"{c['companion']['error'] or float('nan'):.2e}", flush=True)
    model = fit(g)
    model.update(command="python3 bench/error_figure.py --write",
                 date=datetime.date.today().isoformat(),
                 reference={"method": "monolithic exact loop, Radau IIA", "elements": REF[0],
                            "step": REF[1]})
    path = ef.FIGURE_FILE if a.write else RESULTS / "error_figure.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(model, indent=1) + "\n")
    ef._load.cache_clear()
    print(f"\nkappa = {model['kappa']:.3f}; floor = {model['floor']['safety']:g} x ("
          + " + ".join(f"{v:.3g} {k}" for k, v in model["floor"]["terms"].items())
          + f") (its largest ratio to the companion's error on the grid: "
          f"{model['floor']['largest_ratio']:.2f}); kappa from {model['kappa_from']}; "
          f"growth beyond a t^2 build-up: {model['growth']['rate']:.3g} 1/s (the grid's stable "
          f"loops at most {model['growth']['largest_measured']:+.3g}; flexible_pd's rungs "
          + ", ".join(f"{x:+.2f}" for x in model["growth"]["growing"])
          + f"); written to {path}")
    grid_rows = check(g, path)
    table(grid_rows, "The grid (fitted on)")
    o = []
    for name, label, keys in off_grid():
        o.append(measure(name, label, keys))
    off_rows = check(o, path)
    table(off_rows, "Off the grid (not fitted on)")
    cost = [(c["scene"], c["label"], c["companion"]["wall_time"]) for c in o
            if "paper scene" in c["label"]]
    for scene, label, w in cost:
        print(f"  the companion's cost, {scene} ({label}): {w:.3g} s (the master's wall time)")
    cross = cross_check() if a.cross_check else []
    RESULTS.mkdir(parents=True, exist_ok=True)
    measured.write_text(json.dumps({"grid": _strip(g), "off_grid": _strip(o)}, indent=1))
    if a.json:
        Path(a.json).write_text(json.dumps({"model": model, "grid": grid_rows,
                                            "off_grid": off_rows, "cross_check": cross},
                                           indent=1))
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
