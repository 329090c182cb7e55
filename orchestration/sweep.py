"""Sweeps and uncertainty studies: many co-simulations of one scene, as tasks on dask.distributed
(:mod:`orchestration.parallel`), or one after the other in this process.

    flexpend sweep SCENE [--grid KEY=START:STOP:NUM[:log] ...] [--values KEY=V1,V2,...]
                         [--sample KEY=DIST ... --samples N --seed S] [--set KEY=VALUE ...]
                         [--reference] [--workers N | --scheduler ADDRESS | --serial]
                         [--batch N] [--out DIR] [--retry-failed]

* **What varies.** Every scene key (``flexpend scenes``, the keys of ``flexpend run``) can be
  swept: ``--grid`` gives ``NUM`` values from ``START`` to ``STOP`` (geometric with ``:log``),
  ``--values`` a list; several of them make the full grid. ``--sample KEY=DIST`` draws ``--samples``
  random values, reproducibly from ``--seed`` (numpy's ``Generator``): ``DIST`` is
  ``uniform:LO:HI``, ``loguniform:LO:HI``, ``normal:MEAN:SD``, ``integers:LO:HI`` or ``design``,
  the key's range in the uncertainty set of ``flexpend design``
  (:meth:`orchestration.design.UncertaintySet.sample`; ``--sample design`` draws its four keys
  ``plant.n_modes``, ``plant.zeta``, ``plant.EI``, ``plant.m`` together, and ``--set design.*``
  reshapes the set as in ``flexpend design``). Samples combine with a grid: every grid point gets
  the same samples.
* **Every point is validated before anything runs**: an unknown key, a bad spec or a value the
  scene refuses is a :class:`~orchestration.config.ConfigError` naming it (one line, exit 2).
* **One row per run** (:func:`summary_row` takes it from the run's summary): the swept values,
  ``status`` (``ok``; ``failed``: the co-simulation stopped or raised, with its ``message``;
  ``lost``: its worker died), the verdict, the fitted rates and frequencies, ``decay_rate`` (minus
  the largest fitted rate), max |F_c|, the error against the monolithic reference with
  ``--reference``, the master's time ``cosim_time`` and the whole task's ``wall_time``; beside
  the fits, the linearised loop's rates (:func:`linear_decay_rate`).
* **Nothing finished is lost.** Each finished run is appended at once to ``DIR/runs.jsonl``;
  the table (``DIR/sweep.parquet`` with pyarrow, else ``DIR/sweep.csv``) is written from it at
  the end. A run is keyed by the digest of its whole resolved scene (and ``--reference``): a rerun
  with the same ``--out`` runs only the keys without an ``ok`` or ``failed`` row (with
  ``--retry-failed``, without an ``ok`` row).
* **Plots** (``DIR/sweep.png``): a heat map of the decay rate over a 2-D grid, a line plot of
  the rates over a 1-D grid, a histogram of the decay rates of a sample.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import sys
import time
import zlib
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from .config import ConfigError, check_known, parse_override, parse_value
from .scenes import Scene, known_keys, load_scene, scene_from_config

__all__ = ["Axis", "Sampler", "Point", "SweepPlan", "SweepResult", "plan_sweep", "parse_grid",
           "parse_values", "parse_sample", "summary_row", "linear_decay_rate", "fmus_for", "run_sweep", "pending", "sweep_stats",
           "read_table",
           "write_table", "DESIGN_KEYS", "DISTRIBUTIONS"]

#: scene key -> the uncertainty set's parameter (``flexpend design``)
DESIGN_KEYS = {"plant.n_modes": "n_modes", "plant.zeta": "zeta", "plant.EI": "EI",
               "plant.m": "m"}
#: ``--sample`` distributions besides ``design``: name -> number of parameters
DISTRIBUTIONS = {"uniform": 2, "loguniform": 2, "normal": 2, "integers": 2}
JOURNAL = "runs.jsonl"
#: statuses of a finished run (a lost run is rerun by the next sweep into the same folder)
DONE = ("ok", "failed")


# ---------------------------------------------------------------------------- the spec
@dataclass(frozen=True)
class Axis:
    """One swept key: its values, from ``--grid`` (``log``: geometric) or ``--values``."""

    key: str
    values: tuple
    log: bool = False


@dataclass(frozen=True)
class Sampler:
    """One sampled key: ``dist`` is ``design`` or a name of :data:`DISTRIBUTIONS`."""

    key: str
    dist: str
    params: tuple = ()


def _known_key(key: str, option: str) -> str:
    try:
        check_known([key], known_keys())
    except ConfigError as exc:
        raise ConfigError(f"{option}: {exc}") from None
    return key


def _split(item: str, option: str, form: str) -> tuple[str, str]:
    key, sep, spec = item.partition("=")
    if not sep or not key.strip() or not spec.strip():
        raise ConfigError(f"{option} expects {form}, got {item!r}")
    return _known_key(key.strip(), option), spec.strip()


def _integer_key(key: str) -> bool:
    default = known_keys()[key]
    return isinstance(default, int) and not isinstance(default, bool)


def _typed(key: str, value):
    """An integer given for a real-valued key, as a float (``--values controller.kp=400,450.5``
    makes one column of floats, and the same scene key whichever way it was given)."""
    default = known_keys()[key]
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _clean(v: float) -> float:
    """12 significant digits: ``1e-3`` rather than ``0.0010000000000000002`` from geomspace."""
    return float(f"{v:.12g}")


def parse_grid(item: str) -> Axis:
    """``KEY=START:STOP:NUM[:log]`` -> :class:`Axis` (integers for an integer key)."""
    form = "KEY=START:STOP:NUM[:log]"
    key, spec = _split(item, "--grid", form)
    parts = [p.strip() for p in spec.split(":")]
    log = len(parts) == 4 and parts[3] == "log"
    if len(parts) not in (3, 4) or (len(parts) == 4 and not log):
        raise ConfigError(f"--grid expects {form}, got {item!r}")
    start, stop, num = (parse_value(p) for p in parts[:3])
    for name, v in (("START", start), ("STOP", stop)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"--grid {item!r}: {name} must be a finite number, got {v!r}")
    if isinstance(num, bool) or not isinstance(num, int) or num < 1:
        raise ConfigError(f"--grid {item!r}: NUM must be an integer >= 1, got {num!r}")
    if log and (start <= 0 or stop <= 0):
        raise ConfigError(f"--grid {item!r}: a log grid needs START and STOP > 0")
    values = [_clean(v) for v in (np.geomspace if log else np.linspace)(start, stop, num)]
    if _integer_key(key):
        bad = [v for v in values if abs(v - round(v)) > 1e-9 * max(1.0, abs(v))]
        if bad:
            raise ConfigError(f"--grid {item!r}: {key} takes integers; the grid gives {bad[0]:g}")
        values = list(dict.fromkeys(int(round(v)) for v in values))
    return Axis(key, tuple(values), log)


def parse_values(item: str) -> Axis:
    """``KEY=V1,V2,...`` -> :class:`Axis` (each value read as in ``--set``)."""
    key, spec = _split(item, "--values", "KEY=V1,V2,...")
    parts = [p.strip() for p in spec.split(",")]
    if any(not p for p in parts):
        raise ConfigError(f"--values {item!r}: an empty value")
    return Axis(key, tuple(_typed(key, parse_value(p)) for p in parts))


def parse_sample(item: str) -> list[Sampler]:
    """``KEY=DIST`` (or ``design``: the four keys of the uncertainty set) -> samplers."""
    if item.strip() == "design":
        return [Sampler(k, "design") for k in DESIGN_KEYS]
    form = ("KEY=DIST, DIST one of design, uniform:LO:HI, loguniform:LO:HI, normal:MEAN:SD, "
            "integers:LO:HI")
    key, spec = _split(item, "--sample", form)
    name, *params = (p.strip() for p in spec.split(":"))
    if name == "design":
        if params or key not in DESIGN_KEYS:
            raise ConfigError(f"--sample {item!r}: the design's uncertainty set has the keys "
                              f"{', '.join(DESIGN_KEYS)}")
        return [Sampler(key, "design")]
    if name not in DISTRIBUTIONS or len(params) != DISTRIBUTIONS[name]:
        raise ConfigError(f"--sample expects {form}; got {item!r}")
    values = tuple(parse_value(p) for p in params)
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
           for v in values):
        raise ConfigError(f"--sample {item!r}: the parameters must be finite numbers")
    a, b = values
    if name in ("uniform", "loguniform", "integers") and a > b:
        raise ConfigError(f"--sample {item!r}: LO exceeds HI")
    if name == "loguniform" and a <= 0:
        raise ConfigError(f"--sample {item!r}: loguniform needs LO > 0")
    if name == "normal" and b < 0:
        raise ConfigError(f"--sample {item!r}: SD must be >= 0")
    if name == "integers" and not all(float(v).is_integer() for v in values):
        raise ConfigError(f"--sample {item!r}: integers needs integer LO and HI")
    if _integer_key(key) and name != "integers":
        raise ConfigError(f"--sample {item!r}: {key} takes integers; use integers:LO:HI")
    return [Sampler(key, name, values)]


def _stream(seed: int, name: str) -> np.random.Generator:
    """An independent generator per sampled key (or the design set), from the one seed: the
    draws of a key do not depend on which other keys are sampled, nor on their order."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(zlib.crc32(name.encode()),)))


