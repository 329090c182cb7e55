"""The ``flexpend`` command line: it parses and dispatches; the work is in the front door's
modules (:mod:`orchestration.api`, :mod:`orchestration.job`, :mod:`orchestration.sweeps`,
:mod:`orchestration.export`), the text in :mod:`orchestration.report.text`.

    flexpend run [SCENE ...] [--set key=value ...] [--out DIR] [--json] [--reference]
                 [--renderer raster|matplotlib] [--figures png|none]
    flexpend analyze [--set key=value ...] [--json]     linear loop analysis
    flexpend stability SCENE [--set key=value ...] [--max-step S] [--json]
                             [--sampled-region FILE.png]
                                                        where the communication step (and a
                                                        sampled controller's period) is stable
    flexpend design [--set key=value ...] [--json] [--out DIR] [--workers N | --scheduler ADDR]
                                                        robust low-pass filter design
    flexpend sweep SCENE [--grid ...] [--values ...] [--sample ... --samples N] [--workers N]
                                                        many runs, on dask.distributed
    flexpend build [--force] [--out DIR] [--fmus F]     build the FMUs (pythonfmu, native)
    flexpend scenes                                     list the scenes
    flexpend keys [--markdown]                          list every scene key
    flexpend export SCENE [--fmus python|native] [--out FILE.ssp]   the scene as an SSP archive
    flexpend check FMU --reference DIR [--plot FILE.png] [--write-reference]   regress an FMU
    flexpend --version

``flexpend run`` also runs an SSP archive (``flexpend run FILE.ssp``).

The commands that can take long (``run``, ``stability``, ``design``, ``build``, ``sweep``,
``export``) show their progress on stderr (:mod:`orchestration.report.progress`): a bar redrawn
on a terminal, else a line at each quarter and one when the bar's label changes (the rung, the
model, the FMU it is on), once the work has lasted a second (``FLEXPEND_PROGRESS_DELAY``: other
seconds). ``--quiet`` (``-q``; before or after the command's name) silences the progress and the
other chatter on stderr; errors, warnings and the results on stdout are kept.

Exit codes: 0 done (``flexpend run``: every scene ran to its stop time, stable or not); 1
``flexpend check`` found a signal outside its band or a run that did not complete, or a sweep
lost runs; 2 bad input (an unknown key, a bad value, a ``flexpend check`` reference with a signal
that does not vary or a ``--write-reference`` that would record one, an output folder that
cannot be written, a ``--scheduler`` that does not answer as a dask scheduler within 5 s or has
no worker within 30 s: one line naming it), or an output the system refused (a full disk: one line naming the file;
every earlier file is kept whole), or an ``--out`` in use by another run, or a limit of the
machine that the command cannot work within (too few file handles, ``ulimit -n``; too little
memory, ``ulimit -v``: one line naming the limit); 3 ``flexpend run``: a scene stopped early (an
FMU refused to go on; its data up to there is written); 130 interrupted by Ctrl-C, at any moment
(the data so far is written, the FMUs are terminated and freed, every temporary folder is
removed). ``run``, ``sweep`` and ``export`` stop at their next safe point (a communication step,
a run, a report of the reference's progress); ``analyze``, ``stability``, ``design``, ``build``
and ``check`` hold no FMU in this process and stop at once, each output complete or absent
(``build`` ends its compilers; ``check`` its FMU's process).

Every output file is written to a temporary name beside it and renamed into place: it is
complete or absent, and a failed write leaves the earlier file as it was. ``run``, ``design`` and
``sweep`` hold ``--out/.flexpend.lock`` (an exclusive ``flock``, released however the process
ends) while they write; a second command into the same ``--out`` meanwhile is refused.

Heavy modules (numpy, scipy, matplotlib, fmpy, dask) are imported by the command that needs them,
so that ``flexpend --version`` or ``flexpend scenes`` start at once.
"""
from __future__ import annotations

import argparse
import atexit
import contextlib
import errno
import json
import math
import os
import signal
import sys

# One BLAS thread unless the user says otherwise (before numpy is imported): the command's
# matrices are small (the summary's fits, the linearisations), and on a shared 2-core machine a
# threaded BLAS spins against the other processes; a warm `flexpend run` took 30 s instead of 6.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .scene.keys import FMU_FLAVOURS, ConfigError, parse_override  # noqa: E402  (stdlib only)

__all__ = ["main", "entry", "EXIT_USAGE", "EXIT_FAILED", "EXIT_STOPPED", "EXIT_INTERRUPTED"]

EXIT_USAGE = 2
EXIT_FAILED = 1     # flexpend check: a signal outside its band, or a run that did not complete
EXIT_STOPPED = 3
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(message)


def _version() -> str:
    from . import _version as v
    return v()


class Interrupts:
    """Ctrl-C. A SIGINT is only noted: raising KeyboardInterrupt at an arbitrary point can land
    inside a pythonfmu FMU's embedded Python code (which kills the FMU and can crash the
    process) or inside a library's callback (where it is printed and lost). The commands ask
    :meth:`requested` at safe points (the master after every communication step, the job between
    its phases) and stop; so the data so far is written, the FMUs are terminated and freed, and
    the exit code is 130, whenever the SIGINT came. A third SIGINT raises at once, and so does the
    first in a command that holds no FMU in this process (:meth:`raising`)."""

    def __init__(self):
        self.count = 0
        self.at_once = 0

    def __call__(self, signum, frame):
        self.count += 1
        if self.count >= 3 or self.at_once:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def raising(self):
        """Within: the first SIGINT raises KeyboardInterrupt at once, for a command that holds no
        FMU in this process (analyze, stability, design, build, check: pure computation, or
        an FMU in a child process, which ``subprocess`` ends with the exception), so that a long
        computation stops within moments; its outputs are written only after it, each complete
        or absent, and its temporaries are removed by the clean-ups the exception runs."""
        self.at_once += 1
        try:
            self.check()
            yield
        finally:
            self.at_once -= 1

    def requested(self) -> bool:
        return self.count > 0

    def check(self):
        """Raise KeyboardInterrupt here, at a safe point, if Ctrl-C was pressed."""
        if self.count:
            raise KeyboardInterrupt


