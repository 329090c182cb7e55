"""What the benchmarks share: the trivial FMUs (the FMI overhead floor), the co-simulation and
monolithic runs of a scene, the error measure and the timing discipline.

* **Error**: the largest absolute error of ``phi_o`` over the run, on the scene's output grid,
  against the monolithic reference (:func:`orchestration.studies.reference.simulate_reference`, DOP853 at
  rtol = atol = 1e-12).
* **Time**: the median of ``runs`` timed repetitions after one untimed warm-up (JIT compilation,
  caches, page faults), with ``time.perf_counter``. Co-simulation times are the master's
  ``RunStats.wall_time`` (initialisation and stepping; FMU loading excluded, as for a loop that
  runs many times), monolithic times the ``solve_ivp`` call.
* **One core**: BLAS threads are limited to one before numpy is imported.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from orchestration.export import build_fmus  # noqa: E402
from orchestration.cosim.master import Master
from orchestration.cosim.model_exchange import ModelExchangeMaster, ModelExchangeUnit
from orchestration.cosim.slave import Slave
from orchestration.scene.wiring import parse_connection  # noqa: E402
from orchestration.studies.reference import ClosedLoop, simulate_reference  # noqa: E402
from orchestration.job import controller_start_values, plant_start_values  # noqa: E402
from orchestration.scene.records import DEFAULT_CONNECTIONS
from orchestration.scene.schema import load_scene  # noqa: E402

__all__ = ["ROOT", "RESULTS", "product_fmus", "trivial_fmus", "trivial_native_fmus", "CoSim", "monolithic",
           "reference", "median_time", "COUPLING_RECORD", "load_scene"]

RESULTS = ROOT / "bench" / "results"

#: What every timed loop records: the coupling signals only, so that the real and the trivial
#: loops do the same master work.
COUPLING_RECORD = {"phi_o": ("plant", "phi_o"), "omega_o": ("plant", "omega_o"),
                   "x": ("plant", "x_o"), "F_c": ("controller", "F_c")}

_TRIVIAL = '''from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real


class {name}(Fmi2Slave):
    """{doc}"""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
{init}

    def do_step(self, current_time, step_size):
{step}
        return True


if "_PYTHONFMU_DICT_REFS" not in globals():   # see orchestration/export/python_fmus.py
    _PYTHONFMU_DICT_REFS = [globals()] * 1024
'''


def _variables(inputs, outputs):
    lines = []
    for n in (*inputs, *outputs):
        lines.append(f"        self.{n} = 0.0")
    for n in inputs:
        lines.append(f"        self.register_variable(Real({n!r}, causality=Fmi2Causality.input, "
                     f"variability=Fmi2Variability.continuous, start=0.0))")
    for n in outputs:
        lines.append(f"        self.register_variable(Real({n!r}, causality=Fmi2Causality.output, "
                     f"variability=Fmi2Variability.continuous, initial=Fmi2Initial.exact, "
                     f"start=0.0))")
    return "\n".join(lines)


def trivial_fmus(folder: Path | None = None) -> dict:
    """Two pythonfmu FMUs with the interfaces of the product's (same variable names, so the same
    connections), whose ``doStep`` only copies a scaled input: ``{"plant": path, "controller":
    path}``. The loop over them costs what FMI, ctypes, pythonfmu and the master cost."""
    folder = Path(folder or tempfile.mkdtemp(prefix="flexpend_trivial_"))
    specs = {
        "plant": ("TrivialPlant", "F_c -> x_o, phi_o, omega_o: the plant's interface, no model.",
                  ("F_c",), ("x_o", "phi_o", "omega_o"),
                  "        self.x_o = self.phi_o = self.omega_o = 1e-3 * self.F_c"),
        "controller": ("TrivialController", "phi_o, omega_o, x_o -> F_c: the controller's "
                       "interface, no model.", ("phi_o", "omega_o", "x_o"), ("F_c",),
                       "        self.F_c = -0.5 * (self.phi_o + self.omega_o + self.x_o)"),
    }
    paths = {}
    for key, (name, doc, inputs, outputs, step) in specs.items():
        src = folder / f"{name}.py"
        src.write_text(_TRIVIAL.format(name=name, doc=doc, init=_variables(inputs, outputs),
                                       step=step))
        subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(src), "-d",
                        str(folder)], check=True, capture_output=True, cwd=folder)
        paths[key] = folder / f"{name}.fmu"
    return paths


def trivial_native_fmus(folder: Path | None = None) -> dict:
    """Two native FMI 2.0 FMUs with the product's interfaces (same names: the same connections)
    whose step copies an input, built on the product's FMI layer (``fmu_common/native/fmi2.c``) with
    ``bench/native/trivial_model.c``: ``{"plant": path, "controller": path}``. The loop over them
    costs what FMI and the master cost (the master's compiled loop takes them, as it takes the
    product's native FMUs)."""
    import zipfile

    from fmu_common import kernels
    from fmu_common.variables import ModelInfo, Variable
    from orchestration.export import model_description as mdesc
    from orchestration.export import native_fmus

    folder = Path(folder or tempfile.mkdtemp(prefix="flexpend_trivial_native_"))
    specs = {"plant": ("TrivialPlant", ("F_c",), ("x_o", "phi_o", "omega_o")),
             "controller": ("TrivialController", ("phi_o", "omega_o", "x_o"), ("F_c",))}
    out = {}
    for key, (name, ins, outs) in specs.items():
        table = tuple([Variable(n, "input", "Real", "input", None, 0.0) for n in ins]
                      + [Variable(n, "output", "Real", "output") for n in outs])
        model = ModelInfo(name, "trivial", "0", 0.0, 1.0, 1e-3)
        mdesc.TABLES[name] = (model, table)
        gen = folder / f"gen_{name}"
        gen.mkdir(parents=True, exist_ok=True)
        token = "{00000000-0000-4000-8000-%012d}" % len(ins)
        # a table of its own gets no offers and no clocks from generate_header: the clock hooks
        # of a model without clocks come from the product's generator, as in its own FMUs
        (gen / "fpm_vars.h").write_text(
            native_fmus.generate_header(name, token, table=table, mode_tables=False)
            + "\n".join(native_fmus._clock_lines(name)) + "\n")
        lib = folder / f"{name}.so"
        # the product's flags (native_fmus.compile_command: link-time optimisation too) and
        # --no-undefined: a model hook that trivial_model.c lacks fails here, not when the FMU
        # is loaded
        cmd = [kernels.find_compiler(), *kernels.CFLAGS, *native_fmus.FMU_CFLAGS, f"-I{gen}",
               f"-I{native_fmus.SRC}", f"-I{native_fmus.fmi_include_dir()}", "-fPIC", "-shared",
               "-Wl,--no-undefined", "-o", str(lib), str(native_fmus.SRC / "fmi2.c"),
               *(str(native_fmus.SRC / f) for f in native_fmus.CORE_SOURCES),
               str(ROOT / "bench" / "native" / "trivial_model.c"), "-lm"]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"building the trivial native FMU {name} failed:\n"
                               f"{done.stdout}{done.stderr}")
        xml = mdesc.fmi2_model_description(
            name, token, generation_tool="bench", table=table, model=model,
            co_simulation={"modelIdentifier": name, "canGetAndSetFMUstate": "true",
                           "canInterpolateInputs": "true", "canSerializeFMUstate": "true"})
        fmu = folder / f"{name}.fmu"
        with zipfile.ZipFile(fmu, "w") as zf:
            zf.writestr("modelDescription.xml", xml)
            zf.write(lib, f"binaries/linux64/{name}.so")
        out[key] = fmu
    return out


