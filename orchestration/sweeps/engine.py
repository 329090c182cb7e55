"""Running a sweep: one task per point (here or on dask), the journal of finished runs, the table
and the statistics (see :mod:`orchestration.sweeps`).
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

import controller_fmu
import plant_fmu

from ..cosim.pool import SlavePool
from ..export import flavour_fmus
from ..export.native_fmus import GENERATION_TOOL
from ..job import check_wiring, run_scene
from ..report.progress import is_quiet, sink_for
from ..files import atomic_path, open_in_place, output_error
from ..scene.keys import parse_value
from ..scene.records import Scene
from ..studies.analysis import linearisation, max_real_part
from .columns import needs_fits, needs_linear, project, serves
from .executor import Executor, TaskLost, file_name, scratch_dir, worker_file
from .plan import Point, SweepPlan
from .plot import plot_sweep

__all__ = ["summary_row", "verdict_of", "linear_decay_rate", "model_sources_digest", "run_task",
           "Journal",
           "write_table", "read_table", "SweepProgress", "SweepResult", "fmus_for", "pending",
           "run_sweep", "sweep_stats", "SweepFolderError", "check_folder", "FILES"]


JOURNAL = "runs.jsonl"
#: The files a sweep writes into its folder.
FILES = (JOURNAL, "sweep.parquet", "sweep.csv", "sweep.json", "sweep.png")


#: statuses of a finished run (a lost run is rerun by the next sweep into the same folder)
DONE = ("ok", "failed")


# ---------------------------------------------------------------------------- one run
#: A finished run's ``verdict`` from ``stable`` (True, False, None) when its summary has none.
VERDICTS = {True: "stable", False: "unstable", None: "undetermined"}


def verdict_of(row: dict) -> str:
    """The run's verdict (:func:`orchestration.studies.summary.verdict`): ``stable``,
    ``unstable``, ``undetermined`` (no fit decides: too short a run, too few periods in the
    linear range, a rate within its uncertainty of zero) or ``stopped`` (early). Undetermined is
    not "unstable"."""
    return row.get("verdict") or VERDICTS[row.get("stable")]


def summary_row(summary: dict) -> dict:
    """The table's fields of one run, from its summary (:func:`orchestration.studies.summary.summarize`
    and :func:`orchestration.job.run_scene`): the one place that knows the summary's layout.

    A fitted rate is a number only where the summary found the fit reliable (the note says why
    not); ``decay_rate`` is minus the largest reliable rate; ``valid`` is False when the run
    left its rung's measured range (``validity`` says how); ``model_form_error``: the run's
    error figure (rad; :mod:`orchestration.studies.error_figure`: its tip angle's error against
    the exact beam, from its companion run), or without a companion the measured bound
    (:mod:`orchestration.studies.validity`); ``model_form_basis``: what the figure compares with,
    or why there is none."""
    stopped = summary.get("stopped") or {}
    row = {"status": "failed" if stopped else "ok", "stable": summary.get("stable"),
           "verdict": summary.get("verdict")}
    row["verdict"] = verdict_of(row)
    row["verdict_reason"] = summary.get("verdict_reason")
    rates = []
    for key in ("slow", "bending"):
        mode = summary.get(key) or {}
        linear = mode.get("linear") or {}
        row[f"{key}_rate"] = mode.get("rate")
        row[f"{key}_frequency"] = mode.get("frequency")
        row[f"{key}_rate_linear"] = linear.get("rate")
        row[f"{key}_note"] = mode.get("note")
        u = (mode.get("fit") or {}).get("rate_uncertainty")
        if mode.get("reliable") and u is not None and abs(mode["rate"]) > u:
            rates.append(mode["rate"])          # a fit that counts toward the verdict
    row["decay_rate"] = -max(rates) if rates else None
    row["max_abs_F_c"] = summary.get("max_abs_F_c")
    row["max_abs_x"] = summary.get("max_abs_x")
    validity = summary.get("validity") or {}
    warnings = validity.get("warnings") or []
    row["valid"] = not warnings
    row["validity"] = "; ".join(warnings) or None
    figure = summary.get("error_figure")
    if figure:
        row["model_form_error"] = figure["figure"]
        row["model_form_basis"] = (f"against {figure['companion']['text']}"
                                   if figure["figure"] is not None else figure["why"])
    else:
        row["model_form_error"] = validity.get("model_form_error")
        row["model_form_basis"] = (f"the measured bound of the {validity['rung']} rung"
                                   if row["model_form_error"] is not None else
                                   validity.get("note"))
    if "max_error_phi_o" in summary:
        row["max_error_phi_o"] = summary["max_error_phi_o"]
        row["max_error_eta_1"] = summary["max_error_eta_1"]
    if summary.get("model"):
        row["model"] = f"{summary['model']['n_modes']} modes, {summary['model']['fidelity']}"
    row["steps"] = summary.get("steps")
    row["cosim_time"] = summary.get("wall_time")
    row["stopped_at"] = stopped.get("time")
    row["message"] = stopped.get("reason")          # in the user's terms
    row["fmu_message"] = stopped.get("fmu_message")  # the FMU's own, when an FMU stopped it
    return row


def linear_decay_rate(scene: Scene) -> float:
    """The linearised loop's smallest decay rate ``-max Re(lambda)`` over all its roots, the
    cart's drift roots left aside: ``flexpend design``'s criterion, for this one plant; with a
    sampled controller, the sampled loop's ``-log(max |z|) / T``."""
    c = scene.controller
    if c.sampled:
        import math

        from ..studies.sampled import controller_poles
        rho = controller_poles(linearisation(scene).params, c).spectral_radius
        return -math.log(rho) / c.sample_period if rho > 0 else math.inf
    return -max_real_part(linearisation(scene).params, c)