def draw_samples(samplers, n: int, seed: int, uncertainty=None) -> dict:
    """key -> ``n`` values. Value ``i`` of each key comes from the ``i``-th draw of its stream,
    so the first ``k`` of ``n`` samples are the ``k`` samples of the same seed."""
    out = {}
    design = [s for s in samplers if s.dist == "design"]
    if design:
        beams = uncertainty.sample(_stream(seed, "design"), n)
        for s in design:
            out[s.key] = beams[DESIGN_KEYS[s.key]]
    for s in samplers:
        if s.dist == "design":
            continue
        u = _stream(seed, s.key).random(n)
        a, b = s.params
        if s.dist == "uniform":
            v = a + u * (b - a)
        elif s.dist == "loguniform":
            v = np.exp(np.log(a) + u * (np.log(b) - np.log(a)))
        elif s.dist == "normal":
            from scipy.special import ndtri
            v = a + b * ndtri(u)
        else:                                               # integers, LO..HI inclusive
            v = np.minimum(int(a) + np.floor(u * (int(b) - int(a) + 1)), int(b))
        out[s.key] = [int(x) for x in v] if s.dist == "integers" else \
            [_typed(s.key, float(x)) for x in v]
    return out


@dataclass
class Point:
    """One run of the sweep: the swept values, the validated scene and its key."""

    index: int
    params: dict
    sample: int | None
    config: dict = field(repr=False)
    key: str = ""


