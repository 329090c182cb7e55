"""The compiled C kernel per communication step and per call, beside the numba kernel it replaced.

    python bench/bench_kernel.py [--runs 7] [--json FILE]

At n_modes = 4 and H = 1 ms (the FMU's defaults), medians of ``--runs`` timed repetitions after a
warm-up, all in one process, side by side:

* one communication step of RK4 with four substeps: the C loop called directly, the same through
  the stepper (what the FMU's doStep runs), and the numba loop of the previous version called
  directly; the adaptive Dormand-Prince (rtol 1e-6) through the stepper: the C loop against the
  Python loop on the C right-hand side and on the numba one (the previous version's path);
* one right-hand side: ``PlantModel.rhs`` (ctypes) against the numba kernel with its output
  allocated per call (the previous ``PlantModel.rhs``);
* the Python-to-C call overhead: a ctypes call with no argument and with three prebuilt pointer
  arguments, the same through cffi's ABI mode, and an empty numba function.

numba and cffi are not dependencies: their rows are left out when they are not installed (the
numba kernel below is a copy of the removed ``plant_fmu/kernels.py``, for this comparison only).
"""
from __future__ import annotations

import argparse
import ctypes
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from plant_fmu import kernel as pk  # noqa: E402
from plant_fmu.dynamics import plant_model  # noqa: E402
from plant_fmu.integrators import make_stepper  # noqa: E402
from plant_fmu.integrators.rk import RK4  # noqa: E402
from plant_fmu.params import PlantParams  # noqa: E402

try:
    import numba
except ImportError:  # numba is not a dependency: the comparison rows are left out
    numba = None
try:
    import cffi
except ImportError:
    cffi = None

H = 1e-3
STEPS = 200


# ---------------------------------------------------------------------- the numba kernel (old)
def _rhs(x, u, consts, I3, I5, Kd, Dd, Kg, out):
    n = I3.size
    nq = n + 2
    I0, I1, I2, g = consts[0], consts[1], consts[2], consts[3]
    I3I3, I3I5, I5I5, preload = consts[4], consts[5], consts[6], consts[7]
    phi = x[1]
    phid = x[nq + 1]
    c = math.cos(phi)
    s = math.sin(phi)
    I3eta = I3etad = ee = eed = 0.0
    for j in range(n):
        e = x[2 + j]
        ed = x[nq + 2 + j]
        I3eta += I3[j] * e
        I3etad += I3[j] * ed
        ee += e * e
        eed += e * ed
    f0 = u - (I1 * s + I3eta * c) * phid * phid - 2.0 * phid * s * I3etad
    f1 = -2.0 * phid * eed + g * (I1 * s + I3eta * c)
    I3fe = I5fe = 0.0
    for j in range(n):
        e = x[2 + j]
        fe = phid * phid * e + g * s * I3[j] - Kd[j] * e - Dd[j] * x[nq + 2 + j]
        if preload != 0.0:
            kge = 0.0
            for k in range(n):
                kge += Kg[j, k] * x[2 + k]
            fe += c * kge
            f1 -= 0.5 * s * e * kge
        out[nq + 2 + j] = fe
        I3fe += I3[j] * fe
        I5fe += I5[j] * fe
    a00 = I0 - c * c * I3I3
    a01 = -I1 * c + s * I3eta + c * I3I5
    a11 = I2 + ee - I5I5
    r0 = f0 + c * I3fe
    r1 = f1 - I5fe
    det = a00 * a11 - a01 * a01
    xdd = (a11 * r0 - a01 * r1) / det
    phidd = (a00 * r1 - a01 * r0) / det
    for i in range(nq):
        out[i] = x[nq + i]
    out[nq] = xdd
    out[nq + 1] = phidd
    for j in range(n):
        out[nq + 2 + j] += c * xdd * I3[j] - phidd * I5[j]
    return out