#: The process's Ctrl-C record: installed by :func:`entry` before anything else; in a process
#: that calls :func:`main` itself (the tests) it is installed for the command's duration.
INTERRUPTS = None


def _print(lines, file=None):
    print("\n".join(lines), file=file or sys.stdout)


#: What the running command holds until it ends (its output folder's lock), released by main().
_HELD = contextlib.ExitStack()


def _output_dir(text: str):
    """The output folder, created, and held for this command alone until it ends
    (:func:`~orchestration.files.folder_lock`): a path that is a file, cannot be written
    or is in use by another run is a UsageError."""
    import tempfile
    from pathlib import Path

    from .files import FILE_SUFFIXES, OutputError, folder_lock

    out = Path(text)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {text}: exists and is not a folder")
    if out.suffix.lower() in FILE_SUFFIXES:
        raise UsageError(f"--out {text}: names a {out.suffix} file; allowed: a folder, where the "
                         "files are written (it is made if missing)")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
        _HELD.enter_context(folder_lock(out))
    except OutputError as exc:
        raise UsageError(f"--out {text}: {exc.strerror.removeprefix(f'{out}: ')}") from None
    except OSError as exc:
        raise UsageError(f"--out {text}: cannot write there ({exc.strerror or exc})") from None
    return out


def _json(obj) -> str:
    from .files import json_safe
    return json.dumps(json_safe(obj), indent=2)


def _split_design(items):
    """The ``--set`` items of ``flexpend design``: ``(scene items, {design.* key: value})``."""
    scene_items = [o for o in items if not parse_override(o)[0].startswith("design.")]
    design = dict(parse_override(o) for o in items if o not in scene_items)
    return scene_items, design


def _cli_text(exc) -> str:
    """An error's message as the command line words it (:attr:`ConfigError.cli`)."""
    return getattr(exc, "cli", None) or str(exc)


def _set_error(exc):
    """A ``--set`` problem of analyze/design, named as such."""
    text = _cli_text(exc)
    return ConfigError(text if text.startswith("--set") else f"--set: {text}")


# ---------------------------------------------------------------------- commands
def cmd_analyze(args) -> int:
    from .api import analyze
    from .report.text import analysis_lines

    a = analyze(overrides=args.set)
    if args.json:
        print(_json(a.to_json()))
    else:
        _print(analysis_lines(a.plant, a.controller, a))
    return 0


def cmd_stability(args) -> int:
    from .api import stability
    from .report.progress import Progress

    if not math.isfinite(args.max_step) or not 1e-3 <= args.max_step <= 10.0:
        raise UsageError(f"--max-step {args.max_step:g} is not allowed; allowed: a step in "
                         "seconds from 0.001 to 10")
    bar = Progress("flexpend stability")

    def progress(fraction, label=None):
        bar(fraction)
        INTERRUPTS.check()          # a safe point: between two stacks of matrices

    region = _region_path(args.sampled_region) if args.sampled_region else None
    try:
        r = stability(args.scene, args.set, max_step=args.max_step, progress=progress)
    finally:
        bar.close()
    if region is not None:
        r["sampled_region"] = _sampled_region(args, region)
    keys = ("min_step", "max_step", "scene", "couplings", "loop", "sampled", "sampled_region")
    if args.json:
        print(_json({k: r[k] for k in keys if k in r}))
    else:
        _print(stability_lines(r))
    return 0


def _region_path(text: str):
    """``--sampled-region``'s file: a .png (or .pdf, .svg) in a folder that exists."""
    from pathlib import Path

    path = Path(text)
    if path.suffix.lower() not in (".png", ".pdf", ".svg"):
        raise UsageError(f"--sampled-region {text}: allowed: a .png, .pdf or .svg file")
    if path.is_dir():
        raise UsageError(f"--sampled-region {text}: is a folder; allowed: a file")
    if not path.parent.is_dir():
        raise UsageError(f"--sampled-region {text}: the folder {path.parent} does not exist")
    return path


def _sampled_region(args, path) -> dict:
    """Write the stability region of the sampled controller in the plane (T, tau / T)
    (:func:`~orchestration.studies.sampled.stability_region_figure`) for the paper's three
    scenes and, when its plant or controller differs from theirs (but for the sample period and
    the delay, which the figure spans), the scene given; the scene's discretization.
    ``{"file", "discretization", "critical_periods": {scene: {"tau=0": T, "tau=T": T}}}``."""
    import dataclasses

    from .scene.schema import PAPER_SCENES, load_scene
    from .studies.sampled import stability_region_figure

    sc = load_scene(args.scene, args.set)
    panels = list(PAPER_SCENES)

    def loop(s):            # what the region depends on: the plant, the controller but T, tau
        return s.plant, s.controller.replace(sample_period=0.0, delay=0.0,
                                             discretization="tustin")

    if sc.name not in PAPER_SCENES or loop(sc) != loop(load_scene(sc.name)):
        label = f"{sc.name} (--set)" if args.set else sc.name
        panels.append(dataclasses.replace(sc, name=label) if label != sc.name else sc)
    crit = stability_region_figure(path, scenes=panels,
                                   discretization=sc.controller.discretization)
    return {"file": str(path), "discretization": sc.controller.discretization,
            "critical_periods": crit}