@dataclass
class SweepPlan:
    scene: Scene                      # the base scene (with --set)
    axes: list
    samplers: list
    n_samples: int
    seed: int | None
    reference: bool
    points: list
    overrides: list = field(default_factory=list)
    uncertainty: object = None        # the design's set, when sampled
    check_levels: int = 5             # its check grid (design.check_levels)

    @property
    def keys(self) -> list:
        """The swept keys, in the table's order."""
        return [a.key for a in self.axes] + [s.key for s in self.samplers]

    def describe(self) -> dict:
        out = {"scene": self.scene.name, "set": self.overrides,
               "grid": {a.key: list(a.values) for a in self.axes},
               "log": [a.key for a in self.axes if a.log], "runs": len(self.points),
               "reference": self.reference}
        if self.samplers:
            out["sample"] = {s.key: [s.dist, *s.params] for s in self.samplers}
            out["samples"], out["seed"] = self.n_samples, self.seed
        if self.uncertainty is not None:
            out["uncertainty_set"] = self.uncertainty.describe()
        return out


def run_key(name: str, config: dict, reference: bool) -> str:
    """The digest that identifies a run: its scene's every resolved key, and ``reference``."""
    text = json.dumps({"scene": name, "config": sorted(config.items()), "reference": reference},
                      default=repr, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def plan_sweep(scene: str, *, grids=(), values=(), samples=(), n_samples: int | None = None,
               seed: int | None = None, overrides=(), reference: bool = False) -> SweepPlan:
    """Parse and validate a sweep: every point's scene is validated here (a
    :class:`ConfigError` names the first bad one)."""
    axes = [parse_grid(g) for g in grids] + [parse_values(v) for v in values]
    samplers = [s for item in samples for s in parse_sample(item)]
    if not axes and not samplers:
        raise ConfigError("nothing to sweep: give --grid, --values or --sample")
    if samplers and n_samples is None:
        raise ConfigError("--sample needs --samples N")
    if n_samples is not None and not samplers:
        raise ConfigError("--samples needs --sample KEY=DIST")
    if n_samples is not None and (isinstance(n_samples, bool) or n_samples < 1):
        raise ConfigError(f"--samples {n_samples} is not allowed; allowed: an integer >= 1")
    if seed is not None and seed < 0:
        raise ConfigError(f"--seed {seed} is not allowed; allowed: an integer >= 0")
    swept = [a.key for a in axes] + [s.key for s in samplers]
    for k in swept:
        if swept.count(k) > 1:
            raise ConfigError(f"{k} is swept twice")
    design_items = [o for o in overrides if parse_override(o)[0].startswith("design.")]
    scene_items = [o for o in overrides if o not in design_items]
    for o in scene_items:
        if parse_override(o)[0] in swept:
            raise ConfigError(f"--set {o!r}: {parse_override(o)[0]} is also swept")
    base = load_scene(scene, scene_items)
    uncertainty = None
    if any(s.dist == "design" for s in samplers):
        from .design import DESIGN_DEFAULTS, UncertaintySet, design_settings
        known = dict(DESIGN_DEFAULTS)
        pairs = [parse_override(o) for o in design_items]
        try:
            check_known([k for k, _ in pairs], known)
        except ConfigError as exc:
            raise ConfigError(f"--set: {exc}") from None
        settings = design_settings({**known, **dict(pairs)})
        nominal = base.plant if base["plant.n_modes"] != "auto" else \
            scene_from_config(base.name, {**base.config, "plant.n_modes": 0}).plant
        uncertainty = UncertaintySet.from_settings(nominal, settings)
    elif design_items:
        raise ConfigError(f"--set {design_items[0]!r}: design.* keys shape the design's "
                          "uncertainty set; they need --sample design (or KEY=design)")
    seed = 0 if seed is None and samplers else seed
    drawn = draw_samples(samplers, n_samples, seed, uncertainty) if samplers else {}
    points = []
    sample_ids = range(n_samples) if samplers else [None]
    for combo in itertools.product(*(a.values for a in axes), sample_ids):
        *grid_values, j = combo
        params = dict(zip((a.key for a in axes), grid_values))
        if j is not None:
            params.update({s.key: drawn[s.key][j] for s in samplers})
        try:
            sc = scene_from_config(base.name, {**base.config, **params})
        except ConfigError as exc:
            where = ", ".join(f"{k}={v!r}" for k, v in params.items())
            raise ConfigError(f"run {len(points)} ({where}): {exc}") from None
        points.append(Point(len(points), params, j, sc.config,
                            run_key(base.name, sc.config, reference)))
    return SweepPlan(base, axes, samplers, n_samples or 0, seed, reference, points,
                     list(overrides), uncertainty,
                     settings["design.check_levels"] if uncertainty is not None else 5)


# ---------------------------------------------------------------------------- one run
def summary_row(summary: dict) -> dict:
    """The table's fields of one run, from its summary (:func:`orchestration.summary.summarize`
    and :func:`orchestration.run.run_scene`): the one place that knows the summary's layout.

    A fitted rate is a number only where the summary found the fit reliable (the note says why
    not); ``decay_rate`` is minus the largest reliable rate; ``valid`` is False when the run
    left the model's range (``validity`` says how)."""
    stopped = summary.get("stopped") or {}
    row = {"status": "failed" if stopped else "ok", "stable": summary.get("stable")}
    rates = []
    for key in ("slow", "bending"):
        mode = summary.get(key) or {}
        linear = mode.get("linear") or {}
        row[f"{key}_rate"] = mode.get("rate")
        row[f"{key}_frequency"] = mode.get("frequency")
        row[f"{key}_rate_linear"] = linear.get("rate")
        row[f"{key}_note"] = mode.get("note")
        if mode.get("reliable"):
            rates.append(mode["rate"])
    row["decay_rate"] = -max(rates) if rates else None
    row["max_abs_F_c"] = summary.get("max_abs_F_c")
    row["max_abs_x"] = summary.get("max_abs_x")
    warnings = (summary.get("validity") or {}).get("warnings") or []
    row["valid"] = not warnings
    row["validity"] = "; ".join(warnings) or None
    if "max_error_phi_o" in summary:
        row["max_error_phi_o"] = summary["max_error_phi_o"]
        row["max_error_eta_1"] = summary["max_error_eta_1"]
    if summary.get("model"):
        row["model"] = f"{summary['model']['n_modes']} modes, {summary['model']['fidelity']}"
    row["steps"] = summary.get("steps")
    row["cosim_time"] = summary.get("wall_time")
    row["stopped_at"] = stopped.get("time")
    row["message"] = stopped.get("reason")
    return row


def linear_decay_rate(scene: Scene) -> float:
    """The linearised loop's smallest decay rate ``-max Re(lambda)`` over all its roots, the
    cart's drift roots left aside: ``flexpend design``'s criterion, for this one plant."""
    from .analysis import max_real_part
    return -max_real_part(scene.plant, scene.controller)


def _one_line(exc: BaseException, limit: int = 500) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:limit]


