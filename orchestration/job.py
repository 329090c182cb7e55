"""The job: scene -> FMUs -> master -> result -> files.

    simulate(scene, overrides=None, *, fmus=None, reference=False, progress=False) -> Run
    run_scene(scene, fmus, ...) -> Run         one scene on FMUs at hand (a sweep's task)
    run_job(items, out, ...) -> JobResult      ``flexpend run``: every scene, its files, the
                                               paper overview and summary.json

A scene whose model is ``"auto"`` gets it chosen first (:mod:`orchestration.studies.fidelity`);
a scene whose plant FMU would step unstably (``plant.step`` beyond its integrator's stability
limit on the rung's fastest mode, :mod:`orchestration.studies.plant_step`) is refused before it
runs (:func:`check_plant_step`: a ConfigError naming ``plant.step``);
the FMUs of the scene's flavour are built when missing or stale (:mod:`orchestration.export`); the
master (:mod:`orchestration.cosim`) steps them; :mod:`orchestration.report` summarises the result
and draws it. A :class:`Run` holds all of it: ``to_pandas()``, ``plot()`` (a Figure),
``summary``, ``scene``, ``save(folder)``.

A run whose FMU refuses to go on (a divergence, a failed integrator) keeps the output points it
reached, and its summary says when and why; so does a run stopped by its ``stop`` callback
(Ctrl-C). The FMUs are terminated and freed, and their unpacked folders removed, however a run
ends.
"""
from __future__ import annotations

import functools
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from controller_fmu import interface as controller_interface
from plant_fmu import interface as plant_interface
from plant_fmu.beam import beam_model

from .cosim.master import Master
from .cosim.model_exchange import ModelExchangeMaster, ModelExchangeUnit
from .cosim.slave import CoSimulationError, RunInterrupted, Slave, describe
from .export import controller_role, flavour_fmus, plant_role, with_families
from .files import check_folder, write_csv, write_json
from .report import figures
from .report.files import save_figure
from .report.plotting import check_figures, check_renderer
from .report.progress import Steps, check_progress, sink_for
from .scene.keys import FMU_FLAVOURS, ConfigError
from .scene.records import AUTO, Scene
from .scene.schema import load_scene, start_values
from .scene.ssp import read_ssp
from .studies.analysis import linearisation
from .studies.error_figure import assess as assess_figure
from .studies.error_figure import companion_scene, companion_text, own_companion
from .studies.fidelity import available_ladder, climb, refused_rungs, select_model
from .studies.plant_step import checks as plant_step_checks
from .studies.reference import COLUMNS, check_reference, simulate_reference
from .studies.summary import ReportFacts, iteration_counts, report_facts, stop_reason, summarize

__all__ = ["Run", "JobResult", "simulate", "run_scene", "run_job", "paper_figures", "load_job",
           "step_warning", "check_plant_step",
           "check_wiring", "plant_start_values", "controller_start_values", "RECORD",
           "EXIT_STOPPED", "EXIT_INTERRUPTED"]

#: Exit codes of ``flexpend run`` besides 0 (every scene ran to its stop time) and 2 (bad input).
EXIT_STOPPED = 3
EXIT_INTERRUPTED = 130

#: column -> (FMU, variable): what the master records at every output point.
RECORD = {
    "x": ("plant", "x_o"), "x_dot": ("plant", "x_dot"), "phi_o": ("plant", "phi_o"),
    "omega_o": ("plant", "omega_o"), "F_c": ("controller", "F_c"),
    "tip_deflection": ("plant", "tip_deflection"), "eta_1": ("plant", "eta_1"),
    "energy": ("plant", "energy"), "phi": ("plant", "phi"),
    **{f"eta_{j}": ("plant", f"eta_{j}") for j in range(2, 9)},
}


def plant_start_values(scene: Scene) -> dict:
    """The scene's FlexiblePendulum parameters (the table of :mod:`plant_fmu.interface`)."""
    return start_values(scene, plant_interface.VARIABLES)


def controller_start_values(scene: Scene) -> dict:
    """The scene's PDLowPass parameters (the table of :mod:`controller_fmu.interface`)."""
    return start_values(scene, controller_interface.VARIABLES)