def product_fmus(flavour: str = "python") -> dict:
    """The product's FMUs of a flavour (``"python"``: pythonfmu, ``"native"``: C, FMI 2.0), built
    if missing or stale: ``{"plant": path, "controller": path}``."""
    f = build_fmus(flavour=flavour)
    return {"plant": f["FlexiblePendulum"], "controller": f["PDLowPass"]}


class CoSim:
    """The master over two FMUs for one scene, reusable for repeated timed runs (the FMUs are
    loaded once; every run re-initialises them from the scene's parameters)."""

    def __init__(self, scene, fmus: dict, *, trivial: bool = False, record=None):
        self.scene = scene
        self.trivial = trivial
        starts = ({}, {}) if trivial else (plant_start_values(scene),
                                           controller_start_values(scene))
        self.fmus = fmus
        self._starts = starts
        self._record = dict(record or COUPLING_RECORD)
        self._connections = ([parse_connection(c) for c in DEFAULT_CONNECTIONS] if trivial
                             else scene.connections)

    def run(self, progress=None):
        """One run from t = 0: ``(result, stats)``; FMUs instantiated fresh (not timed).
        ``progress``: called with the fraction done, as ``flexpend run``'s bar is."""
        out = self.scene.output
        slaves = {}
        me = self.scene.master.interface == "model-exchange"
        unit = ModelExchangeUnit if me else Slave
        try:
            slaves["plant"] = unit(self.fmus["plant"], "plant", self._starts[0],
                                   unzipdir=self._unzip("plant"))
            slaves["controller"] = unit(self.fmus["controller"], "controller", self._starts[1],
                                        unzipdir=self._unzip("controller"))
            if self.trivial:       # the product's dependency structure: the same master work
                slaves["plant"].feedthrough = False
                slaves["controller"].feedthrough = True
            master = (ModelExchangeMaster if me else Master)(slaves, self._connections,
                                                             self._record, self.scene.master)
            cpu = time.process_time()
            try:
                return master.run(0.0, out.stop_time, out.output_interval, progress=progress)
            finally:
                #: the process CPU time of the last run's master (initialisation and stepping)
                self.cpu = time.process_time() - cpu
        finally:
            for s in slaves.values():
                s.close()

    _unzipped: dict = {}

    def _unzip(self, key):
        from fmpy import extract
        path = str(self.fmus[key])
        if path not in CoSim._unzipped:
            CoSim._unzipped[path] = extract(path)
        return CoSim._unzipped[path]