def _one_line(exc: BaseException, limit: int = 500) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:limit]


@lru_cache(maxsize=None)
def model_sources_digest() -> str:
    """sha256 of this process's model packages (``plant_fmu``, ``controller_fmu``: Python and C
    sources). A pythonfmu FMU runs the packages already imported in its process, so a worker
    whose digest differs from the client's would not run the client's model."""

    h = hashlib.sha256()
    for pkg in (plant_fmu, controller_fmu):
        root = Path(pkg.__file__).resolve().parent
        for f in sorted(root.rglob("*")):
            if f.suffix in (".py", ".c", ".h") and "__pycache__" not in f.parts:
                h.update(f.relative_to(root.parent).as_posix().encode() + b"\0")
                h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


_EXTRACTED: dict = {}


def _extracted(path: str) -> str:
    """The FMU at ``path`` extracted once per process and reused by every run of it (extracting
    and removing a folder per run cost ~90 of the ~140 ms of a 0.05 s run): in a dask worker
    into the worker's own folder, which dask removes with the worker; here into a temporary
    folder removed when this process exits. An FMU rebuilt at the same path (another
    modification time or size) is extracted again."""
    st = os.stat(path)
    key = (path, st.st_mtime_ns, st.st_size)
    if key not in _EXTRACTED:
        import atexit
        import shutil
        import tempfile

        from ..scene.fmu import unpack

        folder = tempfile.mkdtemp(prefix="flexpend_fmu_", dir=scratch_dir())
        _EXTRACTED[key] = unpack(path, folder)
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return _EXTRACTED[key]


def _resets_fully(slave) -> bool:
    """The native FMUs' reset restores the state after instantiation (not pythonfmu's)."""
    return slave.md.generationTool == GENERATION_TOOL


_POOL: list = []


def _pool() -> SlavePool:
    """This process's FMU instances, reused by every run (:mod:`orchestration.cosim.pool`) and
    freed when the process exits."""
    if not _POOL:
        import atexit

        _POOL.append(SlavePool(_resets_fully))
        atexit.register(_POOL[0].close)
    return _POOL[0]


