"""What a run's summary says: the fitted modes beside the linear prediction, the verdict, and
the run's measured model-form error bound.

**Modes.** Two oscillations are fitted (:func:`orchestration.studies.fit.fit_mode`, matrix pencil): the
slow, rigid-pendulum one on ``phi_o`` (0.5 to 60 rad/s) and the bending one on ``eta_1``: the
largest oscillation within 30 % of the plant's first bending mode with the hinge free (its first
open-loop oscillation, 152.5 rad/s for the paper's beam; the loop's mode near it is the one the
PD destabilises, docs/model.md), so that a filter's own mode (near 95 rad/s with the designed
filter) is not taken for it. Both are fitted only over the part of the run where the linearisation at the upright
rest state holds: the longest stretch with ``|phi| <= LINEAR_PHI`` (the frame's rotation; ``sin``
and ``cos`` within 0.7 % and 2 % of their linear values) and the tip deflection within
``FIT_DEFLECTION`` (5 % of L: the fitted modes are the loop's linearised at rest). A fit is
reported as a number only when it is reliable:

* the stretch holds at least ``MIN_PERIODS`` periods of the oscillation;
* the fitted exponentials reproduce the signal over it to ``FIT_RESIDUAL`` (relative RMS): a
  saturated, beating or otherwise nonlinear signal does not;
* the linearised loop has a mode within ``FREQUENCY_MATCH`` of the fitted frequency (no mode is
  reported that the loop does not have); that mode is printed beside the fit.

The linearised loop is the run's rung's, with its damping law
(:func:`orchestration.studies.analysis.linearisation`, the one ``flexpend analyze`` takes): a fit
is compared only with the linear root of the same rung and law. The exact rung has no linear loop
here: the floating frame's preloaded loop of the same law stands in, and ``linear_loop`` says so.

Otherwise the summary says why instead of printing a number.

**Validity.** How far the run's tip angle can be trusted on its rung of the fidelity ladder, in
radians: the bound measured against the geometrically exact beam
(:mod:`orchestration.studies.validity`, ``python3 bench/validity_map.py``), evaluated on the
run's own history of tip deflection and ``|omega_o|``. A run that leaves the range where the rung
was measured (a larger deflection or rate than the sweep reached) is flagged: its bound is then
an extrapolation. A beam turned past the horizontal (``|phi| > pi/2``), or past the plant's own
``phi_limit``, is flagged too.

**Verdict** (:func:`verdict`). A reliable fit counts only when its rate is further from zero
than its uncertainty (``rate_uncertainty``: how far it moves on the window's halves, at the next
order, with the residual). ``verdict`` is ``"unstable"`` when a counted fit grows,
``"stable"`` when every oscillation the model has (the slow one, and the bending one unless the
model is rigid) has a counted fit that decays, and ``"undetermined"`` otherwise, with the reason
and, when a longer run would decide, the stop time that would (``decide_by``); a run that stopped
early has ``"stopped"``. When a counted fit and the linear root of the same rung and law
disagree in sign, the summary says so: the fit is trusted only when it is three uncertainties
clear of zero (the run's own measurement over the linearisation at rest, which is exact only at
small amplitude); otherwise the mode is undetermined. ``stable`` is True, False or None
(undetermined, stopped), as the verdict.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .analysis import (LoopRoots, closed_loop_eigenvalues, first_bending_frequency, linearisation,
                       loop_roots, roots_of)
from .error_figure import UNTRUSTED
from .fit import fit_mode
from .validity import assess

__all__ = ["stop_reason", "SLOW_BAND", "BENDING_BAND", "LINEAR_PHI", "FIT_DEFLECTION",
           "FIT_RESIDUAL", "FREQUENCY_MATCH", "MIN_PERIODS", "linear_modes", "linear_window",
           "iteration_counts",
           "fit_modes", "first_bending_frequency", "validity", "verdict", "summarize",
           "TRUST_AGAINST_LINEAR", "ReportFacts", "report_facts"]

#: Bands (rad/s) of the rigid (slow) and the bending oscillation.
SLOW_BAND = (0.5, 60.0)
BENDING_BAND = (60.0, math.inf)
#: Largest |phi| (rad) at which the fits treat the loop as linear.
LINEAR_PHI = 0.2
#: Largest tip deflection, as a fraction of L, at which the fits treat the loop as linear.
FIT_DEFLECTION = 0.05
#: Largest relative RMS residual of a fit that is reported as a number.
FIT_RESIDUAL = 0.02
#: Largest relative distance between a fitted and a linear mode's frequency.
FREQUENCY_MATCH = 0.1
#: Fewest periods of an oscillation in the window for a fit.
MIN_PERIODS = 3.0

_SIGNALS = {"slow": ("phi_o", SLOW_BAND), "bending": ("eta_1", BENDING_BAND)}


def linear_modes(scene) -> np.ndarray:
    """Closed-loop eigenvalues (upper half-plane, oscillatory) of the scene's linearised loop
    (:func:`~orchestration.studies.analysis.linearisation`: its rung's, with its damping law);
    with a sampled controller, the s-plane equivalents ``log(z) / T`` of the sampled loop's
    poles (:func:`~orchestration.studies.sampled.sampled_poles`: the hold, the delay and the
    filter's difference equation)."""
    c = scene.controller
    if c.sampled:
        from .sampled import controller_poles
        lam = controller_poles(linearisation(scene).params, c).s
        lam = lam[np.isfinite(lam)]
    else:
        lam = closed_loop_eigenvalues(linearisation(scene).params, c)
    return lam[lam.imag > 1e-9]


def _in_linear_range(res: np.ndarray, L: float | None) -> np.ndarray:
    phi = res["phi"] if "phi" in res.dtype.names else res["phi_o"]
    ok = np.abs(phi) <= LINEAR_PHI
    if L is not None and "tip_deflection" in res.dtype.names:
        ok &= np.abs(res["tip_deflection"]) <= FIT_DEFLECTION * L
    return ok


def linear_window(res: np.ndarray, L: float | None) -> slice:
    """The longest stretch of output points where the loop is in its linear range."""
    ok = _in_linear_range(res, L)
    edges = np.diff(np.concatenate(([0], ok.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if not starts.size:
        return slice(0, 0)
    i = int(np.argmax(ends - starts))          # the first of the longest
    return slice(int(starts[i]), int(ends[i]))


def _fit(t, y, key, modes, near=None):
    """One entry of the summary's ``modes``: the fit, the nearest linear mode, and whether the
    fit is reliable (``note`` says why not)."""
    band = _SIGNALS[key][1]
    entry = {"signal": _SIGNALS[key][0], "rate": None, "frequency": None, "reliable": False,
             "linear": None, "note": None, "fit": None,
             "window": [float(t[0]), float(t[-1])] if len(t) else None}
    if modes is not None and len(modes):        # the loop's own mode of this band, by default
        lo, hi = band if near is None else (0.7 * near, 1.3 * near)
        inband = modes[(modes.imag >= lo) & (modes.imag <= hi)]
        if inband.size:
            m0 = inband[np.argmax(inband.real)]
            entry["linear"] = {"rate": float(m0.real), "frequency": float(m0.imag)}
    if len(t) < 8 or np.ptp(y) == 0:
        entry["note"] = "no oscillation in the linear range of the run"
        return entry
    nyquist = math.pi / (t[1] - t[0])
    try:
        with np.errstate(all="ignore"):        # a diverging signal makes a poor fit, no warning
            f = fit_mode(t, y, (band[0], min(band[1], nyquist)), near=near)
    except (ValueError, np.linalg.LinAlgError):
        f = None
    if f is None:
        entry["note"] = ("no oscillation in the band" if near is None else
                         f"no oscillation near the first bending mode ({near:.0f} rad/s)")
        return entry
    entry["fit"] = {"rate": f.rate, "frequency": f.frequency, "residual": f.residual,
                    "window": list(f.window), "order": f.order,
                    "rate_uncertainty": f.rate_uncertainty,
                    "frequency_uncertainty": f.frequency_uncertainty}
    if modes is not None and len(modes):
        entry["linear"] = None
        near = modes[np.argmin(np.abs(modes.imag - f.frequency))]
        if abs(near.imag - f.frequency) <= FREQUENCY_MATCH * near.imag:
            entry["linear"] = {"rate": float(near.real), "frequency": float(near.imag)}
    span = t[-1] - t[0]
    periods = span * f.frequency / (2 * math.pi)
    if periods < MIN_PERIODS:
        entry["note"] = (f"unreliable fit: only {periods:.1f} periods in the linear range "
                         f"(t = {t[0]:.2f} .. {t[-1]:.2f} s)")
    elif f.residual > FIT_RESIDUAL:
        entry["note"] = (f"unreliable fit: exponentials reproduce the signal to "
                         f"{100 * f.residual:.1f} % only (nonlinear, saturating or beating)")
    elif modes is not None and entry["linear"] is None:
        entry["note"] = (f"unreliable fit: the linearised loop has no mode near "
                         f"{f.frequency:.1f} rad/s")
    else:
        entry.update(rate=f.rate, frequency=f.frequency, reliable=True)
    return entry


def fit_modes(res: np.ndarray, scene=None) -> dict:
    """``{"slow": entry, "bending": entry}`` (see :func:`_fit`)."""
    L = scene.plant.params.L if scene is not None else None
    w = linear_window(res, L)
    lin = linearisation(scene) if scene is not None else None
    modes = linear_modes(scene) if scene is not None else None
    t = res["time"][w]
    near = {"bending": first_bending_frequency(lin.params) if lin is not None else None}
    out = {key: _fit(t, res[col][w], key, modes, near.get(key))
           for key, (col, _) in _SIGNALS.items()}
    if scene is not None and scene.plant.params.n_modes == 0:
        out["bending"]["note"] = "none: rigid model (plant.n_modes = 0)"
    return out


def validity(res: np.ndarray, scene) -> dict:
    """The run's model-form error bound on its rung and where it leaves the rung's measured range
    (:func:`orchestration.studies.validity.assess`), and where the beam turns past the horizontal
    or ``plant.phi_limit``: ``warnings`` lists both (see the module docstring).
    ``tip_deflection_limit`` (m): the largest deflection the rung was measured at, or None."""
    phi_max = min(math.pi / 2, scene.plant.phi_limit)
    out = assess(res, scene)
    rng = out["measured_range"]
    out.update(tip_deflection_limit=rng["D"] * scene.plant.params.L if rng else None,
               phi_limit=phi_max, max_abs_tip_deflection=None, max_abs_phi=None,
               warnings=list(out["outside"]))
    if len(res) == 0:
        return out
    t = res["time"]
    out["max_abs_tip_deflection"] = float(np.max(np.abs(res["tip_deflection"])))
    phi = np.abs(res["phi"] if "phi" in res.dtype.names else res["phi_o"])
    out["max_abs_phi"] = float(phi.max())
    over = np.nonzero(phi > phi_max)[0]
    if over.size:
        out["warnings"].append(f"|phi| reaches {phi.max():.3g} rad (beyond {phi_max:.3g} rad "
                               f"from t = {t[over[0]]:.3g} s)")
    return out


_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|[-+]?inf"


def _short(text: str) -> str:
    """``text`` with every number of more than 4 significant digits printed with 4 (an FMU logs
    ``repr`` or ``%.17g``: ``0.40400000000000003``)."""
    import re

    def fmt(m):
        v = m.group(0)
        digits = len(re.sub(r"[^0-9]", "", v.split("e")[0].split("E")[0]).lstrip("0"))
        return format(float(v), ".4g") if digits > 4 else v
    return re.sub(r"(?<![\w.])\d+\.\d+(?:[eE][-+]?\d+)?", fmt, text)


def stop_reason(message: str) -> str:
    """What stopped a run, in the user's terms (the scene's keys, physical words), from the
    message of :class:`~orchestration.cosim.slave.CoSimulationError`: which FMU refused which call
    with which status, and the FMU's log (``|phi| = 1.5797451062103358 exceeds phi_limit = ...;
    restore a saved FMU state to continue``). A message it does not know is kept, its FMI call
    and status left out and its numbers shortened. The summary keeps the whole message beside
    it (``fmu_message``)."""
    import re

    num = _NUMBER
    # "exceeds": a co-simulation step refused; "reached": a Model Exchange event
    m = re.search(rf"divergence at t = ({num}): \|phi\| = ({num}) (?:exceeds|reached) "
                  rf"phi_limit = ({num})", message)
    if m:
        t, phi, lim = map(float, m.groups())
        return (f"the beam tilted past plant.phi_limit = {lim:.4g} rad ({math.degrees(lim):.4g} "
                f"deg) by t = {t:.4g} s (|phi| = {phi:.4g} rad), where the plant stops")
    m = re.search(rf"divergence at t = ({num}): \|energy\| = ({num}) (?:exceeds|reached) "
                  rf"energy_limit = ({num})", message)
    if m:
        t, e, lim = map(float, m.groups())
        return (f"the plant's energy passed plant.energy_limit = {lim:.4g} J by t = {t:.4g} s "
                f"(|energy| = {e:.4g} J), where the plant stops")
    m = re.search(rf"divergence at t = ({num}): the state's norm ({num}) exceeds 1e100", message)
    if m:
        return (f"the plant's state blew up by t = {float(m.group(1)):.4g} s (its norm passed "
                "1e100)")
    m = re.search(rf"integrator '([^']*)' failed between t = ({num}) and ({num}): (.*?)"
                  r"(?:; restore a saved FMU state to continue|$)", message)
    if m:
        name, t0, t1, why = m.groups()
        return (f"the plant's integrator (plant.integrator = {name!r}) failed between t = "
                f"{float(t0):.4g} and {float(t1):.4g} s: {_short(why)}")
    m = re.search(rf"non-finite input F_c .*? at t = ({num})", message)
    if m:
        return f"the controller's force F_c became non-finite at t = {float(m.group(1)):.4g} s"
    m = re.search(rf"an FMU discarded the step at t = ({num}) even at min_step = ({num})",
                  message)
    if m:
        return (f"the adaptive master could not step on at t = {float(m.group(1)):.4g} s, even "
                f"at master.min_step = {float(m.group(2)):.4g} s")
    m = re.match(r"(plant|controller): \w+(?: at t = \S+)? returned \w+: (?:\[\w+\] )?(.*)$",
                 message, re.S)
    if m:
        who, log = m.groups()
        log = log.replace("; restore a saved FMU state to continue", "")
        return f"the {who} FMU stopped the run: {_short(log)}"
    return _short(message)


def iteration_counts(stats) -> dict:
    """The implicit master's interface iterations per communication step (``mean``, ``max``)
    and the FMU steps its difference Jacobians took, from a run's
    :class:`~orchestration.cosim.master.RunStats`; empty for the explicit couplings."""
    if not stats.iterations:
        return {}
    return {"iterations_per_step_mean": stats.iterations / max(stats.steps, 1),
            "iterations_per_step_max": stats.max_iterations,
            "jacobian_steps": stats.jacobian_steps}


#: A fit whose rate is this many uncertainties from zero overrules a linear root of the other sign.
TRUST_AGAINST_LINEAR = 3.0


def _needed_span(f: dict, periods_short: bool) -> float:
    """The fit window a mode would need to decide: ``MIN_PERIODS`` periods, or (when its rate's
    uncertainty is the problem) the window grown until the uncertainty, which falls about as
    the window's length to the power -3/2 (the Cramer-Rao rate of a damped sinusoid's decay),
    is a third of the rate: an estimate."""
    span = f["window"][1] - f["window"][0]
    if periods_short:
        return MIN_PERIODS * 2 * math.pi / f["frequency"] * 1.2
    ratio = f["rate_uncertainty"] / max(abs(f["rate"]), 1e-12)
    return span * (3.0 * ratio) ** (2.0 / 3.0) * 1.2


def verdict(modes: dict, res: np.ndarray, stopped: dict | None, rigid: bool,
            L: float | None = None) -> dict:
    """The run's verdict (see the module): ``{"verdict", "reason", "decide_by", "modes"}``, the
    last a per-mode note of what decided it or why not."""
    if stopped is not None:
        return {"verdict": "stopped", "reason": f"the run stopped at t = {stopped['time']:.4g} s",
                "decide_by": None, "modes": {}}
    keys = ["slow"] + ([] if rigid else ["bending"])
    t_end = float(res["time"][-1]) if len(res) else 0.0
    dt = float(res["time"][1] - res["time"][0]) if len(res) > 1 else 0.0
    decided, notes, needs = {}, {}, []
    for key in keys:
        m = modes.get(key)
        f = m.get("fit") if m else None
        if m is None or f is None:
            notes[key] = (m or {}).get("note") or "no fit"
            lin, win = (m or {}).get("linear"), (m or {}).get("window")
            if lin is not None and win is not None:      # the linear loop's period instead
                needs.append(({"window": win, "frequency": lin["frequency"]}, True))
            continue
        rate, u = f["rate"], f["rate_uncertainty"]
        lin = m.get("linear")
        if not m["reliable"]:
            notes[key] = m["note"]
            if "periods in the linear range" in (m["note"] or ""):
                needs.append((f, True))
            continue
        if u is None:
            notes[key] = (f"rate {rate:+.3g} 1/s: its uncertainty could not be estimated (the "
                          "window is too short to fit its halves)")
            needs.append((f, True))
            continue
        text = f"rate {rate:+.3g} +- {u:.2g} 1/s"
        if not abs(rate) > u:
            notes[key] = f"{text}: its uncertainty exceeds its distance from zero"
            needs.append((f, False))
            continue
        if lin is not None and (lin["rate"] > 0) != (rate > 0):
            if abs(rate) > TRUST_AGAINST_LINEAR * u:
                notes[key] = (f"{text}, against the linear root {lin['rate']:+.3g}: the fit is "
                              f"trusted, {TRUST_AGAINST_LINEAR:g} uncertainties clear of zero "
                              "(the linearisation holds at small amplitude only)")
                decided[key] = rate
            else:
                notes[key] = (f"{text} disagrees in sign with the linear root {lin['rate']:+.3g} "
                              f"and is within {TRUST_AGAINST_LINEAR:g} uncertainties of zero")
                needs.append((f, False))
            continue
        decided[key] = rate
        notes[key] = text
    out = {"modes": notes, "decide_by": None}
    growing = [k for k, r in decided.items() if r > 0]
    if growing:
        out.update(verdict="unstable", reason=f"{growing[0]}: {notes[growing[0]]}")
        return out
    if len(decided) == len(keys):
        out.update(verdict="stable", reason="every oscillation decays: " + "; ".join(
            f"{k}: {notes[k]}" for k in keys))
        return out
    undecided = [k for k in keys if k not in decided]
    reason = "; ".join(f"{k}: {notes[k]}" for k in undecided)
    # would a longer run decide? if the run ends in its linear range, a window from the last
    # entry into it on; if it ends outside, a longer run may (a decaying motion) or may not
    ok = _in_linear_range(res, L) if len(res) else np.zeros(0, bool)
    grows = [(k, modes[k]["linear"]) for k in keys
             if modes.get(k) and modes[k].get("linear") and modes[k]["linear"]["rate"] > 0]
    if needs and grows:
        k, lin = grows[0]
        reason += (f"; the linearised loop grows ({k}: {lin['rate']:+.3g} +- "
                   f"{lin['frequency']:.4g}j): a longer run leaves the linear range, a start "
                   "nearer rest (a smaller initial.phi) would decide")
    elif needs and ok.size and ok[-1]:
        start = float(res["time"][len(ok) - np.argmin(ok[::-1])]) if not ok.all() \
            else float(res["time"][0])
        stop = max(max(start, f["window"][0]) + _needed_span(f, short) for f, short in needs)
        stop = max(stop, t_end + dt)
        stop = math.ceil(stop / max(dt, 1e-12) - 1e-9) * dt if dt else stop
        out["decide_by"] = float(stop)
        reason += f"; a stop time of about {stop:.3g} s would decide"
    elif needs:
        reason += ("; at the stop the motion is outside the linear range (|phi| > "
                   f"{LINEAR_PHI:g} rad or the tip beyond {100 * FIT_DEFLECTION:g} % of L): a "
                   "longer run, if it decays, or a start nearer rest (a smaller initial.phi) "
                   "would decide")
    out.update(verdict="undetermined", reason=reason)
    return out


def _other_oscillations(v: dict, res: np.ndarray, scene, modes: dict) -> dict:
    """The verdict ``v`` of a sampled scene (stable or undetermined on the slow and bending
    oscillations), checked against every other oscillation its sampled loop says grows (an
    aliased or higher mode, which the hold and delay can destabilise and neither band holds):
    each is fitted in ``phi_o`` within 30 % of its frequency; one that the run shows growing
    makes the run unstable (the fit under ``"other"``); one the run cannot show (above the
    output's Nyquist frequency, or no reliable fit) makes a stable verdict undetermined."""
    L = scene.plant.params.L
    w = linear_window(res, L)
    t, y = res["time"][w], res["phi_o"][w]
    first = None
    if scene.plant.params.n_modes:
        first = first_bending_frequency(linearisation(scene).params)
    covered = [(SLOW_BAND[0], SLOW_BAND[1])] + ([(0.7 * first, 1.3 * first)] if first else [])
    lam = linear_modes(scene)
    others = [m for m in lam if m.real > 0
              and not any(lo <= m.imag <= hi for lo, hi in covered)]
    if not others:
        return v
    nyquist = math.pi / float(t[1] - t[0]) if len(t) > 1 else 0.0
    unseen = []
    for m in sorted(others, key=lambda m: -m.real):
        where = f"{m.imag:.4g} rad/s (the linearised loop: rate {m.real:+.3g} 1/s)"
        f = None
        if len(t) >= 8 and 1.3 * m.imag < nyquist:
            try:
                with np.errstate(all="ignore"):
                    f = fit_mode(t, y, (0.7 * m.imag, 1.3 * m.imag), near=m.imag)
            except (ValueError, np.linalg.LinAlgError):
                f = None
        if f is not None and f.residual <= FIT_RESIDUAL and f.rate_uncertainty is not None \
                and f.rate > f.rate_uncertainty:
            text = (f"an oscillation at {f.frequency:.4g} rad/s grows: rate {f.rate:+.3g} +- "
                    f"{f.rate_uncertainty:.2g} 1/s (the linearised loop: {m.real:+.3g} at "
                    f"{m.imag:.4g} rad/s)")
            modes_note = dict(v["modes"], other=text)
            return {**v, "verdict": "unstable", "reason": text, "decide_by": None,
                    "modes": modes_note,
                    "other": {"signal": "phi_o", "rate": f.rate, "frequency": f.frequency,
                              "reliable": True, "note": None,
                              "window": [float(t[0]), float(t[-1])],
                              "fit": {"rate": f.rate, "frequency": f.frequency,
                                      "residual": f.residual, "window": list(f.window),
                                      "order": f.order, "rate_uncertainty": f.rate_uncertainty,
                                      "frequency_uncertainty": f.frequency_uncertainty},
                              "linear": {"rate": float(m.real), "frequency": float(m.imag)}}}
        unseen.append(where if f is None or 1.3 * m.imag < nyquist else where)
    if v["verdict"] == "stable":
        text = (f"the slow and bending oscillations decay, but the linearised loop grows at "
                f"{unseen[0]}, which the run does not show decaying (a finer output_interval or "
                f"a longer run would decide)")
        return {**v, "verdict": "undetermined", "reason": text,
                "modes": dict(v["modes"], other=text)}
    return v


def summarize(res: np.ndarray, scene=None, stopped: dict | None = None,
              fits: bool = True) -> dict:
    """Verdict, fitted modes beside the linear ones, validity, largest force and cart travel.

    ``stopped``: ``{"time": t, "reason": text}`` when the run ended early (with the FMU's own
    message as ``fmu_message`` when an FMU stopped it, see :func:`stop_reason`). ``fits =
    False``: no mode is fitted (a sweep that asks for no column of theirs): the modes, the
    verdict and its reason are None."""
    out = {"completed": stopped is None, "stopped": stopped,
           "max_abs_F_c": float(np.max(np.abs(res["F_c"]))) if len(res) else None,
           "max_abs_x": float(np.max(np.abs(res["x"]))) if len(res) else None}
    if not fits:
        out.update({k: None for k in _SIGNALS}, verdict=None, verdict_reason=None,
                   decide_by=None, verdict_modes=None, stable=None)
        if scene is not None:
            out["validity"] = validity(res, scene)
        return out
    modes = fit_modes(res, scene) if len(res) else {k: None for k in _SIGNALS}
    out.update(modes)
    rigid = scene is not None and scene.plant.params.n_modes == 0
    v = verdict(modes, res, stopped, rigid, scene.plant.params.L if scene is not None else None)
    if scene is not None and scene.controller.sampled and len(res) > 8 and \
            v["verdict"] in ("stable", "undetermined"):
        v = _other_oscillations(v, res, scene, modes)
    if v.get("other") is not None:
        out["other"] = v.pop("other")
    out.update(verdict=v["verdict"], verdict_reason=v["reason"], decide_by=v["decide_by"],
               verdict_modes=v["modes"],
               stable={"stable": True, "unstable": False}.get(v["verdict"]))
    if scene is not None:
        out["linear_loop"] = linearisation(scene).text()     # what the "linear" roots are of
        out["validity"] = validity(res, scene)
    return out


@dataclass(frozen=True)
class ReportFacts:
    """What the figures of a run draw besides its summary, computed once by the job
    (:func:`report_facts`) and handed to :mod:`orchestration.report` as data: ``roots``, the
    closed-loop roots of the scene's linearised loop (its rung's, with its damping law:
    :func:`~orchestration.studies.analysis.linearisation`), with its bending root and first
    bending frequency; ``own``, whether that loop is the rung's own (False for the exact rung,
    whose loop the floating frame's stands in for); ``bending_band``, the lowest frequency
    (rad/s) of the bending oscillation the summary fits (:data:`BENDING_BAND`); ``untrusted``,
    the words for the codes of why a run has no error figure
    (:data:`orchestration.studies.error_figure.UNTRUSTED`)."""

    roots: LoopRoots
    own: bool = True
    bending_band: float = BENDING_BAND[0]
    untrusted: dict = field(default_factory=lambda: dict(UNTRUSTED), repr=False)


def report_facts(scene) -> ReportFacts:
    """:class:`ReportFacts` of a scene: its linearised loop's roots, once (a sampled scene's:
    the s-plane equivalents of its sampled loop's poles)."""
    lin = linearisation(scene)
    c = scene.controller
    if c.sampled:                       # the sampled loop's poles, as s-plane equivalents
        from .sampled import controller_poles
        lam = controller_poles(lin.params, c).s
        roots = roots_of(lam[np.isfinite(lam)], first_bending_frequency(lin.params))
    else:
        roots = loop_roots(lin.params, c)
    return ReportFacts(roots, own=lin.own)
