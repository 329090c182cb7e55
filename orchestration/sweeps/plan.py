"""What a sweep runs: the swept keys (grids, value lists, random samples) and every point's
validated scene (see :mod:`orchestration.sweeps`).
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..scene.keys import DESIGN_LISTED, ConfigError, check_known, parse_override, parse_value
from ..scene.records import Scene
from ..scene.schema import known_keys, load_scene, scene_from_config
from ..studies.analysis import linearisation
from ..studies.design import (
    DESIGN_DEFAULTS,
    UncertaintySet,
    design_settings,
    worst_cases,
)
from .columns import parse_columns

__all__ = ["DESIGN_KEYS", "DISTRIBUTIONS", "Axis", "Sampler", "parse_grid", "parse_values",
           "parse_sample", "draw_samples", "Point", "SweepPlan", "run_key", "plan_sweep",
           "design_worst_case", "expected_run_seconds"]


#: scene key -> the uncertainty set's parameter (``flexpend design``)
DESIGN_KEYS = {"plant.n_modes": "n_modes", "plant.zeta": "zeta", "plant.EI": "EI",
               "plant.m": "m"}


#: ``--sample`` distributions besides ``design``: name -> number of parameters
DISTRIBUTIONS = {"uniform": 2, "loguniform": 2, "normal": 2, "integers": 2}


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
        raise exc.prefixed(f"{option}: ") from None
    return key


#: The most runs one sweep plans (each run's scene is validated here, about 0.5 ms each: 100,000
#: take about a minute; a sweep of more is several sweeps into the same folder).
MAX_RUNS = 100_000


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
        try:
            return float(value)
        except OverflowError:         # beyond the largest double: the key's own check says so
            return value
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
    if isinstance(num, bool) or not isinstance(num, int) or num < 1 or num > MAX_RUNS:
        raise ConfigError(f"--grid {item!r}: NUM must be an integer 1..{MAX_RUNS}, got {num!r}")
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
    scene: Scene = field(repr=False)
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
    columns: tuple | None = None      # the result columns asked for (None: all; .columns)

    @property
    def keys(self) -> list:
        """The swept keys, in the table's order."""
        return [a.key for a in self.axes] + [s.key for s in self.samplers]

    def __repr__(self) -> str:
        """One line: the scene, the keys swept, the number of runs."""
        keys = ", ".join(self.keys)
        if len(keys) > 80:
            keys = keys[:77] + "..."
        return f"SweepPlan({self.scene.name!r} over {keys or 'nothing'}: {len(self.points)} runs)"

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
        if self.columns is not None:
            out["columns"] = list(self.columns)
        return out