# ---------------------------------------------------------------------- a run
@dataclass
class Run:
    """One co-simulation of a scene.

    ``scene``: the scene that ran (its model chosen when it was ``"auto"``); ``result``: the
    output points reached, a numpy structured array (``time`` first, then the CSV's columns in SI
    units); ``summary``: what ``summary.json`` holds for it; ``stats``: the master's counts and
    wall time; ``reference``: the monolithic reference on the same grid (when asked);
    ``interrupted``: stopped by its ``stop`` callback; ``facts``: what its figures draw besides
    the summary (:class:`~orchestration.studies.summary.ReportFacts`: its linearised loop's
    roots), computed once, on first use."""

    scene: Scene
    result: np.ndarray
    summary: dict
    stats: object = None
    reference: np.ndarray | None = None
    frames: list = field(default_factory=list, repr=False)
    interrupted: bool = False

    @property
    def name(self) -> str:
        """The scene's name (its file's stem, or the name its dict or SSP archive gives)."""
        return self.scene.name

    def __repr__(self) -> str:
        """One line: the scene, its rung, how far it ran, the verdict."""
        sc, s = self.scene, self.summary or {}
        ran = ("completed" if s.get("stopped") is None else "stopped early") + \
            (", interrupted" if self.interrupted else "")
        end = float(self.result["time"][-1]) if self.result is not None and len(self.result) \
            else 0.0
        return (f"Run({sc.name!r}: {sc.plant.n_modes} modes {sc.plant.fidelity}, "
                f"{ran} at {end:g} of {sc.output.stop_time:g} s, verdict "
                f"{s.get('verdict', 'none')}, {len(self.result)} points"
                f"{', with reference' if self.reference is not None else ''})")

    @functools.cached_property
    def facts(self) -> ReportFacts:
        """What the run's figures draw besides the summary: its linearised loop's roots, the
        bending band (:class:`~orchestration.studies.summary.ReportFacts`), computed on first
        use."""
        return report_facts(self.scene)

    @property
    def completed(self) -> bool:
        """Whether the run reached its stop time."""
        return self.summary["stopped"] is None

    def to_pandas(self):
        """The result as a pandas DataFrame indexed by ``time`` (s), the columns of the CSV."""
        import pandas as pd

        names = self.result.dtype.names
        return pd.DataFrame({c: self.result[c] for c in names[1:]},
                            index=pd.Index(self.result["time"], name="time"))

    def plot(self, renderer: str = "matplotlib"):
        """The time histories (tip angle, first modal coordinate, tip deflection, force, cart
        position) as a matplotlib Figure (the process's backend is left alone), or drawn by
        another ``renderer`` (:data:`~orchestration.report.plotting.RENDERERS`)."""
        return figures.time_histories(self.result, self.scene, self.reference, self.summary,
                                      facts=self.facts, renderer=renderer)

    def plot_shapes(self, renderer: str = "matplotlib"):
        """The beam and the cart at eight times over the run, a Figure (None before two output
        points); ``renderer`` as :meth:`plot`."""
        if not self.frames:
            return None
        x = self.result["x"]
        return figures.snapshots(beam_model(self.scene.plant.params), self.frames, self.scene,
                                 travel=(float(x.min()), float(x.max())), renderer=renderer)

    def save(self, folder, *, summary: bool = True, renderer: str = "raster",
             figures: str = "png") -> list[Path]:
        """Write what ``flexpend run`` writes for this run into the folder ``folder`` (a
        ValueError for a path that names a file, or has a file's suffix: ``.csv``...):
        ``<name>.csv``, ``<name>.png``, ``<name>_shapes.png`` (drawn by ``renderer``: by default
        the raster renderer, no matplotlib) and (``summary``) this run's entry of
        ``summary.json`` (other entries kept); the paths written. Each file is complete or
        absent. ``figures="none"`` draws and writes no PNG (the rest is the same)."""
        check_renderer(renderer)
        check_figures(figures)
        folder = check_folder(folder)
        folder.mkdir(parents=True, exist_ok=True)
        written = [write_csv(folder / f"{self.name}.csv", self.result)]
        if figures == "png":
            if len(self.result) >= 2:
                written.append(save_figure(self.plot(renderer), folder / f"{self.name}.png"))
            shapes = self.plot_shapes(renderer)
            if shapes is not None:
                written.append(save_figure(shapes, folder / f"{self.name}_shapes.png"))
        if summary:
            entries = _read_summaries(folder / "summary.json")
            entries[self.name] = self.summary
            written.append(write_json(folder / "summary.json", entries))
        return written


def _read_summaries(path: Path) -> dict:
    import json

    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def check_wiring(scene: Scene, fmus: dict) -> None:
    """Every connection of ``scene`` names variables the FMUs (``{"plant": path, "controller":
    path}``) have; a ConfigError names the first that does not. The FMUs are read and checked
    first (:func:`~orchestration.cosim.slave.describe`: a model identifier that is not a C
    identifier is an :class:`~orchestration.scene.fmu.FmuError`), before any is loaded; the
    other rungs' FMUs are checked as they are read, when a run loads them."""
    roles = {r for c in scene.connections for r in (c.src, c.dst)}
    variables = {role: [v.name for v in describe(path).modelVariables]
                 for role, path in fmus.items() if role in roles}
    for c in scene.connections:
        for fmu, var in ((c.src, c.src_var), (c.dst, c.dst_var)):
            if var not in variables[fmu]:
                raise ConfigError(f"{scene.name}: {fmu} has no variable {var!r}; it has: "
                                  f"{', '.join(variables[fmu])}")