def reference(scene) -> np.ndarray:
    """The monolithic reference of ``scene`` (structured array on the output grid)."""
    return simulate_reference(scene)


def phi_error(result, ref) -> float:
    """Largest |phi_o - phi_o_ref| over the output grid (inf if the run failed or diverged)."""
    if len(result) != len(ref):
        return float("inf")
    e = np.abs(result["phi_o"] - ref["phi_o"])
    return float(np.max(e)) if np.all(np.isfinite(e)) else float("inf")


def monolithic(scene, method: str, rtol: float, atol: float | None = None):
    """``solve_ivp`` on the scene's monolithic closed loop (the compiled plant right-hand side):
    ``(seconds, phi_o on the output grid or None if it failed, nfev)``."""
    import scipy.integrate
    loop = ClosedLoop(scene)
    t_end, dt = scene.output.stop_time, scene.output.output_interval
    t_eval = np.arange(int(round(t_end / dt)) + 1) * dt
    t_eval[-1] = min(t_eval[-1], t_end)
    t0 = time.perf_counter()
    with np.errstate(all="ignore"):
        try:
            sol = scipy.integrate.solve_ivp(loop.rhs, (0.0, t_end), loop.x0, method=method,
                                            rtol=rtol, atol=rtol * 1e-3 if atol is None else atol,
                                            t_eval=t_eval)
        except (ValueError, np.linalg.LinAlgError):
            return time.perf_counter() - t0, None, 0
    wall = time.perf_counter() - t0
    if not sol.success or sol.t.size != t_eval.size:
        return wall, None, sol.nfev
    phi = np.array([loop.plant.tip_angle(sol.y[:loop.np, i])[0] for i in range(sol.t.size)])
    return wall, phi, sol.nfev


def median_time(fn, runs: int, max_seconds: float | None = None):
    """``(median seconds, all seconds, last value)`` of ``fn() -> (seconds, value)``, after one
    untimed warm-up call. With ``max_seconds``, a point whose warm-up shows that ``runs`` runs
    would take longer gets fewer runs (at least one): ``len(all seconds)`` says how many."""
    warm, _ = fn()
    if max_seconds is not None and warm * runs > max_seconds:
        runs = max(1, int(max_seconds // max(warm, 1e-12)))
    times, value = [], None
    for _ in range(runs):
        dt, value = fn()
        times.append(dt)
    return statistics.median(times), times, value


def alternating_medians(fns: dict, runs: int) -> dict:
    """``{name: (median seconds, all seconds)}`` of the ``fn() -> (seconds, value)`` of ``fns``,
    side by side: one untimed warm-up call each, then ``runs`` rounds that call each in turn (a
    load that changes during the benchmark falls on all of them alike)."""
    for fn in fns.values():
        fn()
    times = {name: [] for name in fns}
    for _ in range(runs):
        for name, fn in fns.items():
            times[name].append(fn()[0])
    return {name: (statistics.median(t), t) for name, t in times.items()}
