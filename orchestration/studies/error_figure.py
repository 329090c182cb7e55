"""The error figure: how far a run's tip angle can be from the geometrically exact beam, made
from the run itself.

A run on a floating-frame rung (``plant.fidelity`` linear, nonlinear or stiffened; the rigid
model is ``plant.n_modes = 0``) is followed by its **companion**: the same scene on the best
cheap model, the stiffened rung with every cantilever mode up to :data:`COMPANION_FREQUENCY`
(at most :data:`COMPANION_MODES`, the native FMU's most, and at least the run's), run through
the same FMUs and master (:func:`companion_scene`; :func:`orchestration.job.run_scene` runs it).
The run states

    figure = kappa * max |phi_o(run) - phi_o(companion)| + floor

``kappa`` (>= 1) and the floor, the companion's own error (its model-form error and the runs'
numerical error, a function of the companion's motion: :data:`TERMS`), were measured against a
refined geometrically exact reference on a grid of the paper scenes (``python3
bench/error_figure.py --write``, which writes :data:`FIGURE_FILE`; docs/accuracy.md). A run on
the stiffened rung with at least the companion's modes is its own companion's model: its
figure is the floor alone.

A figure that cannot be trusted is not stated as a number; :func:`assess` says why, one of
:data:`UNTRUSTED`:

* ``diverged``: the run stopped before its stop time (or was interrupted);
* ``integrator``: the plant's integrator is unstable at the run's ``plant.step`` on its rung
  (:mod:`orchestration.studies.plant_step`);
* ``companion``: the companion could not run or stopped early;
* ``grows``: the loop grows: a reliably fitted oscillation of the run or of its companion grows
  (the summary's verdict), or the difference between the two grows faster over the second half
  of the run than a build-up from the start (:func:`growth_rate`, beyond :data:`FIGURE_FILE`'s
  ``growth.rate``). The models' differences then grow exponentially, and so does the
  companion's own error, which the floor, measured on loops that do not grow, does not follow;
* ``outside``: the run is outside what was measured: the companion's motion beyond the largest
  the study reached (``range``, with its margin), a coupling the study did not measure
  (its numerical error is part of the floor), or a mesh too coarse for the companion's modes.
"""
from __future__ import annotations

import functools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from plant_fmu.beam import beam_model
from plant_fmu.params import damping_text

__all__ = ["COMPANION_MODES", "COMPANION_FREQUENCY", "STEP_MARGIN", "FIGURE_FILE", "TERMS",
           "UNTRUSTED", "companion_modes", "companion_step", "own_companion", "companion_scene",
           "companion_text", "model", "features", "floor", "growth_rate", "coupling_outside",
           "assess"]

#: The most modes the companion carries: the native plant FMU's most.
COMPANION_MODES = 8
#: The companion carries every cantilever mode up to this frequency (rad/s): on the paper's beam
#: the first 8 (the 8th at 4157 rad/s), on ``rigid_pd``'s beam, 100 times stiffer, the first 3
#: (the 3rd at 4621). Measured (``bench/error_figure.py``, docs/accuracy.md): the modes above it
#: move the tip angle by less than the companion's own error.
COMPANION_FREQUENCY = 5000.0
#: The companion's plant step is at most this fraction of RK4's stability limit on its plant
#: (:func:`orchestration.studies.plant_step.step_limit`): the stiffened rung's frequencies move
#: with the motion.
STEP_MARGIN = 0.8
#: The measured kappa, floor, range and growth rate (reference data, written by
#: ``python3 bench/error_figure.py --write``).
FIGURE_FILE = Path(__file__).with_name("error_figure.json")
#: Why a figure is not stated (:func:`assess`'s ``untrusted``), and the words for it.
UNTRUSTED = {"diverged": "the run diverged",
             "integrator": "the plant's integrator is unstable",
             "companion": "no companion run to the end",
             "grows": "the loop grows",
             "outside": "outside what was measured"}


@functools.lru_cache(maxsize=64)
def _modes_below(p) -> int:
    fine = max(p.n_elements, 3 * COMPANION_MODES)       # a mesh that resolves the 8th mode
    w = beam_model(p.replace(n_elements=fine, n_modes=COMPANION_MODES)).frequencies
    return int(np.count_nonzero(w <= COMPANION_FREQUENCY))


