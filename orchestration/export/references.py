"""Reference results of the FMUs in the FMI cross-check layout (``tests/reference/<Model>/``):
``<Model>_in.csv`` (inputs), ``<Model>_ref.csv`` (the result) and ``<Model>_ref.opt`` (options).

    write_references(fmus)       regenerate them from built FMUs (on purpose, after a deliberate
                                 change of the physics or of the FMUs' defaults)
    simulate_reference_case(fmu, name)   a fresh run of one FMU with its input file and options
    compare_with_reference(result, reference)   the largest deviation per signal
"""
from __future__ import annotations

from pathlib import Path

from .python_fmus import ROOT

__all__ = ["REFERENCE_DIR", "REFERENCE_TOLERANCE", "reference_files", "read_opt",
           "simulate_reference_case", "compare_with_reference", "write_references"]

REFERENCE_DIR = ROOT / "tests" / "reference"


#: Comparison band of a fresh run against the committed reference: for each signal,
#: |y - y_ref| <= REFERENCE_TOLERANCE * (max y_ref - min y_ref) at every sample. Round-off grows at
#: most ~1e3 times over the second (the pendulum's unstable root is +7/s), so a run on another
#: machine stays ~1e-10 inside it, while a change of the physics by 1e-3 leaves it.
REFERENCE_TOLERANCE = 1e-6


def _reference_cases():
    """name -> (options of the .opt file, input columns {name: f(t)})."""
    import numpy as np

    two_pi = 2 * np.pi

    def held(*names):
        """The input-derivative columns, all 0: fmpy holds each input over a step (zero-order
        hold), and an input file that names every input keeps fmpy from warning."""
        return {n: (lambda t: np.zeros_like(t)) for n in names}

    return {
        # the plant alone (defaults: 4 modes, rk4), pushed then pulled, with a ripple at the
        # closed-loop bending frequency (24 Hz = 150 rad/s). The pull is sized so that the pair
        # leaves the unstable pendulum mode (+7/s) almost unexcited: the pendulum stays within
        # 0.02 rad for the whole second while the bending modes ring
        "FlexiblePendulum": (
            {"StartTime": 0.0, "StopTime": 1.0, "StepSize": 1e-3, "RelTol": 1e-6},
            {"F_c": lambda t: (np.where(t < 0.05, 20.0, 0.0)
                               - np.where((t >= 0.05) & (t < 0.1), 29.148, 0.0)
                               + 3.0 * np.sin(two_pi * 24.0 * t)),
             **held("dF_c", "d2F_c")}),
        # the controller alone (defaults: PD + the designed 2nd-order filter, 97.3 rad/s, damping
        # 0.1) on sensor signals with a step, a slow swing and a bending-frequency ripple
        "PDLowPass": (
            {"StartTime": 0.0, "StopTime": 1.0, "StepSize": 1e-3, "RelTol": 1e-6},
            {"phi_o": lambda t: (0.1 * np.sin(two_pi * 2.0 * t) + 0.01 * np.sin(150.0 * t)
                                 + np.where(t >= 0.5, 0.05, 0.0)),
             "omega_o": lambda t: (0.2 * np.pi * 2.0 * np.cos(two_pi * 2.0 * t)
                                   + 1.5 * np.cos(150.0 * t)),
             "x_o": lambda t: 0.5 * t * t,
             **held(*(f"{d}{n}" for d in ("d", "d2") for n in ("phi_o", "omega_o", "x_o")))}),
    }


def reference_files(name: str, ref_dir: Path = REFERENCE_DIR) -> dict:
    d = Path(ref_dir) / name
    return {"in": d / f"{name}_in.csv", "ref": d / f"{name}_ref.csv", "opt": d / f"{name}_ref.opt"}


def read_opt(path) -> dict:
    from fmpy.util import read_ref_opt_file

    return read_ref_opt_file(str(path))


def simulate_reference_case(fmu, name: str, ref_dir: Path = REFERENCE_DIR, start_values=None):
    """Simulate ``fmu`` alone with its committed input file and options (fmpy.simulate_fmu)."""
    from fmpy import simulate_fmu
    from fmpy.util import read_csv

    files = reference_files(name, ref_dir)
    opt = read_opt(files["opt"])
    outputs = {"FlexiblePendulum": ["x_o", "x_dot", "phi_o", "omega_o", "tip_deflection",
                                    "eta_1", "energy"],
               "PDLowPass": ["F_c"]}[name]
    return simulate_fmu(str(fmu), start_time=opt["StartTime"], stop_time=opt["StopTime"],
                        step_size=opt["StepSize"], output_interval=opt["StepSize"],
                        input=read_csv(str(files["in"])), output=outputs,
                        start_values=start_values or {})


def compare_with_reference(result, reference) -> dict:
    """name -> largest deviation of ``result`` from ``reference`` relative to the reference's
    range (the test fails above :data:`REFERENCE_TOLERANCE`)."""
    import numpy as np

    if result.shape != reference.shape or not np.allclose(result["time"], reference["time"],
                                                          rtol=0, atol=1e-9):
        raise ValueError("the result's time grid differs from the reference's")
    out = {}
    for n in reference.dtype.names[1:]:
        span = float(np.max(reference[n]) - np.min(reference[n]))
        dev = float(np.max(np.abs(result[n] - reference[n])))
        out[n] = dev / span if span > 0 else dev
    return out


def write_references(fmus: dict, ref_dir: Path = REFERENCE_DIR) -> dict:
    """Regenerate the input files, options and reference results of every FMU; return paths."""
    import numpy as np
    from fmpy.util import write_csv

    written = {}
    for name, (opt, inputs) in _reference_cases().items():
        files = reference_files(name, ref_dir)
        files["in"].parent.mkdir(parents=True, exist_ok=True)
        n = round((opt["StopTime"] - opt["StartTime"]) / opt["StepSize"])
        t = opt["StartTime"] + np.arange(n + 1) * opt["StepSize"]
        arr = np.zeros(t.size, dtype=[("time", "f8")] + [(k, "f8") for k in inputs])
        arr["time"] = t
        for k, f in inputs.items():
            arr[k] = f(t)
        write_csv(str(files["in"]), arr)
        files["opt"].write_text("".join(f"{k},{v!r}\n" for k, v in opt.items()))
        result = simulate_reference_case(fmus[name], name, ref_dir)
        write_csv(str(files["ref"]), result)
        written[name] = files
    return written