def run_task(task) -> dict:
    """Run one point on a worker (or here): ``(scene, reference, fmus, sources[, columns])``;
    ``fmus`` maps ``plant``/``controller`` to ``(shipped name, client path)``, ``sources`` is the
    client's :func:`model_sources_digest`, ``columns`` the sweep's
    (:mod:`~orchestration.sweeps.columns`; None or absent: every column): the row has those
    only, and their names in its ``columns`` field. Never raises: a failure is a row with its
    message."""

    scene, reference, fmus, sources, *rest = task
    columns = rest[0] if rest else None
    t0 = time.perf_counter()
    try:
        paths = {role: worker_file(ship, path) for role, (ship, path) in fmus.items()}
        if sources != model_sources_digest():
            raise RuntimeError("this worker's flexpend model sources differ from the client's: "
                               "install the client's version on the workers")
        r = run_scene(scene, paths, reference=reference, progress=False,
                      unzipdirs={role: _extracted(p) for role, p in paths.items()}, pool=_pool(),
                      fits=needs_fits(columns))
        row = summary_row(r.summary)
        if needs_linear(columns):
            row["linear_decay_rate"] = linear_decay_rate(r.scene)
            row["linear_stable"] = row["linear_decay_rate"] > 0
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, never the end of a sweep
        row = {"status": "failed", "verdict": verdict_of({}), "message": _one_line(exc)}
    row["wall_time"] = time.perf_counter() - t0
    if columns is not None:
        row = {**project(row, columns), "columns": list(columns)}
    return row


# ---------------------------------------------------------------------------- journal, table
class SweepFolderError(ValueError):
    """A sweep folder whose files cannot be read or written (one line naming the file)."""


def check_folder(folder) -> None:
    """Refuse, before any run, a folder where something other than a file stands in place of
    one of the sweep's files (:data:`FILES`), or a journal that cannot be appended to (read-only,
    immutable): a sweep would run, then fail to write."""
    for name in FILES:
        path = Path(folder) / name
        if path.exists() and not path.is_file():
            what = "a folder" if path.is_dir() else "not a regular file"
            raise SweepFolderError(f"{path}: {what} where the sweep writes its {name}; move it "
                                   "away or choose another --out")
    journal = Path(folder) / JOURNAL
    if journal.exists() and not os.access(journal, os.R_OK | os.W_OK):
        raise SweepFolderError(f"{journal}: cannot be written (read-only or immutable); the "
                               "sweep appends its finished runs there")


#: The fields of a journal row and the types they hold (or null); other fields are the swept
#: keys (taken from the plan, not from the row) and texts.
_NUMBERS = ("run", "sample", "decay_rate", "linear_decay_rate", "max_abs_F_c", "max_abs_x",
            "max_error_phi_o", "max_error_eta_1", "model_form_error", "steps", "cosim_time",
            "stopped_at",
            "wall_time", *(f"{m}_{q}" for m in ("slow", "bending")
                           for q in ("rate", "frequency", "rate_linear")))
_FLAGS = ("stable", "valid")
_TEXTS = ("message", "fmu_message", "model", "validity", "model_form_basis", "slow_note",
          "bending_note")


def _sound(row) -> bool:
    """Whether a journal line's JSON is a row as :func:`_row` writes it."""
    if not (isinstance(row, dict) and isinstance(row.get("key"), str)
            and row.get("status") in (*DONE, "lost")):
        return False
    for name, types in ((_NUMBERS, (int, float)), (_FLAGS, (bool,)), (_TEXTS, (str,))):
        for k in name:
            v = row.get(k)
            if v is not None and (not isinstance(v, types) or (bool not in types
                                                               and isinstance(v, bool))):
                return False
    return True


