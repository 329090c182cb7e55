"""Robust design of the low-pass filter: the filter that keeps the largest worst-case stability
margin over an uncertainty set of beams.

The PD gains are given; the search runs over the filter order (1 and 2), the cutoff and, for the
second order, the filter damping. A candidate is scored by its worst case over the uncertainty set
(by default: ``n_modes`` 2..8, structural damping 0.05 %..0.2 %, ``EI`` +-10 %, cart mass +-20 %):

- ``decay``: the smallest closed-loop decay rate ``-max Re(lambda)`` (1/s), the cart's drift roots
  left aside as in :mod:`orchestration.studies.analysis`;
- ``damping``: the smallest damping ratio ``-Re(lambda)/|lambda|`` of any closed-loop root.

The search evaluates a grid of candidates on a coarse grid of the uncertainty set (``levels``
values of each continuous parameter, every ``n_modes``), refines the best candidate of each order
by Nelder-Mead, rounds it (three significant digits of the cutoff, two decimals of the damping)
and reports its worst case on a finer grid (``check_levels``), which the search did not see.
All closed loops of one size are built and solved as one stack (``numpy.linalg.eigvals`` on a
3-d array), so one candidate over the 189 plants of the default set costs a few milliseconds.

A sampled controller (``controller.sample_period > 0``, docs/sampled.md) is designed for its
sample period, delay and discretization: a candidate's closed loops are the sampled ones
(:mod:`orchestration.studies.sampled`: the plant's exact zero-order hold with the delay, the
filter's difference equation, :func:`controller_fmu.sampled.filter_difference_equation`), and
their roots are the s-plane equivalents ``log(z) / T`` of the z-plane poles. The criteria are the
same: the worst-case decay rate ``-max Re(log z) / T = -log(max |z|) / T`` ranks the candidates
as the spectral radius does (at a fixed ``T``), with the unit circle as the stability boundary.
With the Tustin filter the cutoffs searched stop below the Nyquist limit of its prewarping,
:data:`NYQUIST_FRACTION` ``* pi / T``.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.spec import model_for as controller_model
from fmu_common.checks import check_int, check_real
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams

from ..scene.keys import ConfigError
from .analysis import _drift_free, assemble_closed_loop, frequency_response

__all__ = ["DESIGN_DEFAULTS", "CRITERIA", "NYQUIST_FRACTION", "UncertaintySet", "RobustLoop", "WorstCase",
           "DesignResult", "design_settings", "design_filter", "root_locus", "FILTER_KEYS",
           "worst_cases", "DesignCurves", "design_curves"]

#: A sampled Tustin filter's cutoffs are searched up to this fraction of ``pi / T`` (the rounding
#: of the chosen cutoff to three digits then stays below the limit).
NYQUIST_FRACTION = 0.99

#: Scores of a candidate filter: the worst-case decay rate or the worst-case damping ratio.
CRITERIA = ("decay", "damping")
#: The filter's scene keys, as the design reports them.
FILTER_KEYS = ("controller.filter_order", "controller.cutoff", "controller.filter_damping")

#: ``design.*`` keys of ``flexpend design`` with their defaults.
DESIGN_DEFAULTS = {
    "design.criterion": "decay",
    "design.n_modes_min": 2,
    "design.n_modes_max": 8,
    "design.zeta_min": 5e-4,
    "design.zeta_max": 2e-3,
    "design.EI_spread": 0.1,
    "design.m_spread": 0.2,
    "design.levels": 3,
    "design.check_levels": 5,
    "design.cutoff_min": 20.0,
    "design.cutoff_max": 1000.0,
    "design.n_cutoffs": 41,
    "design.damping_min": 0.1,
    "design.damping_max": 2.0,
    "design.n_dampings": 20,
}


def design_settings(cfg: dict) -> dict:
    """The validated ``design.*`` keys of a configuration (a :class:`ConfigError` names a bad
    one)."""
    out = {k: cfg.get(k, v) for k, v in DESIGN_DEFAULTS.items()}
    try:
        if out["design.criterion"] not in CRITERIA:
            raise ValueError(f"design.criterion = {out['design.criterion']!r} is not allowed; "
                             f"allowed: {', '.join(CRITERIA)}")
        for k, lo, hi in (("design.n_modes_min", 1, 40), ("design.n_modes_max", 1, 40),
                          ("design.levels", 2, 11), ("design.check_levels", 2, 21),
                          ("design.n_cutoffs", 3, 1000), ("design.n_dampings", 2, 1000)):
            out[k] = check_int(k, out[k], low=lo, high=hi)
        for k in ("design.zeta_min", "design.zeta_max"):
            out[k] = check_real(k, out[k], low=0.0, high=1.0, high_open=True)
        for k in ("design.EI_spread", "design.m_spread"):
            out[k] = check_real(k, out[k], low=0.0, high=1.0, low_open=False, high_open=True)
        for k in ("design.cutoff_min", "design.cutoff_max"):
            out[k] = check_real(k, out[k], low=0.0, high=1e7)
        for k in ("design.damping_min", "design.damping_max"):
            out[k] = check_real(k, out[k], low=0.0, high=100.0)
        for lo, hi in (("n_modes_min", "n_modes_max"), ("zeta_min", "zeta_max"),
                       ("cutoff_min", "cutoff_max"), ("damping_min", "damping_max")):
            if out[f"design.{lo}"] > out[f"design.{hi}"]:
                raise ValueError(f"design.{lo} = {out[f'design.{lo}']} exceeds design.{hi} = "
                                 f"{out[f'design.{hi}']}")
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    return out


@dataclass(frozen=True)
class UncertaintySet:
    """Beams around ``nominal``: every ``n_modes`` in ``n_modes``, structural damping in
    ``zeta`` (absolute), ``EI`` and cart mass ``m`` within ``+-EI_spread`` and ``+-m_spread``
    (relative to the nominal)."""

    nominal: PlantParams
    n_modes: tuple = (2, 8)
    zeta: tuple = (5e-4, 2e-3)
    EI_spread: float = 0.1
    m_spread: float = 0.2

    @classmethod
    def from_settings(cls, nominal: PlantParams, s: dict) -> "UncertaintySet":
        return cls(nominal, (s["design.n_modes_min"], s["design.n_modes_max"]),
                   (s["design.zeta_min"], s["design.zeta_max"]), s["design.EI_spread"],
                   s["design.m_spread"])

    def axes(self, levels: int) -> dict:
        """The grid's values per parameter: ``levels`` values of each continuous one, ends
        included (damping spaced geometrically, EI and m linearly)."""
        p = self.nominal
        return {
            "n_modes": list(range(self.n_modes[0], self.n_modes[1] + 1)),
            "zeta": [float(z) for z in np.geomspace(*self.zeta, levels)],
            "EI": [float(p.EI * f) for f in np.linspace(1 - self.EI_spread, 1 + self.EI_spread, levels)],
            "m": [float(p.m * f) for f in np.linspace(1 - self.m_spread, 1 + self.m_spread, levels)],
        }

    def plants(self, levels: int) -> list[PlantParams]:
        """Every combination of :meth:`axes` (the ends of each range included)."""
        ax = self.axes(levels)
        return [self.nominal.replace(n_modes=n, zeta=z, EI=e, m=m)
                for n, z, e, m in itertools.product(*ax.values())]

    def sample(self, rng: np.random.Generator, n: int) -> dict:
        """``n`` random beams of the set, ``{"n_modes": [...], "zeta": [...], "EI": [...],
        "m": [...]}``: ``n_modes`` uniform over its integers, the damping log-uniform (the grid
        spaces it geometrically), ``EI`` and ``m`` uniform within their spreads.

        Beam ``i`` is made from the ``i``-th row of ``rng.random((n, 4))``, so the first ``k``
        of ``n`` samples are the ``k`` samples of the same seed (a sample can be extended)."""
        u = rng.random((int(n), 4))
        lo, hi = self.n_modes
        modes = np.minimum(lo + np.floor(u[:, 0] * (hi - lo + 1)), hi).astype(int)
        z0, z1 = self.zeta
        zeta = (np.exp(np.log(z0) + u[:, 1] * (np.log(z1) - np.log(z0))) if z0 > 0
                else z0 + u[:, 1] * (z1 - z0))
        p = self.nominal
        return {"n_modes": [int(v) for v in modes], "zeta": [float(v) for v in zeta],
                "EI": [float(p.EI * (1 - self.EI_spread + 2 * self.EI_spread * v))
                       for v in u[:, 2]],
                "m": [float(p.m * (1 - self.m_spread + 2 * self.m_spread * v)) for v in u[:, 3]]}

    def describe(self) -> dict:
        return {"n_modes": list(self.n_modes), "zeta": list(self.zeta),
                "EI": [self.nominal.EI * (1 - self.EI_spread), self.nominal.EI * (1 + self.EI_spread)],
                "m": [self.nominal.m * (1 - self.m_spread), self.nominal.m * (1 + self.m_spread)]}


@dataclass
class WorstCase:
    """The worst closed loop of a controller over a set of plants."""

    decay: float                 # smallest decay rate -max Re(lambda), 1/s (negative: unstable)
    damping: float               # smallest damping ratio of any root
    decay_plant: PlantParams     # where they occur
    damping_plant: PlantParams
    decay_root: complex          # the root with the smallest decay rate
    damping_root: complex
    n_plants: int

    def score(self, criterion: str) -> float:
        return self.decay if criterion == "decay" else self.damping

    @property
    def stable(self) -> bool:
        return self.decay > 0

    def to_json(self) -> dict:
        def plant(p):
            return {"n_modes": p.n_modes, "zeta": p.zeta, "EI": p.EI, "m": p.m}
        return {"stable": self.stable, "decay_rate": self.decay, "damping_ratio": self.damping,
                "decay_rate_at": plant(self.decay_plant),
                "decay_rate_root": [self.decay_root.real, self.decay_root.imag],
                "damping_ratio_at": plant(self.damping_plant),
                "damping_ratio_root": [self.damping_root.real, self.damping_root.imag],
                "plants": self.n_plants}


class RobustLoop:
    """Closed loops of one controller with many plants, grouped by size and solved as stacks."""

    def __init__(self, plants):
        groups: dict[int, list[PlantParams]] = {}
        for p in plants:
            groups.setdefault(p.n_modes, []).append(p)
        self.groups = []
        for n, ps in sorted(groups.items()):
            ss = [plant_model(p).state_space() for p in ps]
            A, B, C = (np.stack([s[i] for s in ss]) for i in range(3))
            self.groups.append((ps, A, B, C))
        self.n_plants = sum(len(g[0]) for g in self.groups)
        self._held = {}             # the plants' zero-order holds, per (group, T, tau, kx)

    def eigenvalues(self, c: ControllerParams):
        """``(plants, roots)`` per group; ``roots[k]`` are the closed-loop roots with
        ``plants[k]``, the cart's drift roots left aside when the cart is not fed back. A sampled
        controller's roots are the s-plane equivalents ``log(z) / T`` of its sampled loop's
        poles (``-inf`` for ``z = 0``)."""
        if c.sampled:
            for g, (ps, *_) in enumerate(self.groups):
                yield ps, self._sampled_roots(g, c)
            return
        ctrl = controller_model(c).state_space()
        for ps, A, B, C in self.groups:
            yield ps, np.linalg.eigvals(_drift_free(assemble_closed_loop(A, B, C, ctrl), ps[0]))

    def _sampled_roots(self, g: int, c: ControllerParams) -> np.ndarray:
        """The sampled loops of group ``g`` with ``c`` as one stack (the assembly of
        :func:`orchestration.studies.sampled.sampled_loop`); the plants' holds computed once."""
        from controller_fmu.sampled import filter_difference_equation

        from .sampled import _reduced_plant, plant_discretisation

        T, tau = c.sample_period, c.delay
        key = (g, T, tau, c.kx == 0.0)
        if key not in self._held:
            rows = []
            for p in self.groups[g][0]:
                A, B, C = _reduced_plant(p, c)
                rows.append((*plant_discretisation(A, B, T, tau), C))
            self._held[key] = tuple(np.stack([r[i] for r in rows]) for i in range(4))
        Phi, G_prev, G_new, C = self._held[key]
        Ad, Bd, Cd, Dd = filter_difference_equation(c)
        ge = np.array([[c.kx, c.kp, c.kd]]) @ C               # (k, 1, n): e_k = ge x_k
        Kx, Kf = -Dd @ ge, -Cd                                # F_k = Kx x_k + Kf xf_k
        k, n, nf = Phi.shape[0], Phi.shape[1], Ad.shape[0]
        prev = tau > 0.0
        N = n + nf + (1 if prev else 0)
        M = np.zeros((k, N, N))
        M[:, :n, :n] = Phi + G_new @ Kx
        M[:, :n, n:n + nf] = G_new @ Kf
        M[:, n:n + nf, :n] = Bd @ ge
        M[:, n:n + nf, n:n + nf] = Ad
        if prev:
            M[:, :n, N - 1:] = G_prev
            M[:, N - 1:, :n] = Kx
            M[:, N - 1:, n:n + nf] = Kf
        z = np.linalg.eigvals(M).astype(complex)
        with np.errstate(divide="ignore"):
            return np.log(z) / T

    def worst(self, c: ControllerParams) -> WorstCase:
        best = {"decay": (math.inf, None, None), "damping": (math.inf, None, None)}
        for ps, lam in self.eigenvalues(c):
            decay = -lam.real                                   # (k, m)
            finite = np.isfinite(lam.real)                      # a sampled pole z = 0: -inf
            mag = np.where(finite, np.abs(lam), 0.0)
            zeta = np.where(mag > 0, -lam.real / np.where(mag > 0, mag, 1.0), 1.0)
            for key, vals in (("decay", decay), ("damping", zeta)):
                k, j = np.unravel_index(np.argmin(vals), vals.shape)
                if vals[k, j] < best[key][0]:
                    best[key] = (float(vals[k, j]), ps[k], complex(lam[k, j]))
        (d, dp, dr), (z, zp, zr) = best["decay"], best["damping"]
        return WorstCase(d, z, dp, zp, dr, zr, self.n_plants)