def check_plant_step(scene: Scene, rungs=None) -> str | None:
    """Refuse a scene whose plant FMU would step unstably: a ConfigError, one line naming
    ``plant.step``, its value, the mode, ``plant.integrator`` and the largest stable
    ``plant.step``, when the largest substep is beyond the method's stability limit on the
    linearised plant of its rung (:mod:`orchestration.studies.plant_step`), or of any of
    ``rungs`` (default: the scene's; with ``plant.fidelity = "auto"`` every rung the ladder may
    climb to). The warning line when it is within 10 % of the limit, else None. A model not
    chosen yet (``plant.n_modes = "auto"``) is checked once chosen (:func:`run_scene`)."""
    lines = []
    for c in plant_step_checks(scene, rungs):
        if c.error:
            raise ConfigError(f"{scene.name}: {c.error}")
        if c.warning:
            lines.append(c.warning)
    return lines[0] if lines else None


def run_scene(scene: Scene, fmus: dict, *, reference: bool = False, progress=True,
              connections_out=None, stop=None, snapshot_times=None,
              unzipdirs: dict | None = None, pool=None, check_step: bool = True,
              fits: bool = True) -> Run:
    """Co-simulate ``scene`` with the FMUs at ``fmus`` (``{"plant": path, "controller": path}``).

    ``stop``: a callable asked after every communication step; when it returns True the run
    ends as if an FMU had stopped it, and :attr:`Run.interrupted` is True. ``unzipdirs`` (the
    keys of ``fmus``): folders where the FMUs are already unpacked, reused and left as they are
    (a sweep unpacks once per process). ``pool``: a
    :class:`~orchestration.cosim.pool.SlavePool` that gives the FMU instances and takes them back
    (a sweep's runs reuse them); without one they are made here and freed at the end.
    ``connections_out``: a stream for the connection table. ``progress``: ``True`` (a bar on
    stderr), ``False`` or a callable ``progress(fraction, label)``
    (:mod:`orchestration.report.progress`): the fraction of the whole call (the model's choice,
    every rung's run and companion, the reference), the label naming the rung or the model it
    is on.

    A run on a floating-frame rung is followed by its companion run, and its summary states the
    error figure made from the two (``error_figure``, :func:`_error_figure`; not with
    ``fidelity.companion = false``); a run on the exact rung states its numerical error.

    With ``plant.fidelity = "auto"`` the run climbs the fidelity ladder: it is repeated on the
    next rung up while its error figure exceeds ``fidelity.tolerance`` times its largest
    ``|phi_o|`` or cannot be trusted (without a companion: while its measured global bound
    does; :func:`orchestration.studies.fidelity.climb`); the summary's ``model`` says which rung
    ran and why.

    Before it runs, the plant's substep is checked against its integrator's stability limit on
    the rung, and on every rung the ladder may climb to (:func:`check_plant_step`: a ConfigError
    beyond it). ``check_step = False`` skips that check: the run then shows what the limit
    predicts (the tests that observe the growth beyond it). ``fits = False``: the summaries
    fit no mode and state no verdict (:func:`~orchestration.studies.summary.summarize`; a
    sweep that asks for no column of theirs)."""
    sink = sink_for(progress, scene.name)
    fmus = with_families(fmus)              # the other rungs' native FMUs beside its plant
    try:
        return _run_scene(scene, fmus, sink, reference=reference,
                          connections_out=connections_out, stop=stop,
                          snapshot_times=snapshot_times, unzipdirs=unzipdirs, pool=pool,
                          check_step=check_step, fits=fits)
    finally:
        if sink is not None:
            sink.close()


def _work(scene: Scene, reference: bool) -> tuple:
    """``(rungs, total, {rung: its weight})``: what :func:`run_scene` will run, counted in
    runs (each a part of its progress): the choice of ``plant.n_modes`` (one, for its
    monolithic runs), each rung's run and its companion (the exact rung: its run at twice the
    step instead), and the reference. A climb that stops early leaves the higher rungs'
    share."""
    rungs = available_ladder(scene) if scene.plant.fidelity == AUTO else (scene.plant.fidelity,)
    per_rung = {f: 2 if f == "exact" or scene.fidelity.companion else 1 for f in rungs}
    return rungs, ((1 if scene.plant.n_modes_auto else 0) + sum(per_rung.values())
                   + (1 if reference else 0)), per_rung


