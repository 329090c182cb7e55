"""The measured validity bound: how far a run's tip angle can be trusted on its rung of the
fidelity ladder, in radians.

Each rung (the plant's model: ``plant.fidelity``, ``plant.gravity_preload``, rigid or not) was
compared with the top rung, the geometrically exact beam (:mod:`plant_fmu.exact`, its C kernel),
over the paper scenes and a sweep of initial angles and gains (``python3 bench/validity_map.py``,
which writes ``validity_bound.json`` beside this module; the rungs under the scenes' damping law,
modal, the exact beam under its own, Kelvin-Voigt with the same ``zeta``: the file's ``damping``
says so, and the errors include the two laws' difference above the first cantilever mode). At
every output time ``t`` of every run of the sweep it recorded

* ``E(t)``: the largest ``|phi_o - phi_o(exact)|`` up to ``t`` plus the exact rung's own
  discretisation uncertainty up to ``t`` (its mesh doubled and its step halved);
* the run's features up to ``t`` (:func:`features`): the largest tip deflection ``D`` (fraction
  of L), the largest ``|omega_o|`` ``W`` (rad/s), the largest ``|phi_o|`` ``A`` (rad; the linear
  rung's error is the rotation's linearisation, which the deflection does not see), and the
  accumulated deflection ``I = integral |tip_deflection| / L dt`` (s) and the deflection's
  travel ``V = integral |d tip_deflection / dt| / L dt`` (a bending oscillation accumulates a
  phase error, cycle after cycle, that its amplitude alone does not tell; ``V`` counts its cycles
  weighted by their amplitude, measured on the output grid, which must resolve the bending: the
  scenes' grids do, ``tests/front/test_job.py``), and ``T``, the largest ``|tip_deflection| / L
  * t`` (s: an oscillation's phase error grows with the time it has run, the tip angle's error
  with the amplitude it has then);

and fitted ``E <= max(floor, sum_k c_k term_k)`` over the terms :data:`TERMS` (``D``, ``I``,
``V``, ``T``, ``W``, ``A``, ``A^3``) with ``c_k >= 0`` (a bound that grows with every feature),
the tightest that bounds every point of the fit (linear programming), times a safety factor;
``floor`` is the exact rung's own uncertainty on the stable scenes (no smaller error is claimed).
The bound is evaluated on the run's own features at its end (they only grow), so it holds from
the start to the end of the run. Nothing is simulated here: evaluating it is a few numpy
operations on the run's history.

A run leaves the rung's *measured range* when one of its features passes the largest the sweep
reached on that rung (the bound is then an extrapolation and the summary says so), or, for a rigid
rung (which sees no deflection), when its beam is softer than the one measured.
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np

__all__ = ["BOUND_FILE", "TOP", "TERMS", "RANGE", "rung_name", "term", "RungBound", "bounds",
           "cantilever_frequency", "features", "assess", "MEASURED_DAMPING", "measured_damping"]

#: The fitted bounds (reference data, written by ``python3 bench/validity_map.py``).
BOUND_FILE = Path(__file__).with_name("validity_bound.json")
#: The top rung: the reference every bound is measured against.
TOP = "exact"
#: The first root of ``1 + cos x cosh x = 0``.
BETA1_L = 1.8751040687119611


def rung_name(plant) -> str:
    """The rung of a resolved :class:`~orchestration.scene.records.PlantSetup`: ``"nonlinear"``,
    ``"linear + preload"``, ``"rigid nonlinear"``..."""
    p = plant.params
    if plant.fidelity == TOP:
        return TOP
    if p.n_modes == 0:
        return f"rigid {plant.fidelity}"
    if plant.fidelity == "stiffened":          # it carries the self-weight's stiffness always
        return plant.fidelity
    return plant.fidelity + (" + preload" if p.gravity_preload else "")


#: The bound's terms: functions of a run's features (:func:`features`).
TERMS = {"D": lambda P: P["D"], "T": lambda P: P["T"], "I": lambda P: P["I"],
         "V": lambda P: P["V"],
         "W": lambda P: P["W"], "A": lambda P: P["A"], "A3": lambda P: P["A"] ** 3}
#: The features whose largest measured values make a rung's measured range.
RANGE = ("D", "W", "A", "T", "I", "V")
_RANGE_TEXT = {"D": ("the tip deflection", "% of L"), "W": ("|omega_o|", "rad/s"),
               "A": ("|phi_o|", "rad"), "I": ("the accumulated deflection", "s"),
               "V": ("the deflection's travel", "L"),
               "T": ("the deflection times the time", "s")}


def term(P: dict, name: str) -> np.ndarray:
    """The term ``name`` of :data:`TERMS` at the features ``P`` (arrays or the columns of
    :func:`bench.validity_map.stack`), any other key (``"N"``) as it is."""
    f = TERMS.get(name)
    return np.asarray(f(P) if f else P[name], float)


class RungBound:
    """One rung's fitted bound ``max(floor, sum c_k term_k)`` and its measured range."""

    def __init__(self, name: str, entry: dict):
        self.name = name
        self.floor, self.terms = entry["model"]["floor"], entry["model"]["terms"]
        self.range = {k: entry["range"][k] for k in RANGE}
        self.min_frequency = entry["range"]["first_cantilever_frequency"]

    def __call__(self, P: dict):
        """The bound (rad) at the features ``P`` (:func:`features`)."""
        f = sum(c * term(P, k) for k, c in self.terms.items())
        return np.maximum(self.floor, f)


