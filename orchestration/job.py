"""Run a scene: the two FMUs on the master, then the summary, the CSV and the figures."""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from controller_fmu import interface as controller_interface
from fmu_common.variables import start_values
from plant_fmu import interface as plant_interface

from .scene.keys import ConfigError
from .scene.schema import needs_selection
from .studies.fidelity import select_model
from .cosim.slave import CoSimulationError, RunInterrupted, Slave
from .cosim.master import Master
from .scene.wiring import parse_connection
from .studies.reference import COLUMNS
from .scene.schema import SCENE_DEFAULTS
from .report.summary import summarize

__all__ = ["run_scene", "SceneResult", "DEFAULT_CONNECTIONS", "plant_start_values",
           "controller_start_values", "Progress", "summarize"]

DEFAULT_CONNECTIONS = tuple(SCENE_DEFAULTS["connections"])
#: column -> (FMU, variable): what the master records at every output point.
RECORD = {
    "x": ("plant", "x_o"), "x_dot": ("plant", "x_dot"), "phi_o": ("plant", "phi_o"),
    "omega_o": ("plant", "omega_o"), "F_c": ("controller", "F_c"),
    "tip_deflection": ("plant", "tip_deflection"), "eta_1": ("plant", "eta_1"),
    "energy": ("plant", "energy"), "phi": ("plant", "phi"),
    **{f"eta_{j}": ("plant", f"eta_{j}") for j in range(2, 9)},
}
def plant_start_values(scene) -> dict:
    """Scene keys -> FlexiblePendulum parameters (the table of :mod:`plant_fmu.interface`)."""
    return start_values(scene.config, plant_interface.VARIABLES)


def controller_start_values(scene) -> dict:
    """Scene keys -> PDLowPass parameters (the table of :mod:`controller_fmu.interface`)."""
    return start_values(scene.config, controller_interface.VARIABLES)


class Progress:
    """A progress bar on stderr, shown once a run has lasted a second.

    On a terminal it redraws one line; otherwise it prints a line at each quarter."""

    def __init__(self, label: str, stream=None, delay: float = 1.0):
        self.label, self.stream, self.delay = label, stream or sys.stderr, delay
        self.start = time.perf_counter()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False
        self.last_quarter = 0

    def close(self):
        """End the bar's line early (a run that stopped before the end)."""
        if self.tty and self.shown:
            self.stream.write("\n")
            self.stream.flush()
            self.shown = False

    def __call__(self, fraction: float):
        elapsed = time.perf_counter() - self.start
        if elapsed < self.delay:
            return
        if self.tty:
            if fraction < 1.0 and elapsed - getattr(self, "_last", 0.0) < 0.1:
                return
            self._last = elapsed
            n = int(30 * fraction)
            eta = elapsed * (1 - fraction) / max(fraction, 1e-9)
            self.stream.write(f"\r{self.label} [{'#' * n}{'.' * (30 - n)}] {100 * fraction:5.1f} % "
                              f"{elapsed:6.1f} s, ~{eta:5.1f} s left ")
            self.shown = True
            if fraction >= 1.0:
                self.stream.write("\n")
                self.shown = False
            self.stream.flush()
        else:
            quarter = int(fraction * 4)
            if quarter > self.last_quarter:
                self.last_quarter = quarter
                self.stream.write(f"{self.label}: {25 * quarter} % after {elapsed:.1f} s\n")
                self.stream.flush()


@dataclass
class SceneResult:
    name: str
    result: np.ndarray
    summary: dict
    stats: object = None
    reference: np.ndarray | None = None
    frames: list = field(default_factory=list)
    scene: object = None          # the scene that ran (its model chosen when it was "auto")
    interrupted: bool = False     # stopped by the ``stop`` callback (Ctrl-C)


