"""Model Exchange and the Jacobians of issue 24, measured side by side in one run.

    python bench/bench_model_exchange.py [--runs 3] [--quick] [--json PATH]

* **The model-exchange master against the co-simulation** on the filtered scene
  (``flexible_pd_lowpass``, 10 s): the error of ``phi_o`` against the monolithic reference
  (DOP853 at 1e-12) and the median time, for the co-simulation's default coupling over the
  communication step (the master's compiled loop), the same with the extrapolation built from
  the FMUs' output derivatives (``master.output_derivatives``, also on the compiled loop), and the
  model-exchange master (Radau with the FMUs' directional derivatives) over ``master.rtol``.
  Then, per error target, the fastest point of each that meets it, and the ratios.
* **fmpy's CVode on the ME plant against the CS plant** (the native FMI 2.0 FlexiblePendulum
  alone, ``fmpy.simulate_fmu``), driven by the committed force history
  (``tests/reference/FlexiblePendulum/FlexiblePendulum_in.csv``, 1 s, samples every 1 ms)
  interpolated linearly, as fmpy's ``Input`` does: the reference is the numpy model under that
  force, DOP853 at 1e-12 from sample to sample. CVode over ``relative_tolerance``; the CS plant
  over its RK4 substep ``step``, stepped by hand on fmpy's ``FMU2Slave`` with the force's value
  and slope at the start of each 1 ms step (``fmi2SetRealInputDerivatives``, which the native
  plant integrates exactly; fmpy 0.3.32's own ``set_input_derivatives`` fails on this input). fmpy 0.3.32's CVode applies a
  continuous input in its root function but not in its right-hand side (with the plant's event
  indicators the derivative then sees the input of the last root evaluation, and CVode stalls
  or drifts): the bench applies it in the right-hand side too, as ``tests/export/test_native_me.py``
  does.

* **The compiled model-exchange master on the three paper scenes** (issue 39; ``--paper``
  runs only this part): ``rigid_pd`` and ``flexible_pd_lowpass`` (10 s) and ``flexible_pd``
  (its 2.5 s), the
  model-exchange master's compiled loop (``orchestration/cosim/native/fm_me.c``) over
  ``master.rtol`` against the co-simulation's compiled default over the communication step,
  side by side, the error of ``phi_o`` against the monolithic reference; per error target the
  fastest point of each and their ratio (the issue's goal: at most 3).

Times are medians of ``--runs`` runs after a warm-up, the points of a scene timed in rounds
that alternate them, so that the machine's load falls on both sides of each ratio (until
2026-11-29 each point's runs came one after the other, a family after the other; fmpy's CVode
part still does). Results:
``bench/results/model_exchange.json`` and ``.png`` (error against time).
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import (RESULTS, CoSim, load_scene, median_time, phi_error,  # noqa: E402
                    reference)

from orchestration.export import build_fmus, fmu_pair  # noqa: E402
from orchestration.export.check import reference_files  # noqa: E402

SCENE = "flexible_pd_lowpass"
TARGETS = (1e-5, 1e-6, 1e-7)

#: family -> (scene overrides, sweep key, values (full, quick))
SCENE_FAMILIES = {
    "co-simulation (default coupling)": ([], "master.step",
                                         ([4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4],
                                          [2e-3, 1e-3, 5e-4])),
    "co-simulation, extrapolation from dy/dt": (["master.output_derivatives=true"],
                                                "master.step",
                                                ([4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4],
                                                 [2e-3, 1e-3, 5e-4])),
    "model-exchange master (Radau, compiled)": (["master.interface=model-exchange"],
                                                "master.rtol",
                                                ([1e-5, 1e-6, 1e-7, 1e-8, 1e-9], [1e-6, 1e-8])),
    "model-exchange master (Radau, scipy)": (["master.interface=model-exchange",
                                              "master.compiled=false"], "master.rtol",
                                             ([1e-5, 1e-6, 1e-7, 1e-8, 1e-9], [1e-6, 1e-8])),
}
#: issue 39: the compiled model-exchange master against the compiled co-simulation default on
#: the paper scenes (family -> (overrides, sweep key, values (full, quick)))
PAPER_SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
PAPER_FAMILIES = {
    "co-simulation (default coupling)": ([], "master.step",
                                         ([2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5, 3.125e-5],
                                          [2e-3, 5e-4, 1.25e-4])),
    "model-exchange master (Radau, compiled)": (["master.interface=model-exchange"],
                                                "master.rtol",
                                                ([1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 1e-6, 1e-7],
                                                 [1e-4, 1e-5, 1e-6])),
}
PAPER_TARGETS = (1e-5, 1e-6, 1e-7)
CVODE_RTOLS = ([1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10], [1e-5, 1e-7, 1e-9])
CS_PLANT_STEPS = ([1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5], [5e-4, 2.5e-4, 1.25e-4])


def _overrides(ov, key, value, interval=2e-3):
    """The scene's overrides for ``key = value`` (``interval``: the scene's output interval,
    widened to a longer communication step)."""
    out = list(ov) + [f"{key}={value!r}"]
    if key == "master.step" and value > interval:
        out.append(f"output_interval={value!r}")
    if key == "master.rtol":
        out.append(f"master.atol={value * 1e-2!r}")
    return out


def scene_points(fmus, runs, quick, name=SCENE, families=SCENE_FAMILIES):
    """Every family's points on the scene ``name``: each run once (untimed: the warm-up, and
    the error), then ``runs`` rounds that time every point in turn, so that the machine's load
    falls on all of them; medians."""
    refs = {}
    todo = []
    interval = load_scene(name).output.output_interval
    for fam, (ov, key, values) in families.items():
        for value in values[quick]:
            scene = load_scene(name, _overrides(ov, key, value, interval))
            grid = scene.output.output_interval
            if grid not in refs:
                refs[grid] = reference(scene)
            todo.append((fam, key, value, grid, CoSim(scene, fmus)))
    errors = []
    for fam, key, value, grid, cosim in todo:
        result, _ = cosim.run()
        errors.append(phi_error(result, refs[grid]))
    times = [[] for _ in todo]
    for _ in range(runs):
        for i, entry in enumerate(todo):
            _, stats = entry[4].run()
            times[i].append(stats.wall_time)
    points = []
    for (fam, key, value, _, _), err, t in zip(todo, errors, times):
        med = statistics.median(t)
        points.append(dict(scene=name, family=fam, key=key, value=value, error=err,
                           median_s=med, times=t))
        print(f"  {fam:42s} {key} = {value:<8g} error {err:9.3g} rad  {med * 1e3:9.2f} ms",
              flush=True)
    return points


def paper_points(fmus, runs, quick):
    """Issue 39: per paper scene, the compiled model-exchange master against the compiled
    co-simulation default; ``(points, {scene: rows at equal error})``."""
    points, rows = [], {}
    for name in PAPER_SCENES:
        print(f"{name}: error of phi_o against the monolithic reference, median of {runs}")
        pts = scene_points(fmus, runs, quick, name, PAPER_FAMILIES)
        rows[name] = at_equal_error(pts, PAPER_TARGETS)
        print_equal_error(rows[name], "co-simulation (default coupling)")
        points += pts
    return points, rows


# ---------------------------------------------------------------------- the plant alone
def linear_force_reference(files):
    """phi_o of the numpy plant (the FMU's defaults) under the force interpolated linearly
    between the samples: DOP853 at 1e-12 from sample to sample."""
    from scipy.integrate import solve_ivp

    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams

    data = np.genfromtxt(files["in"], delimiter=",", names=True)
    model = PlantModel(PlantParams())
    x = np.zeros(model.nx)
    phi = [model.tip_angle(x)[0]]
    t, F = data["time"], data["F_c"]
    for k in range(len(t) - 1):
        slope = (F[k + 1] - F[k]) / (t[k + 1] - t[k])

        def rhs(s, y, k=k, slope=slope):
            return model.rhs(s, y, F[k] + slope * (s - t[k]))
        sol = solve_ivp(rhs, (t[k], t[k + 1]), x, method="DOP853", rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        phi.append(model.tip_angle(x)[0])
    return t, np.array(phi)


def _fmpy_input_in_rhs():
    """fmpy 0.3.32's CVode: apply the input at the time of every right-hand side."""
    from fmpy import sundials
    orig = sundials.CVodeSolver.f
    if getattr(orig, "_applies_input", False):
        return

    def f(self, t, y, ydot, user_data):
        self.input.apply(t)
        return orig(self, t, y, ydot, user_data)
    f._applies_input = True
    sundials.CVodeSolver.f = f


def plant_points(plant_fmu, runs, quick):
    from fmpy import extract, simulate_fmu

    files = reference_files("FlexiblePendulum")
    data = np.genfromtxt(files["in"], delimiter=",", names=True)
    signals = np.zeros(len(data), dtype=[("time", "f8"), ("F_c", "f8")])
    signals["time"], signals["F_c"] = data["time"], data["F_c"]
    t_ref, phi_ref = linear_force_reference(files)
    _fmpy_input_in_rhs()
    unzipped = extract(plant_fmu)
    stop = float(t_ref[-1])
    settings = ([("ModelExchange (fmpy CVode)", "relative_tolerance", v)
                 for v in CVODE_RTOLS[quick]] +
                [("CoSimulation (plant RK4)", "step", v) for v in CS_PLANT_STEPS[quick]])
    points = []
    for label, key, value in settings:
        me = label.startswith("Model")

        def fn(me=me, value=value):
            t0 = time.perf_counter()
            if me:
                res = simulate_fmu(unzipped, stop_time=stop, output_interval=1e-3, input=signals,
                                   output=["phi_o"], fmi_type="ModelExchange", solver="CVode",
                                   relative_tolerance=value)
            else:
                res = _cs_plant(unzipped, signals, value)
            return time.perf_counter() - t0, res
        med, times, res = median_time(fn, runs)
        phi = np.interp(t_ref, res["time"], res["phi_o"])
        err = float(np.max(np.abs(phi - phi_ref)))
        points.append(dict(family=label, key=key, value=value, error=err, median_s=med,
                           times=times))
        print(f"  {label:42s} {key} = {value:<8g} error {err:9.3g} rad  {med * 1e3:9.2f} ms",
              flush=True)
    return points


def _cs_plant(unzipped, signals, step):
    """The CS plant over the signal's samples (1 ms), value and slope set at each step's
    start; phi_o at every sample."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(unzipped)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
    fmu.instantiate()
    try:
        fmu.setupExperiment(startTime=0.0)
        fmu.setReal([vr["step"]], [step])
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        t, F = signals["time"], signals["F_c"]
        phi = np.zeros(len(t))
        for k in range(len(t) - 1):
            fmu.setReal([vr["F_c"]], [F[k]])
            fmu.setRealInputDerivatives([vr["F_c"]], [1],
                                        [(F[k + 1] - F[k]) / (t[k + 1] - t[k])])
            fmu.doStep(t[k], t[k + 1] - t[k])
            phi[k + 1] = fmu.getReal([vr["phi_o"]])[0]
        fmu.terminate()
    finally:
        fmu.freeInstance()
    out = np.zeros(len(t), dtype=[("time", "f8"), ("phi_o", "f8")])
    out["time"], out["phi_o"] = t, phi
    return out


def at_equal_error(points, targets):
    """Per target: the fastest point of each family with error <= target."""
    out = []
    fams = list(dict.fromkeys(p["family"] for p in points))
    for target in targets:
        row = {"target": target}
        for f in fams:
            ok = [p for p in points if p["family"] == f and p["error"] <= target]
            row[f] = min(ok, key=lambda p: p["median_s"]) if ok else None
        out.append(row)
    return out


def print_equal_error(rows, base):
    for row in rows:
        b = row.get(base)
        print(f"  error <= {row['target']:.0e} rad:")
        for f, p in row.items():
            if f == "target":
                continue
            if p is None:
                print(f"    {f:42s} not reached")
                continue
            ratio = f"  {p['median_s'] / b['median_s']:.2f} x {base}" if b and f != base else ""
            print(f"    {f:42s} {p['key']} = {p['value']:<8g} {p['median_s'] * 1e3:9.2f} ms"
                  f"{ratio}")


def plot(scene_pts, plant_pts, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, pts, title in ((axes[0], scene_pts, f"{SCENE}, 10 s"),
                           (axes[1], plant_pts, "FlexiblePendulum alone, committed force, 1 s")):
        for f in dict.fromkeys(p["family"] for p in pts):
            sel = [p for p in pts if p["family"] == f and math.isfinite(p["error"])]
            ax.loglog([p["median_s"] for p in sel], [p["error"] for p in sel], "o-", label=f)
        ax.set_xlabel("wall time, s (median)")
        ax.set_ylabel("max |phi_o error|, rad")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path, default=RESULTS / "model_exchange.json")
    ap.add_argument("--paper", action="store_true",
                    help="only the compiled model-exchange master on the paper scenes")
    args = ap.parse_args(argv)
    quick = int(args.quick)
    fmus = fmu_pair(build_fmus(flavour="native"))
    paper, _rows = paper_points(fmus, args.runs, quick)
    if args.paper:
        path = args.json.with_name(args.json.stem + "_paper.json")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"paper": paper}, indent=1))
        print(f"wrote {path}")
        return
    print(f"{SCENE}: error of phi_o against the monolithic reference, median of {args.runs}")
    sp = scene_points(fmus, args.runs, quick)
    rows = at_equal_error(sp, TARGETS)
    print_equal_error(rows, "co-simulation (default coupling)")
    print("FlexiblePendulum alone (fmpy.simulate_fmu), committed force history")
    pp = plant_points(fmus["plant"], args.runs, quick)
    prow = at_equal_error(pp, (1e-6, 1e-8))
    print_equal_error(prow, "CoSimulation (plant RK4)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.json.with_suffix(".tmp")
    tmp.write_text(json.dumps({"scene": sp, "plant": pp, "paper": paper}, indent=1))
    tmp.replace(args.json)
    png = args.json.with_suffix(".png")
    plot(sp, pp, png)
    print(f"wrote {args.json}, {png}")


if __name__ == "__main__":
    main()
