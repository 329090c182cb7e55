"""Write the regression inputs of the fuzz corpus (``tests/fuzz/corpus/<model>/regress-*``).

    python tests/fuzz/make_corpus.py

Each input is a program for ``fuzz_fmi.c`` (the encoder below mirrors its decoder) that replays
one defect of issue 23 on both FMI versions, so that the corpus replay (``fuzz.py``, the test
``tests/export/test_fuzz.py``) fails if it comes back:

* a crafted FMU state: a serialised state edited (a parameter, a size, a mode, the stepper, the
  filter) with its checksum recomputed, deserialised and restored, then stepped;
* a step that silently did nothing or hung: a communication step of 1e19 or 1e300, a plant step
  of 1e-300 or 5e-324 (two doSteps);
* non-finite outputs: phi_dot0 = 1e160 or DBL_MAX, then every output read;
* ``fmi3GetFloat64(inst, NULL, 2, NULL, 2)``;
* parameters whose derived quantities underflow (L = 1e-200, rho = 5e-324).

Inputs that libFuzzer found (``regress-string-handed-back``: a string from getString set back
into the same variable, a strcpy of overlapping memory) are kept as they were found.
"""
from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

INTERESTING = [
    0.0, -0.0, 1.0, -1.0, 1e-3, 2.5e-4, 2e-3, 0.5, 0.3, 1.5707963267948966, 2.0, 4.0, 8.0, 9.0,
    24.0, 100.0, 101.0, 1e6, 1e-300, 5e-324, 2.2250738585072014e-308, 1e19, 1e160, 1e200, 1e300,
    1.7976931348623157e308, math.inf, -math.inf, math.nan, 1e15, 1e-15, 1e-16, 1e16, 1e-9, -1e-3,
    9.223372036854775807e18, 4294967296.0, 2147483648.0, -2147483649.0, 0.1, 97.3, 500.0]
HEADER = 24
KNOWN = ["rk4", "euler", "symplectic_euler", "dopri5", "exponential", "linear", "nonlinear",
         "radau", "exact", "stiffened", "modal", "kelvin-voigt"]
#: the plant's String parameters' value references (plant_fmu/interface.py)
FIDELITY, INTEGRATOR, DAMPING = 29, 30, 72


def f64(x: float) -> bytes:
    for i, y in enumerate(INTERESTING):
        if struct.pack("<d", x) == struct.pack("<d", y):
            return bytes([i])
    return b"\xf0" + struct.pack("<d", x)


def u16(x: int) -> bytes:
    return struct.pack("<H", x & 0xFFFF)