@lru_cache(maxsize=None)
def model_sources_digest() -> str:
    """sha256 of this process's model packages (``plant_fmu``, ``controller_fmu``: Python and C
    sources). A pythonfmu FMU runs the packages already imported in its process, so a worker
    whose digest differs from the client's would not run the client's model."""
    import controller_fmu
    import plant_fmu

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
    folder removed when this process exits."""
    if path not in _EXTRACTED:
        import atexit
        import shutil
        import tempfile

        from fmpy import extract

        from .parallel import scratch_dir
        folder = tempfile.mkdtemp(prefix="flexpend_fmu_", dir=scratch_dir())
        _EXTRACTED[path] = extract(path, unzipdir=folder)
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return _EXTRACTED[path]


def run_task(task) -> dict:
    """Run one point on a worker (or here): ``(name, config, reference, fmus, sources)``;
    ``fmus`` maps ``plant``/``controller`` to ``(shipped name, client path)``, ``sources`` is the
    client's :func:`model_sources_digest`. Never raises: a failure is a row with its message."""
    from .parallel import worker_file
    from .run import run_scene

    name, config, reference, fmus, sources = task
    t0 = time.perf_counter()
    try:
        paths = {role: worker_file(ship, path) for role, (ship, path) in fmus.items()}
        if sources != model_sources_digest():
            raise RuntimeError("this worker's flexpend model sources differ from the client's: "
                               "install the client's version on the workers")
        r = run_scene(Scene(name, dict(config)), paths, reference=reference, progress=False,
                      unzipdirs={role: _extracted(p) for role, p in paths.items()})
        row = summary_row(r.summary)
        row["linear_decay_rate"] = linear_decay_rate(r.scene)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, never the end of a sweep
        row = {"status": "failed", "message": _one_line(exc)}
    row["wall_time"] = time.perf_counter() - t0
    return row