def _run_scene(scene: Scene, fmus: dict, sink, *, reference, connections_out, stop,
               snapshot_times, unzipdirs, pool, check_step, fits) -> Run:
    """:func:`run_scene`, its progress told to ``sink`` (:mod:`orchestration.report.progress`)
    in parts (:func:`_work`), each labelled with the rung or the model it is on."""
    name = scene.name
    rungs, total, per_rung = _work(scene, reference)
    steps = Steps(sink, total)
    model = None
    if not scene.resolved:
        choice = steps.part(1, f"{name}: choosing the model") \
            if scene.plant.n_modes_auto else None      # fidelity "auto" alone: no runs here
        scene, model = select_model(scene, choice)
    if check_step:
        try:
            check_plant_step(scene, available_ladder(scene) if model is not None
                             and model["fidelity_auto"] else None)
        except ConfigError as exc:
            if model is None:
                raise
            raise ConfigError(f"{exc} (the model chosen: {model['n_modes']} modes, "
                              f"{model['fidelity']})") from None
    if reference:
        check_reference(scene)
    climbing = model is not None and model["fidelity_auto"]

    def rung_label(sc):
        f = sc.plant.fidelity
        if not climbing:
            return name
        i = rungs.index(f) + 1 if f in rungs else 0
        return f"{name}: {f} rung" + (f" ({i} of {len(rungs)})" if i else "")

    def rung_steps(sc):
        """The parts of a rung's runs: its run, then its companion (or second run)."""
        return Steps(steps.part(per_rung.get(sc.plant.fidelity, 1), rung_label(sc)),
                     per_rung.get(sc.plant.fidelity, 1))

    kw = dict(connections_out=connections_out, stop=stop,
              snapshot_times=snapshot_times, unzipdirs=unzipdirs, pool=pool, fits=fits)
    parts = rung_steps(scene)
    out = _run_once(scene, fmus, progress=parts.part(1, rung_label(scene)), **kw)
    kw["connections_out"] = None                # the table once
    companions = []                             # [(scene, Run)]: each companion runs once
    _error_figure(out, fmus, kw, companions, check_step, parts, rung_label(scene))
    if climbing:
        model["climb"], ladder, refused = [], available_ladder(scene), refused_rungs(scene)
        while not out.interrupted:
            nxt, why = climb(scene.plant.fidelity, out.summary.get("error_figure")
                             or out.summary["validity"], scene.fidelity.tolerance, ladder,
                             refused, bound=out.summary["validity"])
            model["climb"].append(why)
            if nxt is None:
                break
            scene = scene.replace(plant=scene.plant.with_model(scene.plant.params.n_modes, nxt))
            parts = rung_steps(scene)
            out = next((c for s, c in companions if s == scene), None)
            if out is not None:                 # the companion was this rung's run
                model["climb"][-1] += " (its run: the companion's)"
                parts.part(1, rung_label(scene))
            else:
                out = _run_once(scene, fmus, progress=parts.part(1, rung_label(scene)), **kw)
            _error_figure(out, fmus, kw, companions, check_step, parts, rung_label(scene))
        model["fidelity"] = scene.plant.fidelity
        model["reason"] = "; ".join([model["reason"], *model["climb"]])
    if model is not None:
        out.summary["model"] = model
    if scene.plant.fidelity == "exact" and not out.interrupted:
        out.summary["numerical_error"] = _exact_numerical_error(
            scene, fmus, out, kw, parts.part(1, f"{rung_label(scene)}: numerical error (the run "
                                                "at twice the step)"))
    if reference and out.summary["stopped"] is None:
        try:
            ref = simulate_reference(scene, progress=_stoppable(
                steps.part(1, f"{name}: the monolithic reference"), stop))
        except _Stopped:                        # the run is whole; its reference is left out
            out.interrupted = True
        else:
            out.reference = ref
            out.summary["max_error_phi_o"] = float(np.max(np.abs(out.result["phi_o"]
                                                                 - ref["phi_o"])))
            out.summary["max_error_eta_1"] = float(np.max(np.abs(out.result["eta_1"]
                                                                 - ref["eta_1"])))
    if out.summary["stopped"] is None:
        steps.finish(name)
    return out


class _Stopped(Exception):
    """A computation of the job (the reference) stopped by the run's ``stop`` callback."""


def _stoppable(progress, stop):
    """``progress`` that first asks ``stop`` (if any) and raises :class:`_Stopped` when it says
    so: a long computation told of its progress (the reference: a thousand times over its
    span) ends within one report of a Ctrl-C."""
    if stop is None:
        return progress

    def told(fraction, *args):
        if stop():
            raise _Stopped
        return progress(fraction, *args)
    return told