def _ms_intervals(intervals, stable: bool, rho: bool = False) -> str:
    """The stable (or unstable) intervals in milliseconds, joined; with ``rho`` each unstable
    one's largest spectral radius."""
    from .report.text import num

    parts = [f"{num(i['from'] * 1e3)}-{num(i['to'] * 1e3)}"
             + (f" (rho up to {i['rho_max']:.6g})" if rho and i["rho_max"] is not None
                else "") for i in intervals if i["stable"] == stable]
    return ", ".join(parts) + " ms" if parts else "none"


def stability_lines(r: dict) -> list[str]:
    """``flexpend stability``'s text: the scene's coupling, the verdict at its step, its stable
    and unstable intervals up to the maximum step, and the plant's substep limit; then the
    stable intervals of every coupling the master offers, and the one stable at every step up
    to the largest step (:func:`orchestration.api.stability`)."""
    from .report.text import coupling_text, num

    def first(c):
        H = c["critical_step"]
        if H is None:
            return f"stable at every step up to {num(r['max_step'] * 1e3)} ms"
        if H == 0:
            return (f"unstable already at {num(r['min_step'] * 1e3)} ms (the continuous loop "
                    "is)")
        return f"stable at every step up to {num(H * 1e3)} ms (the first crossing of rho = 1)"

    sc = r["scene"]
    k = sc["coupling"]
    h = sc["substep_limit"]
    lines = [f"{r['name']}: where the linear co-simulation is stable (rho(Phi) < 1), "
             f"communication steps {num(r['min_step'] * 1e3)} to {num(r['max_step'] * 1e3)} ms"]
    if r.get("loop"):
        lines.append(f"  plant: {r['loop']}")
    lines += [f"  assumes {a}" for a in r["assumes"]]
    lines += [f"  its coupling: {coupling_text(k)}",
              f"    master.step = {num(k['step'] * 1e3)} ms: "
              f"{'stable' if sc['stable'] else 'UNSTABLE'} (rho = {sc['rho']:.6g} per step)",
              f"    {first(sc)}",
              f"    stable:   {_ms_intervals(sc['intervals'], True)}",
              f"    unstable: {_ms_intervals(sc['intervals'], False, rho=True)}",
              "    plant substep limit: " + ("none (A-stable)" if h is None else
                                             f"{num(h * 1e3)} ms")]
    rows = r["couplings"]
    w = max(len(coupling_text(c)) for c in rows)
    lines.append(f"  every coupling: the steps at which it is stable (unstable between them and "
                 f"up to {num(r['max_step'] * 1e3)} ms)")
    lines += [f"    {coupling_text(c):<{w}}  {_ms_intervals(c['intervals'], True)}"
              for c in rows]
    key = lambda c: math.inf if c["critical_step"] is None else c["critical_step"]  # noqa: E731
    best = max(rows, key=key)
    lines.append(f"  stable at every step up to the largest first crossing: {coupling_text(best)} "
                 f"({first(best).removeprefix('stable at every step up to ').split(' (')[0]})")
    if r.get("sampled"):
        lines += sampled_stability_lines(r["sampled"])
    if r.get("sampled_region"):
        lines += sampled_region_lines(r["sampled_region"])
    return lines


def _ms(T) -> str:
    from .report.text import num
    return "none (unstable at the smallest)" if T is None else f"{num(T * 1e3)} ms"


def sampled_stability_lines(s: dict) -> list[str]:
    """The sampled controller's part of ``flexpend stability``
    (:func:`orchestration.api.sampled_stability`)."""
    from .report.text import num

    lo, hi = s["scanned"]
    iv = ", ".join(f"{num(a * 1e3)}-{num(b * 1e3)}" for a, b in s["intervals"]) or "none"
    crit = s["critical_periods"]
    return [f"  the sampled controller (T = {num(s['T'] * 1e3)} ms, delay tau = "
            f"{num(s['tau'] * 1e3)} ms, {s['discretization']} filter): max |z| < 1 of the "
            "discrete-time loop",
            f"    at T = {num(s['T'] * 1e3)} ms: {'stable' if s['stable'] else 'UNSTABLE'} "
            f"(margin 1 - max |z| = {s['margin']:+.6f})",
            f"    stable sample periods at tau = {num(s['tau'] * 1e3)} ms (scanned "
            f"{num(lo * 1e3)} to {num(hi * 1e3)} ms): {iv}" + (" ms" if s["intervals"] else ""),
            f"    largest stable T: {_ms(s['critical'])} at tau = {num(s['tau'] * 1e3)} ms; "
            f"{_ms(crit['tau=0'])} with no delay; {_ms(crit['tau=T'])} with a full period's "
            "delay (tau = T)",
            "    (the couplings' steps above are the continuous controller's; the sampled one's "
            "coupling is exact on the ticks)"]


def sampled_region_lines(g: dict) -> list[str]:
    """``--sampled-region``: the file written and each panel's largest stable sample period."""
    rows = g["critical_periods"]
    w = max(len(k) for k in rows)
    out = [f"  wrote {g['file']}: the sampled controller's stability region in (T, tau / T) "
           f"({g['discretization']} filter); the largest stable T:",
           f"    {'scene':<{w}}  {'tau = 0':>12}  {'tau = T':>12}"]
    for name, crit in rows.items():
        a, b = (_ms(crit[k]).replace("none (unstable at the smallest)", "unstable")
                for k in ("tau=0", "tau=T"))
        out.append(f"    {name:<{w}}  {a:>12}  {b:>12}")
    return out


def cmd_design(args) -> int:
    from .api import design
    from .report.text import design_lines
    from .sweeps.executor import SchedulerError

    scene_items, design_keys = _split_design(args.set)
    workers, scheduler = _executor_args(args)
    out_dir = _output_dir(args.out)
    try:
        d = design(overrides=scene_items, design=design_keys, workers=workers,
                   scheduler=scheduler, progress=not args.quiet)
    except SchedulerError as exc:
        raise _scheduler_error(exc) from None
    except ConfigError as exc:
        raise _set_error(exc) from None
    d.save(out_dir)
    if args.json:
        print(_json(d.record))
    else:
        _print(design_lines(d))
    return 0