# ---------------------------------------------------------------------------- journal, table
class Journal:
    """``DIR/runs.jsonl``: one JSON row per finished run, appended and flushed at once."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / JOURNAL

    def read(self) -> dict:
        """key -> the newest row of that key (a torn last line, from a kill, is skipped)."""
        rows = {}
        if self.path.is_file():
            for line in self.path.read_text().splitlines():
                try:
                    row = json.loads(line)
                except ValueError:
                    continue
                if isinstance(row, dict) and "key" in row:
                    rows[row["key"]] = row
        return rows

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "a+")
        self._fh.seek(0, os.SEEK_END)
        if self._fh.tell():                  # start on a fresh line after a torn one
            self._fh.seek(self._fh.tell() - 1)
            last = self._fh.read(1)
            if last != "\n":
                self._fh.write("\n")
        return self

    def append(self, row: dict):
        self._fh.write(json.dumps(row) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def __exit__(self, *exc):
        self._fh.close()


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
    for stale in ("sweep.parquet", "sweep.csv"):
        (folder / stale).unlink(missing_ok=True)
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
        path = folder / "sweep.parquet"
        pq.write_table(pa.table(arrays), path)
        return path
    import csv
    path = folder / "sweep.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in rows:
            w.writerow(["" if r.get(c) is None else repr(r[c]) if isinstance(r.get(c), float)
                        else r[c] for c in cols])
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
        if k in ("message", "key", "status", "model", "validity") or k.endswith("_note"):
            return v
        if v in ("True", "False"):
            return v == "True"
        return parse_value(v)
    return [{k: cell(k, v) for k, v in r.items()} for r in rows]


# ---------------------------------------------------------------------------- progress
class SweepProgress:
    """A bar on stderr: finished, failed and remaining runs, the elapsed time and an estimate
    of the rest. On a terminal it redraws one line; otherwise it prints a line every 10 %."""

    def __init__(self, total: int, stream=None):
        self.total, self.stream = max(total, 0), stream or sys.stderr
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


def _row(point: Point, result: dict, plan: SweepPlan) -> dict:
    """The point's identity (run number, key, swept values, sample), then ``result``'s fields
    (a journal row's identity fields are the point's own)."""
    row = {"run": point.index, "key": point.key}
    row.update({k: point.params.get(k) for k in plan.keys})
    if plan.samplers:
        row["sample"] = point.sample
    row.update((k, v) for k, v in result.items() if k not in row and k != "sample")
    return row


def fmus_for(plan: SweepPlan) -> dict:
    """``{flavour: {"plant": path, "controller": path}}`` for the FMU flavours (``master.fmus``)
    the plan's runs use, built if missing or stale."""
    from .export import build_fmus, fmu_pair
    return {fl: fmu_pair(build_fmus(flavour=fl))
            for fl in dict.fromkeys(p.config["master.fmus"] for p in plan.points)}


