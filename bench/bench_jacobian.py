"""The cost of one exact Jacobian of the plant against one right-hand side, in the C kernel.

    python bench/bench_jacobian.py [--runs 7] [--reps 20000] [--json FILE]

For n_modes 0, 2, 4, 8 (the nonlinear model, with and without the gravity preload), at one
deformed, moving, tilted state: one call of ``fp_rhs`` against one of ``fp_jacobian`` (J and b),
and beside them ``fp_jvp`` (J v + b du without forming J) and ``fp_output_derivatives`` (the
first and second time derivatives of every output). Each figure is timed in C (a loop of
``--reps`` calls with a monotonic clock, in a library built here from ``bench/native/
jacobian_timing.c`` and the kernel's sources with the kernel's flags), so that no Python call
overhead enters; the loops of one configuration alternate within each run, and the table shows
the medians of ``--runs`` runs after a warm-up run. "FD / rhs" is what a forward-difference
Jacobian would cost in right-hand sides (nx + 1), for scale.
"""
from __future__ import annotations

import argparse
import ctypes
import json
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fmu_common import kernels
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams

NATIVE = ROOT / "plant_fmu" / "native"
TIMING_C = ROOT / "bench" / "native" / "jacobian_timing.c"
N_MODES = (0, 2, 4, 8)


def build(out: Path) -> ctypes.CDLL:
    """The timing loops and the kernel in one library (the kernel's compiler and flags)."""
    lib = out / "libjacobian_timing.so"
    cmd = [kernels.find_compiler(), *kernels.CFLAGS, "-fPIC", "-shared", f"-I{NATIVE}", "-o",
           str(lib), str(TIMING_C), str(NATIVE / "fp_plant.c"), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(lib))
    for name in ("fpb_time_rhs", "fpb_time_jacobian", "fpb_time_jvp",
                 "fpb_time_output_derivatives"):
        getattr(dll, name).restype = ctypes.c_double
    return dll


def _ptr(a: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(a.ctypes.data)


def state(m, seed=1) -> np.ndarray:
    """A deformed, moving, tilted state (tip deflection ~5 % of L, phi = 0.8 rad)."""
    rng = np.random.default_rng(seed)
    x = np.zeros(m.nx)
    n, nq = m.n, m.nq
    x[0], x[1], x[nq], x[nq + 1] = 0.2, 0.8, 0.5, -1.5
    if n:
        x[2:nq] = 0.05 * rng.standard_normal(n) / np.sqrt(n) / np.abs(m.tip_defl)
        x[nq + 2:] = np.sqrt(m.Kdiag) * x[2:nq] * rng.standard_normal(n)
    return x


def measure(dll, n: int, preload: bool, runs: int, reps: int) -> dict:
    m = plant_model(PlantParams(n_modes=n, gravity_preload=preload))
    k = m.kernel
    p = k._p                                   # the prepared fp_plant of the kernel's binding
    nx = m.nx
    x = state(m)
    u = 20.0
    out, J, b = np.zeros(nx), np.zeros((nx, nx)), np.zeros(nx)
    d1, d2 = np.zeros(7 + n), np.zeros(7 + n)
    work = np.zeros(4 * nx)
    v = np.random.default_rng(2).standard_normal(nx)
    sink = ctypes.c_double(0.0)
    ps = ctypes.byref(sink)
    U, R = ctypes.c_double(u), ctypes.c_long(reps)
    loops = {
        "rhs": lambda: dll.fpb_time_rhs(p, _ptr(x), U, R, _ptr(out), ps),
        "jacobian": lambda: dll.fpb_time_jacobian(p, _ptr(x), U, R, _ptr(J), _ptr(b),
                                                  _ptr(work), ps),
        "jvp": lambda: dll.fpb_time_jvp(p, _ptr(x), U, _ptr(v), R, _ptr(out), _ptr(work), ps),
        "output_derivatives": lambda: dll.fpb_time_output_derivatives(
            p, _ptr(x), U, R, _ptr(d1), _ptr(d2), _ptr(work), ps),
    }
    # the library's kernel is the one the binding checks against numpy: same J here
    dll.fpb_time_jacobian(p, _ptr(x), U, ctypes.c_long(1), _ptr(J), _ptr(b), _ptr(work), ps)
    J_ref, _ = k.jacobian(x, u)
    assert np.array_equal(J, J_ref), "the timed kernel is not the tested one"
    for f in loops.values():                   # warm-up
        f()
    times = {name: [] for name in loops}
    for _ in range(runs):
        for name, f in loops.items():
            times[name].append(f())
    med = {name: statistics.median(t) for name, t in times.items()}
    return {"n_modes": n, "preload": preload, "nx": nx,
            **{f"{name}_ns": 1e9 * t for name, t in med.items()},
            "jacobian_over_rhs": med["jacobian"] / med["rhs"],
            "fd_over_rhs": nx + 1}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--reps", type=int, default=20000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.runs < 1 or args.reps < 1:
        print("bench_jacobian: --runs and --reps must be >= 1", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        dll = build(Path(tmp))
        rows = [measure(dll, n, pre, args.runs, args.reps) for pre in (False, True)
                for n in N_MODES if not (pre and n == 0)]
    print(f"# bench_jacobian: {platform.processor() or platform.machine()}, medians of "
          f"{args.runs} runs of {args.reps} calls each, after a warm-up")
    print(f"{'n_modes':>7} {'preload':>7} {'nx':>3} {'rhs ns':>8} {'J ns':>8} {'J/rhs':>6} "
          f"{'FD/rhs':>6} {'Jv ns':>7} {'d1,d2 ns':>8}")
    for r in rows:
        print(f"{r['n_modes']:>7} {r['preload']!s:>7} {r['nx']:>3} {r['rhs_ns']:8.1f} "
              f"{r['jacobian_ns']:8.1f} {r['jacobian_over_rhs']:6.2f} {r['fd_over_rhs']:6d} "
              f"{r['jvp_ns']:7.1f} {r['output_derivatives_ns']:8.1f}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