def _erk_steps(y, u0, du, d2u, s0, h, n_steps, A, B, C, consts, I3, I5, Kd, Dd, Kg, K, ys):
    s = B.size
    nx = y.size
    for k in range(n_steps):
        for i in range(s):
            for m in range(nx):
                acc = 0.0
                for j in range(i):
                    acc += (h * A[i, j]) * K[j, m]
                ys[m] = y[m] + acc
            st = s0 + k * h + C[i] * h
            u = u0 + st * (du + 0.5 * st * d2u)
            _rhs_nb(ys, u, consts, I3, I5, Kd, Dd, Kg, K[i])
        norm2 = 0.0
        for m in range(nx):
            acc = 0.0
            for i in range(s):
                acc += (h * B[i]) * K[i, m]
            ys[m] = y[m] + acc
            norm2 += ys[m] * ys[m]
        if not norm2 < math.inf:
            for m in range(nx):
                if not abs(ys[m]) < math.inf:
                    return k
        for m in range(nx):
            y[m] = ys[m]
    return n_steps


if numba is not None:
    _rhs_nb = numba.njit(_rhs)
    _erk_nb = numba.njit(_erk_steps)

    @numba.njit
    def _noop3(a, b, c):
        pass


def _numba_args(m):
    consts = np.array([m.I0, m.I1, m.I2, m.g, m._I3I3, m._I3I5, m._I5I5, float(m.preload)])
    return consts, m.I3, m.I5, m.Kdiag, m.Ddiag, np.ascontiguousarray(m.Kg, dtype=float)


class _NumbaRhsModel:
    """The plant as the previous version's Python loops saw it: ``rhs`` = the numba kernel with
    its output allocated per call, no compiled loops."""

    def __init__(self, m):
        self.nq, self.nx, self.initial_state = m.nq, m.nx, m.initial_state
        args = _numba_args(m)
        nx = m.nx
        self.rhs = lambda t, x, u: _rhs_nb(x, float(u), *args, np.empty(nx))


class _CRhsModel:
    """The plant with the C right-hand side but without the compiled loops."""

    def __init__(self, m):
        self.rhs, self.nq, self.nx, self.initial_state = m.rhs, m.nq, m.nx, m.initial_state


# ---------------------------------------------------------------------- timing
def per_call(fn, n, runs):
    """Median microseconds per call of ``fn`` over ``runs`` batches of ``n`` calls (one warm-up
    batch first)."""
    for _ in range(n):
        fn()
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        ts.append((time.perf_counter() - t0) / n * 1e6)
    return statistics.median(ts)


def stepper_per_step(model, method, runs, **kw):
    """Median microseconds per communication step of a stepper driven as the FMU drives it."""
    x0 = model.initial_state(phi=0.3)

    def run():
        st = make_stepper(method, model, 0.0, x0, **kw)
        t0 = time.perf_counter()
        for k in range(STEPS):
            st.u = 2.0 * math.sin(k * 0.01)
            ok, msg = st.advance((k + 1) * H)
            assert ok, msg
        return (time.perf_counter() - t0) / STEPS * 1e6

    run()
    return statistics.median(run() for _ in range(runs))