def run_scene(scene, fmus: dict, *, reference: bool = False, progress: bool = True,
              connections_out=None, stop=None,
              snapshot_times=None, unzipdirs: dict | None = None) -> SceneResult:
    """Co-simulate ``scene`` with the FMUs at ``fmus`` (``{"plant": path, "controller": path}``).

    A scene with ``plant.n_modes`` or ``plant.fidelity`` ``"auto"`` gets its model chosen first
    (:func:`orchestration.studies.fidelity.select_model`); the summary's ``model`` entry says which and why,
    and the result's ``scene`` is the resolved scene.

    A run whose FMU refuses to go on (a divergence, a failed integrator) keeps the output points
    reached; the summary's ``stopped`` says when and why. ``stop``: a callable asked after every
    communication step (Ctrl-C); when it returns True the run ends the same way and the result's
    ``interrupted`` is True. The FMUs are terminated and freed, and their unpacked folders
    removed, however the run ends; ``unzipdirs`` (same keys as ``fmus``): folders where the FMUs
    are already unpacked, reused and left as they are (a sweep unpacks once per process)."""
    model = None
    if needs_selection(scene):
        scene, model = select_model(scene, Progress(f"{scene.name}: choosing the model")
                                    if progress else None)
    cfg = scene.config
    slaves = {}
    stopped, interrupted, stats, res = None, False, None, None
    try:
        dirs = unzipdirs or {}
        slaves["plant"] = Slave(fmus["plant"], "plant", plant_start_values(scene),
                                unzipdir=dirs.get("plant"))
        slaves["controller"] = Slave(fmus["controller"], "controller",
                                     controller_start_values(scene),
                                     unzipdir=dirs.get("controller"))
        try:
            master = Master(slaves, [parse_connection(c) for c in cfg["connections"]], RECORD,
                            algorithm=cfg["master.algorithm"], first=cfg["master.first"],
                            step=cfg["master.step"], extrapolation=cfg["master.extrapolation"],
                            adaptive=cfg["master.adaptive"], tolerance=cfg["master.tolerance"],
                            min_step=cfg["master.min_step"], max_step=cfg["master.max_step"],
                            input_derivatives=cfg["master.input_derivatives"],
                            compiled=cfg["master.compiled"])
        except ValueError as exc:       # a variable the FMUs do not have
            raise ConfigError(f"{scene.name}: {exc}") from None
        if connections_out is not None:
            connections_out.write(f"{scene.name}: connections\n{master.connection_table()}\n")
        bar = Progress(scene.name) if progress else None
        try:
            res, stats = master.run(0.0, cfg["stop_time"], cfg["output_interval"], progress=bar,
                                    stop=stop)
        except CoSimulationError as exc:
            res, stats = exc.result, exc.stats
            stopped = {"time": exc.time, "reason": str(exc)}
        except RunInterrupted as exc:
            res, stats, interrupted = exc.result, exc.stats, True
            stopped = {"time": exc.time, "reason": "interrupted (Ctrl-C)"}
        if bar is not None and stopped is not None:
            bar.close()
    finally:
        for s in slaves.values():
            s.close()
    if res is None:
        res = np.zeros(0, dtype=[(c, "f8") for c in ("time", *RECORD)])
    n_eta = min(scene.plant.n_modes, 8)
    if snapshot_times is None:             # eight times over the run, as the paper's Figs. 5, 8
        snapshot_times = np.linspace(0.0, cfg["stop_time"], 8)
    frames = _frames(res, n_eta, snapshot_times)
    res = _reorder(res, n_eta)
    summary = summarize(res, scene, stopped)
    if stats is not None:
        summary.update(wall_time=stats.wall_time, steps=stats.steps, rejected_steps=stats.rejected,
                       master_loop=stats.loop)
    if model is not None:
        summary["model"] = model
    out = SceneResult(scene.name, res, summary, stats, frames=frames, scene=scene,
                      interrupted=interrupted)
    if reference and stopped is None:
        from .studies.reference import simulate_reference
        ref = simulate_reference(scene)
        out.reference = ref
        summary["max_error_phi_o"] = float(np.max(np.abs(res["phi_o"] - ref["phi_o"])))
        summary["max_error_eta_1"] = float(np.max(np.abs(res["eta_1"] - ref["eta_1"])))
    return out


def _reorder(res, n_eta):
    """:data:`COLUMNS`, then ``phi`` and the modal coordinates the model has (``eta_2``...)."""
    cols = [*COLUMNS, *(["phi"] if "phi" in (res.dtype.names or ()) else []),
            *(f"eta_{j}" for j in range(2, n_eta + 1))]
    out = np.zeros(len(res), dtype=[(c, "f8") for c in cols])
    for c in cols:
        if c in res.dtype.names:
            out[c] = res[c]
    return out


def _frames(res, n_eta, times):
    """``(t, x, phi, eta)`` at the output points nearest to ``times`` (for shape snapshots)."""
    if len(res) == 0 or "phi" not in res.dtype.names:
        return []
    frames = []
    for t in times:
        if t > res["time"][-1] + 1e-9:
            continue
        i = int(np.argmin(np.abs(res["time"] - t)))
        eta = [res[f"eta_{j}"][i] for j in range(1, n_eta + 1)]
        frames.append((float(res["time"][i]), float(res["x"][i]), float(res["phi"][i]), eta))
    return frames