class Journal:
    """``DIR/runs.jsonl``: one JSON row per finished run, appended and flushed at once (a killed
    process loses no finished row); synced to the disk with the first row :attr:`SYNC_EVERY`
    seconds or more after the last sync, and at the end (an ``fsync`` per row cost a third of a
    10 ms run): a crash of the machine may lose the rows since the last sync, which the next
    sweep into the folder reruns."""

    SYNC_EVERY = 1.0

    def __init__(self, folder: Path):
        self.path = Path(folder) / JOURNAL
        self._synced = 0.0

    def read(self) -> dict:
        """key -> the newest row of that key. A line that is not a sound row (a torn last line
        from a kill, invalid UTF-8, a field of the wrong type) is skipped: its run counts as not
        finished and is run again."""
        rows = {}
        if not self.path.exists():
            return rows
        check_folder(self.path.parent)
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise SweepFolderError(f"{self.path}: cannot be read ({exc.strerror or exc})") \
                from None
        for line in data.splitlines():
            try:
                row = json.loads(line)
            except ValueError:                # not JSON, or not UTF-8
                continue
            if _sound(row):
                rows[row["key"]] = row
        return rows

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = open_in_place(self.path, os.O_RDWR | os.O_CREAT | os.O_APPEND)
        size = os.fstat(self._fd).st_size
        if size and os.pread(self._fd, 1, size - 1) != b"\n":  # a fresh line after a torn one
            self._write(b"\n")
        self._synced = time.monotonic()
        return self

    def append(self, row: dict):
        """Append ``row`` as one whole line (in the file when this returns: a killed process
        loses no finished row; on the disk by the rule of :attr:`SYNC_EVERY`)."""
        self._write((json.dumps(row) + "\n").encode())
        if time.monotonic() - self._synced >= self.SYNC_EVERY:
            self._sync()

    def _write(self, data: bytes):
        """Append ``data`` whole, or (a full disk) not at all: the journal never ends on a torn
        row of ours."""
        size = os.fstat(self._fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(self._fd, view):]
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, size)
            raise output_error(self.path, exc) from None

    def _sync(self):
        try:
            os.fsync(self._fd)
        except OSError as exc:
            raise output_error(self.path, exc) from None
        self._synced = time.monotonic()

    def __exit__(self, *exc):
        try:
            self._sync()
        finally:
            os.close(self._fd)


def _have_pyarrow() -> bool:
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        return False
    return True


def _columns(rows) -> list:
    return list(dict.fromkeys(k for r in rows for k in r))


def write_table(rows, folder: Path, parquet: bool | None = None) -> Path:
    """The rows as ``folder/sweep.parquet`` (pyarrow present, or ``parquet=True``) or
    ``folder/sweep.csv``; a column whose values mix types is written as text."""
    folder = Path(folder)
    cols = _columns(rows)
    parquet = _have_pyarrow() if parquet is None else parquet
    path = folder / ("sweep.parquet" if parquet else "sweep.csv")
    with atomic_path(path) as tmp:
        if parquet:
            import pyarrow as pa
            import pyarrow.parquet as pq
            arrays = {}
            for c in cols:
                vals = [r.get(c) for r in rows]
                try:
                    arrays[c] = pa.array(vals)
                except (pa.ArrowInvalid, pa.ArrowTypeError):
                    arrays[c] = pa.array([None if v is None else str(v) for v in vals])
            pq.write_table(pa.table(arrays), tmp)
        else:
            import csv
            with open(tmp, "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(cols)
                for r in rows:
                    w.writerow(["" if r.get(c) is None else repr(r[c])
                                if isinstance(r.get(c), float) else r[c] for c in cols])
    (folder / ("sweep.csv" if parquet else "sweep.parquet")).unlink(missing_ok=True)  # stale
    return path


def read_table(path) -> list[dict]:
    """The rows of a sweep table (Parquet or CSV), as dicts; CSV cells are read as in
    ``--set`` (numbers, booleans; an empty cell is None)."""
    path = Path(path)
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq
        return pq.read_table(path).to_pylist()
    import csv
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))

    def cell(k, v):
        if v == "":                 # text fields are None when empty, as in the rows
            return None
        if k in ("message", "fmu_message", "key", "status", "model", "validity",
                 "model_form_basis") \
                or k.endswith("_note"):
            return v
        if v in ("True", "False"):
            return v == "True"
        return parse_value(v)
    return [{k: cell(k, v) for k, v in r.items()} for r in rows]


