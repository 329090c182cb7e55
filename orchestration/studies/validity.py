"""The measured validity bound: how far a run's tip angle can be trusted on its rung of the
fidelity ladder, in radians.

Each rung (the plant's model: ``plant.fidelity``, ``plant.gravity_preload``, rigid or not) was
compared with the top rung, the geometrically exact beam (:mod:`plant_fmu.exact`, its C kernel),
over the paper scenes and a sweep of initial angles and gains (``python3 bench/validity_map.py``,
which writes ``validity_bound.json`` beside this module). At every output time ``t`` of every
run of the sweep it recorded

* ``E(t)``: the largest ``|phi_o - phi_o(exact)|`` up to ``t`` plus the exact rung's own
  discretisation uncertainty up to ``t`` (its mesh doubled and its step halved);
* ``D(t)``: the largest ``|tip_deflection| / L`` of the rung's run up to ``t``;
* ``W(t)``: the largest ``|omega_o|`` (rad/s) of the rung's run up to ``t``;

and fitted ``E <= f(D, W) = max(floor, c D^p W^q)`` (``p, q >= 0``: a monotone bound; the rigid
rungs have ``D = 0`` and ``p = 0``), ``c`` raised until every point of the fit is bounded, then
multiplied by a safety factor. The bound is the envelope of the error: it is evaluated on the
run's own running maxima, so it holds from the start to any time, and the run's bound is its value
at the end. Nothing is simulated here: evaluating it is a few numpy operations on the run's
history.

A run leaves the rung's *measured range* when its deflection or rate passes the largest the sweep
reached on that rung (the bound is then an extrapolation and the summary says so), or, for a rigid
rung (which sees no deflection), when its beam is softer than the one measured.
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np

__all__ = ["BOUND_FILE", "rung_name", "RungBound", "bounds", "cantilever_frequency", "envelope", "assess"]

#: The fitted bounds (reference data, written by ``python3 bench/validity_map.py``).
BOUND_FILE = Path(__file__).with_name("validity_bound.json")
#: The first root of ``1 + cos x cosh x = 0``.
BETA1_L = 1.8751040687119611


def rung_name(plant) -> str:
    """The rung of a resolved :class:`~orchestration.scene.records.PlantSetup`: ``"nonlinear"``,
    ``"linear + preload"``, ``"rigid nonlinear"``..."""
    p = plant.params
    if p.n_modes == 0:
        return f"rigid {plant.fidelity}"
    return plant.fidelity + (" + preload" if p.gravity_preload else "")


class RungBound:
    """One rung's fitted bound ``max(floor, c D^p W^q)`` and its measured range."""

    def __init__(self, name: str, entry: dict):
        self.name = name
        m = entry["model"]
        self.c, self.p, self.q, self.floor = m["c"], m["p"], m["q"], m["floor"]
        r = entry["range"]
        self.max_deflection, self.max_rate = r["deflection"], r["rate"]
        self.min_frequency = r["first_cantilever_frequency"]

    def __call__(self, D, W):
        """The bound (rad) at deflection ``D`` (fraction of L) and rate ``W`` (rad/s)."""
        D, W = np.asarray(D, float), np.asarray(W, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = self.c * np.power(D, self.p) * np.power(W, self.q)
        return np.maximum(self.floor, np.nan_to_num(f, nan=0.0))

    def describe(self) -> str:
        d = f" (D/L)^{self.p:.3g}" if self.p else ""
        return f"max({self.floor:.2g}, {self.c:.3g}{d} (W s)^{self.q:.3g}) rad"


@functools.lru_cache(maxsize=None)
def _load(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def bounds(path=BOUND_FILE) -> dict:
    """``{rung: RungBound}`` of the reference data."""
    data = _load(str(path))
    return {name: RungBound(name, e) for name, e in data["rungs"].items()}


def cantilever_frequency(p) -> float:
    """The beam's first cantilever frequency (rad/s), ``(beta_1 L)^2 sqrt(EI / (rhoA L^4))``."""
    return BETA1_L ** 2 * math.sqrt(p.EI / (p.rho * p.EA / p.E * p.L ** 4))


def envelope(res: np.ndarray, L: float):
    """``(D, W)``: the running maxima of ``|tip_deflection| / L`` and ``|omega_o|``."""
    if len(res) == 0:
        return np.zeros(0), np.zeros(0)
    return (np.maximum.accumulate(np.abs(res["tip_deflection"])) / L,
            np.maximum.accumulate(np.abs(res["omega_o"])))


def assess(res: np.ndarray, scene, path=BOUND_FILE) -> dict:
    """The run's model-form error bound on its rung, where it was measured, and where the run
    leaves the measured range: ``{"rung", "model_form_error" (rad, or None without a measured
    bound), "relative" (to the largest |phi_o|), "deflection", "rate", "measured_range",
    "outside": [what left it, in words], "note"}``."""
    name = rung_name(scene.plant)
    table = bounds(path)
    L = scene.plant.params.L
    out = {"rung": name, "model_form_error": None, "relative": None, "deflection": None,
           "rate": None, "measured_range": None, "outside": [], "note": None}
    if len(res) == 0:
        return out
    D, W = envelope(res, L)
    out.update(deflection=float(D[-1]), rate=float(W[-1]))
    b = table.get(name)
    if b is None:
        out["note"] = (f"no measured bound for the {name} rung (measured: "
                       f"{', '.join(table)}; python3 bench/validity_map.py)")
        return out
    out["model_form_error"] = float(b(D[-1], W[-1]))
    scale = float(np.max(np.abs(res["phi_o"])))
    out["relative"] = out["model_form_error"] / scale if scale > 0 else math.inf
    out["measured_range"] = {"deflection": b.max_deflection, "rate": b.max_rate,
                             "first_cantilever_frequency": b.min_frequency}
    t = res["time"]
    over = np.flatnonzero(D > b.max_deflection)
    if over.size:
        out["outside"].append(
            f"the tip deflection reaches {100 * D[-1]:.3g} % of L (from t = {t[over[0]]:.3g} s "
            f"beyond {100 * b.max_deflection:.3g} %, the largest the {name} rung was measured at)")
    over = np.flatnonzero(W > b.max_rate)
    if over.size:
        out["outside"].append(
            f"|omega_o| reaches {W[-1]:.3g} rad/s (from t = {t[over[0]]:.3g} s beyond "
            f"{b.max_rate:.3g} rad/s, the largest the {name} rung was measured at)")
    if scene.plant.params.n_modes == 0 and b.min_frequency is not None:
        w1 = cantilever_frequency(scene.plant.params)
        if w1 < b.min_frequency * (1 - 1e-9):
            out["outside"].append(
                f"the beam is softer (first cantilever mode {w1:.4g} rad/s) than the one the "
                f"{name} rung was measured on ({b.min_frequency:.4g} rad/s): a rigid model "
                "cannot see its deflection")
    return out
