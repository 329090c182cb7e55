"""The native FMUs' targets (issue 15), each measured side by side in one run.

    python bench/bench_native.py [--runs 5] [--quick] [--json bench/results/native.json]

* **T4.** At n_modes = 4 and a 1 ms communication step (the scene's coupling: Gauss-Seidel,
  quadratic extrapolation, input derivatives), the cost per macro step on our fmpy master of the
  native pair, of the pythonfmu pair and of two trivial native FMUs (the same generic FMI layer,
  the same interfaces, a step that copies an input: the floor of FMI and the master). The native
  pairs run on the master's compiled loop (``master.compiled = auto``) and, beside it, on its
  Python loop (``master.compiled = false``). The cost per macro step is that of the steps
  alone: the difference of a 20 s run's and a 4 ms run's times over the difference of their
  steps (the run's fixed cost left out).
  Target: native at most 10 us per macro step on a quiet machine, and within 2x of the floor.
* **T5.** The 10 s filtered scene at a tip-angle error of 1e-5 rad or less: the fastest native
  co-simulation setting (past samples' or output derivatives' extrapolation, or the Hermite
  coupling, all on the compiled loop) against the fastest ``solve_ivp`` method at equal error (its cheapest
  setting whose error is at most the co-simulation's; target: at least 5x faster), and against a
  compiled monolithic RK4 of the same closed-loop ODE built from the C kernel
  (``bench/native/monolithic_rk4.c``; the physical limit on one core: issue 39 wants at most
  1.5x) at equal error: the RK4 steps are the 2 ms output grid over 1, 2, 3... steps, and the
  RK4 curve (time against error, log-log) is interpolated to the co-simulation's error between
  the two RK4 points that bracket it; the largest RK4 step whose error is at most the
  co-simulation's is given too (a bound: its error is lower). Every co-simulation point of at
  most 1e-5 rad is compared so with the RK4 at its own error, all of them and the RK4 points
  timed again side by side in alternated rounds (T5's figure: the fastest point's row). The
  ratio depends on the error (below the fastest point, more plant substeps per macro step share
  the macro step's own cost), and it is given twice: with the co-simulation's initialisation,
  and stepping against stepping (less a run of one output interval, scaled to the horizon: the
  RK4's clock starts after its setup). The Hermite points' times per macro step, a line over
  their plant substeps, split what a substep costs from the rest.
* **C host.** The plain C host of the tests (``tests/native/fmi2_host.c``, Jacobi, held inputs)
  over the native pair: its time per macro step.

Times are medians of ``--runs`` runs after a warm-up; T4's loops and T5's side-by-side points
alternate, so that the machine's load falls on both sides of those ratios (T5's ratios against
``solve_ivp`` and against the largest RK4 step divide medians taken one point after the other);
errors against the monolithic reference (DOP853 at 1e-12). T5's co-simulation times include its
initialisation (about 0.3 ms), the RK4's its stepping loop only. ``--quick`` tries fewer settings (what the README's figures used on a loaded machine
is said there).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import (RESULTS, ROOT, CoSim, alternating_medians, load_scene,  # noqa: E402
                    median_time, phi_error, reference, trivial_native_fmus)
from targets import ivp_points  # noqa: E402

from orchestration.export import build_fmus, fmu_pair  # noqa: E402
from fmu_common import kernels
from orchestration.export import native_fmus  # noqa: E402

SCENE = "flexible_pd_lowpass"
T5_CANDIDATES = {          # the output grid (2 ms) must be a multiple of the step
    "H=2ms, plant step 5e-4, Hermite, plant first": [
        "master.step=2e-3", "plant.step=5e-4", "master.coupling=hermite", "master.first=plant"],
    "H=2ms, plant step 6.67e-4, Hermite, plant first": [
        "master.step=2e-3", f"plant.step={2e-3 / 3!r}", "master.coupling=hermite",
        "master.first=plant"],
    "H=2ms, plant step 4e-4, Hermite, plant first": [
        "master.step=2e-3", "plant.step=4e-4", "master.coupling=hermite", "master.first=plant"],
    "H=2ms, plant step 3.33e-4, Hermite, plant first": [
        "master.step=2e-3", f"plant.step={2e-3 / 6!r}", "master.coupling=hermite",
        "master.first=plant"],
    "H=1ms, plant step 5e-4, output derivatives": ["master.step=1e-3", "plant.step=5e-4",
                                                   "master.output_derivatives=true"],
    "H=2ms, plant step 5e-4, output derivatives": ["master.step=2e-3", "plant.step=5e-4",
                                                   "master.output_derivatives=true"],
    "H=1ms, plant step 5e-4": ["master.step=1e-3", "plant.step=5e-4"],
    "H=2ms, output derivatives": ["master.step=2e-3", "master.output_derivatives=true"],
    "H=2ms, plant step 1e-3": ["master.step=2e-3", "plant.step=1e-3"],
    "H=2ms, plant step 5e-4": ["master.step=2e-3", "plant.step=5e-4"],
    "H=2ms (the scene's)": ["master.step=2e-3"],
    "H=1ms": ["master.step=1e-3"],
}
#: The RK4 steps tried: the 2 ms output grid divided into 1, 2, ... steps, up to this many.
RK4_MAX_DIVISIONS = 40


# ---------------------------------------------------------------------- T4
T4_COUPLINGS = {
    "zero-order hold, Jacobi (the FMI floor)": ["master.extrapolation=0",
                                                "master.input_derivatives=false",
                                                "master.algorithm=jacobi"],
    "the scene's: Gauss-Seidel, quadratic, input derivatives": [],
}


def t4(runs: int, native, python, trivial, log) -> dict:
    return {label: _t4(runs, native, python, trivial, log, label, sets)
            for label, sets in T4_COUPLINGS.items()}


#: T4's two horizons: the cost per macro step is the difference of their run times over the
#: difference of their steps, so that the run's fixed cost (instantiation, initialisation, the
#: output table) does not count (spread over the long run's 2000 steps, it was 20 to 40 % of
#: the figure until 2026-11-29); 20,000 steps, so that the floor (a few ms) is far above the
#: noise of the two times.
T4_STOP_TIMES = (0.004, 20.0)


def _t4(runs, native, python, trivial, log, label, sets) -> dict:
    log(f"T4  coupling: {label}")
    kinds = {"native": (native, False, False), "native, Python loop": (native, False, True),
             "pythonfmu": (python, False, False), "trivial native": (trivial, True, False),
             "trivial, Python loop": (trivial, True, True)}
    loops = {}
    for k, (fmus, trivial_fmus, python_loop) in kinds.items():
        for stop in T4_STOP_TIMES:
            ov = ["plant.n_modes=4", "master.step=1e-3", f"stop_time={stop!r}", *sets]
            if python_loop:
                ov.append("master.compiled=false")
            loops[k, stop] = CoSim(load_scene(SCENE, ov), fmus, trivial=trivial_fmus)
    for loop in loops.values():
        loop.run()                                   # warm-up
    wall = {key: [] for key in loops}
    steps = {}
    for _ in range(runs):
        for key, loop in loops.items():
            _, stats = loop.run()
            wall[key].append(stats.wall_time)
            steps[key] = stats.steps
    short, long_ = T4_STOP_TIMES
    med, per = {}, {}
    for k in kinds:
        n = steps[k, long_] - steps[k, short]
        per[k] = [(a - b) / n * 1e6 for a, b in zip(wall[k, long_], wall[k, short])]
        med[k] = ((statistics.median(wall[k, long_]) - statistics.median(wall[k, short])) / n
                  * 1e6)
    for k, v in med.items():
        log(f"T4  {k:20s} {v:7.2f} us per macro step")
    ratio = med["native"] / med["trivial native"]
    log(f"T4  native / trivial native = {ratio:.2f} (limit 2), native / pythonfmu = "
        f"{med['native'] / med['pythonfmu']:.3f}, compiled / Python loop = "
        f"{med['native'] / med['native, Python loop']:.3f}")
    return {"target": "T4", "us_per_step": med, "runs": per, "ratio_to_floor": ratio,
            "met_floor": ratio <= 2.0, "met_10us": med["native"] <= 10.0}


# ---------------------------------------------------------------------- T5
def monolithic_rk4_binary(folder: Path) -> Path:
    exe = folder / "monolithic_rk4"
    native = kernels.native_dir("flexpend_plant")
    # the FMUs' optimisation (native_fmus.FMU_CFLAGS: link-time), so that neither side of T5 is
    # compiled better than the other
    cmd = [kernels.find_compiler(), "-std=gnu99", "-O2", "-ffp-contract=off", "-DFP_API=",
           *native_fmus.FMU_CFLAGS,
           f"-I{native}", "-o", str(exe), str(ROOT / "bench" / "native" / "monolithic_rk4.c"),
           str(native / "fp_plant.c"), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return exe


def rk4_input(scene, h: float) -> str:
    from plant_fmu.dynamics import plant_model
    m = plant_model(scene.plant.params)
    c = scene.controller
    if c.filter_order != 2:
        raise ValueError("the monolithic RK4 bench takes a 2nd-order filter")
    nums = [m.n, 0, int(m.preload), m.I0, m.I1, m.I2, m.g, *m.I3, *m.I5, *m.Kdiag, *m.Ddiag,
            *m.tip_slope, *m.tip_defl, *np.asarray(m.Kg).ravel(), c.kp, c.kd, c.kx, c.cutoff,
            c.filter_damping, c.force_limit, scene.initial.x, scene.initial.phi,
            scene.initial.x_dot, scene.initial.phi_dot, h, scene.output.stop_time,
            scene.output.output_interval]
    return " ".join(repr(float(x)) if not isinstance(x, int) else str(x) for x in nums)


# A point's ``_run`` is timed again later (side_by_side): each is made by a function of its own,
# so that it keeps its own co-simulation or RK4 input (a closure in the loop would see the loop's
# last one: the side-by-side rounds timed the last candidate and the finest RK4 step until
# 2026-11-29).
def _rk4_run(exe, stdin: str):
    """``run() -> (seconds, tip angles)`` of the monolithic RK4 binary on ``stdin``."""
    def run():
        proc = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True,
                              check=True)
        vals = [float(x) for x in proc.stdout.split()]
        return vals[0], np.array(vals[1:])
    return run


def _cosim_run(cosim):
    """``run() -> (seconds, results)`` of the co-simulation ``cosim``."""
    def run():
        res, stats = cosim.run()
        return stats.wall_time, res
    return run


def rk4_points(runs, exe, scene, ref, log, max_error: float) -> list:
    """RK4 at the steps ``grid / k``, k = 1, 2, ..., until its error is at most ``max_error``
    (the last point is then the cheapest RK4 of that error: the error falls as h^4)."""
    out = []
    grid = scene.output.output_interval
    for k in range(1, RK4_MAX_DIVISIONS + 1):
        h = grid / k
        run = _rk4_run(exe, rk4_input(scene, h))
        med, times, phi = median_time(run, runs)
        err = float(np.max(np.abs(phi - ref["phi_o"]))) if phi.size == len(ref) else np.inf
        if not np.isfinite(err):
            err = np.inf
        out.append({"family": "monolithic RK4 (C)", "setting": f"h={h:.4g}", "seconds": med,
                    "error": err, "all_seconds": times, "_run": run, "h": h})
        log(f"  monolithic RK4 (C) h={h:<8.4g} error {err:9.2e}  {med:8.4f} s")
        if err <= max_error:
            break
    return out


def cosim_points(runs, fmus, ref, log, candidates) -> list:
    out = []
    for label, overrides in candidates.items():
        run = _cosim_run(CoSim(load_scene(SCENE, overrides), fmus))
        med, times, res = median_time(run, runs)
        err = phi_error(res, ref)
        out.append({"family": "native co-simulation", "setting": label, "seconds": med,
                    "error": err, "all_seconds": times, "_run": run, "_fmus": fmus})
        log(f"  native co-simulation {label:52s} error {err:9.2e}  {med:7.3f} s")
    return out


def time_at_error(points, error):
    """The time of the curve ``points`` (their errors and times, log-log, linear between
    neighbours in error) at ``error``; None when no two points bracket it."""
    pts = sorted((p["error"], p["seconds"]) for p in points
                 if np.isfinite(p["error"]) and p["error"] > 0)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:]):
        if e0 <= error <= e1:
            if e1 == e0:
                return t0
            s = (np.log(error) - np.log(e0)) / (np.log(e1) - np.log(e0))
            return float(np.exp(np.log(t0) + s * (np.log(t1) - np.log(t0))))
    return None


def bracket(points, error) -> list:
    """The two points of ``points`` whose errors bracket ``error`` most tightly (fewer when
    none do)."""
    finite = sorted((p for p in points if np.isfinite(p["error"]) and p["error"] > 0),
                    key=lambda p: p["error"])
    for a, b in zip(finite, finite[1:]):
        if a["error"] <= error <= b["error"]:
            return [a, b]
    return []


def side_by_side(points, runs: int) -> list:
    """Median seconds of each of ``points`` timed again in ``runs`` rounds that alternate them
    (one warm-up call each first), so that the machine's load falls on all of them."""
    med = alternating_medians({i: p["_run"] for i, p in enumerate(points)}, runs)
    return [med[i][0] for i in range(len(points))]