def cmd_run(args) -> int:
    from .job import EXIT_INTERRUPTED as JOB_INTERRUPTED
    from .job import EXIT_STOPPED as JOB_STOPPED
    from .job import load_job, run_job, step_warning
    from .report.progress import note
    from .report.text import run_lines
    from .scene.schema import PAPER_SCENES

    stop = INTERRUPTS.requested
    items = load_job(args.scenes or list(PAPER_SCENES), args.set)   # all checked first
    try:
        out_dir = _output_dir(args.out)

        def announce(scene):
            m = scene.run_master
            how = (f"model exchange, {m.solver} at rtol {m.rtol:g}"
                   if m.interface == "model-exchange" else f"communication step {m.step:g} s")
            note(f"{scene.name}: running {scene.output.stop_time:g} s ({how})")
            warning = step_warning(scene)
            if warning:
                print(f"{scene.name}: warning: {warning}", file=sys.stderr, flush=True)

        def report(run, written):
            if not args.json:
                _print(run_lines(run.name, run.summary, written))

        job = run_job(items, out_dir, reference=args.reference,
                      connections_out=sys.stderr if args.connections else None, stop=stop,
                      overview=not args.scenes, announce=announce, report=report,
                      renderer=args.renderer, figures=args.figures,
                      progress=not args.quiet)
    finally:
        for _, system in items:
            if system is not None:
                system.close()
    if args.json:
        print(_json(job.summaries))
    elif out_dir / "paper_overview.png" in job.written:
        names = ("paper_overview.png", "mode_shapes.png", "root_map.png")
        print("paper figures: " + ", ".join(str(out_dir / n) for n in names
                                             if out_dir / n in job.written))
    if job.code == JOB_INTERRUPTED:
        print(f"flexpend: interrupted; the data so far is in {out_dir}", file=sys.stderr)
        return EXIT_INTERRUPTED
    if job.code == JOB_STOPPED:
        stopped = [r.name for r in job.runs if not r.completed]
        print(f"flexpend: {', '.join(stopped)} stopped early (exit code {EXIT_STOPPED})",
              file=sys.stderr)
        return EXIT_STOPPED
    return 0


def cmd_export(args) -> int:
    from pathlib import Path

    from .export.system import export_scene
    from .report.progress import sink_for
    from .scene.schema import load_scene

    if args.out is not None and Path(args.out).suffix != ".ssp":
        raise UsageError(f"--out {args.out}: the archive's name must end in .ssp")
    scene = load_scene(args.scene, args.set)
    sink = sink_for(not args.quiet, f"{scene.name}: export")
    try:
        r = export_scene(scene, args.fmus, args.out, progress=sink)
    except ValueError as exc:           # an FMU without a parameter the scene sets, ...
        raise UsageError(_cli_text(exc)) from None
    finally:
        if sink is not None:
            sink.close()
    sc = r.scene
    print(f"wrote {r.path}: plant {Path(r.fmus['plant']).name}, controller "
          f"{Path(r.fmus['controller']).name} ({args.fmus} FMUs), {len(sc.connections)} "
          f"connections, stop time {sc.output.stop_time:g} s, master {sc.run_master.algorithm} "
          f"at {sc.run_master.step:g} s")
    if r.model is not None:
        print(f"  model: {r.model['n_modes']} modes, {r.model['fidelity']} ({r.model['reason']})")
    return 0


def _written_lines(files: dict) -> list[str]:
    """What ``flexpend check --write-reference`` wrote, and what it drove the FMU with."""
    from .export.check import EXCITATIONS, read_opt

    opt = read_opt(files["opt"])
    new = {str(p) for p in files["written"]}
    mark = {True: " (written)", False: ""}
    n = len(files["signals"])
    lines = [f"wrote {files['ref']}: {n} signal{'s' * (n != 1)}, {opt['StartTime']:g} to "
             f"{opt['StopTime']:g} s in steps of {opt['StepSize']:g} s"]
    if files["excitation"]:
        exc = EXCITATIONS[files["excitation"]]
        lines.append(f"  inputs {files['in']} (written): flexpend's excitation of the "
                     f"{files['excitation']}, {exc.what}")
    elif files["in"].is_file():
        lines.append(f"  inputs {files['in']}")
    else:
        lines.append("  no input file: the FMU has no inputs")
    lines.append(f"  options {files['opt']}{mark[str(files['opt']) in new]}")
    if files["left_out"]:
        lines.append(f"  left out, constant in this run (no band): {', '.join(files['left_out'])}")
    return lines


def cmd_check(args) -> int:
    from .export.check import (
        ReferenceError,
        Rule,
        check_fmu,
        write_reference,
    )
    from .report.check import plot_check

    try:
        rule = Rule(args.tolerance, args.window, args.max_outliers)
    except ValueError as exc:
        raise UsageError(str(exc).replace("max_outliers", "--max-outliers", 1)
                         .replace("tolerance", "--tolerance", 1).replace("window", "--window", 1)) \
            from None
    outputs = [o.strip() for o in args.outputs.split(",") if o.strip()] if args.outputs else None
    try:
        if args.write_reference:
            print("\n".join(_written_lines(write_reference(args.fmu, args.reference, outputs))))
            return 0
        report = check_fmu(args.fmu, args.reference, rule)
    except ReferenceError as exc:
        raise UsageError(str(exc)) from None
    print("\n".join(report.lines()))
    if args.plot:
        print(f"plot: {plot_check(report, args.plot)}")
    return 0 if report.passed else EXIT_FAILED