@functools.lru_cache(maxsize=None)
def _load(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


#: The damping laws the bounds were measured under when the file does not say (before issue 34
#: it did not: the rungs under the scenes' modal law, the exact beam under Kelvin-Voigt).
MEASURED_DAMPING = {"rungs": "modal", "exact": "kelvin-voigt"}


def measured_damping(path=BOUND_FILE) -> dict:
    """``{"rungs": law, "exact": law}``: the damping laws the bounds were measured under."""
    return dict(_load(str(path)).get("damping", MEASURED_DAMPING))


def bounds(path=BOUND_FILE) -> dict:
    """``{rung: RungBound}`` of the reference data."""
    data = _load(str(path))
    return {name: RungBound(name, e) for name, e in data["rungs"].items()}


def cantilever_frequency(p) -> float:
    """The beam's first cantilever frequency (rad/s), ``(beta_1 L)^2 sqrt(EI / (rhoA L^4))``."""
    return BETA1_L ** 2 * math.sqrt(p.EI / (p.rho * p.EA / p.E * p.L ** 4))


def features(res: np.ndarray, L: float) -> dict:
    """The run's history as the bound reads it, at every output point: the running maxima
    ``D`` of ``|tip_deflection| / L``, ``W`` of ``|omega_o|`` (rad/s) and ``A`` of ``|phi_o|``
    (rad); ``I``, the accumulated deflection ``integral |tip_deflection| / L dt`` (s), and ``V``,
    the deflection's travel ``integral |d tip_deflection / dt| / L dt`` (its total variation on
    the output grid: four amplitudes a bending period, so it counts the bending cycles weighted
    by their amplitude); ``T``, the running maximum of ``|tip_deflection| / L * t`` (s: a
    bending oscillation's phase error grows with the time it has run, its effect on the tip
    angle with its amplitude then)."""
    d = np.abs(res["tip_deflection"]) / L
    V = np.concatenate(([0.0], np.cumsum(np.abs(np.diff(res["tip_deflection"]))))) / L
    I = np.zeros(len(res))
    if len(res) > 1:
        I[1:] = np.cumsum(0.5 * (d[1:] + d[:-1]) * np.diff(res["time"]))
    return {"D": np.maximum.accumulate(d), "W": np.maximum.accumulate(np.abs(res["omega_o"])),
            "A": np.maximum.accumulate(np.abs(res["phi_o"])), "I": I, "V": V,
            "T": np.maximum.accumulate(d * res["time"])}


def assess(res: np.ndarray, scene, path=BOUND_FILE) -> dict:
    """The run's model-form error bound on its rung, where it was measured, and where the run
    leaves the measured range: ``{"rung", "model_form_error" (rad, or None without a measured
    bound), "relative" (to the largest |phi_o|), "deflection", "rate", "angle", "measured_range",
    "outside": [what left it, in words], "note", "damping": the laws it was measured under}``."""
    name = rung_name(scene.plant)
    table = bounds(path)
    L = scene.plant.params.L
    out = {"rung": name, "model_form_error": None, "relative": None, "deflection": None,
           "rate": None, "angle": None, "measured_range": None, "outside": [], "note": None,
           "damping": measured_damping(path)}
    if len(res) == 0:
        return out
    P = features(res, L)
    end = {k: v[-1] for k, v in P.items()}
    out.update(deflection=float(end["D"]), rate=float(end["W"]), angle=float(end["A"]),
               accumulated_deflection=float(end["I"]))
    b = table.get(name)
    if name == TOP:
        out["note"] = "the top rung, the reference of every measured bound"
        return out
    if b is None:
        out["note"] = (f"no measured bound for the {name} rung (measured: "
                       f"{', '.join(table)}; python3 bench/validity_map.py)")
        return out
    out["model_form_error"] = float(b(end))
    out["relative"] = out["model_form_error"] / end["A"] if end["A"] > 0 else math.inf
    out["measured_range"] = {**b.range, "first_cantilever_frequency": b.min_frequency}
    t = res["time"]
    for k in RANGE:
        over = np.flatnonzero(P[k] > b.range[k])
        if over.size:
            what, unit = _RANGE_TEXT[k]
            scale = 100 if k == "D" else 1
            out["outside"].append(
                f"{what} reaches {scale * end[k]:.3g} {unit}, beyond the {scale * b.range[k]:.3g} "
                f"{unit} the {name} rung was measured up to (from t = {t[over[0]]:.3g} s)")
    if scene.plant.params.n_modes == 0 and b.min_frequency is not None:
        w1 = cantilever_frequency(scene.plant.params)
        if w1 < b.min_frequency * (1 - 1e-9):
            out["outside"].append(
                f"the beam is softer (first cantilever mode {w1:.4g} rad/s) than the one the "
                f"{name} rung was measured on ({b.min_frequency:.4g} rad/s): a rigid model "
                "cannot see its deflection")
    return out