def companion_modes(p, n_modes: int) -> int:
    """The companion's modes for the plant ``p`` and a run of ``n_modes``: every cantilever mode
    up to :data:`COMPANION_FREQUENCY`, at least one and at least ``n_modes``, at most
    :data:`COMPANION_MODES` and at most the mesh's ``n_elements``."""
    return min(COMPANION_MODES, p.n_elements, max(n_modes, _modes_below(p), 1))


def companion_step(scene, n_modes: int) -> float:
    """The companion's ``plant.step``: the scene's (or its communication step, when shorter),
    or, when that is beyond :data:`STEP_MARGIN` times RK4's stability limit on the companion's
    plant, the largest whole fraction of the communication step within it."""
    from .plant_step import largest_substep, rung_params, step_limit

    p = rung_params(scene.plant.params.replace(n_modes=n_modes), "stiffened")
    h = largest_substep(scene)
    found = step_limit("rk4", p)
    if found is None or h <= STEP_MARGIN * found[0]:
        return h
    H = scene.master.max_step if scene.master.adaptive else scene.master.step
    return H / math.ceil(H / (STEP_MARGIN * found[0]) - 1e-12)


def own_companion(scene) -> bool:
    """Whether the run is on its own companion's model: the stiffened rung with at least the
    companion's modes."""
    p = scene.plant.params
    return (scene.plant.fidelity == "stiffened"
            and p.n_modes >= companion_modes(p, p.n_modes))


def companion_scene(scene):
    """The companion of a resolved floating-frame ``scene``: the stiffened rung at
    :func:`companion_modes`, RK4 at :func:`companion_step`, everything else the scene's (a
    ConfigError when the scene's master cannot run the stiffened rung)."""
    p = scene.plant.params
    n = companion_modes(p, p.n_modes)
    plant = scene.plant.with_model(n, "stiffened")
    plant = replace(plant, integrator="rk4", step=companion_step(scene, n))
    return scene.replace(plant=plant)


def companion_text(scene) -> str:
    """What a run's figure compares with, in words: ``"the stiffened rung, 8 modes, modal
    damping 0.1 %"``."""
    p = scene.plant.params
    n = companion_modes(p, p.n_modes)
    return f"the stiffened rung, {n} mode{'' if n == 1 else 's'}, {damping_text(p)}"


