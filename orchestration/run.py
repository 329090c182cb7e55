"""Run a scene: the two FMUs on the master, then the summary, the CSV and the figures."""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller_fmu import interface as controller_interface
from plant_fmu import interface as plant_interface

from .config import ConfigError
from .fidelity import needs_selection, select_model
from .fit import dominant_oscillation
from .master import CoSimulationError, Master, Slave, parse_connection
from .reference import COLUMNS
from .scenes import SCENE_DEFAULTS

__all__ = ["run_scene", "SceneResult", "DEFAULT_CONNECTIONS", "plant_start_values",
           "controller_start_values", "Progress"]

DEFAULT_CONNECTIONS = tuple(SCENE_DEFAULTS["connections"])
#: column -> (FMU, variable): what the master records at every output point.
RECORD = {
    "x": ("plant", "x_o"), "x_dot": ("plant", "x_dot"), "phi_o": ("plant", "phi_o"),
    "omega_o": ("plant", "omega_o"), "F_c": ("controller", "F_c"),
    "tip_deflection": ("plant", "tip_deflection"), "eta_1": ("plant", "eta_1"),
    "energy": ("plant", "energy"), "phi": ("plant", "phi"),
    **{f"eta_{j}": ("plant", f"eta_{j}") for j in range(2, 9)},
}
#: Bands (rad/s) of the rigid (slow) and the bending oscillation for the fitted rates.
SLOW_BAND = (0.5, 60.0)
BENDING_BAND = (60.0, 1e9)


def plant_start_values(scene) -> dict:
    """Scene keys -> FlexiblePendulum parameters (the table of :mod:`plant_fmu.interface`)."""
    return plant_interface.start_values(scene.config)


def controller_start_values(scene) -> dict:
    """Scene keys -> PDLowPass parameters (the table of :mod:`controller_fmu.interface`)."""
    return plant_interface.start_values(scene.config, controller_interface.VARIABLES)


class Progress:
    """A progress bar on stderr, shown once a run has lasted a second.

    On a terminal it redraws one line; otherwise it prints a line at each quarter."""

    def __init__(self, label: str, stream=None, delay: float = 1.0):
        self.label, self.stream, self.delay = label, stream or sys.stderr, delay
        self.start = time.perf_counter()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False
        self.last_quarter = 0

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


def _fit_window(t, y):
    """The window to fit: the whole run, or, for a signal that grows and saturates, the part
    before it first reaches a tenth of its largest magnitude (if that leaves at least 2 s), while
    the oscillation is still small enough to be linear."""
    a = np.abs(y - np.mean(y[-max(1, len(y) // 10):]))
    peak = a.max()
    if peak == 0:
        return slice(0, len(t))
    i = int(np.argmax(a >= 0.1 * peak))
    if t[i] - t[0] >= 2.0 and i < len(t) - 1:
        return slice(0, i + 1)
    return slice(0, len(t))


def summarize(res: np.ndarray, failure: str | None = None) -> dict:
    """Verdict, fitted rates and frequencies of the slow and bending oscillations, max |F_c|."""
    t = res["time"]
    out = {"max_abs_F_c": float(np.max(np.abs(res["F_c"]))) if len(res) else None}
    rates = []
    for key, col, band in (("slow", "phi_o", SLOW_BAND), ("bending", "eta_1", BENDING_BAND)):
        y = res[col]
        osc = None
        if len(t) > 40 and np.ptp(y) > 0:
            w = _fit_window(t, y)
            nyquist = math.pi / (t[1] - t[0])
            try:
                osc = dominant_oscillation(t[w], y[w], (band[0], min(band[1], nyquist)))
            except (ValueError, np.linalg.LinAlgError):
                osc = None
        out[key] = None if osc is None else {"rate": osc.rate, "frequency": osc.frequency}
        if osc is not None:
            rates.append(osc.rate)
    out["stable"] = failure is None and all(r < 0 for r in rates)
    if failure:
        out["failure"] = failure
    return out


def run_scene(scene, fmus: dict, *, reference: bool = False, progress: bool = True,
              connections_out=None,
              snapshot_times=(0.0, 0.5, 1.0, 2.0, 4.0, 6.0, 8.0, 10.0)) -> SceneResult:
    """Co-simulate ``scene`` with the FMUs at ``fmus`` (``{"plant": path, "controller": path}``).

    A scene with ``plant.n_modes`` or ``plant.fidelity`` ``"auto"`` gets its model chosen first
    (:func:`orchestration.fidelity.select_model`); the summary's ``model`` entry says which and why,
    and the result's ``scene`` is the resolved scene."""
    model = None
    if needs_selection(scene):
        scene, model = select_model(scene, Progress(f"{scene.name}: choosing the model")
                                    if progress else None)
    cfg = scene.config
    slaves = {}
    try:
        slaves["plant"] = Slave(fmus["plant"], "plant", plant_start_values(scene))
        slaves["controller"] = Slave(fmus["controller"], "controller",
                                     controller_start_values(scene))
        try:
            master = Master(slaves, [parse_connection(c) for c in cfg["connections"]], RECORD,
                            algorithm=cfg["master.algorithm"], first=cfg["master.first"],
                            step=cfg["master.step"], extrapolation=cfg["master.extrapolation"],
                            adaptive=cfg["master.adaptive"], tolerance=cfg["master.tolerance"],
                            min_step=cfg["master.min_step"], max_step=cfg["master.max_step"],
                            input_derivatives=cfg["master.input_derivatives"])
        except ValueError as exc:       # a variable the FMUs do not have
            raise ConfigError(f"{scene.name}: {exc}") from None
        if connections_out is not None:
            connections_out.write(f"{scene.name}: connections\n{master.connection_table()}\n")
        bar = Progress(scene.name) if progress else None
        failure = None
        try:
            res, stats = master.run(0.0, cfg["stop_time"], cfg["output_interval"], progress=bar)
        except CoSimulationError as exc:
            failure, stats = str(exc), None
            res = np.zeros(0, dtype=[(c, "f8") for c in COLUMNS])
    finally:
        for s in slaves.values():
            s.close()
    n_eta = min(scene.plant.n_modes, 8)
    frames = _frames(res, n_eta, snapshot_times)
    res = _reorder(res, n_eta)
    summary = summarize(res, failure)
    if stats is not None:
        summary.update(wall_time=stats.wall_time, steps=stats.steps, rejected_steps=stats.rejected)
    if model is not None:
        summary["model"] = model
    out = SceneResult(scene.name, res, summary, stats, frames=frames, scene=scene)
    if reference and failure is None:
        from .reference import simulate_reference
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