# ---------------------------------------------------------------------------- progress
class SweepProgress:
    """A bar on stderr: finished, failed and remaining runs, the elapsed time and an estimate
    of the rest. On a terminal it redraws one line; otherwise it prints a line every 10 %.
    Silent within :func:`orchestration.report.progress.quiet`. With ``callback``, no bar:
    ``callback(fraction, label)`` is told the fraction of the runs finished
    (:mod:`orchestration.report.progress`)."""

    def __init__(self, total: int, stream=None, callback=None, name: str = "sweep"):
        self.total, self.stream = max(total, 0), stream or sys.stderr
        self.callback, self.name = callback, name
        self.ok = self.failed = self.lost = 0
        self.t0 = time.perf_counter()
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._next = 0.1
        self._last = 0.0

    @property
    def finished(self):
        return self.ok + self.failed + self.lost

    def text(self) -> str:
        el = time.perf_counter() - self.t0
        n, tot = self.finished, max(self.total, 1)
        bar = "#" * int(30 * n / tot)
        eta = f", ~{el * (self.total - n) / n:.0f} s left" if 0 < n < self.total else ""
        lost = f", {self.lost} lost" if self.lost else ""
        return (f"sweep [{bar:.<30}] {n}/{self.total} finished, {self.failed} failed{lost}, "
                f"{self.total - n} remaining, {el:.0f} s{eta}")

    def update(self, status: str):
        setattr(self, status, getattr(self, status) + 1)
        done = self.finished >= self.total
        if self.callback is not None:
            self.callback(self.finished / max(self.total, 1),
                          f"{self.name}: {self.finished} of {self.total} runs finished, "
                          f"{self.failed} failed" + (f", {self.lost} lost" if self.lost else ""))
            return
        if is_quiet():
            return
        if self.tty:
            now = time.perf_counter()
            if done or now - self._last > 0.2:
                self._last = now
                self.stream.write("\r" + self.text() + " " * 4 + ("\n" if done else ""))
                self.stream.flush()
        elif done or self.finished / max(self.total, 1) >= self._next:
            while self._next <= self.finished / max(self.total, 1):
                self._next += 0.1
            self.stream.write(self.text() + "\n")
            self.stream.flush()


# ---------------------------------------------------------------------------- the sweep
@dataclass
class SweepResult:
    rows: list                  # one per point, in the plan's order
    ran: int                    # runs done by this call
    skipped: int                # runs found finished in the folder's journal
    seconds: float
    table: Path | None = None
    plot: Path | None = None

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)

    def __repr__(self) -> str:
        """One line: the rows, how many ran and were skipped, the time."""
        return (f"SweepResult({len(self.rows)} rows: {self.ran} ran, {self.skipped} found "
                f"finished; {self.seconds:.3g} s)")


def _row(point: Point, result: dict, plan: SweepPlan, journal: bool = False) -> dict:
    """The point's identity (run number, key, swept values, sample), then ``result``'s fields
    (a journal row's identity fields are the point's own): for the table, those of the
    columns the plan asks for (:func:`~orchestration.sweeps.columns.project`); for the journal
    (``journal``), every field the run computed, with the ``columns`` it was made for."""
    row = {"run": point.index, "key": point.key}
    row.update({k: point.params.get(k) for k in plan.keys})
    if plan.samplers:
        row["sample"] = point.sample
    made = result.get("columns")
    if result.get("status") in DONE and (made is None or "verdict" in made):
        # an older journal has no verdict: it follows from the row's ``stable``
        result = {**result, "verdict": result.get("verdict") or verdict_of(result)}
    if not journal:
        result = project({k: v for k, v in result.items() if k != "columns"}, plan.columns)
    row.update((k, v) for k, v in result.items() if k not in row and k != "sample")
    return row


def fmus_for(plan: SweepPlan, progress: bool = False) -> dict:
    """``{flavour: {"plant": path, "controller": path}}`` for the FMU flavours (``master.fmus``)
    the plan's runs use, built if missing or stale; ``progress``: a bar on stderr for each
    build."""
    out = {}
    for fl in dict.fromkeys(p.scene.master.fmus for p in plan.points):
        sink = sink_for(progress, f"the {fl} FMUs")
        try:
            out[fl] = flavour_fmus(fl, progress=sink)
        finally:
            if sink is not None:
                sink.close()
    return out


def pending(plan: SweepPlan, out_dir, retry_failed: bool = False) -> int:
    """How many runs of ``plan`` have no finished row in ``out_dir`` yet."""
    check_folder(out_dir)
    results = Journal(Path(out_dir)).read()
    return len({p.key for p in plan.points
                if not _finished(results.get(p.key), plan, retry_failed)})


