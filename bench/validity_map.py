"""The validity map: each rung of the fidelity ladder against the exact rung, over the paper
scenes and a sweep of initial angles and gains; the fitted bound written as reference data
(``orchestration/studies/validity_bound.json``, read by every run's summary:
:mod:`orchestration.studies.validity`).

Cases: each paper scene (``rigid_pd``, ``flexible_pd``, ``flexible_pd_lowpass``) from the initial
angles :data:`ANGLES` with the PD gains ``kp`` and ``kd`` scaled together by :data:`GAINS`; 3 s
each (``flexible_pd``: its own 2.5 s; the largest error of the stable scenes falls within the
first 2 s: the same to three digits over 10 s). The held-out case of each scene
(:data:`HELD_OUT`) is measured but not fitted: it checks the bound on a point it was not made from.

Rungs (:data:`RUNGS`; add one there and rerun): each by the monolithic closed loop
(:func:`orchestration.studies.reference.simulate_reference`, DOP853, rtol = atol = 1e-10) with
the scene's own beam (``rigid_pd``: the rigid model, ``n_modes = 0``, on its stiff beam; the others
4 modes). The exact rung: the C kernel (:func:`orchestration.studies.exact_loop.exact_run`) at
:data:`FINE` (16 elements, h = 50 us) as the reference; the same at :data:`COARSE` (8 elements,
h = 0.1 ms) gives its uncertainty (the coarse-fine difference, which bounds the fine run's error
when the method converges; both are quoted), added to every measured error.

Damping laws (docs/model.md section 7), named: the exact reference damps by material, Kelvin-Voigt
with the scene's ``zeta`` (:data:`EXACT_LAW`: its own law, the only one it takes with damping);
the rungs run under ``--law`` (:data:`LAW`): ``modal`` (the paper's reading and the product's
default), as ``validity_bound.json`` was measured, so that its errors include the two laws'
difference above the first cantilever mode (largest on ``flexible_pd``, whose bending root grows
at +1.64/s under the modal law and +1.21/s under Kelvin-Voigt); or ``kelvin-voigt``, the same law
on both sides. The output records both (``damping``).

At every output time: the error's running maximum ``E`` and the rung's features
(:func:`orchestration.studies.validity.features`: the running maxima ``D``, ``W``, ``A`` of the
tip deflection, ``|omega_o|`` and ``|phi_o|``, ``T`` of the deflection times the time, the
accumulated deflection ``I`` and the deflection's travel ``V``). A case whose exact-rung
uncertainty is more than :data:`RESOLVED` of the rung's error is left out (none is, today). Fit
per rung: the nonnegative combination of the terms :data:`TERM_SET` that bounds every fitted
point with the least sum of ``bound / E`` (``scipy.optimize.linprog``), times :data:`SAFETY`;
``floor`` the exact rung's largest uncertainty on the stable scenes (:data:`STABLE`). The script
also prints, per rung, the median of ``E / bound`` (the bound's looseness) with other term sets
(:data:`ALTERNATIVES`: without ``T``; the axial load factor ``N``, the running maximum of
``(|g cos phi_o + L/2 omega_o^2| + |x_ddot|) / g``, in place of the rate), and for each paper
scene from pi/6 the error of each rung, its bound and the monolithic solve's cost.

    python3 bench/validity_map.py [--processes 2] [--out orchestration/studies/validity_bound.json]
                                  [--law modal|kelvin-voigt]
    python3 bench/validity_map.py --refit   # fit the last run's cases again (bench/results/)

Measured (2026-11-26, 2 processes on a shared, loaded machine: 4 to 6.5 min):

    rung                 bound (rad)                        E/bound: median  max  held-out
    linear               1.78 T + 0.00396 V + 4.17 A3                0.419  0.667  0.602
    linear + preload     1.14 T + 4.36 A3                            0.441  0.667  0.588
    nonlinear            1.48 T + 8.58e-05 W                         0.268  0.667  0.406
    nonlinear + preload  1.67 T                                      0.160  0.667  0.339
    rigid linear         3.69 A3                                     0.543  0.667  0.579
    rigid nonlinear      7.38e-05 W + 2.18e-05 A + 0.000314 A3       0.643  0.667  0.658
    (median E/bound without T: nonlinear 0.139, + preload 0.078; with N for W: 0.273, 0.160)

    scene (pi/6)         rung                 error (rad)  bound    exact rung's uncertainty
    rigid_pd             rigid nonlinear      2.53e-04     3.92e-04 3.6e-06
    flexible_pd          nonlinear            1.07e-01     3.68e-01 6.9e-04
    flexible_pd          nonlinear + preload  1.58e-01     4.20e-01
    flexible_pd_lowpass  nonlinear            1.08e-03     8.25e-03 7.9e-06
    flexible_pd_lowpass  nonlinear + preload  1.06e-03     8.88e-03

The floor is 9.0e-6 rad; the exact rung's largest uncertainty, 5.8e-2 rad, is on ``flexible_pd``
at 1.4 times its gains, where the bending grows fastest (the rungs' errors there are larger still).
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.exact_loop import exact_run  # noqa: E402
from orchestration.studies.reference import simulate_reference  # noqa: E402
from orchestration.studies.validity import (BOUND_FILE, RANGE, cantilever_frequency,  # noqa: E402
                                            features, rung_name, term)

SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
ANGLES = (0.05, 0.2, 0.35, math.pi / 6)
GAINS = (0.7, 1.0, 1.4)
#: Per scene, the (angle, gain) measured but left out of the fit.
HELD_OUT = (0.35, 1.0)
#: The rungs: (plant.fidelity, plant.gravity_preload). The rigid scene runs each fidelity without
#: modes (the preload has no meaning there). A new rung (a plant.fidelity value that
#: simulate_reference solves) is measured by adding it here and rerunning the script.
RUNGS = (("linear", False), ("nonlinear", False), ("linear", True), ("nonlinear", True),
         ("stiffened", False))
#: The exact rung: (elements, step) of the reference and of its uncertainty estimate.
FINE, COARSE = (16, 5e-5), (8, 1e-4)
STOP = 3.0
RTOL = ATOL = 1e-10
#: The bound's margin over the largest measured ratio.
SAFETY = 1.5
#: A case is left out of a rung's fit (and of its measured range) when the exact rung's own
#: uncertainty is more than this fraction of the rung's error: the reference does not resolve it.
RESOLVED = 0.25
#: The scenes whose loop is stable: the exact rung's largest uncertainty over their cases is the
#: bound's floor (no smaller error is claimed than the reference resolves).
STABLE = ("rigid_pd", "flexible_pd_lowpass")
#: The bound's terms (orchestration.studies.validity.TERMS), and other sets whose looseness is
#: printed beside it: without T (and V); the axial load factor N for the rate.
TERM_SET = ("D", "T", "I", "V", "W", "A", "A3")
ALTERNATIVES = {"without T": ("D", "I", "V", "W", "A", "A3"),
                "without T, V": ("D", "I", "W", "A", "A3"),
                "N for W": ("D", "T", "I", "V", "N", "A", "A3")}
#: Points kept per case and rung (evenly in time, plus the last).
POINTS = 24
#: The damping law of the exact reference (its own) and, by default, of the rungs (see above).
EXACT_LAW = "kelvin-voigt"
LAW = "modal"


def case_scene(name, phi0, gain, overrides=()):
    base = load_scene(name)
    c = base.controller
    values = {"initial.phi": phi0, "controller.kp": c.kp * gain, "controller.kd": c.kd * gain,
              "stop_time": min(STOP, base.output.stop_time)}
    values.update(overrides)
    return load_scene(name, values)


def run_case(case, law=LAW):
    """One case: the exact reference (under :data:`EXACT_LAW`) and every rung's points (under
    ``law``)."""
    name, phi0, gain = case
    sc = case_scene(name, phi0, gain, {"plant.damping": law})
    ex = case_scene(name, phi0, gain, {"plant.damping": EXACT_LAW})
    fine = exact_run(ex, *FINE, kernel=True)
    t0 = time.perf_counter()
    coarse = exact_run(ex, *COARSE, kernel=True)
    exact_cost = time.perf_counter() - t0           # the coarse one: the rung as one would run it
    u = np.maximum.accumulate(np.abs(fine - coarse))
    L = sc.plant.params.L
    n_out = len(fine)
    keep = np.unique(np.r_[np.linspace(0, n_out - 1, POINTS).astype(int), n_out - 1])
    rungs = {}
    for fid, pre in RUNGS:
        if name == "rigid_pd" and pre:
            continue
        r_sc = case_scene(name, phi0, gain, {"plant.fidelity": fid,
                                             "plant.gravity_preload": pre,
                                             "plant.damping": law})
        t1 = time.perf_counter()
        try:
            r = simulate_reference(r_sc, rtol=RTOL, atol=ATOL)
        except RuntimeError as exc:
            print(f"  {name} {phi0:.3g} x{gain:g} {fid}{' + preload' if pre else ''}: {exc}")
            continue
        cost = time.perf_counter() - t1
        if len(r) != n_out:
            continue
        E = np.maximum.accumulate(np.abs(r["phi_o"] - fine)) + u
        feats = features(r, L)
        acc = np.gradient(r["x_dot"], r["time"])
        g = sc.plant.params.g
        feats["N"] = np.maximum.accumulate(
            np.abs(g * np.cos(r["phi_o"]) + 0.5 * L * r["omega_o"] ** 2) + np.abs(acc)) / g
        rungs[rung_name(r_sc.plant)] = {
            "E": E[keep].tolist(), **{k: v[keep].tolist() for k, v in feats.items()},
            "cost": cost / sc.output.stop_time, "uncertainty": float(u[-1])}
    return {"case": [name, phi0, gain], "damping": {"rungs": law, "exact": EXACT_LAW},
            "uncertainty": float(u[-1]),
            "exact_cost": exact_cost / sc.output.stop_time, "duration": sc.output.stop_time,
            "first_cantilever_frequency": cantilever_frequency(sc.plant.params), "rungs": rungs}


def design(P: dict, names) -> np.ndarray:
    """The columns of the named terms (:data:`orchestration.studies.validity.TERMS`)."""
    return np.column_stack([term(P, k) for k in names])


def fit(P: dict, floor: float, names) -> dict:
    """The tightest bound ``sum c_k term_k >= E`` (``c_k >= 0``) at every point above the floor,
    by linear programming (minimise the sum of ``bound / E``), times :data:`SAFETY`."""
    from scipy.optimize import linprog

    E = np.asarray(P["E"])
    ok = E > floor
    X = design(P, names)[ok]
    res = linprog((X / E[ok, None]).sum(axis=0), A_ub=-X, b_ub=-E[ok], bounds=(0, None),
                  method="highs")
    if not res.success:
        raise RuntimeError(f"the bound's fit failed: {res.message}")
    terms = {k: float(SAFETY * c) for k, c in zip(names, res.x) if c > 0}
    return {"floor": floor, "terms": terms}


def evaluate(model, P: dict) -> np.ndarray:
    """The model at the points (the same formula as RungBound, written out here)."""
    f = sum(c * term(P, k) for k, c in model["terms"].items())
    return np.maximum(model["floor"], f)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--out", default=str(BOUND_FILE))
    ap.add_argument("--raw", default=str(ROOT / "bench" / "results" / "validity_map.json"),
                    help="the measured cases (written; read back by --refit)")
    ap.add_argument("--refit", action="store_true", help="fit the cases measured before")
    ap.add_argument("--law", choices=("modal", "kelvin-voigt"), default=LAW,
                    help=f"the rungs' damping law (the exact reference's: {EXACT_LAW})")
    args = ap.parse_args(argv)
    cases = [(n, a, g) for n in SCENES for a in ANGLES for g in GAINS]
    print(f"{len(cases)} cases x {len(RUNGS)} rungs; exact rung: {FINE[0]} elements at h = "
          f"{FINE[1]:g} s, its uncertainty against {COARSE[0]} at {COARSE[1]:g} s", flush=True)
    t0 = time.perf_counter()
    raw = Path(args.raw)
    if args.refit:
        results = json.loads(raw.read_text(encoding="utf-8"))
    else:
        results = measure(cases, args.processes, t0, args.law)
        raw.parent.mkdir(parents=True, exist_ok=True)
        raw.with_suffix(".tmp").write_text(json.dumps(results), encoding="utf-8")
        raw.with_suffix(".tmp").replace(raw)
    write_bound(results, args.out, t0)


def measure(cases, processes, t0, law=LAW):
    import functools

    results = []
    one = functools.partial(run_case, law=law)
    if processes > 1:
        import multiprocessing as mp
        with mp.get_context("spawn").Pool(processes) as pool:
            for i, r in enumerate(pool.imap_unordered(one, cases), 1):
                results.append(r)
                print(f"  [{i}/{len(cases)}] {r['case'][0]} phi0 = {r['case'][1]:.3g} gain "
                      f"x{r['case'][2]:g}: exact uncertainty {r['uncertainty']:.1e} rad "
                      f"({time.perf_counter() - t0:.0f} s)", flush=True)
    else:
        for i, c in enumerate(cases, 1):
            results.append(one(c))
            print(f"  [{i}/{len(cases)}] {c[0]} phi0 = {c[1]:.3g} gain x{c[2]:g}: exact "
                  f"uncertainty {results[-1]['uncertainty']:.1e} rad "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
    return results


def point_rows(P: dict) -> list:
    """The points as rows (the features of RANGE, then E), to 4 significant digits (the bound's
    margin over them is SAFETY, far above the rounding), a row equal to the one before left out."""
    out = []
    for row in zip(*(P[k] for k in (*RANGE, "E"))):
        row = [float(f"{v:.4g}") for v in row]
        if not out or row != out[-1]:
            out.append(row)
    return out


def dumps(out: dict) -> str:
    """JSON, indented, each innermost list on one line."""
    import re
    text = json.dumps(out, indent=1)
    return re.sub(r"\[\s+([^\[\]{}]+?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]",
                  text) + "\n"


def stack(cases) -> dict:
    """The points of several cases, column by column."""
    keys = (*RANGE, "E", "N")
    return {k: np.concatenate([np.asarray(c[k], float) for c in cases]) if cases
            else np.zeros(0) for k in keys}


def write_bound(results, path, t0):
    results.sort(key=lambda r: (SCENES.index(r["case"][0]), r["case"][1], r["case"][2]))
    names = sorted({k for r in results for k in r["rungs"]})
    out = {"command": "python3 bench/validity_map.py",
           "date": datetime.date.today().isoformat(),
           "form": "E <= max(floor, sum c_k term_k) rad (orchestration/studies/validity.py "
                   "TERMS); E the running maximum of the tip-angle error against the exact rung "
                   "plus the exact rung's uncertainty; points [" + ", ".join(RANGE) + ", E]",
           "exact_rung": {"reference": {"elements": FINE[0], "step": FINE[1]},
                          "uncertainty_against": {"elements": COARSE[0], "step": COARSE[1]},
                          "largest_uncertainty": max(r["uncertainty"] for r in results)},
           "damping": results[0].get("damping", {"rungs": LAW, "exact": EXACT_LAW}),
           "sweep": {"scenes": list(SCENES), "angles": list(ANGLES), "gains": list(GAINS),
                     "held_out": list(HELD_OUT), "stop_time": STOP, "safety": SAFETY},
           "rungs": {}, "scenes": {}}
    print(f"\nfloor {max(r['uncertainty'] for r in results if r['case'][0] in STABLE):.2g} rad; "
          f"E/bound at the fitted points (median, max), at the held-out case (max); the median "
          f"with other predictors: {', '.join(ALTERNATIVES)}")
    print(f"{'rung':<20} {'bound (rad)':<44} {'median':>6} {'max':>5} {'held-out':>8}")
    for name in names:
        fitted, held, unresolved = [], [], []
        for r in results:
            if name not in r["rungs"]:
                continue
            v = r["rungs"][name]
            if v["uncertainty"] > RESOLVED * (v["E"][-1] - v["uncertainty"]):
                unresolved.append(r["case"])
                continue
            (held if tuple(r["case"][1:]) == HELD_OUT else fitted).append(v)
        F, H = stack(fitted), stack(held)
        floor = float(max(r["uncertainty"] for r in results if r["case"][0] in STABLE))
        model = fit(F, floor, TERM_SET)
        ratio = F["E"] / evaluate(model, F)
        held_ratio = H["E"] / evaluate(model, H) if len(H["E"]) else np.zeros(1)
        loose = {label: float(np.median((F["E"] / evaluate(fit(F, floor, terms), F))[
            F["E"] > floor])) for label, terms in ALTERNATIVES.items()}
        P = stack(fitted + held)
        covered = [r["first_cantilever_frequency"] for r in results if name in r["rungs"]]
        out["rungs"][name] = {
            "model": model,
            "range": {**{k: float(np.max(P[k])) for k in RANGE},
                      "first_cantilever_frequency": float(min(covered))},
            "fit_points": point_rows(F), "held_out_points": point_rows(H),
            "looseness": {"median": float(np.median(ratio[F["E"] > floor])),
                          "max": float(ratio.max()), "held_out_max": float(held_ratio.max())},
            "other_predictors": loose,
            "unresolved_cases": unresolved,
            "cost": float(np.median([r["rungs"][name]["cost"] for r in results
                                     if name in r["rungs"]]))}
        terms = " + ".join(f"{c:.3g} {k}" for k, c in model["terms"].items())
        print(f"{name:<20} {terms:<44} {np.median(ratio[F['E'] > floor]):6.3f} "
              f"{ratio.max():5.3f} {held_ratio.max():8.3f}   "
              + "  ".join(f"{v:.3f}" for v in loose.values())
              + (f"  unresolved: {unresolved}" if unresolved else ""))
        print(f"{'':<20} range: " + ", ".join(f"{k} {np.max(P[k]):.3g}" for k in RANGE))
    print(f"\n{'scene':<20} {'rung':<18} {'error (rad)':>11} {'bound':>9} {'D':>7} {'W':>7} "
          f"{'cost s/s':>9}")
    for name in SCENES:
        paper = next(r for r in results if r["case"] == [name, math.pi / 6, 1.0])
        rows = {}
        for rung, v in paper["rungs"].items():
            last = {k: np.asarray(v[k][-1:]) for k in (*RANGE, "E", "N")}
            bound = float(evaluate(out["rungs"][rung]["model"], last)[0])
            E, D, W = v["E"][-1], v["D"][-1], v["W"][-1]
            rows[rung] = {"error": E - v["uncertainty"], "uncertainty": v["uncertainty"],
                          "bound": bound, "deflection": D, "rate": W, "cost": v["cost"]}
            print(f"{name:<20} {rung:<18} {E - v['uncertainty']:11.2e} {bound:9.2e} {D:7.3%} "
                  f"{W:7.3g} {v['cost']:9.3g}")
        rows["exact"] = {"uncertainty": paper["uncertainty"], "cost": paper["exact_cost"]}
        print(f"{name:<20} {'exact (8+16 el.)':<18} {paper['uncertainty']:11.1e} (its own "
              f"uncertainty){'':>12} {paper['exact_cost']:9.3g}")
        out["scenes"][name] = rows
    tmp = Path(path).with_suffix(".tmp")
    tmp.write_text(dumps(out), encoding="utf-8")
    tmp.replace(path)
    print(f"\nwrote {path} ({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