def _scheduler_error(exc):
    """A :class:`~orchestration.sweeps.executor.SchedulerError` in the command's terms."""
    return UsageError(f"--scheduler {exc.address}: {exc.reason}")


def _executor_args(args):
    """``(workers, scheduler)`` of ``--workers``/``--scheduler``; ``--workers`` processes are
    checked against the process's limits first
    (:func:`~orchestration.sweeps.executor.process_limits`)."""
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers} is not allowed; allowed: an integer >= 1")
    if args.workers is not None and args.scheduler:
        raise UsageError("--workers starts processes here, --scheduler uses an existing dask "
                         "cluster: give one of them")
    if args.workers is not None:
        from .sweeps.executor import process_limits

        problem = process_limits(args.workers)
        if problem:
            raise UsageError(f"{problem}; raise the limit, give fewer --workers or run --serial")
    return args.workers, args.scheduler


def _machine_limit(exc: BaseException) -> str | None:
    """The one line of a failure that a limit of the machine caused, found anywhere in the
    exception's chain (a library may wrap it: dask's "Nanny failed to start", an ImportError
    of a library that could not be mapped): too many open files, or out of memory. None for
    any other failure."""
    import errno
    import resource

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.EMFILE, errno.ENFILE):
            if exc.errno == errno.ENFILE:
                return "too many open files on this system (its file table is full)"
            soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
            return f"too many open files: this process may open {soft} (ulimit -n); raise the limit"
        if (isinstance(exc, MemoryError)
                or (isinstance(exc, OSError) and exc.errno == errno.ENOMEM)
                or (isinstance(exc, ImportError) and "failed to map segment" in str(exc))):
            mib = _address_space_mib()
            if mib is None:
                return "out of memory"
            return (f"out of memory: this process may use {mib} MiB of address space "
                    "(ulimit -v); raise the limit")
        exc = exc.__cause__ or exc.__context__
    return None


#: The least address space (``ulimit -v``) a command starts with: below it numpy's OpenBLAS
#: cannot allocate its buffers and ends the process itself (exit 1, a line of its own), or a
#: library cannot be mapped at all; a run of a paper scene needs about 200 MiB.
MIN_ADDRESS_SPACE = 192 << 20


def _address_space_floor() -> str | None:
    """The one line refusing a process whose address space is below :data:`MIN_ADDRESS_SPACE`
    (checked before numpy is imported), else None."""
    try:
        mib = _address_space_mib()
    except ImportError:               # not even the small `resource` library could be mapped
        return ("out of memory: this process cannot map its libraries (ulimit -v); raise the "
                "limit")
    if mib is None or mib >= MIN_ADDRESS_SPACE >> 20:
        return None
    return (f"out of memory: this process may use {mib} MiB of address space (ulimit -v); "
            f"flexpend needs at least {MIN_ADDRESS_SPACE >> 20} MiB")


def _memory_hint(exc: BaseException) -> str:
    """``; ... ulimit -v`` when a failure without an errno (a library's own message: PIL's
    "codec configuration error" when zlib gets no memory) came under an address-space limit."""
    cause = exc.__cause__ or exc.__context__ or exc
    mib = _address_space_mib()
    if mib is None or getattr(cause, "errno", None) is not None or "ulimit" in str(exc):
        return ""
    return (f" (this process may use {mib} MiB of address space, ulimit -v: raise the limit if "
            "that is too little)")


def _address_space_mib() -> int | None:
    """This process's limit of address space (``ulimit -v``) in MiB, None when unlimited."""
    import resource

    space = resource.getrlimit(resource.RLIMIT_AS)[0]
    return None if space == resource.RLIM_INFINITY else space >> 20


def cmd_sweep(args) -> int:
    from .report.progress import note
    from .report.text import sweep_lines
    from .sweeps.executor import SchedulerError
    from .sweeps.job import sweep

    if args.serial and (args.workers is not None or args.scheduler):
        raise UsageError("--serial runs here, one run after the other: it takes no --workers or "
                         "--scheduler")
    if args.batch < 1:
        raise UsageError(f"--batch {args.batch} is not allowed; allowed: an integer >= 1")
    workers, scheduler = _executor_args(args)
    _output_dir(args.out)

    def on_executor(ex):
        note(f"running on {ex.describe()}")
        dashboard = getattr(ex, "dashboard_note", lambda: None)()
        if dashboard:
            note(dashboard)

    argv = sys.argv[1:] if args.argv is None else args.argv
    try:
        s = sweep(args.scene, grid=args.grid, values=args.values, sample=args.sample,
                  samples=args.samples, seed=args.seed, overrides=args.set,
                  reference=args.reference, columns=args.columns, workers=workers,
                  scheduler=scheduler,
                  serial=args.serial, batch=args.batch, retry_failed=args.retry_failed,
                  out=args.out, command="flexpend " + " ".join(argv), on_executor=on_executor,
                  stop=INTERRUPTS.requested, progress=not args.quiet)
    except SchedulerError as exc:
        raise _scheduler_error(exc) from None
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise UsageError(str(exc)) from None          # an unreachable scheduler
    except KeyboardInterrupt:
        from .sweeps.engine import Journal
        journal = Journal(args.out)
        if _finished_rows(journal):
            print(f"\ninterrupted: the finished runs are in {journal.path}; the same command "
                  "continues the sweep", file=sys.stderr)
        else:                                           # name no file that is not there
            print("\ninterrupted before any run finished; the same command starts the sweep",
                  file=sys.stderr)
        return EXIT_INTERRUPTED
    if args.json:
        print(_json(s.record))
    else:
        _print(sweep_lines(s.plan, s.result, s.stats, _Described(s.executor)))
    return 1 if s.stats["lost"] else 0


def _finished_rows(journal) -> bool:
    """Whether the sweep's ``journal`` holds a finished run (a readable, sound row)."""
    try:
        return bool(journal.read())
    except (OSError, ValueError):       # unreadable: nothing to name
        return False