def pending(plan: SweepPlan, out_dir, retry_failed: bool = False) -> int:
    """How many runs of ``plan`` have no finished row in ``out_dir`` yet."""
    results = Journal(Path(out_dir)).read()
    done_status = ("ok",) if retry_failed else DONE
    return len({p.key for p in plan.points
                if results.get(p.key, {}).get("status") not in done_status})


def run_sweep(plan: SweepPlan, fmus: dict, out_dir, executor=None, *, batch: int = 1,
              retry_failed: bool = False, progress=True, plot: bool = True) -> SweepResult:
    """Run the points of ``plan`` that ``out_dir`` has no finished row for, with ``executor``
    (:mod:`orchestration.parallel`; ``None``: serially here); write the table and the plot.

    ``fmus``: ``{"plant": path, "controller": path}`` for every run, or ``{flavour: {...}}``
    per scene key ``master.fmus`` (built once by the caller, :func:`fmus_for`; a dask executor
    must have been opened with ``files=`` these paths)."""
    from .parallel import Executor, TaskLost, file_name

    executor = executor or Executor()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    journal = Journal(out_dir)
    done_status = ("ok",) if retry_failed else DONE
    results = journal.read()
    # one task per key: points whose scenes resolve alike (repeated integer draws) run once
    todo = list({p.key: p for p in plan.points
                 if results.get(p.key, {}).get("status") not in done_status}.values())
    by_flavour = {None: fmus} if "plant" in fmus else fmus
    shipped = {fl: {role: (file_name(path), str(path)) for role, path in pair.items()}
               for fl, pair in by_flavour.items()}

    def pair(p):
        return shipped[None] if None in shipped else shipped[p.config["master.fmus"]]
    tasks = [(plan.scene.name, p.config, plan.reference, pair(p), model_sources_digest())
             for p in todo]
    bar = SweepProgress(len(todo), None if progress is True else progress) if progress else None
    t0 = time.perf_counter()
    with journal:
        for i, result in executor.map(run_task, tasks, batch=batch):
            if isinstance(result, TaskLost):
                result = {"status": "lost", "message": result.message}
            row = _row(todo[i], result, plan)
            journal.append(row)
            results[row["key"]] = row
            if bar is not None:
                bar.update(row["status"])
    seconds = time.perf_counter() - t0
    ordered = [_row(p, results[p.key], plan) for p in plan.points]
    skipped = len({p.key for p in plan.points}) - len(todo)
    out = SweepResult(ordered, len(todo), skipped, seconds)
    out.table = write_table(ordered, out_dir)
    if plot:
        out.plot = plot_sweep(plan, ordered, out_dir / "sweep.png")
    return out