def run_key(name: str, config: dict, reference: bool) -> str:
    """The digest that identifies a run: its scene's every resolved key, and ``reference``."""
    text = json.dumps({"scene": name, "config": sorted(config.items()), "reference": reference},
                      default=repr, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def plan_sweep(scene: str, *, grids=(), values=(), samples=(), n_samples: int | None = None,
               seed: int | None = None, overrides=(), reference: bool = False,
               columns=None) -> SweepPlan:
    """Parse and validate a sweep: every point's scene is validated here (a
    :class:`ConfigError` names the first bad one). ``columns``: the result columns to compute
    (:func:`~orchestration.sweeps.columns.parse_columns`; None: all)."""
    try:
        columns = parse_columns(columns)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    needs = [c for c in columns or () if c.startswith("max_error_")]
    if needs and not reference:
        raise ConfigError(f"--columns: {needs[0]} is the error against the monolithic "
                          f"reference: it needs --reference")
    if reference and columns is not None and not needs:
        raise ConfigError("--reference solves every run's monolithic reference for the columns "
                          "max_error_phi_o and max_error_eta_1: ask for one of them in --columns, "
                          "or leave --reference out")
    axes = [parse_grid(g) for g in grids] + [parse_values(v) for v in values]
    samplers = [s for item in samples for s in parse_sample(item)]
    if not axes and not samplers:
        raise ConfigError("nothing to sweep: give --grid, --values or --sample")
    if samplers and n_samples is None:
        raise ConfigError("--sample needs --samples N")
    if n_samples is not None and not samplers:
        raise ConfigError("--samples needs --sample KEY=DIST")
    if n_samples is not None and (isinstance(n_samples, bool) or not 1 <= n_samples <= MAX_RUNS):
        raise ConfigError(f"--samples {n_samples} is not allowed; allowed: an integer "
                          f"1..{MAX_RUNS}")
    runs = math.prod(len(a.values) for a in axes) * (n_samples or 1)
    if runs > MAX_RUNS:
        raise ConfigError(f"the sweep has {runs} runs; allowed: at most {MAX_RUNS} in one sweep")
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
    if "fidelity.companion" not in swept + [parse_override(o)[0] for o in scene_items]:
        # a sweep's runs state the measured bound, not the error figure, unless asked: the
        # companion run costs up to 50 default runs (the stiffened rung with 8 modes)
        scene_items = [*scene_items, "fidelity.companion=false"]
    base = load_scene(scene, scene_items)
    uncertainty = None
    if any(s.dist == "design" for s in samplers):
        known = dict(DESIGN_DEFAULTS)
        pairs = [parse_override(o) for o in design_items]
        try:
            check_known([k for k, _ in pairs], known, listed=DESIGN_LISTED)
        except ConfigError as exc:
            raise exc.prefixed("", "--set: ") from None
        settings = design_settings({**known, **dict(pairs)})
        # the nominal beam, as the scene's rung linearises it (its n_modes is the set's; 0
        # stands for "auto")
        uncertainty = UncertaintySet.from_settings(linearisation(base).params, settings)
    elif design_items:
        raise ConfigError(f"--set {design_items[0]!r}: design.* keys shape the design's "
                          "uncertainty set; they need --sample design (or KEY=design)")
    seed = 0 if seed is None and samplers else seed
    drawn = draw_samples(samplers, n_samples, seed, uncertainty) if samplers else {}
    points = []
    sample_ids = range(n_samples) if samplers else [None]
    base_config = dict(base.config)
    for combo in itertools.product(*(a.values for a in axes), sample_ids):
        *grid_values, j = combo
        params = dict(zip((a.key for a in axes), grid_values))
        if j is not None:
            params.update({s.key: drawn[s.key][j] for s in samplers})
        try:
            sc = scene_from_config(base.name, {**base_config, **params})
        except ConfigError as exc:
            where = ", ".join(f"{k}={v!r}" for k, v in params.items())
            raise ConfigError(f"run {len(points)} ({where}): {exc}") from None
        points.append(Point(len(points), params, j, sc, run_key(base.name, sc.config, reference)))
    return SweepPlan(base, axes, samplers, n_samples or 0, seed, reference, points,
                     list(overrides), uncertainty,
                     settings["design.check_levels"] if uncertainty is not None else 5, columns)


# ---------------------------------------------------------------------------- run length
#: What a run costs besides its steps: loading its FMUs, the summary's fits (s).
RUN_FIXED = 0.1
#: One communication step (s): the native FMUs on the compiled loop, on the Python loop
#: (``master.compiled = false``), the pythonfmu FMUs.
STEP_COST = {"compiled": 2e-6, "native": 5e-5, "python": 1e-4}
#: Model exchange, per simulated second (s).
MODEL_EXCHANGE_SECOND = 0.35
#: The monolithic reference (``--reference``): once, and per simulated second (s).
REFERENCE_FIXED, REFERENCE_SECOND = 1.0, 0.15


def expected_run_seconds(scene: Scene, reference: bool = False) -> float:
    """About how long one run of ``scene`` takes on one core, from its length
    (``stop_time / master.step`` steps, or ``stop_time`` on model exchange) and the constants
    above, measured on the 2-core machine of docs/sweeps.md (the 10 s filtered scene: 0.1 s).
    It decides whether a sweep starts a cluster (:func:`~orchestration.sweeps.executor.
    cluster_workers`); it is no prediction to rely on."""
    m, stop = scene.master, scene.output.stop_time
    if m.interface == "model-exchange":
        work = MODEL_EXCHANGE_SECOND * stop
    else:
        kind = "python" if m.fmus == "python" else "native" if m.compiled is False \
            else "compiled"
        work = stop / m.step * STEP_COST[kind]
    return RUN_FIXED + work + (REFERENCE_FIXED + REFERENCE_SECOND * stop if reference else 0.0)


# ---------------------------------------------------------------------------- plots
def design_worst_case(plan: SweepPlan):
    """``flexpend design``'s worst case of the scene's controller over the sampled uncertainty
    set (its check grid, :func:`orchestration.studies.design.worst_cases`), or None without a design
    sample."""
    if plan.uncertainty is None:
        return None
    return worst_cases(plan.uncertainty.plants(plan.check_levels), [plan.scene.controller])[0]