class _Described:
    def __init__(self, text):
        self.text = text

    def describe(self):
        return self.text


def cmd_build(args) -> int:
    from pathlib import Path

    from .export import BuildError, build_fmus
    from .report.progress import Steps, sink_for
    out = None if args.out is None else Path(args.out)
    builds = [("python", 2, out), ("native", 2, out and out / "native"),
              ("native", 3, out and out / "native")]
    if args.fmus:
        builds = [b for b in builds if b[0] == args.fmus]
    sink = sink_for(not args.quiet, "flexpend build")
    steps = Steps(sink, len(builds))
    try:
        for flavour, version, folder in builds:
            part = steps.part(1, f"building the {flavour} FMUs (FMI {version}.0)")
            for name, path in build_fmus(folder, force=args.force, flavour=flavour,
                                         fmi_version=version, progress=part).items():
                print(f"{name} ({flavour}, FMI {version}.0): {path}")
        steps.finish("flexpend build")
    except BuildError as exc:
        print(f"flexpend: {exc}", file=sys.stderr)
        return 2
    finally:
        if sink is not None:
            sink.close()
    return 0


def cmd_keys(args) -> int:
    from .report.keys import keys_lines, keys_markdown

    print(keys_markdown() if args.markdown else "\n".join(keys_lines()))
    return 0


def cmd_scenes(args) -> int:
    from .scene.schema import list_scenes, load_scene
    for name in list_scenes():
        print(f"{name:24s} {load_scene(name).description}")
    return 0