class Program:
    """A program for fuzz_fmi.c: ``op(code, ...)`` appends one operation."""

    def __init__(self, version: int):
        self.version = version
        self.b = bytearray([1 if version == 3 else 0])

    def op(self, code, vrs=(), dvs=(), ivs=(), n=None, nul=False, a=1, b=1, extra=b"", svs=()):
        vrs, dvs, ivs, svs = list(vrs), list(dvs), list(ivs), list(svs)
        n = len(vrs) if n is None else n
        self.b += bytes([code, n])
        if n > 0:
            self.b.append(0 if nul else 1)
        if self.version == 3:
            self.b.append(1)                                   # nValues = nvr
        for k in range(4):
            self.b.append(vrs[k] if k < len(vrs) else 0)
            self.b += f64(dvs[k] if k < len(dvs) else 0.0)
            iv = ivs[k] if k < len(ivs) else 0
            self.b += u16(iv) + u16(iv >> 16)
            if self.version == 3:
                self.b.append(1)
                self.b.append(KNOWN.index(svs[k]) if k < len(svs) else 0)
        self.b += bytes([a, b]) + extra
        return self

    # the operations, by FMI version
    def start(self, reals=(), ints=(), init=True, strings=()):
        """Instantiate, set parameters (value reference -> value), initialise."""
        v2 = self.version == 2
        self.op(0, a=1 if v2 else 1, b=1 if v2 else 0)
        if v2:
            self.op(1, dvs=[0.0, 0.0, 0.0], a=0, b=0)          # setupExperiment(start 0)
            self.op(2)
        else:
            self.op(1, dvs=[0.0, 0.0, 0.0], a=0, b=0)          # enterInitializationMode
        for vr, x in reals:
            self.op(6 if v2 else 5, vrs=[vr], dvs=[x], a=1)
        for vr, x in ints:
            self.op(7 if v2 else 6, vrs=[vr], ivs=[x])
        self.strings(strings)
        if init:
            self.op(3 if v2 else 2)
        return self

    def strings(self, items):
        """Set String parameters (value reference -> one of KNOWN)."""
        for vr, text in items:
            if self.version == 3:
                self.op(8, vrs=[vr], svs=[text])
            else:
                self.op(9, vrs=[vr], extra=bytes([40 + KNOWN.index(text), 40, 40, 1]))
        return self

    def roundtrip(self):
        """Serialise the state, deserialise it, restore it (no edit)."""
        return self.op(17, a=1) if self.version == 2 else self.op(15, a=1, extra=b"\x00")

    def model_exchange(self, reals=(), ints=()):
        """A Model-Exchange instance through initialisation, then every Model-Exchange call
        (fuzz_fmi.c's operation 24 / 22: the sub-operation in ``a``) and the derivatives."""
        v2 = self.version == 2
        me = 24 if v2 else 22
        if v2:
            self.op(0, a=0, b=1)                                # a % 8 == 0: Model Exchange
            self.op(1, dvs=[0.0, 0.0, 0.0], a=0, b=0)
            self.op(2)
        else:
            self.op(0, a=1, b=7)                                # b % 8 == 7: Model Exchange
            self.op(1, dvs=[0.0, 0.0, 0.0], a=0, b=0)
        for vr, x in reals:
            self.op(6 if v2 else 5, vrs=[vr], dvs=[x], a=1)
        for vr, x in ints:
            self.op(7 if v2 else 6, vrs=[vr], ivs=[x])
        self.op(3 if v2 else 2)
        subs = ((1, 2, 4, 6, 7 | 32, 8, 9, 10, 11, 5, 3, 0) if v2
                else (1, 3, 5, 6 | 32, 7, 8, 9, 10, 11, 4, 2, 0))
        for a in subs:
            self.op(me, vrs=[3, 4, 5, 0], dvs=[0.5, 1.0, 1.0, 0.0], ivs=[1, 1, 1, 1], n=2, a=a,
                    b=3)
        return self

    def derivatives(self, vr, order, value):
        return self.op(21, vrs=[vr], ivs=[order], dvs=[value]) if self.version == 2 else self

    def step(self, h):
        return self.op(4 if self.version == 2 else 3, dvs=[0.0, h])

    def outputs(self):
        return self.op(10 if self.version == 2 else 9)

    def crafted(self, edits):
        """Serialise, write (offset, kind, value) edits, recompute the checksum, restore."""
        extra = bytes([len(edits)])
        for at, kind, value in edits:
            extra += bytes([kind]) + u16(at)
            extra += f64(value) if kind == 0 else u16(value) + u16(value >> 16)
        return self.op(18 if self.version == 2 else 15, a=1, extra=extra)

    def fmi3_null_arrays(self):
        return self.op(5, a=8)                                  # a % 8 == 0


# ---------------------------------------------------------------------- the layout of a state
def layout(model: str, strings: dict) -> dict:
    """Offsets of the items of a serialised state of ``model`` (the payload of fpm_core.c's
    serialize(), then fpm_model_save()), for the default strings of the table."""
    from fmu_common.variables import native_variables
    from orchestration.export.model_description import TABLES

    _, table = TABLES[model]
    at = {"mode": HEADER, "discarded": HEADER + 4}
    pos = HEADER + 8
    for vr, v in native_variables(table):
        if v.causality in ("output", "local"):     # calculated: not in a state
            continue
        at[v.name] = pos
        pos += 4 + len(strings.get(v.name, v.start)) if v.type == "String" else 8
    if model == "PDLowPass":
        for name, size in (("t0", 8), ("t", 8), ("initialized", 4), ("d", 48), ("xc0", 8),
                           ("xc1", 8), ("F", 8)):
            at[name] = pos
            pos += size
    else:
        for name, size in (("t0", 8), ("dF", 8), ("d2F", 8), ("initialized", 4), ("failed", 4),
                           ("error", 4), ("t", 8), ("t_base", 8), ("k", 8), ("y", 8)):
            at[name] = pos
            pos += size
    return at