def _error_figure(run: Run, fmus: dict, kw: dict, companions: list, check_step: bool,
                  parts=None, label: str | None = None) -> None:
    """Put the run's error figure into its summary (``error_figure``,
    :func:`orchestration.studies.error_figure.assess`): a run on a floating-frame rung is
    compared with its companion, the same scene on the stiffened rung with the companion's
    modes through the same FMUs and master (run here once per scene and kept in
    ``companions``, ``[(scene, Run)]``: a climb compares every rung with the same one, and a
    rung that is the companion takes its run). The exact rung states its numerical error
    instead (:func:`_exact_numerical_error`); ``fidelity.companion = false`` states none (the
    measured global bound only). ``parts``: the rung's :class:`~orchestration.report.progress.
    Steps`, whose next part the companion's run is (``label``: the rung's)."""
    scene = run.scene
    if (scene.plant.fidelity == "exact" or not scene.fidelity.companion
            or "error_figure" in run.summary):
        return
    integrator = None
    if not check_step:                      # checked before the run otherwise
        bad = [c.error for c in plant_step_checks(scene) if c.error]
        integrator = bad[0] if bad else None
    companion, why = None, None
    if not (run.interrupted or run.summary["stopped"] or integrator or own_companion(scene)):
        try:
            cs = companion_scene(scene)
            check_plant_step(cs)
        except ConfigError as exc:
            why = f"it cannot run: {exc}"
        else:
            companion = next((c for s, c in companions if s == cs), None)
            if companion is None:
                part = parts and parts.part(1, f"{label or scene.name}: the companion "
                                                f"({companion_text(scene)})")
                companion = _run_once(cs, fmus, **{**kw, "connections_out": None,
                                                   "progress": part})
                companions.append((cs, companion))
    run.summary["error_figure"] = assess_figure(run, scene, companion, why, integrator)


def _exact_numerical_error(scene: Scene, fmus: dict, run: Run, kw: dict,
                           progress=None) -> dict:
    """The exact rung's own numerical error, from the run itself: the same run at twice the
    step (``plant.exact_step``, which is also the communication step), and the largest
    ``|phi_o|`` difference from it on their common output points. In the convergence study
    (``python3 bench/exact_convergence.py``, docs/exact.md) the error fell about in proportion
    to the step (what the L-stable step damps of the beam's undamped high modes dominates it,
    not the method's order), and this difference was 1.2 to 2 times the run's error against a
    refined reference: it is stated as the run's error bound. A run stopped early gets none.
    ``progress``: the run at twice the step's (fraction, label) callback."""
    h = scene.plant.exact_step
    out = {"phi_o": None, "method": "step doubling: the run at plant.exact_step = "
           f"{2 * h:g} s", "step": h, "note": None}
    if run.summary["stopped"] is not None or len(run.result) < 2:
        out["note"] = "the run stopped early"
        return out
    o = scene.output
    dt = o.output_interval
    if abs(dt / (2 * h) - round(dt / (2 * h))) > 1e-9 * dt / h:
        dt = 2 * dt                                  # a multiple of 2 h
    n = int(math.floor(o.stop_time / dt + 1e-9))
    if n < 1:
        out["note"] = "the run is shorter than one step of twice its own"
        return out
    try:
        coarse = scene.replace(plant=replace(scene.plant, exact_step=2 * h),
                               output=replace(o, output_interval=dt, stop_time=n * dt))
    except ConfigError as exc:
        out["note"] = f"no run at twice the step: {exc}"
        return out
    kw = {**kw, "connections_out": None, "snapshot_times": (), "progress": progress}
    shadow = _run_once(coarse, fmus, **kw)
    if shadow.interrupted or shadow.summary["stopped"] is not None:
        out["note"] = ("the run at twice the step stopped: "
                       f"{(shadow.summary['stopped'] or {}).get('reason', 'interrupted')}")
        return out
    t, ts = run.result["time"], shadow.result["time"]
    idx = np.searchsorted(t, ts)
    near = np.abs(t[np.minimum(idx, len(t) - 1)] - ts) <= 1e-9 * max(1.0, o.stop_time)
    ok = (idx < len(t)) & near
    diff = np.abs(run.result["phi_o"][idx[ok]] - shadow.result["phi_o"][ok])
    out["phi_o"] = float(diff.max()) if diff.size else None
    return out


