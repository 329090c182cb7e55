"""Cost of one communication step of each FMU, side by side with the FMI overhead floor.

    python bench/bench_fmu.py [--steps 1000] [--runs 7] [--json bench/results/fmu_bench.json]

For each case the loop is what a master does per 1 ms communication step through fmpy's
FMU2Slave: ``setReal`` of the inputs, ``doStep``, ``getReal`` of the outputs it needs. The floor
is the same loop over a trivial pythonfmu FMU (``y = u``): what FMI, ctypes and pythonfmu cost
before any model runs. Every run restarts from the same saved FMU state (t = 0) and takes
``--steps`` steps; the first run is a warm-up; the table gives the median and the minimum over
``--runs`` runs, in microseconds per step.
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import controller_fmu.pd_lowpass  # noqa: E402,F401  (the project's packages first, see conftest)
import plant_fmu.dynamics  # noqa: E402,F401
from orchestration.export import build_fmus  # noqa: E402

H = 1e-3

TRIVIAL = '''from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class Trivial(Fmi2Slave):
    """y = u: the FMI overhead floor."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Real("u", causality=Fmi2Causality.input,
                                    variability=Fmi2Variability.continuous, start=0.0))
        self.register_variable(Real("y", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.continuous,
                                    initial=Fmi2Initial.exact, start=0.0))

    def do_step(self, current_time, step_size):
        self.y = self.u
        return True


if "_PYTHONFMU_DICT_REFS" not in globals():   # see orchestration/export/python_fmus.py
    _PYTHONFMU_DICT_REFS = [globals()] * 1024
'''


def build_trivial(folder: Path) -> Path:
    src = folder / "Trivial.py"
    src.write_text(TRIVIAL)
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(src), "-d", str(folder)],
                   check=True, capture_output=True, cwd=folder)
    return folder / "Trivial.fmu"


class Case:
    """One FMU instance and the loop of one benchmark case."""

    def __init__(self, label, path, inputs, outputs, start_values=None):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        self.label = label
        self.dir = extract(str(path))
        md = read_model_description(self.dir)
        vr = {v.name: v.valueReference for v in md.modelVariables}
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self.dir,
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName=label.replace(" ", "_"))
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        for name, value in (start_values or {}).items():
            t = next(v.type for v in md.modelVariables if v.name == name)
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger,
                      "String": self.fmu.setString}[t]
            setter([vr[name]], [value])
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.vr_in = [vr[n] for n in inputs]
        self.vr_out = [vr[n] for n in outputs]
        self.start = self.fmu.getFMUstate()

    def run(self, values) -> float:
        """Seconds for len(values) steps of setReal + doStep + getReal, from the saved state."""
        fmu, vr_in, vr_out = self.fmu, self.vr_in, self.vr_out
        set_real, do_step, get_real = fmu.setReal, fmu.doStep, fmu.getReal
        fmu.setFMUstate(self.start)
        t0 = time.perf_counter()
        for k, u in enumerate(values):
            set_real(vr_in, u)
            do_step(k * H, H)
            get_real(vr_out)
        return time.perf_counter() - t0

    def close(self):
        self.fmu.freeFMUstate(self.start)
        self.fmu.terminate()
        self.fmu.freeInstance()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1000, help="steps per run (1 ms each)")
    ap.add_argument("--runs", type=int, default=7, help="timed runs after one warm-up")
    ap.add_argument("--json", default=str(ROOT / "bench" / "results" / "fmu_bench.json"),
                    help="where to write the results ('' to skip)")
    args = ap.parse_args(argv)

    fmus = build_fmus()
    tmp = Path(tempfile.mkdtemp(prefix="flexpend_bench_"))
    trivial = build_trivial(tmp)
    n = args.steps
    force = [[0.5 * math.sin(2 * math.pi * 5 * k * H)] for k in range(n)]
    sensors = [[0.01 * math.sin(12 * k * H), 0.12 * math.cos(12 * k * H), 0.001 * k * H]
               for k in range(n)]
    sensor_names = ["phi_o", "omega_o", "x_o"]
    plant_sensors = ["x_o", "phi_o", "omega_o"]
    all_outputs = ["x_o", "x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1", "energy"]
    plant = fmus["FlexiblePendulum"]
    cases = [
        (Case("trivial pythonfmu FMU (floor)", trivial, ["u"], ["y"]), force),
        (Case("PDLowPass (2nd-order filter)", fmus["PDLowPass"], sensor_names, ["F_c"]), sensors),
        (Case("PDLowPass (no filter)", fmus["PDLowPass"], sensor_names, ["F_c"],
              {"filter_order": 0}), sensors),
        (Case("FlexiblePendulum n_modes=0", plant, ["F_c"], plant_sensors,
              {"n_modes": 0}), force),
        (Case("FlexiblePendulum n_modes=4", plant, ["F_c"], plant_sensors,
              {"n_modes": 4}), force),
        (Case("FlexiblePendulum n_modes=4, all 7 outputs", plant, ["F_c"], all_outputs,
              {"n_modes": 4}), force),
        (Case("FlexiblePendulum n_modes=4, energy_limit=INF", plant, ["F_c"], plant_sensors,
              {"n_modes": 4, "energy_limit": math.inf}), force),
        (Case("FlexiblePendulum n_modes=4, step=1e-3", plant, ["F_c"], plant_sensors,
              {"n_modes": 4, "step": 1e-3}), force),
        (Case("FlexiblePendulum n_modes=4, dopri5", plant, ["F_c"], plant_sensors,
              {"n_modes": 4, "integrator": "dopri5"}), force),
    ]
    results = []
    try:
        for case, values in cases:
            case.run(values)                                  # warm-up (JIT, caches)
            times = [case.run(values) / n * 1e6 for _ in range(args.runs)]
            results.append({"case": case.label, "median_us": statistics.median(times),
                            "min_us": min(times), "runs": times})
    finally:
        for case, _ in cases:
            case.close()
    floor = results[0]["median_us"]
    print(f"setReal + doStep + getReal per 1 ms step, fmpy {__import__('fmpy').__version__}, "
          f"pythonfmu {__import__('pythonfmu').__version__}, Python {platform.python_version()}, "
          f"{n} steps x {args.runs} runs (median, min), microseconds")
    print(f"{'case':45s} {'median':>8s} {'min':>8s} {'above floor':>12s}")
    for r in results:
        print(f"{r['case']:45s} {r['median_us']:8.1f} {r['min_us']:8.1f} "
              f"{r['median_us'] - floor:12.1f}")
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"steps": n, "runs": args.runs, "step_size": H,
                                   "python": platform.python_version(),
                                   "machine": platform.machine(), "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
