"""The ``flexpend`` command line.

    flexpend run [SCENE ...] [--set key=value ...] [--out DIR] [--json] [--reference]
    flexpend analyze [--set key=value ...] [--json]     linear loop analysis
    flexpend design [--set key=value ...] [--json] [--out DIR] [--workers N | --scheduler ADDR]
                                                        robust low-pass filter design
    flexpend sweep SCENE [--grid ...] [--values ...] [--sample ... --samples N] [--workers N]
                                                        many runs, on dask.distributed
    flexpend build [--force] [--out DIR] [--fmus F]     build the FMUs (pythonfmu, native)
    flexpend scenes                                     list the scenes
    flexpend export SCENE [--fmus python|native] [--out FILE.ssp]   the scene as an SSP archive
    flexpend check FMU --reference DIR [--plot FILE.png] [--write-reference]   regress an FMU

``flexpend run`` also runs an SSP archive (``flexpend run FILE.ssp``).

Every error in the user's input (an unknown key, a bad value, an output folder that cannot be
written) is printed as one line naming it, and the exit code is 2. ``flexpend run`` exits with 0
when every scene ran to its stop time (stable or not), 3 when a scene stopped early (an FMU
refused to go on; its data up to there is written), 130 when interrupted by Ctrl-C (the data so
far is written, the FMUs are terminated and freed).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys

# One BLAS thread unless the user says otherwise (before numpy is imported): the command's
# matrices are small (the summary's fits, the linearisations), and on a shared 2-core machine a
# threaded BLAS spins against the other processes; a warm `flexpend run` took 30 s instead of 6.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .scene.keys import (CONTROLLER_KEYS, ConfigError, apply_overrides, controller_params,
                         default_config, fidelity, plant_params)

__all__ = ["main"]

EXIT_USAGE = 2
EXIT_FAILED = 1     # flexpend check: a signal outside its band, or a run that did not complete


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(message)


def _json_safe(obj):
    if isinstance(obj, float):
        if math.isnan(obj):
            return None
        if math.isinf(obj):
            return "inf" if obj > 0 else "-inf"
        return obj
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def _fmt(v, spec=".4g"):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return format(v, spec)


def _no_auto(cfg, command):
    for key in ("plant.n_modes", "plant.fidelity"):
        if cfg.get(key) == "auto":
            raise ConfigError(f"{key} = 'auto' is chosen by a run (flexpend run); flexpend "
                              f"{command} needs a value")


def cmd_analyze(args) -> int:
    from .studies.analysis import analyze

    from .scene.schema import known_keys

    # every scene key is accepted; those that do not change the linear loop are ignored
    cfg = apply_overrides(default_config(), args.set, known=known_keys())
    _no_auto(cfg, "analyze")
    fidelity(cfg)
    p, c = plant_params(cfg), controller_params(cfg)
    a = analyze(p, c)
    if args.json:
        out = {"plant": {f.name: getattr(p, f.name) for f in dataclasses.fields(p)},
               "controller": {k: getattr(c, k) for k in CONTROLLER_KEYS}, **a.to_json()}
        print(json.dumps(_json_safe(out), indent=2))
        return 0
    filt = _filter_text(c.filter_order, c.cutoff, c.filter_damping)
    print(f"plant: n_modes = {p.n_modes}, zeta = {p.zeta:g}, gravity_preload = "
          f"{str(p.gravity_preload).lower()}  (linearised at the upright rest state)")
    print(f"controller: kp = {c.kp:g}, kd = {c.kd:g}, kx = {c.kx:g}, filter: {filt}")
    if a.cantilever_frequencies:
        print("cantilever frequencies (rad/s): "
              + ", ".join(f"{w:.2f}" for w in a.cantilever_frequencies))
    print()
    print(f"{'closed-loop eigenvalue':>30}  {'|lambda| rad/s':>14}  {'damping ratio':>13}")
    for re, im, wn, zeta in a.modes():
        lam = f"{re:+.4f} {'+-' if im > 0 else '  '} {im:.4f}j" if im > 0 else f"{re:+.4f}"
        print(f"{lam:>30}  {wn:14.3f}  {_fmt(zeta, '13.4f'):>13}")
    print()
    verdict = "STABLE" if a.stable else "UNSTABLE"
    note = " (cart drift roots at 0 left aside)" if c.kx == 0 else ""
    print(f"max real part{note}: {a.max_real_part:+.4f}  ->  {verdict}")
    m = a.margins
    if m["nominal_stable"]:
        print(f"gain margin: x{_fmt(m['gain_margin_upper'])} upward (at "
              f"{_fmt(m['gain_margin_upper_freq'])} rad/s), x{_fmt(m['gain_margin_lower'])} "
              f"downward (at {_fmt(m['gain_margin_lower_freq'])} rad/s)")
    print(f"phase margin: {_fmt(m['phase_margin_deg'])} deg at {_fmt(m['phase_margin_freq'])} "
          "rad/s (smallest of all gain crossovers)")
    return 0


def _filter_text(order, cutoff, damping) -> str:
    return {0: "none", 1: f"1st order, wc = {cutoff:g} rad/s",
            2: f"2nd order, wc = {cutoff:g} rad/s, zf = {damping:g}"}[order]


def cmd_design(args) -> int:
    import numpy as np

    from .report import figures as plots
    from .studies.analysis import frequency_response
    from .studies.design import DESIGN_DEFAULTS, design_filter, design_settings, root_locus
    from .job import Progress
    from .scene.schema import known_keys

    known = {**known_keys(), **DESIGN_DEFAULTS}
    cfg = apply_overrides(known, args.set, known=known)
    _no_auto(cfg, "design")
    fidelity(cfg)
    settings = design_settings(cfg)
    p, c = plant_params(cfg), controller_params(cfg)
    out_dir = _output_dir(args.out)
    workers, scheduler = _executor_args(args)
    if workers is None and not scheduler:
        r = design_filter(p, c, settings, progress=Progress("design"))
    else:                          # the check grid's closed loops as dask tasks
        with _open_executor(workers, scheduler) as ex:
            r = design_filter(p, c, settings, progress=Progress("design"), executor=ex)
    crit = r.criterion
    ylabel = ("worst-case decay rate -max Re(lambda) (1/s)" if crit == "decay"
              else "worst-case damping ratio")
    # the worst case against cutoff, as CSV and plot
    labels = list(r.sweep)
    cutoffs = r.sweep[labels[0]][0]
    rows = np.column_stack([cutoffs] + [r.sweep[k][1] for k in labels])
    header = "cutoff," + ",".join(k.replace(",", ";") for k in labels)
    np.savetxt(out_dir / "design_sweep.csv", rows, delimiter=",", header=header, comments="")
    ch = r.chosen
    chosen_label = f"chosen: {_filter_text(ch.filter_order, ch.cutoff, ch.filter_damping)}"
    uset = r.uncertainty.describe()
    plots.plot_worst_case(
        r.sweep, (ch.cutoff, r.worst.score(crit), chosen_label), ylabel,
        f"worst case over n_modes {uset['n_modes'][0]}..{uset['n_modes'][1]}, zeta "
        f"{uset['zeta'][0]:g}..{uset['zeta'][1]:g}, EI +-{100 * r.uncertainty.EI_spread:g} %, "
        f"m +-{100 * r.uncertainty.m_spread:g} % (PD kp = {c.kp:g}, kd = {c.kd:g})",
        out_dir / "design_worst_case.png")
    # Bode of the loop without and with the filter, and the root locus, on the nominal beam
    w = np.logspace(0, np.log10(max(20.0 * ch.cutoff, 5e3)), 3000)
    loops = {"PD, no filter": frequency_response(p, c.replace(filter_order=0), w),
             chosen_label.replace("chosen: ", "PD + "): frequency_response(p, ch, w)}
    if (c.filter_order, c.cutoff, c.filter_damping) != (ch.filter_order, ch.cutoff, ch.filter_damping) \
            and c.filter_order:
        loops[f"PD + given {_filter_text(c.filter_order, c.cutoff, c.filter_damping)}"] = \
            frequency_response(p, c, w)
    marks = [(ch.cutoff, "cutoff")]
    plots.plot_loop_bode(w, loops, f"loop broken at the force, L = -K G (nominal beam, "
                                   f"{p.n_modes} modes)", out_dir / "design_bode.png", marks)
    wcs, roots = root_locus(p, ch, np.union1d(np.geomspace(settings["design.cutoff_min"],
                                                            settings["design.cutoff_max"], 300),
                                               [ch.cutoff]))
    plots.plot_root_locus(wcs, roots, ch.cutoff,
                          f"closed-loop roots as the cutoff varies ({_filter_text(ch.filter_order, 0, ch.filter_damping).replace(', wc = 0 rad/s', '')}"
                          f"; nominal beam, {p.n_modes} modes)", out_dir / "design_root_locus.png")
    result = r.to_json()
    result["plots"] = [str(out_dir / f) for f in ("design_bode.png", "design_root_locus.png",
                                                 "design_worst_case.png")]
    result["sweep_csv"] = str(out_dir / "design_sweep.csv")
    (out_dir / "design.json").write_text(json.dumps(_json_safe(result), indent=2))
    if args.json:
        print(json.dumps(_json_safe(result), indent=2))
        return 0

    def where(pl):
        return f"n_modes = {pl.n_modes}, zeta = {pl.zeta:g}, EI = {pl.EI:.4g}, m = {pl.m:.3g}"

    def root(z):
        return f"{z.real:+.4f} +- {abs(z.imag):.2f}j" if z.imag else f"{z.real:+.4f}"

    print(f"robust low-pass design for the PD kp = {c.kp:g}, kd = {c.kd:g}, kx = {c.kx:g}")
    print(f"uncertainty: n_modes {uset['n_modes'][0]}..{uset['n_modes'][1]}, zeta "
          f"{uset['zeta'][0]:g}..{uset['zeta'][1]:g}, EI {uset['EI'][0]:.4g}..{uset['EI'][1]:.4g}, "
          f"m {uset['m'][0]:.3g}..{uset['m'][1]:.3g}; searched on {r.levels} levels, checked on "
          f"{r.check_levels} levels ({r.worst.n_plants} plants)")
    print(f"criterion: the smallest closed-loop {'decay rate' if crit == 'decay' else 'damping ratio'}"
          " over the set, maximised")
    print()
    print(f"chosen filter: {_filter_text(ch.filter_order, ch.cutoff, ch.filter_damping)}")
    print("  " + " ".join(f"--set {k}={v:g}" for k, v in r.filter_keys().items()))
    wc_ = r.worst
    print(f"  worst-case decay rate {wc_.decay:+.4f} 1/s: root {root(wc_.decay_root)} at "
          f"{where(wc_.decay_plant)}")
    print(f"  worst-case damping ratio {wc_.damping:+.5f}: root {root(wc_.damping_root)} at "
          f"{where(wc_.damping_plant)}")
    print(f"  {'STABLE' if wc_.stable else 'UNSTABLE'} over the whole set")
    print()
    print(f"{'filter':<56}  {'worst decay 1/s':>15}  {'worst damping':>13}")
    rows = [(f"best {o}{'st' if o == 1 else 'nd'} order", cc, ww) for o, (cc, ww) in r.per_order.items()]
    rows += [(k, cc, ww) for k, (cc, ww) in r.baseline.items()]
    for label, cc, ww in rows:
        text = f"{label}: {_filter_text(cc.filter_order, cc.cutoff, cc.filter_damping)}"
        print(f"{text:<56}  {ww.decay:+15.4f}  {ww.damping:+13.5f}")
    print()
    print(f"wrote {out_dir / 'design.json'}, {out_dir / 'design_sweep.csv'}, "
          + ", ".join(result["plots"]))
    return 0


def _mode_text(m) -> str:
    """One fitted mode, with the linear prediction beside it."""
    if m is None:
        return "-"
    lin = m.get("linear")
    lin_text = (f"   (linear: {lin['rate']:+.3f} +- {lin['frequency']:.2f}j)" if lin else "")
    if m["reliable"]:
        return f"rate {m['rate']:+.3f} 1/s at {m['frequency']:.2f} rad/s{lin_text}"
    return f"{m['note']}{lin_text}"


def _print_summary(name, s, written):
    if s["stopped"] is not None:
        verdict = f"STOPPED at t = {s['stopped']['time']:.6g} s"
    else:
        verdict = {True: "stable", False: "UNSTABLE", None: "no verdict (no reliable fit)"}[
            s["stable"]]
    print(f"{name}: {verdict}")
    if s["stopped"] is not None:
        print(f"  stopped: {s['stopped']['reason']}")
    if s.get("model"):
        m = s["model"]
        auto = " and ".join(k for k, on in (("plant.n_modes", m["n_modes_auto"]),
                                               ("plant.fidelity", m["fidelity_auto"])) if on)
        print(f"  model: {m['n_modes']} modes, {m['fidelity']} ({auto} = auto, tolerance "
              f"{100 * m['tolerance']:g} % on {', '.join(m['outputs'])})")
        for part in m["reason"].split("; "):
            print(f"    {part}")
    print(f"  slow (rigid) oscillation: {_mode_text(s.get('slow'))}")
    print(f"  bending oscillation:      {_mode_text(s.get('bending'))}")
    v = s.get("validity")
    if v and v["warnings"]:
        for w in v["warnings"]:
            print(f"  WARNING, outside the model's range: {w}")
    elif v and v["max_abs_tip_deflection"] is not None:
        print(f"  within the model's range (tip deflection at most {v['max_abs_tip_deflection']:.3g}"
              f" m, |phi| at most {v['max_abs_phi']:.3g} rad)")
    if s.get("max_abs_F_c") is not None:
        print(f"  max |F_c|: {s['max_abs_F_c']:.4g} N; max |x|: {s['max_abs_x']:.4g} m")
    if "wall_time" in s:
        loop = f"; {s['master_loop']} loop" if s.get("master_loop") else ""
        print(f"  wall time: {s['wall_time']:.3g} s ({s['steps']} communication steps, "
              f"{s['rejected_steps']} rejected{loop})")
    if "max_error_phi_o" in s:
        print(f"  max error against the monolithic reference: phi_o {s['max_error_phi_o']:.3e} rad, "
              f"eta_1 {s['max_error_eta_1']:.3e} m kg^0.5")
    if written:
        print(f"  wrote {', '.join(str(w) for w in written)}")


def _output_dir(text: str):
    """The output folder, created; a path that is a file or cannot be written is a UsageError."""
    import tempfile
    from pathlib import Path

    out = Path(text)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {text}: exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise UsageError(f"--out {text}: cannot write there ({exc.strerror or exc})") from None
    return out


class _Interrupts:
    """Ctrl-C during ``flexpend run``. A SIGINT is only noted: raising KeyboardInterrupt at an
    arbitrary point can land inside a pythonfmu FMU's embedded Python code (which kills the FMU
    and can crash the process) or inside a library's callback (where it is printed and lost).
    The master asks :meth:`requested` after every communication step and stops; the command
    checks it between its phases (:meth:`check`). So the data so far is written, the FMUs are
    terminated and freed, and the exit code is 130. A third SIGINT raises at once."""

    def __init__(self):
        self.count = 0

    def __call__(self, signum, frame):
        self.count += 1
        if self.count >= 3:
            raise KeyboardInterrupt

    def requested(self) -> bool:
        return self.count > 0

    def check(self):
        """Raise KeyboardInterrupt here, at a safe point, if Ctrl-C was pressed."""
        if self.count:
            raise KeyboardInterrupt

    def install(self):
        import signal

        self._previous = signal.signal(signal.SIGINT, self)
        return self

    def restore(self):
        import signal

        signal.signal(signal.SIGINT, self._previous)


#: Exit codes of ``flexpend run``.
EXIT_STOPPED = 3
EXIT_INTERRUPTED = 130


def cmd_run(args) -> int:
    from .scene.schema import PAPER_SCENES, load_scene

    names = args.scenes or list(PAPER_SCENES)
    # validate all before running; an SSP archive brings its own FMUs
    loaded = [_read_ssp(n, args.set) if n.endswith(".ssp") else load_scene(n, args.set)
              for n in names]
    scenes = [getattr(s, "scene", s) for s in loaded]
    own_fmus = {id(s.scene): s.fmus for s in loaded if hasattr(s, "fmus")}
    out_dir = _output_dir(args.out)

    interrupts = _Interrupts().install()                  # Ctrl-C is noted from here on
    try:
        from fmpy.util import write_csv  # noqa: F401

        from .report import figures as plots
        from .export import build_fmus
        from .job import run_scene  # noqa: F401
        plots._pyplot()
        interrupts.check()
        from .export import fmu_pair
        fmus = {fl: fmu_pair(build_fmus(flavour=fl))          # the flavours the scenes use
                for fl in dict.fromkeys(sc["master.fmus"] for sc in scenes
                                        if id(sc) not in own_fmus)}
        _check_wiring(scenes, fmus, own_fmus)              # before any scene runs
        interrupts.check()
        return _run_scenes(args, scenes, fmus, out_dir, interrupts, own_fmus)
    except KeyboardInterrupt:
        if not (out_dir / "summary.json").exists():     # interrupted before any scene ran
            (out_dir / "summary.json").write_text("{}")
        print("flexpend: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        interrupts.restore()


def _check_wiring(scenes, fmus, own_fmus=None):
    """Every connection of every scene names variables the FMUs have (ConfigError otherwise);
    ``own_fmus``: id(scene) -> the FMUs of a scene read from an SSP archive."""
    from fmpy import read_model_description

    from .scene.wiring import parse_connection

    for scene in scenes:
        variables = {k: [v.name for v in read_model_description(str(p)).modelVariables]
                     for k, p in ((own_fmus or {}).get(id(scene))
                                  or fmus[scene["master.fmus"]]).items()}
        for text in scene["connections"]:
            c = parse_connection(text)
            for fmu, var in ((c.src, c.src_var), (c.dst, c.dst_var)):
                if var not in variables[fmu]:
                    raise ConfigError(f"{scene.name}: {fmu} has no variable {var!r}; it has: "
                                      f"{', '.join(variables[fmu])}")


def _run_scenes(args, scenes, fmus, out_dir, interrupts, own_fmus=None) -> int:
    from fmpy.util import write_csv

    from .report import figures as plots
    from .job import run_scene

    summaries, results = {}, {}
    code = 0
    try:
        for scene in scenes:
            interrupts.check()
            print(f"{scene.name}: running {scene['stop_time']:g} s (communication step "
                  f"{scene['master.step']:g} s)", file=sys.stderr, flush=True)
            r = run_scene(scene, (own_fmus or {}).get(id(scene)) or fmus[scene["master.fmus"]],
                          reference=args.reference and not interrupts.requested(),
                          progress=True, connections_out=sys.stderr if args.connections else None,
                          stop=interrupts.requested)
            written = _write_scene(r, scene, out_dir, write_csv, plots)
            summaries[scene.name] = r.summary
            results[scene.name] = r.result
            if not args.json:
                _print_summary(scene.name, r.summary, written)
            if r.interrupted:
                code = EXIT_INTERRUPTED
                break
            if r.summary["stopped"] is not None:
                code = EXIT_STOPPED
        if not args.scenes and code != EXIT_INTERRUPTED and len(results) == len(scenes):
            plots.plot_paper_overview(results, out_dir / "paper_overview.png")
            if not args.json:
                print(f"paper overview: {out_dir / 'paper_overview.png'}")
    finally:
        (out_dir / "summary.json").write_text(json.dumps(_json_safe(summaries), indent=2))
    if args.json:
        print(json.dumps(_json_safe(summaries), indent=2))
    if code == EXIT_INTERRUPTED:
        print(f"flexpend: interrupted; the data so far is in {out_dir}", file=sys.stderr)
    elif code == EXIT_STOPPED:
        stopped = [n for n, s in summaries.items() if s["stopped"] is not None]
        print(f"flexpend: {', '.join(stopped)} stopped early (exit code {EXIT_STOPPED})",
              file=sys.stderr)
    return code


def _write_scene(r, scene, out_dir, write_csv, plots) -> list:
    """The CSV and the figures of one run (whatever it reached); the paths written."""
    written = [out_dir / f"{scene.name}.csv"]
    write_csv(str(written[0]), r.result)
    title = scene["description"] or scene.name
    if len(r.result) >= 2:
        written.append(out_dir / f"{scene.name}.png")
        plots.plot_time_histories(r.result, scene.name, title, written[-1], r.reference,
                                  r.summary)
    if r.frames:
        written.append(out_dir / f"{scene.name}_shapes.png")
        plots.plot_snapshots(scene_beam(r.scene), r.frames, f"{scene.name}: beam shapes",
                             written[-1])
    return written


def _read_ssp(path, overrides):
    """An SSP archive as a scene and its FMUs (unpacked until the process exits)."""
    import atexit

    from .scene.ssp import read_ssp
    system = read_ssp(path, overrides)
    atexit.register(system.close)
    return system


def cmd_export(args) -> int:
    from pathlib import Path

    from .export.flavours import FlavourUnavailable
    from .export.system import export_scene
    from .job import Progress
    from .scene.schema import load_scene

    if args.out is not None and Path(args.out).suffix != ".ssp":
        raise UsageError(f"--out {args.out}: the archive's name must end in .ssp")
    scene = load_scene(args.scene, args.set)
    try:
        r = export_scene(scene, args.fmus, args.out,
                         progress=Progress(f"{scene.name}: choosing the model"))
    except FlavourUnavailable as exc:
        raise UsageError(f"--fmus {args.fmus}: {exc}") from None
    except ValueError as exc:           # an FMU without a parameter the scene sets, ...
        raise UsageError(str(exc)) from None
    cfg = r.scene.config
    print(f"wrote {r.path}: plant {Path(r.fmus['plant']).name}, controller "
          f"{Path(r.fmus['controller']).name} ({args.fmus} FMUs), {len(cfg['connections'])} "
          f"connections, stop time {cfg['stop_time']:g} s, master {cfg['master.algorithm']} "
          f"at {cfg['master.step']:g} s")
    if r.model is not None:
        print(f"  model: {r.model['n_modes']} modes, {r.model['fidelity']} ({r.model['reason']})")
    return 0


def cmd_check(args) -> int:
    from .export.check import ReferenceError, Rule, check_fmu, plot_check, write_reference

    try:
        rule = Rule(args.tolerance, args.window, args.max_outliers)
    except ValueError as exc:
        raise UsageError(str(exc).replace("max_outliers", "--max-outliers", 1)
                         .replace("tolerance", "--tolerance", 1).replace("window", "--window", 1)) \
            from None
    outputs = [o.strip() for o in args.outputs.split(",") if o.strip()] if args.outputs else None
    try:
        if args.write_reference:
            files = write_reference(args.fmu, args.reference, outputs)
            print(f"wrote {files['ref']} (options {files['opt']}"
                  + (f", inputs {files['in']}" if files["in"].is_file() else ", no input file")
                  + ")")
            return 0
        report = check_fmu(args.fmu, args.reference, rule)
    except ReferenceError as exc:
        raise UsageError(str(exc)) from None
    print("\n".join(report.lines()))
    if args.plot:
        print(f"plot: {plot_check(report, args.plot)}")
    return 0 if report.passed else EXIT_FAILED


def _executor_args(args):
    """``(workers, scheduler)`` for :func:`orchestration.sweep.executor.open_executor`."""
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers} is not allowed; allowed: an integer >= 1")
    if args.workers is not None and args.scheduler:
        raise UsageError("--workers starts a LocalCluster, --scheduler uses an existing one: "
                         "give one of them")
    return args.workers, args.scheduler


def _open_executor(workers, scheduler, files=()):
    from .sweep.executor import open_executor
    try:
        ex = open_executor(workers, scheduler, files=files)
    except ValueError as exc:                # an unreachable scheduler
        raise UsageError(str(exc)) from None
    print(f"running on {ex.describe()}", file=sys.stderr)
    note = getattr(ex, "dashboard_note", lambda: None)()
    if note:
        print(note, file=sys.stderr)
    return ex


def cmd_sweep(args) -> int:
    from pathlib import Path

    from .sweep.executor import default_workers
    from .sweep.plan import design_worst_case, plan_sweep
    from .sweep.engine import fmus_for, pending, run_sweep, sweep_stats

    if args.serial and (args.workers is not None or args.scheduler):
        raise UsageError("--serial runs here, without dask: it takes no --workers or --scheduler")
    if args.batch < 1:
        raise UsageError(f"--batch {args.batch} is not allowed; allowed: an integer >= 1")
    workers, scheduler = _executor_args(args)
    plan = plan_sweep(args.scene, grids=args.grid, values=args.values, samples=args.sample,
                      n_samples=args.samples, seed=args.seed, overrides=args.set,
                      reference=args.reference)
    out_dir = Path(args.out)
    todo = pending(plan, out_dir, args.retry_failed)
    done = len({p.key for p in plan.points}) - todo
    _output_dir(args.out)
    print(f"sweep of {plan.scene.name}: {len(plan.points)} runs"
          + (f", {done} already finished in {out_dir}" if done else ""), file=sys.stderr)
    fmus = fmus_for(plan)
    if args.serial or todo == 0:
        from .sweep.executor import Executor
        executor = Executor()
    else:
        if workers is None and not scheduler:
            workers = min(default_workers(), todo)
        executor = _open_executor(workers, scheduler,
                                  files=[f for pair in fmus.values() for f in pair.values()])
    try:
        with executor:
            res = run_sweep(plan, fmus, out_dir, executor, batch=args.batch,
                            retry_failed=args.retry_failed)
    except KeyboardInterrupt:
        print(f"\ninterrupted: the finished runs are in {out_dir / 'runs.jsonl'}; the same "
              "command continues the sweep", file=sys.stderr)
        return EXIT_INTERRUPTED
    stats = sweep_stats(res.rows)
    design = design_worst_case(plan)
    if design is not None:
        stats["design_worst_case"] = design.to_json()
    meta = {"command": "flexpend " + " ".join(sys.argv[1:]) if args.argv is None else
            "flexpend " + " ".join(args.argv),
            **plan.describe(), "executor": executor.describe(), "batch": args.batch,
            "ran": res.ran, "skipped": res.skipped, "seconds": res.seconds, "stats": stats,
            "table": str(res.table), "plot": None if res.plot is None else str(res.plot)}
    (out_dir / "sweep.json").write_text(json.dumps(_json_safe(meta), indent=2))
    if args.json:
        print(json.dumps(_json_safe(meta), indent=2))
    else:
        _print_sweep(plan, res, stats, executor)
    return 1 if stats["lost"] else 0


def _print_sweep(plan, res, stats, executor):
    print(f"{plan.scene.name}: {stats['runs']} runs: {stats['ok']} ok, {stats['failed']} failed"
          + (f", {stats['lost']} lost (their workers died; rerun the same command to retry "
             "them)" if stats["lost"] else "")
          + (f"; {res.ran} ran in {res.seconds:.1f} s on {executor.describe()}" if res.ran
             else "; 0 ran")
          + (f", {res.skipped} were already done" if res.skipped else ""))
    if stats["stable_fraction"] is not None:
        print(f"  stable: {stats['stable']} of {stats['ok'] + stats['failed']} finished runs "
              f"({100 * stats['stable_fraction']:.1f} %); unstable {stats['unstable']}, no "
              f"verdict {stats['no_verdict']} (stopped early, or no reliable fit)"
              + (f"; {stats['invalid']} left the model's range" if stats["invalid"] else ""))
    if "worst_decay_rate" in stats:
        worst = res.rows[stats["worst_run"]]
        where = ", ".join(f"{k} = {_fmt(worst[k]) if isinstance(worst[k], float) else worst[k]}"
                          for k in plan.keys)
        print(f"  decay rate -max(fitted rate): worst {stats['worst_decay_rate']:+.4g} 1/s "
              f"(run {stats['worst_run']}: {where}), median {stats['median_decay_rate']:+.4g}, "
              f"best {stats['best_decay_rate']:+.4g}")
    if "worst_linear_decay_rate" in stats:
        print(f"  linearised loop over the same runs: worst decay rate "
              f"{stats['worst_linear_decay_rate']:+.4g} 1/s (run {stats['worst_linear_run']})")
    if "design_worst_case" in stats:
        w = stats["design_worst_case"]
        at = ", ".join(f"{k} = {_fmt(v)}" for k, v in w["decay_rate_at"].items())
        print(f"  flexpend design's worst case over the uncertainty set (linear, {w['plants']} "
              f"plants): {w['decay_rate']:+.4g} 1/s at {at}")
    failed = [r for r in res.rows if r["status"] != "ok"]
    for r in failed[:3]:
        print(f"  run {r['run']} {r['status']}: {(r['message'] or '')[:160]}")
    if len(failed) > 3:
        print(f"  ... {len(failed) - 3} more (the table has every message)")
    print(f"  wrote {res.table}" + (f", {res.plot}" if res.plot else ""))


def scene_beam(scene):
    from plant_fmu.beam import beam_model
    return beam_model(scene.plant)


def cmd_build(args) -> int:
    from pathlib import Path

    from .export import BuildError, build_fmus
    out = None if args.out is None else Path(args.out)
    builds = [("python", 2, out), ("native", 2, out and out / "native"),
              ("native", 3, out and out / "native")]
    if args.fmus:
        builds = [b for b in builds if b[0] == args.fmus]
    try:
        for flavour, version, folder in builds:
            for name, path in build_fmus(folder, force=args.force, flavour=flavour,
                                         fmi_version=version).items():
                print(f"{name} ({flavour}, FMI {version}.0): {path}")
    except BuildError as exc:
        print(f"flexpend: {exc}", file=sys.stderr)
        return 2
    return 0


def cmd_scenes(args) -> int:
    from .scene.schema import list_scenes, load_scene
    for name in list_scenes():
        print(f"{name:24s} {load_scene(name)['description']}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="flexpend", description="Flexible inverted pendulum: analysis and "
                                                  "co-simulation of the FMUs.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    pa = sub.add_parser("analyze", help="linear analysis of the closed loop",
                        description="Eigenvalues, stability and margins of the linearised loop.")
    pa.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a parameter, e.g. plant.n_modes=4 or controller.cutoff=150")
    pa.add_argument("--json", action="store_true", help="print the result as JSON")
    pa.set_defaults(func=cmd_analyze)

    pd = sub.add_parser("design", help="robust design of the low-pass filter",
                        description="Search the filter order, cutoff and damping for the largest "
                                    "worst-case closed-loop decay rate (or damping ratio) over an "
                                    "uncertainty set of beams; write <out>/design.json, "
                                    "design_sweep.csv and three plots.")
    pd.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key, e.g. controller.kd=6 or design.criterion=damping")
    pd.add_argument("--out", default="out", help="output folder (default: out)")
    pd.add_argument("--json", action="store_true", help="print the result as JSON")
    pd.add_argument("--workers", type=int, default=None, metavar="N",
                    help="check the chosen filter's worst case on a dask LocalCluster of N "
                         "processes (default: here; worth it for a fine design.check_levels)")
    pd.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="check it on the dask cluster of this scheduler")
    pd.set_defaults(func=cmd_design)

    pr = sub.add_parser("run", help="co-simulate scenes (default: the paper's three)",
                        description="Co-simulate the plant and controller FMUs for each scene; "
                                    "write <out>/<scene>.csv and PNG plots, print a summary.")
    pr.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="scene names (see 'flexpend scenes'), paths to .toml files or SSP "
                         "archives (.ssp)")
    pr.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene key, e.g. master.step=5e-4")
    pr.add_argument("--out", default="out", help="output folder (default: out)")
    pr.add_argument("--json", action="store_true", help="print the summary as JSON")
    pr.add_argument("--connections", action="store_true",
                    help="print each scene's connection table (wiring by variable name)")
    pr.add_argument("--reference", action="store_true",
                    help="also solve the monolithic reference and report the error against it")
    pr.set_defaults(func=cmd_run)

    pb = sub.add_parser("build", help="build the two FMUs (only when their sources changed)")
    pb.add_argument("--force", action="store_true", help="rebuild even if up to date")
    pb.add_argument("--out", default=None, help="output folder (default: build/fmus; the native "
                    "FMUs in its native/fmi2 and native/fmi3)")
    pb.add_argument("--fmus", choices=("native", "python"), default=None,
                    help="build only this flavour (default: both)")
    pb.set_defaults(func=cmd_build)

    pw = sub.add_parser("sweep", help="many runs of a scene over a grid or a random sample, "
                                      "on dask.distributed",
                        description="Co-simulate a scene over a grid of keys and/or random "
                                    "samples, on a dask LocalCluster (or --scheduler); write "
                                    "<out>/sweep.parquet (or .csv), sweep.png, sweep.json, and "
                                    "runs.jsonl (rerunning into the same --out skips the runs "
                                    "already finished).")
    pw.add_argument("scene", metavar="SCENE", help="scene name or path to a .toml file")
    pw.add_argument("--grid", action="append", default=[], metavar="KEY=START:STOP:NUM[:log]",
                    help="NUM values of a scene key from START to STOP (geometric with :log)")
    pw.add_argument("--values", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="a list of values of a scene key")
    pw.add_argument("--sample", action="append", default=[], metavar="KEY=DIST",
                    help="random values: design (the key's range in flexpend design's "
                         "uncertainty set; '--sample design' samples its four keys), "
                         "uniform:LO:HI, loguniform:LO:HI, normal:MEAN:SD, integers:LO:HI")
    pw.add_argument("--samples", type=int, default=None, metavar="N",
                    help="number of random samples")
    pw.add_argument("--seed", type=int, default=None, metavar="S",
                    help="seed of the samples (default 0)")
    pw.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a fixed scene key (or a design.* key of the uncertainty set)")
    pw.add_argument("--reference", action="store_true",
                    help="also solve each run's monolithic reference and report the error")
    pw.add_argument("--workers", type=int, default=None, metavar="N",
                    help="worker processes of the LocalCluster (default: one per core)")
    pw.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="use the dask cluster of this scheduler, e.g. tcp://host:8786")
    pw.add_argument("--serial", action="store_true", help="run here, one run after the other")
    pw.add_argument("--batch", type=int, default=1, metavar="N",
                    help="runs per dask task (batch short runs; default 1)")
    pw.add_argument("--retry-failed", action="store_true",
                    help="rerun the runs that failed in an earlier sweep into the same --out")
    pw.add_argument("--out", default="out/sweep", help="output folder (default: out/sweep)")
    pw.add_argument("--json", action="store_true", help="print the sweep's record as JSON")
    pw.set_defaults(func=cmd_sweep)

    ps = sub.add_parser("scenes", help="list the scenes")
    ps.set_defaults(func=cmd_scenes)

    from .export.flavours import DEFAULT_FLAVOUR, FLAVOURS
    pe = sub.add_parser("export", help="write a scene as an SSP archive (both FMUs, wiring, "
                                       "parameters, experiment)",
                        description="Write SCENE as an SSP 1.0 archive: SystemStructure.ssd and "
                                    "both FMUs under resources/. 'auto' models are chosen first. "
                                    "Run it back with 'flexpend run FILE.ssp'.")
    pe.add_argument("scene", metavar="SCENE", help="scene name or path to a .toml file")
    pe.add_argument("--fmus", choices=list(FLAVOURS), default=DEFAULT_FLAVOUR,
                    help=f"which FMUs to package (default: {DEFAULT_FLAVOUR})")
    pe.add_argument("--out", default=None, metavar="FILE.ssp",
                    help="the archive (default: out/<scene>.ssp)")
    pe.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene key, e.g. master.algorithm=jacobi")
    pe.set_defaults(func=cmd_export)

    pc = sub.add_parser("check", help="regress an FMU against reference results (FMI "
                                      "cross-check layout)",
                        description="Simulate FMU alone with <Model>_in.csv and <Model>_ref.opt "
                                    "of the reference folder and compare every signal of "
                                    "<Model>_ref.csv within FMPy's cross-check band. Prints one "
                                    "line per signal; exits 1 on any signal outside its band "
                                    "or a run that does not reach the stop time, 2 on bad input.")
    pc.add_argument("fmu", metavar="FMU", help="the .fmu file")
    pc.add_argument("--reference", required=True, metavar="DIR",
                    help="folder with <Model>_ref.csv, <Model>_ref.opt, <Model>_in.csv (or a "
                         "<Model> subfolder with them)")
    pc.add_argument("--plot", metavar="FILE.png", help="draw each signal over its band")
    pc.add_argument("--write-reference", action="store_true",
                    help="write <Model>_ref.csv from a run instead of checking (and "
                         "<Model>_ref.opt from the FMU's default experiment if missing)")
    pc.add_argument("--outputs", metavar="NAMES",
                    help="with --write-reference: comma-separated signals to record (default: "
                         "those of the existing reference, else every output)")
    pc.add_argument("--tolerance", type=float, default=0.1,
                    help="band half-width as a fraction of each signal's range (default: 0.1)")
    pc.add_argument("--window", type=int, default=21,
                    help="samples the band is widened over (default: 21; 1: none)")
    pc.add_argument("--max-outliers", type=float, default=0.1,
                    help="fraction of samples allowed outside the band (default: 0.1; 0: none)")
    pc.set_defaults(func=cmd_check)
    return parser


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        args.argv = None if argv is None else list(argv)
        return args.func(args)
    except (UsageError, ConfigError) as exc:
        print(f"flexpend: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. piped into head
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("flexpend: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def entry():
    """The ``flexpend`` command. After Ctrl-C the process ends at once with 130 (its output
    flushed): a KeyboardInterrupt that reached code run by an FMU's embedded Python makes the
    interpreter kill itself with SIGINT at finalisation, and pythonfmu's finalisation can
    abort (see docs/fmus.md); the data is already written and the FMUs freed."""
    code = main()
    if code == EXIT_INTERRUPTED:
        import os

        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":
    entry()