def regressions(model: str, version: int) -> dict:
    out = {}
    P = lambda: Program(version)  # noqa: E731
    at = layout(model, {})
    if model == "FlexiblePendulum":
        vr = {"n_modes": 26, "n_elements": 27, "step": 31, "phi_dot0": 38, "L": 19, "rho": 20,
              "phi0": 36}
        base = lambda: P().start(reals=[(vr["phi0"], 0.3)]).step(1e-3)  # noqa: E731
        out["crafted-n-modes"] = base().crafted([(at["n_modes"], 0, 4194304.0)]).step(1e-3)
        out["crafted-n-elements"] = base().crafted([(at["n_elements"], 0, 1e19)]).step(1e-3)
        out["crafted-not-ready"] = base().crafted([(at["initialized"], 1, 0)]).step(1e-3)
        out["crafted-mode"] = base().crafted([(at["mode"], 1, 0x7FFFFFFF)]).step(1e-3)
        out["crafted-k"] = base().crafted([(at["k"], 0, 9.223372036854775807e18)]).step(1e-3)
        out["crafted-state-nan"] = base().crafted([(at["y"], 0, math.nan)]).outputs()
        out["crafted-time"] = base().crafted([(at["t"], 0, math.inf)]).step(1e-3)
        out["crafted-error-length"] = base().crafted([(at["error"], 1, 1048576)]).step(1e-3)
        out["step-1e19"] = P().start().step(1e19).outputs()
        out["step-1e300"] = P().start().step(1e300).outputs()
        out["plant-step-1e-300"] = P().start(reals=[(vr["step"], 1e-300)]).step(1e-3).step(1e-3)
        out["plant-step-5e-324"] = P().start(reals=[(vr["step"], 5e-324)]).step(1e-3).step(1e-3)
        out["phi-dot0-1e160"] = P().start(reals=[(vr["phi_dot0"], 1e160)]).outputs().step(1e-3)
        out["phi-dot0-dbl-max"] = P().start(
            reals=[(vr["phi_dot0"], 1.7976931348623157e308)]).outputs()
        out["L-underflow"] = P().start(reals=[(vr["L"], 1e-200)]).outputs().step(1e-3)
        out["rho-subnormal"] = P().start(reals=[(vr["rho"], 5e-324)]).outputs().step(1e-3)
        # the exact rung (issue 27): its state [q, qd, qdd, a] follows the floating frame's
        # items; two elements (nq = 11), two modes (nx = 8)
        # (the exact rung damps by material: its runs say damping = 'kelvin-voigt')
        ex = layout(model, {"fidelity": "exact", "damping": "kelvin-voigt"})
        xb = ex["y"] + 8 * 8 * 2 + 8 * 5 + 4 + 32 + 4
        nq = 4 * 2 + 3
        exact = lambda: P().start(reals=[(vr["phi0"], 0.3)], ints=[(27, 2), (26, 2)],  # noqa: E731
                                  strings=[(FIDELITY, "exact"),
                                           (DAMPING, "kelvin-voigt")]).step(1e-3)
        out["crafted-exact-nan"] = exact().crafted([(xb, 0, math.nan)]).step(1e-3)
        out["crafted-exact-tip-slope"] = exact().crafted(
            [(xb + 8 * (nq - 2), 0, 0.0), (xb + 8 * (nq - 1), 0, 0.0)]).outputs().step(1e-3)
        out["crafted-exact-root-turned"] = exact().crafted([(xb + 16, 0, -1.0)]).step(1e-3)
        out["crafted-exact-huge"] = exact().crafted([(xb + 8 * nq, 0, 1e300)]).step(1e-3)
    else:
        vr = {"phi_o": 0, "filter_order": 13, "force_limit": 16}
        base = lambda: P().start(reals=[(vr["phi_o"], 0.1)]).step(1e-3)  # noqa: E731
        out["crafted-filter-order"] = base().crafted([(at["filter_order"], 0, 1048576.0)]).step(1e-3)
        out["crafted-filter-state"] = base().crafted([(at["xc0"], 0, math.inf)]).outputs()
        out["crafted-force"] = base().crafted([(at["F"], 0, -math.inf)]).outputs()
        out["crafted-force-limit"] = base().crafted([(at["force_limit"], 0, -1.0)]).step(1e-3)
        out["crafted-not-initialised"] = base().crafted([(at["initialized"], 1, 0)]).step(1e-3)
        out["step-1e300"] = P().start().step(1e300).outputs()
    if version == 3:
        out["fmi3-null-arrays"] = P().start().fmi3_null_arrays()
    return {f"regress-fmi{version}-{k}": bytes(p.b) for k, p in out.items()}


