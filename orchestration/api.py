"""The front door's functions (exported by :mod:`orchestration`): keyword arguments, typed
results, errors that subclass ``ValueError`` or ``TypeError`` and name the bad key or argument.

    load_scene(scene, overrides=None) -> Scene
    simulate(scene, overrides=None, *, fmus=None, reference=False, progress=False) -> Run
    analyze(scene=None, overrides=None) -> Analysis
    stability(scene=None, overrides=None, *, max_step=None, progress=False) -> dict
    sampled_stability(loop, T_max=None) -> dict
    design(scene=None, overrides=None, *, design=None, workers=None, scheduler=None,
           progress=False) -> DesignReport
    sweep(scene, *, grid=..., values=..., sample=..., samples=None, ..., progress=False) -> Sweep
    build_fmus(flavour="native", *, fmi_version=2, out=None, force=False,
               progress=False) -> {name: path}
    scene_keys() -> (KeySpec, ...)

``progress=``, the same in every function that takes it: ``False`` (the default: silent),
``True`` (a bar on stderr, shown once the work has lasted a second) or a callable
``progress(fraction, label)``, called with the fraction of the whole call done (0 to 1, never
decreasing, 1.0 last when the work completes) and a str naming what is being done (the rung,
the model, the FMU); anything else is a TypeError naming ``progress``
(:mod:`orchestration.report.progress`).
"""
from __future__ import annotations

from pathlib import Path

from .export import build_fmus as _build_fmus
from .job import Run, simulate
from .report.design import DesignReport
from .report.progress import Steps, check_progress, sink_for
from .scene.keys import DESIGN_LISTED, FMU_FLAVOURS, ConfigError, check_known
from .scene.records import KeySpec, Scene, key_specs
from .scene.schema import load_scene
from .studies.analysis import Analysis, Linearisation, linearisation
from .studies.analysis import analyze as _analyze
from .studies.design import DESIGN_DEFAULTS, design_curves, design_filter, design_settings
from .sweeps.executor import open_executor
from .sweeps.job import Sweep, sweep

__all__ = ["load_scene", "simulate", "analyze", "stability", "design", "sweep", "build_fmus",
           "scene_keys", "Scene", "Run", "Analysis", "DesignReport", "Sweep", "KeySpec",
           "ConfigError"]


def scene_keys() -> tuple:
    """Every scene key, in the order of a scene file, as a
    :class:`~orchestration.scene.records.KeySpec`: its ``key``, ``type``, ``default``, ``unit``,
    ``allowed`` (the rule the scene's records enforce, then what it needs with other keys) and
    ``meaning``; what ``flexpend keys`` prints.

        {k.key: k.default for k in scene_keys()}["controller.kp"]    # 500.0
    """
    return key_specs()


def _resolved(scene, overrides, command: str) -> tuple[Scene, Linearisation]:
    """The scene (default: the default scene) with its model given, and its linearisation
    (:func:`~orchestration.studies.analysis.linearisation`): analyses need a model whose own
    linearisation the floating frame is."""
    sc = load_scene(scene if scene is not None else {}, overrides)
    if not sc.resolved:
        key = "plant.n_modes" if sc.plant.n_modes_auto else "plant.fidelity"
        raise ConfigError(f"{key} = 'auto' is chosen by a run (simulate); {command} needs a "
                          "value", cli=f"{key} = 'auto' is chosen by a run (flexpend run); "
                          f"{command} needs a value")
    lin = linearisation(sc)
    if not lin.own:
        raise ConfigError(f"plant.fidelity = '{sc.plant.fidelity}': {command} works on the "
                          "floating frame's linearised loop, which the exact beam does not have "
                          "here; set plant.fidelity = 'nonlinear' (the same beam with "
                          "plant.n_modes modes)")
    return sc, lin


