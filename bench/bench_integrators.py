"""Cost of one plant communication step for every integration method, with its accuracy.

For n_modes in (0, 2, 4, 8), the nonlinear plant is advanced over ``--steps`` communication steps
of ``H = 1 ms`` with a prescribed zero-order-hold force, from a deflected state. For each method
the table gives, per communication step: the median wall time in microseconds, the same as a
ratio to one evaluation of ``rhs`` (timed side by side in the same repetition; the ratio is the
median of the per-repetition ratios), the rhs evaluations, the substeps, and the error of the
final state (max-norm, relative to the largest component) against scipy's DOP853 at
rtol = 1e-12 (``exponential`` integrates the linearised plant and is compared with DOP853 on the
linear model).

    python bench/bench_integrators.py                 # full table (a minute or two)
    python bench/bench_integrators.py --modes 4 --repeat 5 --json results.json

Timings are medians of ``--repeat`` repetitions after one warm-up. Each repetition restores the
snapshot taken right after construction, so the first Jacobian and factorisation of the implicit
methods are inside the timed runs, as in an FMU's first steps.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from plant_fmu.dynamics import linear_plant_model, plant_model  # noqa: E402
from plant_fmu.integrators import make_stepper  # noqa: E402
from plant_fmu.params import PlantParams  # noqa: E402

H = 1e-3

#: (label, method, options); h is the substep of the fixed-step methods, the initial step of the
#: adaptive ones.
CONFIGS = [
    ("euler h=H/100", "euler", {"h": H / 100}),
    ("symplectic_euler h=H/10", "symplectic_euler", {"h": H / 10}),
    ("rk4 h=H/10", "rk4", {"h": H / 10}),
    ("dopri5 adaptive 1e-6", "dopri5", {"h": H, "rtol": 1e-6, "atol": 1e-9}),
    ("dopri5 h=H/10", "dopri5", {"h": H / 10, "adaptive": False}),
    ("radau adaptive 1e-6", "radau", {"h": H, "rtol": 1e-6, "atol": 1e-9}),
    ("radau h=H", "radau", {"h": H, "adaptive": False, "rtol": 1e-6, "atol": 1e-9}),
    ("genalpha h=H/10", "genalpha", {"h": H / 10, "rho_inf": 0.8}),
    ("genalpha h=H", "genalpha", {"h": H, "rho_inf": 0.8}),
    ("exponential h=H", "exponential", {"h": H}),
]


def force(k: int) -> float:
    return 5.0 * math.sin(2 * math.pi * 5.0 * k * H)


def initial_state(model):
    x0 = model.initial_state(phi=0.05, phi_dot=-0.2)
    x0[2:model.nq] = 1e-3 * (-0.3) ** np.arange(model.nq - 2)
    return x0


def reference(model, x0, n_steps):
    y = x0.copy()
    for k in range(n_steps):
        y = solve_ivp(model.rhs, (k * H, (k + 1) * H), y, method="DOP853", rtol=1e-12,
                      atol=1e-14, args=(force(k),)).y[:, -1]
    return y


def time_rhs(model, x, n=2000):
    rhs = model.rhs
    t0 = time.perf_counter()
    for _ in range(n):
        rhs(0.0, x, 1.0)
    return (time.perf_counter() - t0) / n


def time_method(stepper, snap, n_steps):
    stepper.set_state(snap)
    forces = [force(k) for k in range(n_steps)]
    t0 = time.perf_counter()
    for k in range(n_steps):
        stepper.u = forces[k]
        ok, msg = stepper.advance((k + 1) * H)
        if not ok:
            return math.nan, msg
    return (time.perf_counter() - t0) / n_steps, None


def bench(n_modes, n_steps, repeat, configs):
    p = PlantParams(n_modes=n_modes)
    model = plant_model(p)
    x0 = initial_state(model)
    y_ref = reference(model, x0, n_steps)
    y_ref_lin = reference(linear_plant_model(p), x0, n_steps)
    steppers = {}
    for label, name, opts in configs:
        s = make_stepper(name, model, 0.0, x0, u=force(0), **opts)
        steppers[label] = (s, s.get_state())
    rows = {label: {"us": [], "ratio": []} for label, _, _ in configs}
    rhs_us = []
    for rep in range(repeat + 1):                      # repetition 0 is the warm-up
        t_rhs = time_rhs(model, x0)
        for label, (s, snap) in steppers.items():
            dt, msg = time_method(s, snap, n_steps)
            if rep:
                rows[label]["us"].append(dt * 1e6)
                rows[label]["ratio"].append(dt / t_rhs)
            rows[label]["msg"] = msg
        if rep:
            rhs_us.append(t_rhs * 1e6)
    out = {"n_modes": n_modes, "rhs_us": statistics.median(rhs_us), "methods": {}}
    for label, name, _ in configs:
        s, snap = steppers[label]
        # counters of one timed run (the snapshot restores them to the initial values)
        s.set_state(snap)
        nfev0, nsteps0 = s.nfev, s.nsteps
        ok = True
        for k in range(n_steps):
            s.u = force(k)
            ok, _ = s.advance((k + 1) * H)
            if not ok:
                break
        ref = y_ref_lin if name == "exponential" else y_ref
        err = float(np.abs(s.y - ref).max() / np.abs(ref).max()) if ok else math.nan
        r = rows[label]
        out["methods"][label] = {
            "us": statistics.median(r["us"]), "ratio": statistics.median(r["ratio"]),
            "nfev": (s.nfev - nfev0) / n_steps, "substeps": (s.nsteps - nsteps0) / n_steps,
            "error": err, "failure": r.get("msg"),
        }
    return out


def rhs_anatomy(n_modes=4, n=20000, repeat=7):
    """Where the time of one ``rhs`` call goes (medians, us): the C kernel does ~100 flops, the
    rest is the Python-to-C call (ctypes) and the arrays in and out."""
    import ctypes

    m = plant_model(PlantParams(n_modes=n_modes))
    kern = m.kernel
    x = initial_state(m)
    buf, out = np.zeros(m.nx), np.zeros(m.nx)
    px, pout = ctypes.c_void_p(buf.ctypes.data), ctypes.c_void_p(out.ctypes.data)
    f, p, u = kern._lib.fp_rhs, kern._p, ctypes.c_double(1.0)
    cases = {
        "model.rhs(t, x, u) as it is": lambda: m.rhs(0.0, x, 1.0),
        "fp_rhs by ctypes, prebuilt arguments, no copies": lambda: f(p, px, u, pout),
        "the copies alone (state in, new array out)": lambda: (buf.__setitem__(slice(None), x),
                                                              out.copy()),
        "a ctypes call with no argument": kern._lib.fp_plant_abi,
    }
    for fn in cases.values():
        fn()
    res = {}
    for name, fn in cases.items():
        ts = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            ts.append((time.perf_counter() - t0) / n * 1e6)
        res[name] = statistics.median(ts)
    return res


def print_table(results):
    modes = [r["n_modes"] for r in results]
    labels = list(results[0]["methods"])
    print(f"\none communication step H = {H * 1e3:g} ms of the nonlinear plant; "
          f"median wall time in us [ratio to one rhs evaluation]")
    head = "| method | " + " | ".join(f"n={n}" for n in modes) + " |"
    print(head)
    print("|" + "---|" * (len(modes) + 1))
    print("| one rhs evaluation | " + " | ".join(f"{r['rhs_us']:.2f} us" for r in results) + " |")
    for lab in labels:
        cells = []
        for r in results:
            m = r["methods"][lab]
            cells.append("failed" if math.isnan(m["us"]) else f"{m['us']:.1f} [{m['ratio']:.1f}]")
        print(f"| {lab} | " + " | ".join(cells) + " |")
    print("\nper communication step: rhs evaluations / substeps; relative error of the final state "
          "(max-norm, over max |y_ref|)")
    print(head)
    print("|" + "---|" * (len(modes) + 1))
    for lab in labels:
        cells = [f"{m['nfev']:.1f} / {m['substeps']:.1f} / {m['error']:.1e}"
                 for m in (r["methods"][lab] for r in results)]
        print(f"| {lab} | " + " | ".join(cells) + " |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modes", type=int, nargs="+", default=[0, 2, 4, 8])
    ap.add_argument("--steps", type=int, default=50, help="communication steps per run")
    ap.add_argument("--repeat", type=int, default=7, help="timed repetitions after the warm-up")
    ap.add_argument("--methods", nargs="+", help="only these labels' methods (registry names)")
    ap.add_argument("--json", type=Path, help="also store the results here")
    ap.add_argument("--no-anatomy", action="store_true", help="skip the rhs call anatomy")
    a = ap.parse_args(argv)
    configs = [c for c in CONFIGS if not a.methods or c[1] in a.methods]
    results = [bench(n, a.steps, a.repeat, configs) for n in a.modes]
    print_table(results)
    anatomy = None
    if not a.no_anatomy:
        anatomy = rhs_anatomy()
        print("\nanatomy of one rhs call (n_modes = 4), median us")
        for name, us in anatomy.items():
            print(f"| {name} | {us:.2f} |")
    if a.json:
        meta = {"python": platform.python_version(), "numpy": np.__version__,
                "machine": platform.machine(), "H": H, "steps": a.steps, "repeat": a.repeat}
        a.json.write_text(json.dumps({"meta": meta, "results": results, "rhs_anatomy": anatomy},
                                     indent=1))


if __name__ == "__main__":
    main()