def _task_columns(columns, row):
    """The columns a run computes for a sweep asking for ``columns`` whose journal has ``row``
    (or None) for it: those, and those the row was made for (a rerun for new columns keeps the
    old ones: the journal's row then serves both sweeps)."""
    if columns is None or row is None:
        return columns
    made = row.get("columns")
    if made is None:                # a row of every column (retried): keep it so
        return None if row.get("status") in DONE else columns
    return (*columns, *(c for c in made if c not in columns))


def _columns_item(columns) -> tuple:
    """The task's columns item: none for every column (the task of an older flexpend, which a
    worker of that version reads)."""
    return () if columns is None else (columns,)


def _finished(row, plan: SweepPlan, retry_failed: bool) -> bool:
    """Whether a journal row (or None) finishes its run for ``plan``: ``ok`` (or ``failed``,
    unless ``retry_failed``), with the columns the plan asks for
    (:func:`~orchestration.sweeps.columns.serves`)."""
    return (row is not None and row.get("status") in (("ok",) if retry_failed else DONE)
            and serves(row, plan.columns))


def run_sweep(plan: SweepPlan, fmus: dict, out_dir, executor=None, *, batch: int = 1,
              retry_failed: bool = False, progress=True, plot: bool = True,
              stop=None) -> SweepResult:
    """Run the points of ``plan`` that ``out_dir`` has no finished row for, with ``executor``
    (:mod:`orchestration.sweeps.executor`; ``None``: serially here); write the table and the plot.

    ``fmus``: ``{"plant": path, "controller": path}`` for every run, or ``{flavour: {...}}``
    per scene key ``master.fmus`` (built once by the caller, :func:`fmus_for`; a dask executor
    must have been opened with ``files=`` these paths). ``stop``: asked before the first run
    and after each (Ctrl-C); when it returns True the sweep ends with KeyboardInterrupt, every
    finished run in the journal. ``progress``: ``True`` (a bar on stderr), a stream for the
    bar, a callable ``progress(fraction, label)`` told the runs finished, or ``False``
    (:class:`SweepProgress`)."""

    executor = executor or Executor()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    journal = Journal(out_dir)
    results = journal.read()
    # one task per key: points whose scenes resolve alike (repeated integer draws) run once
    todo = list({p.key: p for p in plan.points
                 if not _finished(results.get(p.key), plan, retry_failed)}.values())
    by_flavour = {None: fmus} if "plant" in fmus else fmus
    for fmu_pair in by_flavour.values():       # every FMU checked before any run loads one
        check_wiring(plan.scene, fmu_pair)
    shipped = {fl: {role: (file_name(path), str(path)) for role, path in pair.items()}
               for fl, pair in by_flavour.items()}

    def pair(p):
        return shipped[None] if None in shipped else shipped[p.scene.master.fmus]
    tasks = [(p.scene, plan.reference, pair(p), model_sources_digest(),
              *_columns_item(_task_columns(plan.columns, results.get(p.key)))) for p in todo]
    if progress is True or hasattr(progress, "write"):
        bar = SweepProgress(len(todo), None if progress is True else progress)
    elif progress:
        bar = SweepProgress(len(todo), callback=progress, name=f"sweep of {plan.scene.name}")
    else:
        bar = None
    t0 = time.perf_counter()
    if stop is not None and stop():
        raise KeyboardInterrupt
    with journal:
        for i, result in executor.map(run_task, tasks, batch=batch):
            if isinstance(result, TaskLost):
                result = {"status": "lost", "message": result.message}
            row = _row(todo[i], result, plan, journal=True)
            journal.append(row)
            results[row["key"]] = row
            if bar is not None:
                bar.update(row["status"])
            if stop is not None and stop():
                raise KeyboardInterrupt
    seconds = time.perf_counter() - t0
    ordered = [_row(p, results[p.key], plan) for p in plan.points]
    skipped = len({p.key for p in plan.points}) - len(todo)
    out = SweepResult(ordered, len(todo), skipped, seconds)
    out.table = write_table(ordered, out_dir)
    if plot:
        out.plot = plot_sweep(plan, ordered, out_dir / "sweep.png")
        if out.plot is None:                    # no figure of this sweep: none of an earlier
            (out_dir / "sweep.png").unlink(missing_ok=True)
    return out