def _run_once(scene: Scene, fmus: dict, *, progress, connections_out, stop, snapshot_times,
              unzipdirs, pool, fits=True) -> Run:
    """One co-simulation of a resolved scene (:func:`run_scene` without the model's choice and
    the reference); ``progress``: called with the fraction of it done (or None); ``fits``: as
    in :func:`run_scene`."""
    slaves = {}
    stopped, interrupted, stats, res = None, False, None, None
    reusable = False                # the instances may serve another run (pool)
    try:
        dirs = unzipdirs or {}
        me = scene.master.interface == "model-exchange"
        unit = ModelExchangeUnit if me else Slave
        make = unit if pool is None else \
            (lambda path, role, values, unzipdir: pool.acquire(unit, path, role, values, unzipdir))
        try:
            role = plant_role(fmus, scene.plant.fidelity)       # the rung's plant FMU
            slaves["plant"] = make(fmus[role], "plant", plant_start_values(scene),
                                   unzipdir=dirs.get(role))
            crole = controller_role(fmus, scene.controller)    # continuous or sampled
            slaves["controller"] = make(fmus[crole], "controller",
                                        controller_start_values(scene),
                                        unzipdir=dirs.get(crole))
            master = (ModelExchangeMaster if me else Master)(slaves, scene.connections, RECORD,
                                                             scene.run_master)
        except ValueError as exc:       # a variable the FMUs do not have, no ME interface
            raise ConfigError(f"{scene.name}: {exc}") from None
        if connections_out is not None:
            connections_out.write(f"{scene.name}: connections\n{master.connection_table()}\n")
        try:
            res, stats = master.run(0.0, scene.output.stop_time, scene.output.output_interval,
                                    progress=progress, stop=stop)
            reusable = True
        except CoSimulationError as exc:
            res, stats = exc.result, exc.stats
            stopped = {"time": exc.time, "reason": stop_reason(str(exc)),
                       "fmu_message": str(exc)}
            reusable = exc.status != 4          # fmi2Fatal: the instance is unusable
        except RunInterrupted as exc:
            res, stats, interrupted = exc.result, exc.stats, True
            stopped = {"time": exc.time, "reason": "interrupted (Ctrl-C)"}
            reusable = True
    finally:
        for s in slaves.values():
            if pool is None:
                s.close()
            else:
                pool.release(s, reusable)
    if res is None:
        res = np.zeros(0, dtype=[(c, "f8") for c in ("time", *RECORD)])
    n_eta = min(scene.plant.params.n_modes, 8)
    if snapshot_times is None:   # eight times over what ran, as the paper's Figs. 5, 8
        snapshot_times = np.linspace(0.0, res["time"][-1] if len(res) else 0.0, 8)
    frames = _frames(res, n_eta, snapshot_times)
    res = _reorder(res, n_eta)
    summary = summarize(res, scene, stopped, fits=fits)
    if stats is not None:
        summary.update(wall_time=stats.wall_time, steps=stats.steps, rejected_steps=stats.rejected,
                       master_loop=stats.loop, **iteration_counts(stats))
    return Run(scene, res, summary, stats, frames=frames, interrupted=interrupted)


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


# ---------------------------------------------------------------------- the front door's run
def simulate(scene, overrides=None, *, fmus: str | None = None, reference: bool = False,
             progress=False) -> Run:
    """Co-simulate one scene and return its :class:`Run`.

    ``scene``: a scene name (``flexpend scenes``), a path to a ``.toml`` scene file or to an SSP
    archive (``.ssp``, which brings its own FMUs), a dict of scene keys, or a
    :class:`~orchestration.scene.records.Scene`. ``overrides``: a dict of scene keys on top
    (``{"controller.kp": 400, "stop_time": 2}``). ``fmus``: ``"native"`` or ``"python"`` (the
    scene key ``master.fmus``; default: the scene's, native unless it says otherwise), built if
    missing or stale. ``reference``: also solve the monolithic reference and put the error
    against it in the summary. ``progress``: ``False`` (silent), ``True`` (a bar on stderr) or
    a callable ``progress(fraction, label)`` (:mod:`orchestration.report.progress`): the
    fraction of the whole call (building missing FMUs, choosing an ``"auto"`` model, every
    rung's run and companion, the reference), the label naming the rung or the model.

    A bad scene, key or value raises :class:`~orchestration.scene.keys.ConfigError` (a
    ``ValueError``) naming it; a wrong type, ``TypeError``. A run that an FMU stops early is
    not an error: its summary says when and why (:attr:`Run.completed` is False). A
    ``plant.step`` beyond its integrator's stability limit is a ConfigError before anything
    runs; within 10 % of it, a ``RuntimeWarning`` (:func:`check_plant_step`)."""
    if fmus is not None and fmus not in FMU_FLAVOURS:
        raise ValueError(f"fmus = {fmus!r} is not allowed; allowed: "
                         f"{', '.join(map(repr, FMU_FLAVOURS))}")
    if not isinstance(reference, bool):
        raise TypeError(f"reference must be True or False, got {reference!r}")
    check_progress(progress)                  # a TypeError naming progress, before any work
    (sc, own), = load_job([scene], overrides)
    sink = None
    try:
        if fmus is not None and own is None:
            sc = sc.replace(master=replace(sc.master, fmus=fmus))
        warning = check_plant_step(sc)
        if warning:
            warnings.warn(f"{sc.name}: {warning}", RuntimeWarning, stacklevel=2)
        sink = sink_for(progress, sc.name)
        steps = Steps(sink, 20)                    # the FMUs 1, the run 19
        build = steps.part(1, f"{sc.name}: the {sc.master.fmus} FMUs")
        pair = own.fmus if own is not None else flavour_fmus(sc.master.fmus, progress=build)
        check_wiring(sc, pair)
        run = run_scene(sc, pair, reference=reference,
                        progress=steps.part(19, sc.name) if sink is not None else False)
        if sink is not None and run.summary["stopped"] is None:
            steps.finish(sc.name)
        return run
    finally:
        if sink is not None:
            sink.close()
        if own is not None:
            own.close()