class _VersionAction(argparse.Action):
    """``--version``: the installed version, looked up only when asked (the lookup imports
    importlib.metadata and scans the installed distributions: about 15 ms of every command)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0,
                         help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"flexpend {_version()}")
        parser.exit()


#: ``--quiet``'s help.
_QUIET_HELP = ("no progress and no other chatter on stderr (errors, warnings and the results "
               "on stdout are kept)")


def _add_quiet(p) -> None:
    """``-q``/``--quiet`` on a command (as well as before it: the flag is set by either)."""
    p.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                   help=_QUIET_HELP)


#: Where ``--set``'s help sends the reader for the keys.
_KEYS_HINT = "(every key: flexpend keys)"


#: The commands that hold no FMU in this process: Ctrl-C raises in them at once
#: (:meth:`Interrupts.raising`); the others (run, sweep, export) stop at their safe points.
_AT_ONCE = {cmd_analyze, cmd_stability, cmd_design, cmd_build, cmd_check, cmd_scenes, cmd_keys}


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="flexpend", description="Flexible inverted pendulum: analysis and "
                                                  "co-simulation of the FMUs.")
    parser.add_argument("--version", action=_VersionAction,
                        help="print the installed version and exit")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help=_QUIET_HELP + " (also after the command's name)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    pa = sub.add_parser("analyze", help="linear analysis of the closed loop",
                        description="Eigenvalues, stability and margins of the linearised loop.")
    pa.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene key, e.g. plant.n_modes=4 or controller.cutoff=150 "
                         f"{_KEYS_HINT}")
    pa.add_argument("--json", action="store_true", help="print the result as JSON")
    _add_quiet(pa)
    pa.set_defaults(func=cmd_analyze)

    pt = sub.add_parser("stability", help="the stable intervals of the communication step "
                                           "per coupling",
                        description="The communication steps at which the linearised "
                                    "co-simulation is stable (rho of the step's transition matrix "
                                    "< 1), as intervals up to --max-step, for the scene's coupling "
                                    "and every coupling the master offers, and the plant method's "
                                    "substep limit.")
    pt.add_argument("scene", metavar="SCENE", help="a scene name or a path to a .toml file")
    pt.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help=f"override a scene key, e.g. controller.cutoff=150 {_KEYS_HINT}")
    pt.add_argument("--max-step", type=float, default=0.05, metavar="SECONDS",
                    help="the largest communication step scanned (default 0.05 s; 0.001 to 10)")
    pt.add_argument("--json", action="store_true", help="print the result as JSON")
    pt.add_argument("--sampled-region", default=None, metavar="FILE.png",
                    help="also write the stability region of the sampled controller in the "
                         "plane (sample period T, delay tau / T) for the paper's three scenes "
                         "(and SCENE when it is not one of them unchanged), and print their "
                         "largest stable T with tau = 0 and tau = T (docs/sampled.md)")
    _add_quiet(pt)
    pt.set_defaults(func=cmd_stability)

    pd = sub.add_parser("design", help="robust design of the low-pass filter",
                        description="Search the filter order, cutoff and damping for the largest "
                                    "worst-case closed-loop decay rate (or damping ratio) over an "
                                    "uncertainty set of beams; write <out>/design.json, "
                                    "design_sweep.csv and three plots.")
    pd.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key, e.g. controller.kd=6 or design.criterion=damping "
                         f"{_KEYS_HINT}")
    pd.add_argument("--out", default="out", help="output folder (default: out)")
    pd.add_argument("--json", action="store_true", help="print the result as JSON")
    pd.add_argument("--workers", type=int, default=None, metavar="N",
                    help="check the chosen filter's worst case on N worker processes here "
                         "(default: in this process; worth it for a fine design.check_levels)")
    pd.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="check it on the dask cluster of this scheduler (it must answer "
                         "dask's handshake within 5 s)")
    _add_quiet(pd)
    pd.set_defaults(func=cmd_design)

    pr = sub.add_parser("run", help="co-simulate scenes (default: the paper's three)",
                        description="Co-simulate the plant and controller FMUs for each scene; "
                                    "write <out>/<scene>.csv and PNG plots, print a summary.")
    pr.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="scene names (see 'flexpend scenes'), paths to .toml files or SSP "
                         "archives (.ssp)")
    pr.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help=f"override a scene key, e.g. master.step=5e-4 {_KEYS_HINT}")
    pr.add_argument("--out", default="out", help="output folder (default: out)")
    pr.add_argument("--json", action="store_true", help="print the summary as JSON")
    pr.add_argument("--connections", action="store_true",
                    help="print each scene's connection table (wiring by variable name)")
    pr.add_argument("--reference", action="store_true",
                    help="also solve the monolithic reference and report the error against it")
    pr.add_argument("--renderer", choices=("raster", "matplotlib"), default="raster",
                    help="what draws the PNGs: raster (default: Pillow, fast) or matplotlib")
    pr.add_argument("--figures", choices=("png", "none"), default="png",
                    help="png (default): write the PNG figures; none: skip them (the CSV files, "
                         "the summary and the text are the same)")
    _add_quiet(pr)
    pr.set_defaults(func=cmd_run)

    pb = sub.add_parser("build", help="build the two FMUs (only when their sources changed)")
    pb.add_argument("--force", action="store_true", help="rebuild even if up to date")
    pb.add_argument("--out", default=None, help="output folder (default: build/fmus; the native "
                    "FMUs in its native/fmi2 and native/fmi3)")
    pb.add_argument("--fmus", choices=("native", "python"), default=None,
                    help="build only this flavour (default: both)")
    _add_quiet(pb)
    pb.set_defaults(func=cmd_build)

    pw = sub.add_parser("sweep", help="many runs of a scene over a grid or a random sample, "
                                      "on this machine's cores or a dask cluster",
                        description="Co-simulate a scene over a grid of keys and/or random "
                                    "samples: serially here, or on worker processes here (one "
                                    "per core) where they win by the runs' number and expected "
                                    "length against their start-up (about 1 s), or on the dask "
                                    "cluster of --scheduler; write "
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
                    help="a fixed scene key (or a design.* key of the uncertainty set) "
                         f"{_KEYS_HINT}")
    pw.add_argument("--reference", action="store_true",
                    help="also solve each run's monolithic reference and report the error")
    pw.add_argument("--columns", default=None, metavar="COL,COL,...",
                    help="only these result columns, each run computing only what they need "
                         "(max_abs_x,max_abs_F_c: no mode fit, no verdict; the columns: "
                         "docs/sweeps.md; default: all)")
    pw.add_argument("--workers", type=int, default=None, metavar="N",
                    help="worker processes here (default: one per core, only where they end "
                         "before the serial runs: 1 s + ceil(runs / cores) * (t + 0.004 s) < "
                         "runs * t, t the expected run length from stop_time / master.step; "
                         "see docs/sweeps.md)")
    pw.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="use the dask cluster of this scheduler, e.g. tcp://host:8786 (it must "
                         "answer dask's handshake within 5 s; without workers, one must join "
                         "within 30 s)")
    pw.add_argument("--serial", action="store_true",
                    help="run here, one run after the other (the default where worker "
                         "processes would not win)")
    pw.add_argument("--batch", type=int, default=1, metavar="N",
                    help="runs per task sent to a worker (batch short runs; default 1)")
    pw.add_argument("--retry-failed", action="store_true",
                    help="rerun the runs that failed in an earlier sweep into the same --out")
    pw.add_argument("--out", default="out/sweep", help="output folder (default: out/sweep)")
    pw.add_argument("--json", action="store_true", help="print the sweep's record as JSON")
    _add_quiet(pw)
    pw.set_defaults(func=cmd_sweep)

    ps = sub.add_parser("scenes", help="list the scenes")
    ps.set_defaults(func=cmd_scenes)

    pk = sub.add_parser("keys", help="list every scene key (type, default, unit, allowed, "
                                     "meaning)",
                        description="Every key a scene file, --set, a sweep axis or the API "
                                    "takes: its type, default, unit, the values allowed and "
                                    "its meaning, one line each.")
    pk.add_argument("--markdown", action="store_true",
                    help="print the manual's page (docs/keys.md) instead")
    pk.set_defaults(func=cmd_keys)

    pe = sub.add_parser("export", help="write a scene as an SSP archive (both FMUs, wiring, "
                                       "parameters, experiment)",
                        description="Write SCENE as an SSP 1.0 archive: SystemStructure.ssd and "
                                    "both FMUs under resources/. 'auto' models are chosen first. "
                                    "Run it back with 'flexpend run FILE.ssp'.")
    pe.add_argument("scene", metavar="SCENE", help="scene name or path to a .toml file")
    pe.add_argument("--fmus", choices=list(FMU_FLAVOURS), default="native",
                    help="which FMUs to package (default: native)")
    pe.add_argument("--out", default=None, metavar="FILE.ssp",
                    help="the archive (default: out/<scene>.ssp)")
    pe.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help=f"override a scene key, e.g. master.algorithm=jacobi {_KEYS_HINT}")
    _add_quiet(pe)
    pe.set_defaults(func=cmd_export)

    pc = sub.add_parser("check", help="regress an FMU against reference results (FMI "
                                      "cross-check layout)",
                        description="Simulate FMU alone with <Model>_in.csv and <Model>_ref.opt "
                                    "of the reference folder and compare every signal of "
                                    "<Model>_ref.csv within FMPy's band (fmpy.util."
                                    "validate_signal). Prints one line per signal; exits 1 on "
                                    "any signal outside its band or a run that does not reach "
                                    "the stop time, 2 on bad input, a reference signal that "
                                    "does not vary (no band) included.")
    pc.add_argument("fmu", metavar="FMU", help="the .fmu file")
    pc.add_argument("--reference", required=True, metavar="DIR",
                    help="folder with <Model>_ref.csv, <Model>_ref.opt, <Model>_in.csv (or a "
                         "<Model> subfolder with them)")
    pc.add_argument("--plot", metavar="FILE.png", help="draw each signal over its band")
    pc.add_argument("--write-reference", action="store_true",
                    help="write <Model>_ref.csv from a run instead of checking; without "
                         "<Model>_in.csv, flexpend's excitation of a plant (input F_c) or a "
                         "controller (phi_o, omega_o, x_o) is written as one, with its "
                         "options if <Model>_ref.opt is missing too")
    pc.add_argument("--outputs", metavar="NAMES",
                    help="with --write-reference: comma-separated signals to record (default: "
                         "those of the existing reference, else every output that varies)")
    pc.add_argument("--tolerance", type=float, default=0.1,
                    help="band half-width as a fraction of each signal's range (default: 0.1)")
    pc.add_argument("--window", type=int, default=21,
                    help="samples the band is widened over (default: 21; 1: none)")
    pc.add_argument("--max-outliers", type=float, default=0.1,
                    help="fraction of samples allowed outside the band (default: 0.1; 0: none)")
    _add_quiet(pc)
    pc.set_defaults(func=cmd_check)
    return parser



#: errno of a write that the system refused for want of room or permission
_WRITE_ERRNOS = {getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EFBIG", "EROFS")
                 if hasattr(errno, name)}


def _output_failure(exc: OSError) -> str | None:
    """The one line of an output that could not be written (a full disk...), else None."""
    from .files import OutputError

    if isinstance(exc, OutputError):
        return str(exc)
    if exc.errno in _WRITE_ERRNOS:
        return f"cannot write {exc.filename or 'the output'}: {exc.strerror}"
    return None


def _interrupted(exc: BaseException) -> bool:
    """Whether ``exc`` is a Ctrl-C in disguise: a KeyboardInterrupt raised where a library turned
    it into another error (a C extension's module initialisation, interrupted, raises
    ImportError "initialization failed" from it)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def main(argv=None) -> int:
    """Run one command; its exit code. Ctrl-C is noted (:class:`Interrupts`) while it runs."""
    global INTERRUPTS
    installed = None
    if INTERRUPTS is None:
        INTERRUPTS = Interrupts()
        try:
            installed = signal.signal(signal.SIGINT, INTERRUPTS)
        except ValueError:            # not the main thread: Ctrl-C is not ours to handle
            installed = None
    try:
        floor = _address_space_floor()
        if floor is not None:
            print(f"flexpend: error: {floor}", file=sys.stderr)
            return EXIT_USAGE
        args = build_parser().parse_args(argv)
        args.argv = None if argv is None else list(argv)
        args.quiet = getattr(args, "quiet", False)
        from .report.progress import quiet

        at_once = INTERRUPTS.raising() if args.func in _AT_ONCE else contextlib.nullcontext()
        with quiet(args.quiet), at_once:
            code = args.func(args)
        if INTERRUPTS.requested() and code != EXIT_INTERRUPTED:  # after the last safe point
            print("flexpend: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        return code
    except (UsageError, ConfigError) as exc:
        print(f"flexpend: error: {_cli_text(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. piped into head
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print("flexpend: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:          # a full disk, a limit of the machine, however it surfaced
        if _interrupted(exc):
            print("flexpend: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        line = (_output_failure(exc) if isinstance(exc, OSError) else None) or _machine_limit(exc)
        if line is None:
            raise
        line += _memory_hint(exc)
        print(f"flexpend: error: {line}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        _HELD.close()                 # the output folder's lock
        if installed is not None:     # a process that called main() itself gets its own back
            signal.signal(signal.SIGINT, installed)
            INTERRUPTS = None


def entry():
    """The ``flexpend`` command. Ctrl-C is noted from here on, for the process's whole life, so
    that it exits with 130 at any moment: while the command runs, after it (its clean-ups at
    exit: unpacked FMUs, a LocalCluster's folders), and from the last clean-up on a Ctrl-C ends
    the process at once, with 130. After a Ctrl-C the process ends right after its
    clean-ups, its output flushed, without the interpreter's finalisation: a KeyboardInterrupt
    that reached code run by an FMU's embedded Python makes the interpreter kill itself with
    SIGINT at finalisation, and pythonfmu's finalisation can abort (see docs/fmus.md); the data
    is already written and the FMUs freed."""
    global INTERRUPTS, _EXIT_CODE
    INTERRUPTS = Interrupts()
    signal.signal(signal.SIGINT, INTERRUPTS)
    atexit.register(_last_clean_up)     # registered first: runs after every other clean-up
    try:
        _EXIT_CODE = main()
    except KeyboardInterrupt:
        _EXIT_CODE = EXIT_INTERRUPTED
    sys.exit(_EXIT_CODE)


#: The exit code of :func:`entry`'s command (130 also when a Ctrl-C came after it).
_EXIT_CODE = None


def _last_clean_up():
    """The last thing the ``flexpend`` process does at exit: from here a Ctrl-C ends it at once
    with 130 (nothing is left to clean up), and an earlier one makes the exit code 130. The
    process ends here, its output flushed, without the interpreter's finalisation: that puts
    back the default action of SIGINT, which would end the process by the signal (a shell shows
    130, a parent process -2), and it has nothing of ours left to do. A command that ended in a
    traceback (no exit code) is left to the interpreter."""
    signal.signal(signal.SIGINT, _exit_interrupted)
    if _EXIT_CODE == EXIT_INTERRUPTED or (INTERRUPTS is not None and INTERRUPTS.requested()):
        _exit_interrupted()
    if isinstance(_EXIT_CODE, int):
        _flush()
        os._exit(_EXIT_CODE)


def _exit_interrupted(*_signal):
    _flush()
    os._exit(EXIT_INTERRUPTED)


def _flush():
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):     # closed, or a pipe no one reads
            stream.flush()


if __name__ == "__main__":
    entry()