def sweep_stats(rows) -> dict:
    """Counts, the fraction of stable runs and the decay rates (worst, median, best) of the
    finished runs."""
    n = len(rows)
    ok = [r for r in rows if r["status"] == "ok"]
    decays = [r for r in ok if r.get("decay_rate") is not None]
    out = {"runs": n, "ok": len(ok), "failed": sum(r["status"] == "failed" for r in rows),
           "lost": sum(r["status"] == "lost" for r in rows),
           "stable": sum(r.get("stable") is True for r in rows),
           "unstable": sum(r.get("stable") is False for r in rows),
           "invalid": sum(r.get("valid") is False for r in rows)}
    finished = out["ok"] + out["failed"]
    out["no_verdict"] = finished - out["stable"] - out["unstable"]
    out["stable_fraction"] = out["stable"] / finished if finished else None
    if decays:
        worst = min(decays, key=lambda r: r["decay_rate"])
        vals = [r["decay_rate"] for r in decays]
        out.update(worst_decay_rate=worst["decay_rate"], worst_run=worst["run"],
                   median_decay_rate=float(np.median(vals)), best_decay_rate=max(vals))
    lin = [r for r in ok if r.get("linear_decay_rate") is not None]
    if lin:
        worst = min(lin, key=lambda r: r["linear_decay_rate"])
        out.update(worst_linear_decay_rate=worst["linear_decay_rate"],
                   worst_linear_run=worst["run"])
    return out


# ---------------------------------------------------------------------------- plots
def design_worst_case(plan: SweepPlan):
    """``flexpend design``'s worst case of the scene's controller over the sampled uncertainty
    set (its check grid, :func:`orchestration.design.worst_cases`), or None without a design
    sample."""
    if plan.uncertainty is None:
        return None
    from .design import worst_cases
    return worst_cases(plan.uncertainty.plants(plan.check_levels), [plan.scene.controller])[0]