# ---------------------------------------------------------------------- flexpend run
def load_job(refs, overrides=None) -> list:
    """``[(scene, system or None)]`` for scene references: names, paths of scene files, dicts,
    scenes, or SSP archives (``.ssp``; ``system`` is the archive, unpacked, which brings its own
    FMUs: close it when done). Every scene is read and checked before any runs."""
    out = []
    try:
        for ref in refs:
            if isinstance(ref, (str, os.PathLike)) and os.fspath(ref).endswith(".ssp"):
                system = read_ssp(ref, overrides or ())
                out.append((system.scene, system))
            else:
                out.append((load_scene(ref, overrides), None))
    except BaseException:
        for _, system in out:
            if system is not None:
                system.close()
        raise
    return out


def paper_figures(runs, folder, renderer: str = "raster") -> list[Path]:
    """The figures of a set of runs side by side (``flexpend run`` of the paper's scenes):
    ``paper_overview.png`` (:func:`~orchestration.report.figures.paper_overview`),
    ``mode_shapes.png``, the cantilever modes of each flexible plant that ran
    (:func:`~orchestration.report.figures.mode_shapes`; none when every run is rigid), and
    ``root_map.png``, the closed-loop roots of each run's linearised loop
    (:func:`~orchestration.report.figures.root_map`); the paths written. Drawn by ``renderer``
    (by default the raster renderer, no matplotlib)."""
    check_renderer(renderer)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = [save_figure(figures.paper_overview(runs, renderer=renderer),
                           folder / "paper_overview.png")]
    plants = {}                            # plant (its linearisation's) -> the runs on it
    for r in runs:
        if r.scene.plant.params.n_modes > 0:
            plants.setdefault(linearisation(r.scene).params, []).append(r)
    if plants:
        labelled = [(f"{', '.join(r.name for r in on)}: {figures.plant_text(on[0].scene)}", p,
                     on[0].facts.roots.bending_frequency) for p, on in plants.items()]
        written.append(save_figure(figures.mode_shapes(labelled, renderer=renderer),
                                   folder / "mode_shapes.png"))
    written.append(save_figure(figures.root_map([r.scene for r in runs], [r.facts for r in runs],
                                                renderer=renderer), folder / "root_map.png"))
    return written


@dataclass
class JobResult:
    """What ``flexpend run`` did: the runs (in order), the exit code and the files written."""

    runs: list
    code: int = 0
    written: list = field(default_factory=list)

    @property
    def summaries(self) -> dict:
        return {r.name: r.summary for r in self.runs}

    def __repr__(self) -> str:
        """One line: the runs' names, the exit code, the number of files written."""
        names = ", ".join(r.name for r in self.runs)
        if len(names) > 100:
            names = names[:97] + "..."
        return (f"JobResult({len(self.runs)} runs: {names}; code {self.code}, "
                f"{len(self.written)} files)")