def bench(runs: int) -> dict:
    m = plant_model(PlantParams(n_modes=4))
    kern = m.kernel
    x = m.initial_state(phi=0.3)
    x[2:6] = [1e-3, -2e-4, 5e-5, -1e-5]
    y = x.copy()
    rk4 = kern.tableau(RK4.A, RK4.B, RK4.C)
    res = {"step": {}, "rhs": {}, "overhead": {}}
    step = res["step"]
    step["rk4 h = H/4: C loop, direct call"] = per_call(
        lambda: kern.fixed_steps("rk4", rk4, y, (2.0, 0.0, 0.0, 0.0), 0.0, H / 4, 4), 2000, runs)
    step["rk4 h = H/4: C loop through the stepper (the FMU's doStep)"] = stepper_per_step(
        m, "rk4", runs, h=H / 4)
    if numba is not None:
        args = _numba_args(m)
        K, ys, yy = np.empty((4, m.nx)), np.empty(m.nx), x.copy()

        def nb():
            y2 = yy.copy()
            return _erk_nb(y2, 2.0, 0.0, 0.0, 0.0, H / 4, 4, RK4.A, RK4.B, RK4.C, *args, K, ys)

        step["rk4 h = H/4: numba loop, direct call (previous version)"] = per_call(nb, 2000, runs)
    step["dopri5 rtol 1e-6: C adaptive loop through the stepper"] = stepper_per_step(
        m, "dopri5", runs, h=H / 4, rtol=1e-6, atol=1e-9)
    step["dopri5 rtol 1e-6: Python loop on the C rhs"] = stepper_per_step(
        _CRhsModel(m), "dopri5", runs, h=H / 4, rtol=1e-6, atol=1e-9)
    if numba is not None:
        step["dopri5 rtol 1e-6: Python loop on the numba rhs (previous version)"] = \
            stepper_per_step(_NumbaRhsModel(m), "dopri5", runs, h=H / 4, rtol=1e-6, atol=1e-9)

    res["rhs"]["PlantModel.rhs (C by ctypes, new array)"] = per_call(
        lambda: m.rhs(0.0, x, 1.0), 20000, runs)
    if numba is not None:
        nbm = _NumbaRhsModel(m)
        res["rhs"]["numba kernel, new array (previous PlantModel.rhs)"] = per_call(
            lambda: nbm.rhs(0.0, x, 1.0), 20000, runs)

    ov = res["overhead"]
    lib = pk.library()
    abi = lib.fp_plant_abi
    tip = lib.fp_tip
    buf, out = np.zeros(m.nx), np.zeros(2)
    p, px, pout = kern._p, ctypes.c_void_p(buf.ctypes.data), ctypes.c_void_p(out.ctypes.data)
    ov["ctypes: call with no argument (fp_plant_abi)"] = per_call(abi, 50000, runs)
    ov["ctypes: fp_tip with 3 prebuilt pointer arguments"] = per_call(
        lambda: tip(p, px, pout), 50000, runs)
    ov["PlantKernel.tip(x): copy in, call, two floats out"] = per_call(
        lambda: kern.tip(x), 50000, runs)
    if cffi is not None:
        ffi = cffi.FFI()
        ffi.cdef("int fp_plant_abi(void); void fp_tip(const void *p, const double *x, "
                 "double *tip);")
        clib = ffi.dlopen(lib._name)
        cp = ffi.cast("void *", ctypes.addressof(kern._struct))
        cx = ffi.cast("double *", buf.ctypes.data)
        cout = ffi.cast("double *", out.ctypes.data)
        ov["cffi ABI mode: call with no argument"] = per_call(clib.fp_plant_abi, 50000, runs)
        ov["cffi ABI mode: fp_tip with 3 prebuilt pointer arguments"] = per_call(
            lambda: clib.fp_tip(cp, cx, cout), 50000, runs)
    if numba is not None:
        a3 = np.zeros(3)
        ov["numba: an empty function of 3 array arguments"] = per_call(
            lambda: _noop3(a3, a3, a3), 50000, runs)
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="timed repetitions after the warm-up")
    ap.add_argument("--json", type=Path, help="also store the results here")
    a = ap.parse_args(argv)
    res = bench(a.runs)
    for title, unit in (("step", "us per 1 ms communication step, n_modes = 4"),
                        ("rhs", "us per right-hand side, n_modes = 4"),
                        ("overhead", "us per call from Python")):
        print(f"\n{unit}")
        for name, us in res[title].items():
            print(f"| {name} | {us:.2f} |")
    if numba is None:
        print("\n(numba is not installed: `pip install numba` for the previous version's rows)")
    if a.json:
        meta = {"python": platform.python_version(), "numpy": np.__version__,
                "numba": getattr(numba, "__version__", None), "runs": a.runs}
        a.json.write_text(json.dumps({"meta": meta, **res}, indent=1))


if __name__ == "__main__":
    main()