def _label(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _ticks(ax, axis, values, which):
    n = len(values)
    step = max(1, math.ceil(n / 10))
    pos = list(range(0, n, step))
    getattr(ax, f"set_{which}ticks")(pos)
    getattr(ax, f"set_{which}ticklabels")([_label(values[i]) for i in pos],
                                          rotation=45 if which == "x" and n > 5 else 0)
    getattr(ax, f"set_{which}label")(axis.key + (" (log grid)" if axis.log else ""))


def _decay(r):
    v = r.get("decay_rate") if r["status"] == "ok" else None
    return math.nan if v is None else v


def plot_sweep(plan: SweepPlan, rows, path: Path) -> Path | None:
    """Heat map (2 swept axes), line plot (1 axis) or histogram (a sample) of the decay rate
    ``-max(fitted rate)``; failed runs marked. None when the sweep has no such shape."""
    from .plots import _pyplot

    title = f"flexpend sweep {plan.scene.name}" + (
        f" ({' '.join('--set ' + o for o in plan.overrides)})" if plan.overrides else "")
    failed = [r for r in rows if r["status"] != "ok"]
    if plan.samplers:
        plt = _pyplot()
        fig, ax = plt.subplots(figsize=(8, 5))
        vals = np.array([_decay(r) for r in rows])
        vals = vals[np.isfinite(vals)]
        lin = np.array([r.get("linear_decay_rate") for r in rows if r["status"] == "ok"
                        and r.get("linear_decay_rate") is not None], dtype=float)
        design = design_worst_case(plan)
        if len(vals):
            marks = [*vals, *lin, *([] if design is None else [design.decay])]
            lo, hi = min(marks), max(marks)
            pad = 0.05 * (hi - lo or 1.0)
            bins = np.linspace(lo - pad, hi + pad, max(10, min(60, int(np.sqrt(len(vals))) * 2)))
            ax.hist(vals, bins=bins, color="C0", edgecolor="white",
                    label="co-simulation: -max(fitted rate)")
            if len(lin):
                ax.hist(lin, bins=bins, histtype="step", color="C1", lw=1.5,
                        label="linearised loop: -max Re(lambda)")
            ax.axvline(vals.min(), color="C0", lw=1.2, ls=":",
                       label=f"worst fitted {vals.min():+.4g} 1/s")
            if design is not None:
                ax.axvline(design.decay, color="k", lw=1.2, ls="--",
                           label=f"flexpend design's worst case over the set (linear) "
                                 f"{design.decay:+.4g} 1/s")
            if lo - pad < 0 < hi + pad:
                ax.axvline(0.0, color="r", lw=1, label="0: grows to the left")
            ax.legend(fontsize=8)
        ax.set_xlabel("decay rate, 1/s")
        ax.set_ylabel("runs")
        keys = ", ".join(s.key for s in plan.samplers)
        ax.set_title(f"{title}\n{len(rows)} runs ({len(plan.points) // max(plan.n_samples, 1)} "
                     f"x {plan.n_samples} samples of {keys}, seed {plan.seed}); "
                     f"{len(failed)} failed, {len(rows) - len(failed) - len(vals)} without a fit",
                     fontsize=9)
    elif len(plan.axes) == 1:
        plt = _pyplot()
        axis = plan.axes[0]
        fig, ax = plt.subplots(figsize=(8, 5))
        x = np.arange(len(axis.values))
        for col, label, style in (("decay_rate", "decay rate -max(fitted rate)", "k-o"),
                                  ("linear_decay_rate", "linearised loop: -max Re(lambda)",
                                   "k:"),
                                  ("slow_rate", "slow (rigid) rate, fitted", "C0--s"),
                                  ("bending_rate", "bending rate, fitted", "C1--^")):
            y = [math.nan if r["status"] != "ok" or r.get(col) is None else r[col] for r in rows]
            ax.plot(x, y, style, ms=4, lw=1.2, label=label)
        bad = [i for i, r in enumerate(rows) if r["status"] != "ok"]
        if bad:
            ax.plot(bad, [0.0] * len(bad), "rx", ms=9, mew=2, label="failed run")
        ax.axhline(0.0, color="0.5", lw=0.8)
        _ticks(ax, axis, axis.values, "x")
        ax.set_ylabel("1/s")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        ax.set_title(title, fontsize=9)
    elif len(plan.axes) == 2:
        plt = _pyplot()
        from matplotlib.colors import TwoSlopeNorm
        ax0, ax1 = plan.axes
        grid = np.array([_decay(r) for r in rows]).reshape(len(ax0.values), len(ax1.values))
        fig, ax = plt.subplots(figsize=(9, 6.5))
        finite = grid[np.isfinite(grid)]
        # colours up to the 5th/95th percentile (one outlier does not wash out the rest); the
        # cells of a small grid carry their values
        lim = max(float(np.percentile(np.abs(finite), 95)) if finite.size else 1.0, 1e-12)
        im = ax.imshow(np.ma.masked_invalid(grid.T), origin="lower", aspect="auto",
                       cmap="RdBu", norm=TwoSlopeNorm(vmin=-lim, vcenter=0.0, vmax=lim))
        if grid.size <= 150:
            for (i, j), v in np.ndenumerate(grid):
                if np.isfinite(v):
                    ax.text(i, j, f"{v:+.3g}", ha="center", va="center", fontsize=7,
                            color="w" if abs(v) > 0.6 * lim else "k")
        for r in failed:
            i, j = divmod(r["run"], len(ax1.values))
            ax.plot(i, j, "kx", ms=9, mew=2)
        _ticks(ax, ax0, ax0.values, "x")
        _ticks(ax, ax1, ax1.values, "y")
        fig.colorbar(im, ax=ax, extend="both",
                     label="decay rate -max(fitted rate), 1/s (red: grows)")
        ax.set_title(title + "\nx: failed run; grey: no fit", fontsize=9)
    else:
        return None
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