def analyze(scene=None, overrides=None) -> Analysis:
    """The linearised closed loop of a scene's plant and controller (every scene key is accepted;
    those that do not change the linear loop are ignored): eigenvalues, damping ratios, the
    verdict and the margins (:class:`~orchestration.studies.analysis.Analysis`).

    ``scene``: as :func:`load_scene` takes it (default: the default scene); ``overrides``: a
    dict of scene keys (``{"plant.n_modes": 3, "controller.filter_order": 0}``). A sampled
    controller (``controller.sample_period > 0``) adds its discrete-time loop at its sample
    period, delay and discretization, ``Analysis.sampled``
    (:class:`~orchestration.studies.sampled.SampledPoles`: the z-plane poles, their s-plane
    equivalents, the spectral radius, the margin ``1 - max |z|``, the verdict); the other
    fields stay the continuous controller's."""
    sc, lin = _resolved(scene, overrides, "analyze")
    a = _analyze(lin.params, sc.controller, loop=lin.text())
    c = sc.controller
    if c.sampled:
        import dataclasses

        from .studies.sampled import controller_poles, sampled_margins
        a.sampled = dataclasses.replace(
            controller_poles(lin.params, c),
            margins=sampled_margins((lin.params, c), c.sample_period, c.delay, c.discretization))
    return a


def stability(scene=None, overrides=None, *, max_step: float | None = None,
              progress=False) -> dict:
    """Where the scene's linearised co-simulation is stable: for its own coupling and for every
    coupling the master offers, the stable and unstable intervals of the communication step from
    0.1 ms to ``max_step`` (default 0.05 s), the first crossing of ``rho = 1``, and the plant
    method's substep limit (``flexpend stability``;
    :func:`orchestration.studies.stability.stability_report`), with ``"assumes"``: what the
    prediction assumes (:func:`~orchestration.studies.stability.assumptions`), ``"loop"``:
    which linearised loop, its damping law named, and ``"name"``: the scene's.

    ``progress``: as the module's docstring says (the fraction of the scan's grid of steps).
    A ConfigError for a scene whose co-simulation has no transition matrix (adaptive,
    Model Exchange, an adaptive plant method); a ValueError naming ``max_step`` for a step
    outside 1 ms .. 10 s.

    A sampled controller (``controller.sample_period > 0``) adds ``"sampled"``
    (:func:`sampled_stability`): the stable intervals of its sample period at the scene's delay
    and the largest stable sample period with no delay and with a full period's delay."""
    from .studies.stability import assumptions, stability_report

    check_progress(progress)
    sc, lin = _resolved(scene, overrides, "stability")
    sink = sink_for(progress, f"{sc.name}: stability")
    try:
        report = stability_report(sc, max_step=max_step, progress=sink)
        if sc.controller.sampled:
            report["sampled"] = sampled_stability((lin.params, sc.controller),
                                                  T_max=report["max_step"])
        if sink is not None:
            sink.finish()
    except ValueError as exc:
        if str(exc).startswith("max_step"):
            raise
        raise ConfigError(f"{sc.name}: no prediction: {exc}") from None
    finally:
        if sink is not None:
            sink.close()        # a bar's line ended, had the work stopped before its end
    return {**report, "name": sc.name, "loop": lin.text(), "assumes": assumptions(sc)}