def fastest(points, max_error=1e-5):
    ok = [p for p in points if p["error"] <= max_error]
    return min(ok, key=lambda p: p["seconds"]) if ok else None


def t5(runs, native, log, quick) -> dict:
    scene = load_scene(SCENE)
    ref = reference(scene)
    cands = dict(list(T5_CANDIDATES.items())[:7]) if quick else T5_CANDIDATES
    co = cosim_points(runs, native, ref, log, cands)
    c = fastest(co)
    ivp = ivp_points(max(1, runs // 2) if quick else runs, scene, ref, log)
    i = fastest(ivp, c["error"] if c else 1e-5)
    res = {"target": "T5", "native": c, "solve_ivp": i}
    if c and i:
        res["speedup_vs_solve_ivp"] = i["seconds"] / c["seconds"]
        log(f"T5  native {c['setting']}: {c['error']:.2e} rad in {c['seconds']:.4f} s; fastest "
            f"solve_ivp {i['setting']}: {i['error']:.2e} in {i['seconds']:.4f} s -> "
            f"{res['speedup_vs_solve_ivp']:.1f}x (target >= 5)")
    ok = [p for p in co if p["error"] <= 1e-5]
    with tempfile.TemporaryDirectory() as tmp:
        exe = monolithic_rk4_binary(Path(tmp))
        rk = rk4_points(runs, exe, scene, ref, log,
                        min(p["error"] for p in ok) if ok else 1e-5)
        res.update(rk4_ratio(c, rk, log))
        res.update(rk4_ratios(runs, c, ok, rk, log, scene.output.stop_time))
    res["points"] = co + rk + ivp
    for p in res["points"]:
        p.pop("_run", None)
        p.pop("_fmus", None)
    return res


def rk4_ratio(c, rk, log) -> dict:
    """The co-simulation point ``c`` against the largest RK4 step of at most its error (a lower
    bound of the ratio at equal error; :func:`rk4_ratios` gives the ratio itself)."""
    r = fastest(rk, c["error"]) if c else None
    res = {"monolithic_rk4": r}
    if not (c and r):
        return res
    res["ratio_to_monolithic_rk4_step"] = c["seconds"] / r["seconds"]
    log(f"T5  monolithic RK4 (C), largest step at most as large an error, {r['setting']}: "
        f"{r['error']:.2e} in {r['seconds']:.4f} s -> native co-simulation / RK4 = "
        f"{res['ratio_to_monolithic_rk4_step']:.2f} (a lower bound of the ratio at equal error: "
        f"that RK4 is {c['error'] / r['error']:.3g} times as accurate; T5's figure is the "
        f"side-by-side one below)")
    return res


def rk4_ratios(runs, c, ok, rk, log, stop: float) -> dict:
    """Every co-simulation point ``ok`` (error at most 1e-5 rad) against the RK4 curve ``rk`` at
    its error: all of them and the RK4 points timed again side by side in alternated rounds, the
    RK4 curve interpolated (log-log) between the two RK4 points that bracket each error. The
    ratio of T5 is a function of the error: the fastest point (``c``) is the one a user after
    1e-5 would run; below it, more plant substeps per macro step spread the macro step's own
    cost over more of the RK4's work."""
    pts = [p for p in ok if bracket(rk, p["error"])]
    if not pts:
        return {}
    # each point's run of one output interval (its initialisation, as its full run's, and the
    # steps of that interval): the difference to the full run is the rest of the stepping, and
    # scaled to the whole horizon, the stepping alone, as the RK4's clock measures it (its setup
    # is outside it)
    grid = load_scene(SCENE).output.output_interval
    ones = [{"_run": _cosim_run(CoSim(load_scene(SCENE, [*T5_CANDIDATES[p["setting"]],
                                                         f"stop_time={grid!r}"]),
                                      p["_fmus"]))} for p in pts]
    steps = stop / grid
    times = side_by_side([*pts, *ones, *rk], runs)
    t_pts, t_one = times[:len(pts)], times[len(pts):2 * len(pts)]
    rk_timed = [{**p, "seconds": t} for p, t in zip(rk, times[2 * len(pts):])]
    rows = []
    log(f"T5  every co-simulation point of at most 1e-5 rad against the RK4 at its error "
        f"({runs} alternated rounds of all of them; 'stepping': the co-simulation less its "
        f"initialisation, as the RK4's clock, which starts after its setup):")
    for p, t, t1 in sorted(zip(pts, t_pts, t_one), key=lambda pt: -pt[0]["error"]):
        t_eq = time_at_error(rk_timed, p["error"])
        row = {"setting": p["setting"], "error": p["error"], "seconds": t,
               "initialisation_seconds": t1, "monolithic_rk4_at_equal_error": t_eq,
               "ratio": t / t_eq, "ratio_stepping": (t - t1) * steps / (steps - 1) / t_eq,
               "fastest": p is c}
        rows.append(row)
        log(f"  {p['setting']:52s} {p['error']:9.2e} rad {t:8.4f} s (one output "
            f"interval {t1 * 1e3:.2f} ms); RK4 {t_eq:8.4f} s -> {row['ratio']:.2f}, "
            f"stepping {row['ratio_stepping']:.2f}"
            f"{'  (the fastest of at most 1e-5)' if row['fastest'] else ''}")
    best = {}
    for key, what in (("ratio", "with the co-simulation's initialisation"),
                      ("ratio_stepping", "stepping against stepping")):
        best[key] = min(rows, key=lambda r: r[key])
        met = [r for r in rows if r[key] <= 1.5]
        where = ", ".join(f"{r['error']:.2e}" for r in met)
        log(f"T5  at most 1.5x the RK4 at equal error, {what}: "
            f"{'met at ' + where + ' rad' if met else 'met at no error of at most 1e-5'}; the "
            f"best ratio {best[key][key]:.2f} ({best[key]['setting']}, "
            f"{best[key]['error']:.2e} rad)")
    res = {"ratios_at_equal_error": rows, "best_ratio_to_monolithic_rk4": best["ratio"],
           **substep_split(rows, stop, log)}
    first = [r for r in rows if r["fastest"]]
    if first:                       # T5's figure: the fastest point's row
        res["monolithic_rk4_at_equal_error"] = first[0]["monolithic_rk4_at_equal_error"]
        res["ratio_to_monolithic_rk4"] = first[0]["ratio"]
    return res


def substep_split(rows, stop: float, log) -> dict:
    """The co-simulation's time per macro step split by a straight line over the Hermite points
    ``rows`` (one macro step H, plant steps H / k for several k; least squares of the time per
    macro step against k): what one more plant substep costs, and the rest (the FMI calls, the
    coupling, the output derivatives, the FMUs' checks, the initialisation spread over the
    run); and, at each k, the rest that 1.5x the RK4 at that point's error allows."""
    pts = []
    for r in rows:
        sets = dict(o.split("=", 1) for o in T5_CANDIDATES.get(r["setting"], []))
        if sets.get("master.coupling") != "hermite":
            continue
        big, small = float(sets["master.step"]), float(sets["plant.step"])
        n_macro = round(stop / big)
        pts.append((round(big / small), r["seconds"] / n_macro, r["monolithic_rk4_at_equal_error"]
                    / n_macro, r["setting"], r["initialisation_seconds"] / n_macro))
    if len({k for k, *_ in pts}) < 2:
        return {}
    k = np.array([p[0] for p in pts], float)
    per = np.array([p[1] for p in pts])
    sub, rest = np.polyfit(k, per, 1)
    init = statistics.median(p[4] for p in pts)
    log(f"T5  per macro step (Hermite, H = 2 ms; a line over {len(pts)} plant steps): "
        f"{rest * 1e9:.0f} ns + k x {sub * 1e9:.0f} ns for k plant substeps (the RK4: "
        f"{statistics.median(p[2] / p[0] for p in pts) * 1e9:.0f} ns a step); of the "
        f"{rest * 1e9:.0f} ns, the initialisation spread over the run's steps: {init * 1e9:.0f} ns")
    for kk, _, rk_per, *_ in sorted(pts):
        log(f"    k = {kk}: 1.5x wants the rest at most {(1.5 * rk_per - kk * sub) * 1e9:.0f} ns")
    return {"substep_ns": sub * 1e9, "rest_ns": rest * 1e9, "initialisation_ns": init * 1e9,
            "rest_for_1_5x_ns": {str(kk): (1.5 * rk_per - kk * sub) * 1e9
                                 for kk, _, rk_per, *_ in pts}}


# ---------------------------------------------------------------------- C host
def c_host(runs, native, log) -> dict:
    from fmpy import read_model_description
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        exe = tmp / "fmi2_host"
        subprocess.run([kernels.find_compiler(), "-O2", "-std=gnu11",
                        f"-I{native_fmus.fmi_include_dir()}", "-o", str(exe),
                        str(ROOT / "tests" / "native" / "fmi2_host.c"), "-ldl"], check=True)
        args, vrs = [], {}
        for name in ("FlexiblePendulum", "PDLowPass"):
            d = tmp / name
            with zipfile.ZipFile(native[name]) as zf:
                zf.extractall(d)
            md = read_model_description(str(d / "modelDescription.xml"))
            vrs[name] = {v.name: v.valueReference for v in md.modelVariables}
            args += [str(d / "binaries" / "linux64" / f"{name}.so"), md.guid]
        args += ["10000", "1e-3"]
        args += [str(vrs["FlexiblePendulum"][n]) for n in ("F_c", "x_o", "phi_o", "omega_o")]
        args += [str(vrs["PDLowPass"][n]) for n in ("x_o", "phi_o", "omega_o", "F_c")]
        args += [f"{vrs['FlexiblePendulum']['phi0']}=0.5235987755982988", "bench"]
        times = []
        for k in range(runs + 1):
            out = subprocess.run([str(exe), *args], capture_output=True, text=True, check=True)
            if k:
                times.append(float(out.stdout) * 1e6)
    med = statistics.median(times)
    log(f"C host (Jacobi, held inputs, n_modes 4, 1 ms): {med:.2f} us per macro step")
    return {"us_per_step": med, "runs": times}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="fewer settings in T5")
    ap.add_argument("--json", default=str(RESULTS / "native.json"))
    ap.add_argument("--only", choices=("T4", "T5", "host"), help="measure this one alone")
    args = ap.parse_args(argv)
    if args.runs < 1:
        print(f"bench_native: --runs = {args.runs}; allowed: >= 1", file=sys.stderr)
        return 2

    def log(msg):
        print(msg, flush=True)

    native = fmu_pair(build_fmus(flavour="native"))
    r4 = host = r5 = None
    if args.only in (None, "T4"):
        python = fmu_pair(build_fmus(flavour="python"))
        with tempfile.TemporaryDirectory() as tmp:
            trivial = trivial_native_fmus(Path(tmp))
            r4 = t4(args.runs, native, python, trivial, log)
    if args.only in (None, "host"):
        host = c_host(args.runs, build_fmus(flavour="native"), log)
    if args.only in (None, "T5"):
        r5 = t5(args.runs, native, log, args.quick)
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".part")      # complete or absent
        tmp.write_text(json.dumps({"T4": r4, "T5": r5, "c_host": host}, indent=2,
                                  default=float))
        tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
