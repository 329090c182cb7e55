"""The co-simulation's stability map, predicted and observed, and the plant methods' substep limits.

    python bench/stability_map.py            # the full map (a few minutes on one core)
    python bench/stability_map.py --quick    # a coarse map (under a minute)
    python bench/stability_map.py --table    # the stable intervals per coupling, 2 scenes, runs

1. Map over the communication step H and the filter cutoff (2nd-order filter, damping 0.5, PD
   500/5, n_modes = 4, plant RK4 with substep 2.5e-4), one panel per coupling scheme (Jacobi,
   Gauss-Seidel controller first, Gauss-Seidel plant first) and extrapolation order (0, 1, 2).
   Predicted: the spectral radius of the transition matrix of one communication step
   (orchestration/studies/stability.py), shaded, with its contour rho = 1. Observed: the real
   FMUs on the master with the nonlinear plant from initial.phi = 1e-3, 120 communication steps;
   the growth factor per step of the sampled outputs (eigensystem realisation) decides grow (x)
   or decay (o).
   The critical H at the default cutoff (150 rad/s) is the first crossing of rho = 1.
2. Substep limits of each plant method on the plant's highest mode for n_modes = 1..8. Predicted:
   the first h where the method's stability function on that eigenvalue exceeds 1. Observed: the
   real stepper on the nonlinear plant, started on the highest mode (amplitude 1e-6), run at
   0.9, 0.98, 1.02 and 1.1 times the predicted limit (A-stable methods: at 10 times RK4's limit);
   the growth per substep along the mode (its left eigenvector of the method's substep matrix).
3. ``--table``: every coupling the master offers on the filtered scene (to 50 ms) and the rigid
   one (to 200 ms): the predicted stable and unstable intervals (``flexpend stability``); at the
   steps just inside and outside each boundary (``probe_steps``) how a run of the scene's plant
   from initial.phi = 1e-3 ends (``observed_verdict``: settles, grows, falls), as
   tests/studies/test_stability_intervals.py decides it; and each boundary located from runs of the
   FMU's linear plant (60 steps, the observed growth factor bisected between the two probes).

Every part is a list of independent tasks (orchestration.sweeps.executor): one after the other
here, or with ``--workers N`` on a dask LocalCluster (``--scheduler ADDRESS``: an existing
cluster), with the same numbers.

Writes into bench/results/ (or --out): stability_map.csv (predicted grid), stability_observed.csv
(observed points with the predicted radius), stability_critical.json (critical steps and substep
limits, with the agreement counts), stability_map.png and integrator_limits.png; with --table,
stability_table.md and stability_table.json.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from controller_fmu.pd_lowpass import ControllerParams  # noqa: E402
from plant_fmu.dynamics import plant_model  # noqa: E402
from plant_fmu.integrators import make_stepper  # noqa: E402
from plant_fmu.params import PlantParams  # noqa: E402
from orchestration.studies.stability import (SCHEMES as HELD_SCHEMES,
                                             highest_mode,
                                             integrator_step_limit, linear_plant,
                                             observed_spectral_radius,
                                             plant_polynomial_step_map,
                                             spectral_radius, substep_matrix,
                                             substep_spectral_radius, transition_matrix)

METHODS = ("euler", "symplectic_euler", "rk4", "dopri5", "genalpha", "radau")
OBSERVED = ["phi_o", "omega_o", "F_c", "phi", "eta_1", "eta_2", "eta_3", "eta_4"]
DEFAULT_CUTOFF = 150.0
#: the map's rows: (label, algorithm, first FMU, input derivatives); the fourth is the scenes'
#: default coupling (its p = 2 panel; at p = 0 input derivatives change nothing), the fifth the
#: implicit master with the same interface polynomial (orchestration/cosim/implicit.py)
SCHEMES = tuple((label, alg, first, False) for label, alg, first in HELD_SCHEMES) + (
    ("gs-input-derivatives", "gauss-seidel", "controller", True),
    ("implicit", "implicit", "controller", True))


def log(msg):
    print(msg, file=sys.stderr, flush=True)


class Bar:
    """Progress on stderr: a line every 10 % with the elapsed time and an estimate of the rest."""

    def __init__(self, label, total):
        self.label, self.total, self.done = label, max(total, 1), 0
        self.t0 = time.perf_counter()
        self.next = 0.1

    def step(self):
        self.done += 1
        f = self.done / self.total
        if f >= self.next or self.done == self.total:
            el = time.perf_counter() - self.t0
            log(f"{self.label}: {self.done}/{self.total} ({100 * f:.0f} %), {el:.1f} s, "
                f"~{el * (1 - f) / f:.0f} s left")
            while self.next <= f:
                self.next += 0.1


# ---------------------------------------------------------------------- tasks
# Every part is a list of independent tasks run by an executor (orchestration.sweeps.executor): here
# one after the other, or on dask workers; each task is a module-level function of one item.

def run_tasks(ex, fn, items, label):
    """``[fn(item) for item in items]`` on the executor, with a progress bar; a task lost with
    its worker stops the study (a map with a hole is no map)."""
    from orchestration.sweeps.executor import TaskLost
    out = [None] * len(items)
    bar = Bar(label, len(items))
    for i, value in ex.map(fn, items):
        if isinstance(value, TaskLost):
            raise RuntimeError(f"{label}: a task was lost with its worker: {value.message}")
        out[i] = value
        bar.step()
    return out


# ---------------------------------------------------------------------- 1. the map
def _predicted_row(item):
    """rho[scheme, extrapolation, cutoff] at one communication step H."""
    p, H, cutoffs, substep = item
    plant = linear_plant(p)
    pm = plant_polynomial_step_map("rk4", plant.A, plant.B, plant.nq, float(H), substep)
    rho = np.empty((len(SCHEMES), 3, len(cutoffs)))
    for s, (_, alg, first, ind) in enumerate(SCHEMES):
        for e in range(3):
            for j, wc in enumerate(cutoffs):
                c = ControllerParams(cutoff=float(wc), filter_damping=0.5)
                rho[s, e, j] = spectral_radius(transition_matrix(
                    p, c, float(H), algorithm=alg, first=first, extrapolation=e,
                    input_derivatives=ind, substep=substep, plant_map=pm))
    return rho


def predicted_map(p, Hs, cutoffs, substep, ex):
    rows = run_tasks(ex, _predicted_row, [(p, float(H), cutoffs, substep) for H in Hs],
                     "predicted map")
    return np.stack(rows, axis=2)                # (scheme, extrapolation, H, cutoff)


def _critical_step(item):
    from orchestration.studies.stability import critical_step
    p, alg, first, e, ind, substep = item
    c = ControllerParams(cutoff=DEFAULT_CUTOFF, filter_damping=0.5)
    Hc = critical_step(p, c, algorithm=alg, first=first, extrapolation=e, input_derivatives=ind,
                       substep=substep, hi=4e-2)
    return Hc or None


def critical_steps(p, substep, ex):
    cases = [(label, alg, first, e, ind) for label, alg, first, ind in SCHEMES for e in range(3)]
    Hcs = run_tasks(ex, _critical_step, [(p, alg, first, e, ind, substep)
                                         for _, alg, first, e, ind in cases], "critical steps")
    out = {}
    for (label, _, _, e, _), Hc in zip(cases, Hcs):
        out[f"{label} p={e}"] = Hc
        log(f"critical H at cutoff {DEFAULT_CUTOFF:g}: {label:20s} p={e}: "
            f"{'none below 40 ms' if Hc is None else f'{Hc * 1e3:.4f} ms'}")
    return out


def observe_cosim(paths, alg, first, e, H, wc, n_steps, n_modes, ind=False):
    from orchestration.job import run_scene
    from orchestration.scene.schema import scene_from_config
    scene = scene_from_config("stability_map", {
        "plant.n_modes": n_modes, "controller.filter_order": 2, "controller.cutoff": float(wc),
        "controller.filter_damping": 0.5, "initial.phi": 1e-3, "master.step": float(H),
        "output_interval": float(H), "stop_time": n_steps * float(H), "master.algorithm": alg,
        "master.first": first, "master.extrapolation": e, "plant.fidelity": "nonlinear",
        "master.input_derivatives": ind, "fidelity.companion": False})
    r = run_scene(scene, paths, progress=False)
    if r.summary["stopped"] is not None:   # diverged (phi beyond pi/2, energy beyond 1e6): grows
        return math.inf, r.summary["stopped"]["reason"]
    Y = np.column_stack([r.result[c] for c in OBSERVED[:4 + min(n_modes, 4)]])[e + 2:]
    return observed_spectral_radius(Y, rtol=1e-6), ""


def _observed_point(item):
    """One point of the map: the predicted radius and the observed co-simulation."""
    from orchestration.sweeps.executor import worker_file
    p, fmus, label, alg, first, e, ind, H, wc, substep, n_steps = item
    paths = {role: worker_file(ship, path) for role, (ship, path) in fmus.items()}
    c = ControllerParams(cutoff=float(wc), filter_damping=0.5)
    pred = spectral_radius(transition_matrix(p, c, float(H), algorithm=alg, first=first,
                                             extrapolation=e, input_derivatives=ind,
                                             substep=substep))
    obs, failure = observe_cosim(paths, alg, first, e, H, wc, n_steps, p.n_modes, ind)
    return {"scheme": label, "extrapolation": e, "H": float(H), "cutoff": float(wc),
            "rho_predicted": pred, "rho_observed": obs, "agree": (obs < 1) == (pred < 1),
            "failure": failure}


def observed_map(p, Hs, cutoffs, substep, n_steps, ex, fmus):
    """``fmus``: role -> (shipped name, path), see orchestration.sweeps.executor.worker_file."""
    items = [(p, fmus, label, alg, first, e, ind, float(H), float(wc), substep, n_steps)
             for label, alg, first, ind in SCHEMES for e in range(3) for H in Hs
             for wc in cutoffs]
    return run_tasks(ex, _observed_point, items, "observed co-simulations")


# ---------------------------------------------------------------------- 2. substep limits
def observe_substep(method, p, h, max_steps=400, grow_stop=1e4):
    """Growth per substep of the real stepper (nonlinear plant) along the highest mode."""
    model = plant_model(p)
    plant = linear_plant(p)          # without the cart's drift (a defective double root)
    A, B, keep = plant.A, plant.B, plant.keep
    lam, V = np.linalg.eig(A)
    i = int(np.argmax(np.abs(lam) * (lam.imag >= 0)))
    # the mode's continuation under the method: the two eigenvectors of the substep matrix that
    # carry most of the initial state (a complex pair, or two real eigenvalues once the method
    # has split it); their left eigenvectors project the observed state on them
    v = V[:, i]
    y0 = np.zeros(model.nx)
    y0[keep] = 1e-6 * np.real(v) / np.abs(v).max()
    S = A if method == "genalpha" else substep_matrix(method, A, B, plant.nq, h)[:-1, :-1]
    mu, U = np.linalg.eig(S)
    U = U / np.linalg.norm(U, axis=0)
    Uinv = np.linalg.inv(U)
    pair = np.argsort(np.abs(Uinv @ y0[keep]))[-2:]
    w = np.zeros((2, model.nx), dtype=complex)
    w[:, keep] = Uinv[pair]
    opts = {"adaptive": False} if method in ("dopri5", "radau") else {}
    st = make_stepper(method, model, 0.0, y0, u=0.0, h=h, **opts)
    a0 = np.linalg.norm(w @ y0)
    n = 0
    while n < max_steps:
        ok, _ = st.advance((n + 1) * h)
        if not ok:
            return math.inf
        n += 1
        if np.linalg.norm(w @ st.y) > grow_stop * a0 or n * h > 0.05 and n >= 20:
            break
    return (np.linalg.norm(w @ st.y) / a0) ** (1.0 / n)


def substep_limits(modes, factors, ex):
    rows = run_tasks(ex, _substep_rows, [(n, method, tuple(factors)) for n in modes
                                         for method in METHODS], "substep limits")
    return [r for part in rows for r in part]


def _substep_rows(item):
    """The rows of one method at one n_modes."""
    n, method, factors = item
    rows = []
    p = PlantParams(n_modes=n)
    lam = highest_mode(p)
    rk4 = integrator_step_limit("rk4", lam)
    hs = integrator_step_limit(method, lam)
    pts = [(f, f * hs) for f in factors] if hs else [(None, 10 * rk4)]
    if not factors:            # predicted limit only
        rows.append({"n_modes": n, "method": method, "mode_re": lam.real,
                     "mode_im": lam.imag, "h_limit": hs, "factor": None, "h": None,
                     "rho_predicted": None, "rho_observed": None, "agree": None})
        pts = []
    for f, h in pts:
        pred = substep_spectral_radius(method, lam, h)
        obs = observe_substep(method, p, h)
        rows.append({"n_modes": n, "method": method, "mode_re": lam.real,
                     "mode_im": lam.imag, "h_limit": hs, "factor": f, "h": h,
                     "rho_predicted": pred, "rho_observed": obs,
                     "agree": (obs < 1) == (pred < 1)})
    return rows


# ---------------------------------------------------------------------- figures
def plot_map(path, Hs, cutoffs, rho, observed, crit):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm
    fig, axes = plt.subplots(len(SCHEMES), 3, figsize=(15, 4 * len(SCHEMES)), sharex=True,
                             sharey=True)
    # the rate per second of the slowest-decaying mode, log(rho)/H, clipped
    L = np.log(np.clip(rho, 1e-300, None)) / Hs[None, None, :, None]
    norm = TwoSlopeNorm(vmin=-3.0, vcenter=0.0, vmax=3.0)
    for s, (label, _, _, _) in enumerate(SCHEMES):
        for e in range(3):
            ax = axes[s, e]
            im = ax.pcolormesh(Hs * 1e3, cutoffs, L[s, e].T, cmap="RdBu_r", norm=norm,
                               shading="nearest")
            ax.contour(Hs * 1e3, cutoffs, rho[s, e].T, levels=[1.0], colors="k", linewidths=1.2)
            pts = [r for r in observed if r["scheme"] == label and r["extrapolation"] == e]
            for grow, mk in ((False, "o"), (True, "x")):
                sel = [r for r in pts if (r["rho_observed"] >= 1) == grow]
                if not sel:
                    continue
                colors = ["k" if r["agree"] else "m" for r in sel]
                xy = ([r["H"] * 1e3 for r in sel], [r["cutoff"] for r in sel])
                if grow:
                    ax.scatter(*xy, marker="x", c=colors, s=40, linewidths=1.5)
                else:
                    ax.scatter(*xy, marker="o", edgecolors=colors, facecolors="none", s=40,
                               linewidths=1.5)
            Hc = crit.get(f"{label} p={e}")
            if Hc:
                ax.plot([Hc * 1e3], [DEFAULT_CUTOFF], marker="*", color="gold", ms=14,
                        markeredgecolor="k")
            ax.set_xscale("log")
            ax.set_title(f"{label}, p = {e}" + (f": H_c = {Hc * 1e3:.2f} ms" if Hc else ""),
                         fontsize=9)
            if s == len(SCHEMES) - 1:
                ax.set_xlabel("communication step H, ms")
            if e == 0:
                ax.set_ylabel("filter cutoff, rad/s")
    fig.colorbar(im, ax=axes, shrink=0.6, label="predicted rate log(rho)/H, 1/s (clipped to +-3)")
    fig.suptitle("Stability map (n_modes = 4, PD 500/5, 2nd-order filter, damping 0.5): predicted "
                 "rho = 1 black line, red grows, blue decays;\nobserved nonlinear co-simulation: "
                 "o decays, x grows (magenta: disagrees with the prediction); star: H_c at "
                 f"{DEFAULT_CUTOFF:g} rad/s", fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_limits(path, rows, modes):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 6))
    for k, method in enumerate(METHODS):
        lim = {r["n_modes"]: r["h_limit"] for r in rows if r["method"] == method}
        ns = [n for n in modes if lim.get(n)]
        if not ns:
            ax.plot([], [], " ", label=f"{method}: no limit (A-stable)")
            continue
        line, = ax.plot(ns, [lim[n] for n in ns], "-", label=f"{method} (predicted)")
        for r in rows:
            if r["method"] == method and r["factor"] is not None and r["h"] is not None:
                col = line.get_color() if r["agree"] else "m"
                if r["rho_observed"] >= 1:
                    ax.scatter(r["n_modes"], r["h"], marker="x", color=col, s=25)
                else:
                    ax.scatter(r["n_modes"], r["h"], marker="o", edgecolors=col,
                               facecolors="none", s=25)
    ax.set_yscale("log")
    ax.set_xlabel("n_modes")
    ax.set_ylabel("substep h, s")
    ax.set_title("Substep limit on the highest mode (line: predicted); observed stepper: o stable, "
                 "x grows", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_csv(path, rows):
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


# ---------------------------------------------------------------------- 3. the table per coupling
#: the scenes of the table and the largest step scanned on each (s)
TABLE_SCENES = {"flexible_pd_lowpass": 0.05, "rigid_pd": 0.2}
#: the boundaries located from runs: the FMU's linear plant (its samples are exactly a linear
#: system's, so the observed growth equals rho(Phi) to rounding), a small motion, nothing stops
#: the run
OBSERVE_SETS = {"initial.phi": 1e-3, "fidelity.companion": False, "plant.phi_limit": "inf",
                "plant.energy_limit": "inf", "plant.fidelity": "linear"}
TABLE_STEPS = 60            # communication steps per run that locates a boundary
VERDICT_CHANNELS = ("phi_o", "omega_o", "F_c")


def _scene_run(name, sets, paths):
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    scene = load_scene(name, [f"{k}={str(v).lower() if isinstance(v, bool) else v}"
                              for k, v in sets.items()])
    return scene, run_scene(scene, paths, progress=False)


def _observed_rho(name, coupling, H, paths):
    """The observed growth factor per step of scene ``name`` with ``coupling`` at step ``H``
    (the linear plant, TABLE_STEPS steps)."""
    sets = {**OBSERVE_SETS, "master.step": H, "output_interval": H, "stop_time": TABLE_STEPS * H,
            **{f"master.{k}": v for k, v in coupling.items()}}
    scene, r = _scene_run(name, sets, paths)
    if r.summary["stopped"] is not None:
        return math.inf
    Y = np.column_stack([r.result[c] for c in OBSERVED if c in r.result.dtype.names])
    if not np.all(np.abs(Y) < 1e100):     # overflowing (or past it): it grows
        return math.inf
    return observed_spectral_radius(Y[scene.master.extrapolation + 2:], rtol=1e-8)


def _verdict(name, coupling, H, rho, paths):
    """How the scene's own plant (its rung) co-simulated with ``coupling`` at ``H`` from
    initial.phi = 1e-3 ends (``observed_verdict``), run as long as the predicted ``rho`` needs
    to change the amplitude a thousandfold (200 to 4000 steps), as the tests do."""
    from orchestration.studies.stability import observed_verdict
    N = int(min(4000, max(200, math.ceil(math.log(1e3) / abs(math.log(rho))))))
    sets = {"master.step": H, "output_interval": H, "stop_time": N * H, "initial.phi": 1e-3,
            "fidelity.companion": False, **{f"master.{k}": v for k, v in coupling.items()}}
    _, r = _scene_run(name, sets, paths)
    Y = np.column_stack([r.result[c] for c in VERDICT_CHANNELS])
    return observed_verdict(Y, stopped=r.summary["stopped"] is not None)


def _table_row(item):
    """One coupling on one scene: its predicted intervals; at the probe steps beside each
    boundary (``probe_steps``) how a run of the scene's plant ends; and each boundary located
    from runs of the linear plant, by bisecting the observed growth factor between the two
    probes beside it (to 1e-7)."""
    from orchestration.scene.schema import load_scene
    from orchestration.studies.analysis import linearisation
    from orchestration.studies.stability import (spectral_radius, stability_report,
                                                 transition_matrix)
    from orchestration.studies.stability_intervals import probe_steps
    from orchestration.sweeps.executor import worker_file
    name, coupling, fmus = item
    paths = {role: worker_file(ship, path) for role, (ship, path) in fmus.items()}
    scene = load_scene(name)
    report = stability_report(scene, max_step=TABLE_SCENES[name])
    row = next(r for r in report["couplings"] if all(r[k] == v for k, v in coupling.items()))
    iv = row["intervals"]
    p = linearisation(scene).params
    model = dict(integrator=scene.plant.integrator, substep=scene.plant.step)
    rho = lambda H: spectral_radius(transition_matrix(p, scene.controller, H, **model,  # noqa
                                                      **coupling))
    probes = []
    for H, stable in probe_steps(iv):
        r = rho(H)
        verdict, ratio, factor = _verdict(name, coupling, H, r, paths)
        probes.append({"H": H, "stable": stable, "rho": r, "verdict": verdict, "ratio": ratio,
                       "factor": factor, "agree": (verdict == "settles") == stable})
    located = []
    for a, b in zip(iv, iv[1:]):
        # the probes beside the boundary a["to"]: the last in a, the first in b
        left = max(q["H"] for q in probes if a["from"] < q["H"] < a["to"])
        right = min(q["H"] for q in probes if b["from"] < q["H"] < b["to"])
        f = lambda H: _observed_rho(name, coupling, H, paths) - 1.0  # noqa: E731
        lo, hi, below = left, right, f(left) < 0
        while hi / lo - 1 > 1e-7:
            mid = math.sqrt(lo * hi)
            if (f(mid) < 0) == below:
                lo = mid
            else:
                hi = mid
        located.append({"predicted": a["to"], "observed": math.sqrt(lo * hi)})
    return {"scene": name, **coupling, "intervals": iv, "probes": probes, "boundaries": located}


def _ms_list(iv):
    parts = [f"{i['from'] * 1e3:.4g}-{i['to'] * 1e3:.4g}" for i in iv if i["stable"]]
    return ", ".join(parts) or "none"


def stability_table(out, ex, fmus):
    """Per coupling on the filtered and the rigid scene: the predicted stable intervals, how
    many probe runs agree, and the boundaries located from runs against the predicted ones:
    stability_table.json and stability_table.md, the table printed."""
    from orchestration.report.text import coupling_text
    from orchestration.scene.schema import load_scene
    from orchestration.studies.stability import couplings
    t0 = time.perf_counter()
    items = [(name, k, fmus) for name in TABLE_SCENES
             for k in couplings(load_scene(name).master)]
    rows = run_tasks(ex, _table_row, items, "stability table")
    by = {(r["scene"], coupling_text(r)): r for r in rows}
    keys = list(dict.fromkeys(coupling_text(r) for r in rows))
    head = ("| coupling | " + " | ".join(
        f"{n} to {TABLE_SCENES[n] * 1e3:g} ms: stable (ms) | runs agreeing" for n in TABLE_SCENES)
        + " |")
    lines = [head, "|" + "---|" * (1 + 2 * len(TABLE_SCENES))]
    for k in keys:
        cells = []
        for n in TABLE_SCENES:
            r = by[n, k]
            cells.append(f"{_ms_list(r['intervals'])} | "
                         f"{sum(q['agree'] for q in r['probes'])}/{len(r['probes'])}")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    table = "\n".join(lines) + "\n"
    (out / "stability_table.md").write_text(table)
    (out / "stability_table.json").write_text(json.dumps(rows, indent=2))
    print(table)
    probes = [q for r in rows for q in r["probes"]]
    bounds = [b for r in rows for b in r["boundaries"]]
    worst = max((abs(b["observed"] / b["predicted"] - 1) for b in bounds), default=0.0)
    print(f"probe runs agreeing with the prediction: {sum(q['agree'] for q in probes)} of "
          f"{len(probes)}; boundaries located from runs: {len(bounds)}, largest relative "
          f"difference from the predicted: {worst:.2e}; {time.perf_counter() - t0:.0f} s")
    for r in rows:
        for q in r["probes"]:
            if not q["agree"]:
                print(f"disagreement: {r['scene']}, {coupling_text(r)}: {q}")
    print(f"wrote {out}/stability_table.md, stability_table.json")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="coarse grids (under a minute)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"), help="output folder")
    ap.add_argument("--table", action="store_true",
                    help="only the table of the stable intervals per coupling on the filtered "
                         "and the rigid scene, predicted and observed (docs/stability.md)")
    ap.add_argument("--no-observe", action="store_true",
                    help="predicted map and limits only (no co-simulations)")
    ap.add_argument("--workers", type=int, default=None, metavar="N",
                    help="run the tasks on a dask LocalCluster of N processes (same numbers)")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the tasks on the dask cluster of this scheduler (its workers "
                         "need this checkout at the same path)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"stability_map: --out {args.out!r} cannot be created: {exc}", file=sys.stderr)
        return 2
    from orchestration.export import build_fmus
    from orchestration.sweeps.executor import file_name, open_executor
    built = build_fmus(flavour="native")
    fmu_paths = {"plant": built["FlexiblePendulum"], "controller": built["PDLowPass"]}
    fmus = {role: (file_name(path), str(path)) for role, path in fmu_paths.items()}
    try:
        ex = open_executor(args.workers, args.scheduler, paths=[str(Path(__file__).parent)],
                           files=list(fmu_paths.values()))
    except ValueError as exc:
        print(f"stability_map: {exc}", file=sys.stderr)
        return 2
    log(f"running on {ex.describe()}" + (f"; dask dashboard {ex.dashboard}"
                                         if ex.dashboard else ""))
    with ex:
        if args.table:
            return stability_table(out, ex, fmus)
        return _study(args, out, ex, fmus)


def _study(args, out, ex, fmus):
    p = PlantParams(n_modes=4)
    substep = 2.5e-4
    if args.quick:
        Hs, cutoffs = np.geomspace(5e-4, 4e-2, 24), np.linspace(60, 300, 13)
        Ho, co = np.array([1e-3, 3e-3, 1e-2, 3e-2]), np.array([80.0, 150.0, 260.0])
        modes, factors = (1, 4, 8), (0.9, 1.1)
    else:
        Hs, cutoffs = np.geomspace(5e-4, 4e-2, 48), np.linspace(60, 300, 25)
        Ho = np.geomspace(1e-3, 3.2e-2, 6)
        co = np.array([80.0, 120.0, 150.0, 200.0, 260.0])
        modes, factors = tuple(range(1, 9)), (0.9, 0.98, 1.02, 1.1)
    t0 = time.perf_counter()
    crit = critical_steps(p, substep, ex)
    rho = predicted_map(p, Hs, cutoffs, substep, ex)
    write_csv(out / "stability_map.csv", [
        {"scheme": lab, "extrapolation": e, "H": float(H), "cutoff": float(wc),
         "rho": float(rho[s, e, i, j])}
        for s, (lab, _, _, _) in enumerate(SCHEMES) for e in range(3)
        for i, H in enumerate(Hs) for j, wc in enumerate(cutoffs)])
    observed = [] if args.no_observe else observed_map(p, Ho, co, substep, 120, ex, fmus)
    if observed:
        write_csv(out / "stability_observed.csv", observed)
    limits = substep_limits(modes, () if args.no_observe else factors, ex)
    write_csv(out / "integrator_limits.csv", limits)
    plot_map(out / "stability_map.png", Hs, cutoffs, rho, observed, crit)
    plot_limits(out / "integrator_limits.png", limits, modes)
    summary = {
        "command": "python bench/stability_map.py" + (" --quick" if args.quick else ""),
        "plant": "n_modes = 4, rk4 substep 2.5e-4", "controller": "PD 500/5, 2nd-order filter, "
        "damping 0.5", "critical_H_at_cutoff_150": crit,
        "substep_limits": {f"n={n}": {m: next(r["h_limit"] for r in limits
                                            if r["n_modes"] == n and r["method"] == m)
                                      for m in METHODS} for n in modes},
        "highest_mode": {f"n={n}": [next(r["mode_re"] for r in limits if r["n_modes"] == n),
                                    next(r["mode_im"] for r in limits if r["n_modes"] == n)]
                         for n in modes},
        "cosim_points": len(observed), "cosim_agree": sum(r["agree"] for r in observed),
        "substep_points": sum(r["agree"] is not None for r in limits),
        "substep_agree": sum(bool(r["agree"]) for r in limits),
        "wall_time_s": time.perf_counter() - t0, "executor": ex.describe(),
    }
    (out / "stability_critical.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: summary[k] for k in ("critical_H_at_cutoff_150", "cosim_points",
                                                  "cosim_agree", "substep_points",
                                                  "substep_agree")}, indent=2))
    print(f"wrote {out}/stability_map.png, integrator_limits.png, stability_map.csv, "
          f"stability_observed.csv, integrator_limits.csv, stability_critical.json")
    for r in observed + limits:
        if r["agree"] is False:
            print(f"disagreement: {r}")
    return 0


if __name__ == "__main__":
    # run as the module ``stability_map`` (this folder is on sys.path), so that dask pickles
    # its task functions by reference and the workers import them
    import stability_map
    sys.exit(stability_map.main())