def seeds(model: str, version: int) -> dict:
    """Programs that reach each method and mode, for the fuzzer to start from."""
    P = lambda: Program(version)  # noqa: E731
    out = {}
    if model == "FlexiblePendulum":
        for integ, fid, extra in (("dopri5", "nonlinear", []), ("exponential", "linear", []),
                                  ("symplectic_euler", "nonlinear", [(26, 8)]),
                                  ("euler", "nonlinear", [(26, 0)])):
            p = P().start(reals=[(36, 0.3), (34, 0.5)], ints=extra,
                          strings=[(INTEGRATOR, integ), (FIDELITY, fid)])
            out[f"{integ}"] = (p.derivatives(0, 1, 2.0).step(1e-3).roundtrip().step(2e-3)
                               .outputs().step(0.5).step(0.5).outputs())
        out["preload"] = P().start(reals=[(36, 0.3)], ints=[(28, 1)]).step(1e-3).outputs()
        out["exact"] = (P().start(reals=[(36, 0.3)], ints=[(27, 2), (26, 2)],
                                  strings=[(FIDELITY, "exact"), (DAMPING, "kelvin-voigt")])
                        .derivatives(0, 1, 2.0).step(1e-3).roundtrip().step(2e-3).outputs()
                        .step(0.5).outputs())
        # the exact rung refuses the modal law with zeta > 0 (an error at initialisation)
        out["exact-modal"] = (P().start(reals=[(36, 0.3)], ints=[(27, 2), (26, 2)],
                                        strings=[(FIDELITY, "exact"), (DAMPING, "modal")])
                              .step(1e-3).outputs())
        out["kelvin-voigt"] = (P().start(reals=[(36, 0.3), (24, 0.01)],
                                         strings=[(DAMPING, "kelvin-voigt")])
                               .derivatives(0, 1, 2.0).step(1e-3).roundtrip().step(2e-3)
                               .outputs().step(0.5).outputs())
        out["stiffened"] = (P().start(reals=[(36, 0.3)], ints=[(27, 2), (26, 2)],
                                      strings=[(FIDELITY, "stiffened")])
                            .derivatives(0, 1, 2.0).step(1e-3).roundtrip().step(2e-3).outputs()
                            .step(0.5).outputs())
        out["stiffened-largest"] = (P().start(reals=[(36, 0.3)], ints=[(27, 100), (26, 8)],
                                              strings=[(FIDELITY, "stiffened")])
                                    .step(1e-3).roundtrip().outputs())   # the most mass points
        out["model-exchange"] = P().model_exchange(reals=[(36, 0.3)]).roundtrip()
    else:
        for order in (0, 1, 2):
            p = P().start(reals=[(0, 0.1), (16, 10.0)], ints=[(13, order)])
            out[f"order{order}"] = (p.derivatives(0, 1, 3.0).derivatives(1, 2, -1.0).step(1e-3)
                                    .roundtrip().step(2e-3).outputs())
        out["model-exchange"] = P().model_exchange(reals=[(0, 0.1)], ints=[(13, 2)]).roundtrip()
    return {f"seed-fmi{version}-{k}": bytes(p.b) for k, p in out.items()}


def main() -> int:
    for model in ("FlexiblePendulum", "PDLowPass"):
        folder = HERE / "corpus" / model
        folder.mkdir(parents=True, exist_ok=True)
        for version in (2, 3):
            for name, data in {**regressions(model, version), **seeds(model, version)}.items():
                (folder / name).write_bytes(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