# ---------------------------------------------------------------------- the measured model
@functools.lru_cache(maxsize=None)
def _load(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def model(path=FIGURE_FILE) -> dict | None:
    """The measured ``kappa``, ``floor``, ``range``, ``coupling``, ``damped`` and ``growth``
    (:data:`FIGURE_FILE`), or None when the study has not been run."""
    try:
        return _load(str(path))
    except FileNotFoundError:
        return None


def ringing(p, damped: dict) -> float:
    """1 unless the beam is damped as the study's damped scenes were (``damped``: the law and
    at least the ``zeta`` measured): the exact beam's modes above the companion's then ring,
    undamped or lightly damped, and the companion's error is larger (measured: about twice).
    The modal law counts as ringing until it is measured against the exact beam (its modes
    above the first are damped less than Kelvin-Voigt's)."""
    return 0.0 if (p.damping == damped["law"] and p.zeta >= damped["zeta"] * (1 - 1e-9)) \
        else 1.0


#: The floor's terms: functions of the companion's features (:func:`features`).
TERMS = {
    "D": lambda P: P["D"],                       # the deflection: the stiffened model's error
    "D_ringing": lambda P: P["D"] * P["ringing"],   # ... larger when the high modes ring
    "D_stiffness": lambda P: P["D"] * P["stiffness"],  # ... the beam's elastic load
    "D2": lambda P: P["D"] ** 2,                 # beyond first order in the deflection
    "kd_W": lambda P: P["kd"] * P["W"],          # the coupling: the derivative force's rate
    "1": lambda P: 1.0,
}


def features(res: np.ndarray, scene, damped: dict) -> dict:
    """What the floor and the measured range read off a run (the companion's) and its scene:
    the largest ``|phi_o|`` ``A`` (rad), tip deflection ``D`` (fraction of L) and ``|omega_o|``
    ``W`` (rad/s); the controller's ``kd``; the beam's ``stiffness``, ``omega_1^2 L / g`` (its
    first cantilever mode's elastic load against its weight: 70.7 for the paper's beam) and
    :func:`ringing`."""
    from .validity import cantilever_frequency

    p = scene.plant.params
    return {"A": float(np.max(np.abs(res["phi_o"]))),
            "D": float(np.max(np.abs(res["tip_deflection"]))) / p.L,
            "W": float(np.max(np.abs(res["omega_o"]))),
            "kd": float(scene.controller.kd),
            "stiffness": cantilever_frequency(p) ** 2 * p.L / p.g,
            "ringing": ringing(p, damped)}


def floor(P: dict, m: dict) -> float:
    """The floor (rad) at the companion's features ``P``: ``safety * sum c_k term_k``."""
    f = m["floor"]
    return f["safety"] * sum(c * TERMS[k](P) for k, c in f["terms"].items())


def growth_rate(t: np.ndarray, d: np.ndarray, windows: int) -> float:
    """How much faster than a build-up from the start ``d`` (the run's difference from its
    companion) grows over the second half of the run, 1/s: the least-squares slope of the
    logarithm of its largest value in each of the last ``windows // 2`` of ``windows`` equal
    windows, less ``2 / t_c`` (``t_c`` their mean time): the slope of a difference that grows as
    ``t^2`` from the start, as two models' do at first (a stable loop's difference then levels
    off as its phase error grows only linearly and its amplitude decays; a growing loop's grows
    exponentially). ``-inf`` with too few points."""
    if len(t) < 2 * windows or t[-1] <= t[0]:
        return -math.inf
    edges = np.linspace(t[0], t[-1], windows + 1)
    idx = np.searchsorted(t, edges)
    env = np.array([np.max(d[a:max(b, a + 1)]) for a, b in zip(idx[:-1], idx[1:])])
    half = env[windows // 2:]
    tc = 0.5 * (edges[:-1] + edges[1:])[windows // 2:]
    if np.any(half <= 0):
        return -math.inf
    return float(np.polyfit(tc, np.log(half), 1)[0] - 2.0 / (tc.mean() - t[0]))


def coupling_outside(scene, m: dict) -> str | None:
    """How the scene's coupling differs from those the study measured (the floor holds their
    numerical error), in words, or None."""
    c, s = m["coupling"], scene.master
    if s.interface != "co-simulation":
        return f"master.interface = {s.interface!r}"
    if s.adaptive:
        return "master.adaptive = true (the study measured fixed steps)"
    for key, value, allowed in (("algorithm", s.algorithm, c["algorithm"]),
                                ("first", s.first, c["first"])):
        if value not in allowed:
            return (f"master.{key} = {value!r} (measured: "
                    f"{', '.join(map(repr, allowed))})")
    if s.extrapolation < c["extrapolation"] or (c["input_derivatives"]
                                                 and not s.input_derivatives):
        return (f"master.extrapolation = {s.extrapolation}, master.input_derivatives = "
                f"{str(s.input_derivatives).lower()} (measured: {c['extrapolation']}, "
                f"{str(c['input_derivatives']).lower()})")
    if s.step > c["max_step"] * (1 + 1e-9):
        return f"master.step = {s.step:g} s (measured up to {c['max_step']:g} s)"
    return None


_RANGE_TEXT = {"A": ("|phi_o|", "rad", 1), "D": ("the tip deflection", "% of L", 100),
               "W": ("|omega_o|", "rad/s", 1)}


def _outside(P: dict, m: dict, own: bool) -> list:
    r = m["range"]
    out = []
    if own and P["stiffness"] < r["stiffness"] / (1 + r["margin"]):
        out.append(f"the beam (omega_1^2 L / g = {P['stiffness']:.3g}) is softer than any the "
                   f"floor was measured on ({r['stiffness']:.3g}, with a {100 * r['margin']:g} % "
                   "margin): on a run on its companion's model the floor is the whole figure")
    for k, (what, unit, scale) in _RANGE_TEXT.items():
        top = r[k] * (1 + r["margin"])
        if P[k] > top:
            out.append(f"{what} reaches {scale * P[k]:.3g} {unit}, beyond the "
                       f"{scale * top:.3g} {unit} measured (with a {100 * r['margin']:g} % "
                       "margin)")
    return out


def _entry(scene, m) -> dict:
    p = scene.plant.params
    n = companion_modes(p, p.n_modes)
    from .validity import rung_name

    return {"rung": rung_name(scene.plant), "figure": None, "relative": None,
            "max_abs_phi_o": None, "difference": None,
            "floor": None, "kappa": m["kappa"] if m else None,
            "companion": {"rung": "stiffened", "n_modes": n, "damping": p.damping,
                          "zeta": p.zeta, "text": companion_text(scene), "own": False,
                          "plant_step": None, "wall_time": None},
            "untrusted": None, "why": None,
            "measured": ({"command": m["command"], "date": m["date"]} if m else None)}


def _untrusted(out, key, why):
    out["untrusted"], out["why"] = key, f"{UNTRUSTED[key]}: {why}"
    return out


def assess(run, scene, companion=None, companion_why: str | None = None,
           integrator: str | None = None, path=FIGURE_FILE) -> dict:
    """The error figure of ``run`` (a :class:`orchestration.job.Run` on the resolved
    floating-frame ``scene``) against its ``companion`` (the Run of :func:`companion_scene`;
    None when the run is its own companion's model, :func:`own_companion`, or when it could not
    run: ``companion_why`` says why); ``integrator``: why the run's plant integrator is
    unstable, if it is. ``{"figure" (rad, or None), "relative" (to the run's largest |phi_o|),
    "difference", "floor", "kappa", "companion": {rung, n_modes, damping, zeta, text, own,
    plant_step, wall_time}, "untrusted": a key of UNTRUSTED or None, "why", "measured"}``."""
    m = model(path)
    out = _entry(scene, m)
    res = run.result
    if len(res):
        out["max_abs_phi_o"] = float(np.max(np.abs(res["phi_o"])))
    if m is None:
        return _untrusted(out, "outside", "no measurement (python3 bench/error_figure.py "
                          "--write)")
    if run.interrupted:
        return _untrusted(out, "diverged", "the run was interrupted")
    stopped = run.summary.get("stopped")
    if stopped is not None:
        return _untrusted(out, "diverged", f"it stopped at t = {stopped['time']:.4g} s "
                          f"({stopped['reason']})")
    if integrator:
        return _untrusted(out, "integrator", integrator)
    own = own_companion(scene)
    out["companion"]["own"] = own
    c = run if own else companion
    if c is None:
        return _untrusted(out, "companion", companion_why or "it did not run")
    out["companion"]["plant_step"] = c.scene.plant.step
    out["companion"]["wall_time"] = c.summary.get("wall_time")
    if not own:
        if c.interrupted or c.summary.get("stopped") is not None:
            why = (c.summary.get("stopped") or {}).get("reason", "interrupted")
            return _untrusted(out, "companion", f"it stopped ({why})")
        if len(c.result) != len(res) or not np.allclose(c.result["time"], res["time"]):
            return _untrusted(out, "companion", "its output points are not the run's")
    d = np.abs(res["phi_o"] - c.result["phi_o"])
    out["difference"] = float(d.max()) if len(d) else 0.0
    P = features(c.result, c.scene, m["damped"])
    out["floor"] = floor(P, m)
    grows = [(who, s) for who, s in (("the run", run.summary), ("its companion", c.summary))
             if s.get("stable") is False]
    growing = [who for who, _ in grows]
    if growing:
        rate = max(((s.get(k) or {}).get("rate") or -math.inf for _, s in grows
                    for k in ("slow", "bending", "other") if (s.get(k) or {}).get("reliable")),
                   default=-math.inf)
        fitted = f" (a fitted oscillation at {rate:+.3g} 1/s)" if math.isfinite(rate) else ""
        return _untrusted(out, "grows", f"{' and '.join(growing)} grow{'s' * (len(growing) == 1)}"
                          f"{fitted}, and the models' differences grow with it")
    g = m["growth"]
    if not own:
        rate = growth_rate(res["time"], d, g["windows"])
        if rate > g["rate"]:
            return _untrusted(out, "grows", f"its difference from the companion grows "
                              f"{rate:.2g} 1/s faster than a build-up from the start over the "
                              f"second half of the run (the stable loops measured: at most "
                              f"{g['largest_measured']:+.2g} 1/s)")
    outside = _outside(P, m, own)
    p = scene.plant.params
    want = min(COMPANION_MODES, max(_modes_below(p), 1))
    if p.n_elements < want:
        outside.append(f"plant.n_elements = {p.n_elements} carries fewer modes than the "
                       f"companion measured ({want})")
    why = coupling_outside(scene, m)
    if why:
        outside.append(f"the coupling: {why}, whose numerical error was not measured")
    if outside:
        return _untrusted(out, "outside", ", and ".join(outside))
    out["figure"] = m["kappa"] * out["difference"] + out["floor"]
    A = out["max_abs_phi_o"]
    out["relative"] = out["figure"] / A if A else math.inf
    return out