def run_job(items, out, *, reference: bool = False, connections_out=None, stop=None,
            overview: bool = False, announce=None, report=None,
            renderer: str = "raster", figures: str = "png", progress: bool = True) -> JobResult:
    """``flexpend run``: run ``items`` (from :func:`load_job`) one after the other into the
    folder ``out``, each run's files written as soon as it ends (:meth:`Run.save`), then, with
    ``overview``, the figures of the runs side by side (:func:`paper_figures`); ``summary.json``
    holds every run's summary, and is written
    even when nothing ran.

    ``stop``: asked between runs and after every communication step (Ctrl-C); ``announce(scene)``
    is called before a run and ``report(run, written)`` after it. The exit code: 0 when every
    scene ran to its stop time, :data:`EXIT_STOPPED` when one stopped early,
    :data:`EXIT_INTERRUPTED` when ``stop`` ended the job (the data so far is written). Every
    scene's plant step is checked before any runs (:func:`check_plant_step`; a scene with
    ``plant.n_modes = "auto"`` once its model is chosen, when it runs).
    ``renderer``: what draws the PNGs (:data:`~orchestration.report.plotting.RENDERERS`; by
    default the raster renderer, which does not import matplotlib); ``figures="none"``: no
    PNG is drawn or written (:data:`~orchestration.report.plotting.FIGURES`). ``progress``: a bar on
    stderr for the FMUs' build and for each scene (:func:`run_scene`)."""
    check_renderer(renderer)
    check_figures(figures)
    out = Path(out)
    job = JobResult([])
    pairs = {}
    unpacked = _Unpacked()
    try:
        for scene, system in items:                 # FMUs and wiring before any scene runs
            check_plant_step(scene)
            if system is None and scene.master.fmus not in pairs:
                if stop is not None and stop():
                    job.code = EXIT_INTERRUPTED
                    return job
                sink = sink_for(progress, f"the {scene.master.fmus} FMUs")
                try:
                    pairs[scene.master.fmus] = flavour_fmus(scene.master.fmus, progress=sink)
                finally:
                    if sink is not None:
                        sink.close()
            check_wiring(scene, system.fmus if system is not None else pairs[scene.master.fmus])
            if reference:
                check_reference(scene)
        for scene, system in items:
            if stop is not None and stop():
                job.code = EXIT_INTERRUPTED
                break
            if announce is not None:
                announce(scene)
            fmus = system.fmus if system is not None else pairs[scene.master.fmus]
            run = run_scene(scene, fmus, reference=reference and not (stop and stop()),
                            progress=progress, connections_out=connections_out, stop=stop,
                            unzipdirs=unpacked.of(fmus))
            job.runs.append(run)
            # interrupted: its data and summary, not its figures (Ctrl-C ends the job at once)
            written = run.save(out, summary=False, renderer=renderer,
                               figures="none" if run.interrupted else figures)
            write_json(out / "summary.json", job.summaries)
            job.written += written
            if report is not None:
                report(run, written)
            if run.interrupted:
                job.code = EXIT_INTERRUPTED
                break
            if not run.completed:
                job.code = EXIT_STOPPED
        if (overview and figures == "png" and job.code != EXIT_INTERRUPTED
                and len(job.runs) == len(items) and not (stop and stop())):
            job.written += paper_figures(job.runs, out, renderer)
        if stop is not None and stop():
            job.code = EXIT_INTERRUPTED
    finally:
        unpacked.remove()
        if not job.runs:
            write_json(out / "summary.json", {})
    return job


class _Unpacked:
    """The FMUs of a job, each unpacked once (into one temporary folder) for every scene that
    runs it: the paper's three scenes unpack two FMUs, not six. :meth:`remove` removes them."""

    def __init__(self):
        self.folder, self.dirs = None, {}

    def of(self, fmus: dict) -> dict:
        """``{role: folder}`` for ``{role: FMU path}``, unpacked when first asked."""
        import tempfile

        from .scene.fmu import unpack

        if self.folder is None:
            self.folder = tempfile.mkdtemp(prefix="flexpend_fmu_")
        for path in fmus.values():
            if str(path) not in self.dirs:
                self.dirs[str(path)] = unpack(path, os.path.join(self.folder,
                                                                 str(len(self.dirs))))
        return {role: self.dirs[str(path)] for role, path in fmus.items()}

    def remove(self):
        if self.folder is not None:
            import shutil
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder, self.dirs = None, {}


#: the predictions of :func:`step_warning` kept (the newest)
_WARNINGS_KEPT = 256


def step_warning(scene) -> str | None:
    """One line when the scene's plant step is near its integrator's stability limit (beyond it
    the scene is refused: :func:`check_plant_step`) or its communication step is beyond its
    coupling's predicted largest stable step (:func:`orchestration.studies.stability.
    step_warning`), else None. Kept in ``<home>/stability_warnings.json``
    (:func:`orchestration.export.places.home`) by the scene's plant, controller and master and
    the predicting modules' sources: a warm ``flexpend run`` neither imports scipy nor searches
    the step again. A cache that cannot be read or written is only not used."""
    import hashlib
    import json

    from .export.places import home

    studies = Path(__file__).resolve().parent / "studies"
    try:
        key = hashlib.sha256(repr((scene.plant, scene.controller, scene.master)).encode()
                             + (studies / "stability.py").read_bytes()
                             + (studies / "plant_step.py").read_bytes()).hexdigest()
    except OSError:
        key = None
    path = home() / "stability_warnings.json"
    try:
        kept = json.loads(path.read_text())
        if not isinstance(kept, dict):
            kept = {}
    except (OSError, ValueError):
        kept = {}
    if key in kept:
        return kept[key]
    from .studies.stability import step_warning as predict

    text = predict(scene)
    if key is not None:
        kept.pop(key, None)
        kept[key] = text
        try:
            write_json(path, dict(list(kept.items())[-_WARNINGS_KEPT:]))
        except OSError:
            pass
    return text