def sweep_stats(rows, columns=None) -> dict:
    """Counts, the verdicts and the decay rates (worst, median, best) of the finished runs.

    ``stable``, ``unstable``, ``undetermined``: the finished runs' verdicts (:func:`verdict_of`;
    a run stopped early counts as undetermined here);
    ``no_fit``: the runs that completed without a reliable fit (the failed ones stopped early);
    ``stable_fraction``: stable among the runs with a verdict (None without any);
    ``linear_stable``, ``linear_unstable``: the linearised loops of the completed runs, and
    ``no_fit_linear_stable``: those stable among the runs without a reliable fit.

    ``columns``: the sweep's (:mod:`~orchestration.sweeps.columns`; None: all). Without
    ``verdict`` or ``stable`` among them there are no verdict counts; ``columns_range`` gives,
    for each numeric column asked for, its smallest, median and largest value over the completed
    runs and the runs of the extremes."""
    n = len(rows)
    ok = [r for r in rows if r["status"] == "ok"]
    decays = [r for r in ok if r.get("decay_rate") is not None]
    out = {"runs": n, "ok": len(ok), "failed": sum(r["status"] == "failed" for r in rows),
           "lost": sum(r["status"] == "lost" for r in rows)}
    if columns is None or "valid" in columns:
        out["invalid"] = sum(r.get("valid") is False for r in rows)
    lin = [r for r in ok if r.get("linear_decay_rate") is not None]
    if needs_linear(columns):
        out["linear_stable"] = sum(r["linear_decay_rate"] > 0 for r in lin)
        out["linear_unstable"] = len(lin) - out["linear_stable"]
    if columns is None or {"verdict", "stable"} & set(columns):
        verdicts = [verdict_of(r) for r in rows]
        out["stable"] = verdicts.count("stable")
        out["unstable"] = verdicts.count("unstable")
        finished = out["ok"] + out["failed"]
        out["undetermined"] = finished - out["stable"] - out["unstable"]
        no_fit = [r for r, v in zip(rows, verdicts)
                  if r["status"] == "ok" and v not in ("stable", "unstable")]
        out["no_fit"] = len(no_fit)
        judged = out["stable"] + out["unstable"]
        out["stable_fraction"] = out["stable"] / judged if judged else None
        if needs_linear(columns):
            out["no_fit_linear_stable"] = sum((r.get("linear_decay_rate") or 0) > 0
                                              for r in no_fit)
    if decays:
        worst = min(decays, key=lambda r: r["decay_rate"])
        vals = [r["decay_rate"] for r in decays]
        out.update(worst_decay_rate=worst["decay_rate"], worst_run=worst["run"],
                   median_decay_rate=float(np.median(vals)), best_decay_rate=max(vals))
    if lin:
        worst = min(lin, key=lambda r: r["linear_decay_rate"])
        out.update(worst_linear_decay_rate=worst["linear_decay_rate"],
                   worst_linear_run=worst["run"])
    if columns is not None:
        out["columns"] = list(columns)
        ranges, flags = {}, {}
        for c in columns:
            if c == "decay_rate":
                continue                        # its worst, median and best are above
            if all(isinstance(r.get(c), bool) or r.get(c) is None for r in ok) and \
                    any(isinstance(r.get(c), bool) for r in ok):
                flags[c] = {"true": sum(r.get(c) is True for r in ok),
                            "false": sum(r.get(c) is False for r in ok)}
                continue
            have = [r for r in ok if isinstance(r.get(c), (int, float))
                    and not isinstance(r.get(c), bool) and math.isfinite(r[c])]
            if have:
                lo, hi = min(have, key=lambda r: r[c]), max(have, key=lambda r: r[c])
                ranges[c] = {"min": lo[c], "min_run": lo["run"],
                             "median": float(np.median([r[c] for r in have])),
                             "max": hi[c], "max_run": hi["run"], "runs": len(have)}
        out["columns_range"], out["columns_flags"] = ranges, flags
    return out