def sampled_stability(loop, T_max: float | None = None) -> dict:
    """The sampled controller's stability in its sample period (``flexpend stability`` of a
    sampled scene): ``loop`` is a scene or a pair ``(PlantParams, ControllerParams)`` whose
    controller has ``sample_period > 0``; its delay ``tau`` and discretization are kept.
    ``{"T", "tau", "discretization", "scanned": [T_min, T_max], "intervals": [[T_low, T_high],
    ...] (stable at the delay tau, T >= tau), "critical": the largest T up to which it stays
    stable at tau (None: unstable at the smallest), "stable": the verdict at T, "margin":
    1 - max |z| at T, "critical_periods": {"tau=0": ..., "tau=T": ...}}`` (seconds;
    :func:`~orchestration.studies.sampled.stable_intervals`,
    :func:`~orchestration.studies.sampled.critical_periods`; the sample periods from 0.1 ms to
    ``T_max``, default 0.05 s, the Tustin filter's below ``pi / cutoff``)."""
    from .studies.sampled import (MIN_PERIOD, T_RANGE, _params, controller_poles,
                                  critical_periods, stable_intervals)

    p, c = _params(loop)
    if not c.sampled:
        raise ValueError("sampled_stability needs a sampled controller "
                         "(controller.sample_period > 0)")
    T_range = (MIN_PERIOD, T_RANGE[1] if T_max is None else float(T_max))
    at = stable_intervals((p, c), T_range, tau=c.delay, discretization=c.discretization)
    now = controller_poles(p, c)
    return {"T": c.sample_period, "tau": c.delay, "discretization": c.discretization,
            "scanned": list(at.scanned), "intervals": [list(i) for i in at.intervals],
            "critical": at.critical, "stable": now.stable, "margin": now.margin,
            "critical_periods": critical_periods((p, c), c.discretization, T_range)}


def design(scene=None, overrides=None, *, design: dict | None = None, workers: int | None = None,
           scheduler: str | None = None, progress=False) -> DesignReport:
    """The robust low-pass filter for the scene's PD gains (``flexpend design``): the filter
    order, cutoff and damping with the largest worst-case decay rate (or damping ratio) over
    the uncertainty set around the scene's plant. ``design``: the ``design.*`` keys
    (``{"design.criterion": "damping"}``); ``workers``/``scheduler``: check the worst case on
    that many worker processes here, or on the dask cluster of that scheduler. ``progress``: as the module's docstring says (the candidate filters searched, the
    check, the curves). The result's ``save(folder)`` writes what ``flexpend design``
    writes."""
    check_progress(progress)
    sc, lin = _resolved(scene, overrides, "design")
    items = dict(design or {})
    check_known(items, DESIGN_DEFAULTS, listed=DESIGN_LISTED)
    settings = design_settings({**DESIGN_DEFAULTS, **items})
    sink = sink_for(progress, f"{sc.name}: design")
    steps = Steps(sink, 20)
    search = steps.part(19, f"{sc.name}: design: searching the filters")
    p, c = lin.params, sc.controller
    try:
        if workers is None and not scheduler:
            r = design_filter(p, c, settings, progress=search)
        else:
            with open_executor(workers, scheduler) as ex:
                r = design_filter(p, c, settings, progress=search, executor=ex)
        steps.part(1, f"{sc.name}: design: the frequency responses and the root locus")
        report = DesignReport(r, p, c, settings, design_curves(r, p, c, settings))
        steps.finish(f"{sc.name}: design")
    finally:
        if sink is not None:
            sink.close()
    return report


def build_fmus(flavour: str = "native", *, fmi_version: int = 2, out=None,
               force: bool = False, progress=False) -> dict:
    """Build the plant and controller FMUs of ``flavour`` (``"native"``: C, FMI 2.0 or 3.0;
    ``"python"``: pythonfmu, FMI 2.0) if missing or stale; ``{model name: path}``.
    ``progress``: as the module's docstring says (each step of each FMU built, named:
    ``"building PDLowPass (native, FMI 2.0): compiled its linux64 binary"``)."""
    if flavour not in FMU_FLAVOURS:
        raise ValueError(f"flavour = {flavour!r} is not allowed; allowed: "
                         f"{', '.join(map(repr, FMU_FLAVOURS))}")
    sink = sink_for(progress, f"building the {flavour} FMUs (FMI {fmi_version}.0)")
    try:
        paths = _build_fmus(Path(out) if out is not None else None, force=force,
                            flavour=flavour, fmi_version=fmi_version, progress=sink)
        if sink is not None:
            sink.finish()
    finally:
        if sink is not None:
            sink.close()
    return paths