def _worst_of_chunk(task):
    plants, controllers = task
    loop = RobustLoop(plants)
    return [loop.worst(c) for c in controllers]


def worst_cases(plants, controllers, executor=None, chunks: int | None = None) -> list:
    """:meth:`RobustLoop.worst` of each of ``controllers`` over ``plants``.

    Without ``executor``, one :class:`RobustLoop` here. With one
    (:mod:`orchestration.sweeps.executor`), the plants, ordered as a :class:`RobustLoop` orders them
    (by ``n_modes``, stably), are cut into ``chunks`` contiguous pieces (default: 4 per worker)
    run as tasks, and the pieces' worst cases are merged in order, keeping the first of equal
    values: each closed loop's eigenvalues are computed alone, so the result is the serial one,
    number for number."""
    plants, controllers = list(plants), list(controllers)
    if executor is None:
        return _worst_of_chunk((plants, controllers))
    plants.sort(key=lambda p: p.n_modes)
    n = max(1, min(len(plants), chunks or 4 * max(1, executor.workers)))
    bounds = np.linspace(0, len(plants), n + 1).round().astype(int)
    tasks = [(plants[a:b], controllers) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    parts = [None] * len(tasks)
    for i, value in executor.map(_worst_of_chunk, tasks):
        if not isinstance(value, list):      # a lost task: no partial worst case
            raise RuntimeError(f"design check grid: a task was lost: {value.message}")
        parts[i] = value
    out = []
    for k in range(len(controllers)):
        best = parts[0][k]
        decay = (best.decay, best.decay_plant, best.decay_root)
        damping = (best.damping, best.damping_plant, best.damping_root)
        for part in parts[1:]:
            w = part[k]
            if w.decay < decay[0]:
                decay = (w.decay, w.decay_plant, w.decay_root)
            if w.damping < damping[0]:
                damping = (w.damping, w.damping_plant, w.damping_root)
        out.append(WorstCase(decay[0], damping[0], decay[1], damping[1], decay[2], damping[2],
                             sum(part[k].n_plants for part in parts)))
    return out


def _filter(base: ControllerParams, order: int, cutoff: float, damping: float) -> ControllerParams:
    return base.replace(filter_order=order, cutoff=float(cutoff), filter_damping=float(damping))


def _round(order: int, cutoff: float, damping: float) -> tuple:
    """Three significant digits of the cutoff, two decimals of the damping (what a scene holds)."""
    digits = 2 - int(math.floor(math.log10(cutoff)))
    return order, round(cutoff, digits), (round(damping, 2) if order == 2 else damping)


@dataclass
class DesignResult:
    criterion: str
    uncertainty: UncertaintySet
    chosen: ControllerParams
    worst: WorstCase                       # of the chosen filter, on the check grid
    per_order: dict                        # order -> (ControllerParams, WorstCase on check grid)
    baseline: dict                         # label -> (ControllerParams, WorstCase on check grid)
    grid: list = field(default_factory=list)    # rows: order, cutoff, filter_damping, decay, damping
    sweep: dict = field(default_factory=dict)   # label -> (cutoffs, worst-case score)
    levels: int = 3
    check_levels: int = 5

    def __repr__(self) -> str:
        """One line: the filter chosen, its worst case, the criterion."""
        c, w = self.chosen, self.worst
        return (f"DesignResult(order {c.filter_order}, cutoff {c.cutoff:g} rad/s, damping "
                f"{c.filter_damping:g}; worst decay rate {w.decay:.4g} 1/s, damping ratio "
                f"{w.damping:.4g}; criterion {self.criterion})")

    def filter_keys(self) -> dict:
        c = self.chosen
        return {"controller.filter_order": c.filter_order, "controller.cutoff": c.cutoff,
                "controller.filter_damping": c.filter_damping}

    def to_json(self) -> dict:
        def ctrl(c):
            return {"controller.filter_order": c.filter_order, "controller.cutoff": c.cutoff,
                    "controller.filter_damping": c.filter_damping}
        c = self.chosen
        return {
            "criterion": self.criterion,
            **({"sampled": {"T": c.sample_period, "tau": c.delay,
                            "discretization": c.discretization}} if c.sampled else {}),
            "filter": self.filter_keys(),
            "worst_case": self.worst.to_json(),
            "uncertainty": {**self.uncertainty.describe(),
                            "search_levels": self.levels, "check_levels": self.check_levels,
                            "check_plants": self.worst.n_plants},
            "best_per_order": {str(o): {"filter": ctrl(c), "worst_case": w.to_json()}
                               for o, (c, w) in self.per_order.items()},
            "baselines": {k: {"filter": ctrl(c), "worst_case": w.to_json()}
                          for k, (c, w) in self.baseline.items()},
        }


def design_filter(nominal: PlantParams, base: ControllerParams, settings: dict,
                  progress=None, executor=None) -> DesignResult:
    """Search the filter with the largest worst-case score (see the module's docstring).

    ``nominal`` fixes the beam around which ``EI`` and ``m`` vary (its ``n_modes`` and ``zeta``
    are replaced by the uncertainty set's); ``base`` holds the PD gains; ``settings`` are the
    validated ``design.*`` keys (:func:`design_settings`); ``progress(fraction)`` is called as the
    grid is evaluated. ``executor`` (:mod:`orchestration.sweeps.executor`) runs the check grid's closed
    loops as tasks (:func:`worst_cases`: the same numbers as without it).
    """
    import scipy.optimize           # here: importing it costs every sweep 0.3 s

    s = settings = _sampled_settings(base, settings)
    crit = s["design.criterion"]
    uset = UncertaintySet.from_settings(nominal, s)
    search = RobustLoop(uset.plants(s["design.levels"]))
    cutoffs = np.geomspace(s["design.cutoff_min"], s["design.cutoff_max"], s["design.n_cutoffs"])
    dampings = np.linspace(s["design.damping_min"], s["design.damping_max"], s["design.n_dampings"])
    cands = [(1, wc, base.filter_damping) for wc in cutoffs]
    cands += [(2, wc, zf) for wc in cutoffs for zf in dampings]
    grid = []
    for i, (order, wc, zf) in enumerate(cands):
        w = search.worst(_filter(base, order, wc, zf))
        grid.append((order, float(wc), float(zf), w.decay, w.damping))
        if progress is not None:
            progress(0.9 * (i + 1) / len(cands))
    score = 3 if crit == "decay" else 4

    def neg_score(order, x):
        wc, zf = math.exp(x[0]), (x[1] if order == 2 else base.filter_damping)
        if not (s["design.cutoff_min"] <= wc <= s["design.cutoff_max"]) or not (
                s["design.damping_min"] <= zf <= s["design.damping_max"]):
            return math.inf
        return -search.worst(_filter(base, order, wc, zf)).score(crit)

    chosen_per_order = {}
    for order in (1, 2):
        rows = [r for r in grid if r[0] == order]
        _, wc, zf, *_ = max(rows, key=lambda r: r[score])
        x0 = [math.log(wc), zf][:order]
        opt = scipy.optimize.minimize(lambda x: neg_score(order, x), x0, method="Nelder-Mead",
                                      options={"xatol": 1e-3, "fatol": 1e-6, "maxiter": 200,
                                               "initial_simplex": _simplex(x0)})
        x = opt.x if opt.fun <= neg_score(order, x0) else np.asarray(x0)
        chosen_per_order[order] = _filter(base, *_round(order, math.exp(x[0]),
                                                        x[1] if order == 2 else zf))
    # the check grid, which the search did not see: the best of each order and the baselines
    checked = [chosen_per_order[1], chosen_per_order[2], base.replace(filter_order=0), base]
    w1, w2, w_none, w_given = worst_cases(uset.plants(s["design.check_levels"]), checked,
                                          executor)
    per_order = {1: (checked[0], w1), 2: (checked[1], w2)}
    if progress is not None:
        progress(0.95)
    chosen_order = max(per_order, key=lambda o: per_order[o][1].score(crit))
    chosen, worst = per_order[chosen_order]
    baseline = {"no filter": (checked[2], w_none), "given": (checked[3], w_given)}
    # worst case against cutoff: 1st order, 2nd order at the chosen damping and at the best one
    sweep = {"1st order": (cutoffs, [r[score] for r in grid if r[0] == 1])}
    best_zf = [max((r for r in grid if r[0] == 2 and r[1] == wc), key=lambda r: r[score])[score]
               for wc in cutoffs]
    sweep["2nd order, best damping per cutoff"] = (cutoffs, best_zf)
    zf = per_order[2][0].filter_damping
    sweep[f"2nd order, zf = {zf:g}"] = (
        cutoffs, [search.worst(_filter(base, 2, wc, zf)).score(crit) for wc in cutoffs])
    if progress is not None:
        progress(1.0)
    return DesignResult(crit, uset, chosen, worst, per_order, baseline, grid, sweep,
                        s["design.levels"], s["design.check_levels"])


def _sampled_settings(base: ControllerParams, settings: dict) -> dict:
    """``settings`` with ``design.cutoff_max`` lowered to :data:`NYQUIST_FRACTION` ``* pi / T``
    for a sampled Tustin filter (the prewarping's limit); a ConfigError when no cutoff of the
    range is left."""
    if not (base.sampled and base.discretization == "tustin"):
        return settings
    top = NYQUIST_FRACTION * math.pi / base.sample_period
    if settings["design.cutoff_min"] >= top:
        raise ConfigError(f"design.cutoff_min = {settings['design.cutoff_min']:g} rad/s: the "
                          f"tustin filter at controller.sample_period = {base.sample_period:g} s "
                          f"needs a cutoff below pi / T = {math.pi / base.sample_period:.6g} "
                          "rad/s; lower design.cutoff_min or the sample period")
    if settings["design.cutoff_max"] <= top:
        return settings
    return {**settings, "design.cutoff_max": top}


def _simplex(x0):
    """Initial Nelder-Mead simplex: 10 % in cutoff, 0.05 in damping."""
    steps = [0.1, 0.05][:len(x0)]
    return [list(x0)] + [[v + (steps[i] if i == j else 0.0) for i, v in enumerate(x0)]
                         for j in range(len(x0))]


def root_locus(p: PlantParams, c: ControllerParams, cutoffs) -> tuple[np.ndarray, np.ndarray]:
    """``(cutoffs, roots)``: the closed-loop roots (cart drift left aside) of ``p`` with ``c``
    as its cutoff varies; ``roots[i]`` belongs to ``cutoffs[i]``."""
    loop = RobustLoop([p])
    roots = [next(loop.eigenvalues(c.replace(cutoff=float(wc))))[1][0] for wc in cutoffs]
    return np.asarray(cutoffs, dtype=float), np.array(roots)


@dataclass(frozen=True)
class DesignCurves:
    """The curves the design's figures draw (:func:`design_curves`, computed once with the
    design and handed to :class:`~orchestration.report.design.DesignReport`): ``w`` (rad/s) and
    ``loops``, the loop broken at the force ``L(jw)`` (:func:`~orchestration.studies.analysis.
    frequency_response`) of the PD without a filter (``"none"``), with the chosen filter
    (``"chosen"``) and, when it differs and has one, with the scene's own (``"given"``);
    ``cutoffs`` and ``roots``, the root locus over the cutoff (:func:`root_locus`)."""

    w: np.ndarray
    loops: dict
    cutoffs: np.ndarray
    roots: np.ndarray


def design_curves(result: DesignResult, p: PlantParams, c: ControllerParams,
                  settings: dict) -> DesignCurves:
    """:class:`DesignCurves` of a design ``result`` of the filter of ``c``'s PD on the nominal
    plant ``p``, with its ``settings`` (the cutoff range of the root locus)."""
    ch = result.chosen
    w = np.logspace(0, np.log10(max(20.0 * ch.cutoff, 5e3)), 3000)
    loops = {"none": frequency_response(p, c.replace(filter_order=0), w),
             "chosen": frequency_response(p, ch, w)}
    if (c.filter_order, c.cutoff, c.filter_damping) != \
            (ch.filter_order, ch.cutoff, ch.filter_damping) and c.filter_order:
        loops["given"] = frequency_response(p, c, w)
    settings = _sampled_settings(c, settings)
    cutoffs, roots = root_locus(p, ch, np.union1d(
        np.geomspace(settings["design.cutoff_min"], settings["design.cutoff_max"], 300),
        [ch.cutoff]))
    return DesignCurves(w, loops, cutoffs, roots)
