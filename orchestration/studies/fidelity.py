"""Fidelity selection: the smallest plant model a scene needs.

``plant.n_modes = "auto"`` (in a scene or by ``--set``) is resolved here, before the
co-simulation, by measuring the scene's own outputs over the scene's own run on the monolithic
closed loop (:func:`orchestration.studies.reference.simulate_reference`, DOP853 at
``rtol = 1e-8``: its error is far below any sensible tolerance):

1. Modes (``n_modes = "auto"``). The linearised loop's stability verdict is computed for every
   ``n = 0 .. fidelity.max_modes``; a model whose verdict differs from that of any richer model is
   skipped (it predicts stability wrongly: one cantilever mode says the PD is stable, two say it is
   not). From the first model left, ``n`` and ``n + 1`` are simulated, and the first ``n`` whose
   outputs agree with ``n + 1`` to ``fidelity.tolerance`` is chosen. If none does up to
   ``fidelity.max_modes``, the richest is taken and the summary says the ladder did not converge.
   The modes are compared with the nonlinear model when the fidelity is also ``auto``.
2. Fidelity (``fidelity = "auto"``). The run starts on the lowest rung of :data:`LADDER` that
   is a ``plant.fidelity`` value and climbs: after each run, if the run's error figure
   (:mod:`orchestration.studies.error_figure`: its difference from its companion run, scaled,
   plus the companion's own error) is more than ``fidelity.tolerance`` times the largest
   ``|phi_o|`` of the run, or the figure cannot be trusted (it then says why), the run is
   repeated on the next rung up (:func:`climb`; the run loop is
   :func:`orchestration.job.run_scene`). When the companion cannot run, the rung's measured
   global bound (:mod:`orchestration.studies.validity`) decides instead, and the reason says so.
   The top available rung is kept, and the summary says so.

For ``n_modes``, two runs agree when, for every output in ``fidelity.outputs``, the largest
difference over the run is at most ``tolerance`` times the largest magnitude of that output in the
richer run.
"""
from __future__ import annotations

import numpy as np

from plant_fmu.interface import FIDELITIES

from ..scene.keys import ConfigError
from ..scene.records import AUTO
from .analysis import linearisation, max_real_part
from .reference import simulate_reference
from .validity import assess

__all__ = ["LADDER", "available_ladder", "refused_rungs", "climb", "output_difference",
           "select_model"]

#: The fidelity ladder, bottom to top (``plant.fidelity`` values; ``plant.gravity_preload`` is
#: kept as the scene sets it). A name that is not (yet) a ``plant.fidelity`` value is skipped.
LADDER = ("linear", "nonlinear", "stiffened", "exact")

#: Accuracy of the monolithic runs that are compared.
RTOL, ATOL = 1e-8, 1e-10


def output_difference(a: np.ndarray, b: np.ndarray, outputs) -> dict:
    """Per output: ``max |a - b| / max |b|`` over the run (``b`` the richer model's run)."""
    out = {}
    for col in outputs:
        scale = float(np.max(np.abs(b[col])))
        diff = float(np.max(np.abs(a[col] - b[col])))
        out[col] = diff / scale if scale > 0 else (0.0 if diff == 0 else float("inf"))
    return out


def available_ladder(scene=None) -> tuple:
    """The rungs of :data:`LADDER` this build offers, bottom to top; with a ``scene``, only those
    its FMUs, master and damping law can run (the exact rung refuses, e.g., the pythonfmu plant,
    Model Exchange and the modal law with damping: :func:`refused_rungs` says why)."""
    rungs = tuple(f for f in LADDER if f in FIDELITIES)
    if scene is None:
        return rungs
    refused = refused_rungs(scene)
    return tuple(f for f in rungs if f not in refused)


def refused_rungs(scene) -> dict:
    """``{rung: why}``: the rungs of the ladder this build offers that ``scene`` cannot run, each
    with the scene's one-line refusal (:class:`orchestration.scene.records.Scene`)."""
    n = 0 if scene.plant.n_modes_auto else scene.plant.n_modes
    out = {}
    for f in (f for f in LADDER if f in FIDELITIES):
        try:
            scene.replace(plant=scene.plant.with_model(n, f))
        except ConfigError as exc:
            out[f] = str(exc)
    return out


def climb(fidelity: str, figure: dict, tolerance: float, ladder: tuple | None = None,
          refused: dict | None = None, bound: dict | None = None):
    """``(next fidelity or None, reason)``: whether a run on ``fidelity`` is repeated on the next
    rung up of ``ladder`` (default :func:`available_ladder`; see the module docstring).

    ``figure``: the run's error figure (the summary's ``error_figure``,
    :func:`orchestration.studies.error_figure.assess`): the run climbs while the figure is more
    than ``tolerance`` times the run's largest ``|phi_o|``, or while it cannot be trusted; when
    its companion could not run, the measured global bound (``bound``, the summary's
    ``validity``) decides instead. A ``validity`` entry in place of ``figure`` (a run without
    a figure: ``flexpend export``'s monolithic runs) is judged by its bound.
    ``refused``: why the scene cannot run the rungs left out of ``ladder``
    (:func:`refused_rungs`), said when the climb stops below them."""
    if fidelity == LADDER[-1]:
        rung = figure.get("rung", fidelity)
        return None, f"{rung}: the top rung (the reference of every measured error): kept"
    def judged(what, value, rel, tail=""):
        """The reason for a stated ``value`` (rad): the text, and whether it meets the
        tolerance."""
        ok = rel <= tolerance
        return (f"{rung}: {what} <= {value:.1e} rad, {100 * rel:.3g} % of max |phi_o| "
                f"{'<=' if ok else '>'} {100 * tolerance:g} %{tail}"), ok

    ok = False
    if "figure" in figure and not (figure["untrusted"] == "companion" and bound is not None
                                   and bound.get("model_form_error") is not None):
        rung = figure["rung"]
        if figure["figure"] is None:
            why = f"{rung}: no error figure ({figure['why']})"
        else:
            why, ok = judged("error", figure["figure"], figure["relative"])
    else:
        if "figure" in figure:
            fallback = f" (no error figure, {figure['why']}: the measured global bound)"
            figure = bound
        else:
            fallback = ""
        rung, b = figure["rung"], figure["model_form_error"]
        if b is None:
            why = f"{rung}: no measured bound{fallback}"
        elif figure["outside"]:
            why = f"{rung}: outside its measured range ({figure['outside'][0]}){fallback}"
        else:
            why, ok = judged("model-form error", b, figure["relative"], fallback)
    if ok:
        return None, f"{why}: kept"
    ladder = available_ladder() if ladder is None else ladder
    i = ladder.index(fidelity) if fidelity in ladder else len(ladder) - 1
    if i + 1 < len(ladder):
        return ladder[i + 1], f"{why}: climbs to {ladder[i + 1]}"
    refused = refused or {}
    missing = [f"{f} not available" + (f", {refused[f]}" if f in refused else "")
               for f in LADDER[LADDER.index(ladder[-1]) + 1:]]
    return None, (f"{why}; {fidelity} is the top available rung"
                  + (f" ({', '.join(missing)})" if missing else "") + ": kept")


def _label(n: int, fid: str) -> str:
    return f"{n} mode{'' if n == 1 else 's'}, {fid}"


def select_model(scene, progress=None, monolithic: bool = False):
    """``(resolved scene, report)``: the scene with ``plant.n_modes`` chosen and
    ``plant.fidelity = "auto"`` on the lowest rung (the run climbs from there:
    :func:`orchestration.job.run_scene`), and a JSON-ready report of the choice and the
    differences measured. ``monolithic``: climb here, on the monolithic runs of the scene (for a
    scene that is not co-simulated: ``flexpend export``). ``progress(fraction, label)``: the
    fraction of the monolithic runs done (counted: every model the choice may solve), the label
    naming the model being solved (``"flexible_pd: choosing the model: solving 3 modes,
    nonlinear"``)."""
    tol, outs, n_max = scene.fidelity.tolerance, scene.fidelity.outputs, scene.fidelity.max_modes
    auto_n, auto_f = scene.plant.n_modes_auto, scene.plant.fidelity == AUTO
    mode_fid = "nonlinear" if auto_f else scene.plant.fidelity
    runs = {}
    total = (n_max + 2 if auto_n else 0) + (len(available_ladder()) if auto_f and monolithic
                                            else 0)

    def concrete(n, fid):
        return scene.replace(plant=scene.plant.with_model(n, fid))

    def run(n, fid):
        if (n, fid) not in runs:
            sub, k = None, len(runs)
            if progress is not None:
                label = f"{scene.name}: choosing the model: solving {_label(n, fid)}"

                def solving(f):
                    progress(min(1.0, (k + f) / max(total, 1)), label)
                sub = solving
                sub(0.0)
            try:
                runs[(n, fid)] = simulate_reference(concrete(n, fid), rtol=RTOL, atol=ATOL,
                                                    progress=sub)
            except RuntimeError as exc:
                raise ConfigError(f"{scene.name}: fidelity selection: the {_label(n, fid)} model "
                                  f"could not be solved ({exc})") from None
        return runs[(n, fid)]

    def compare(small, rich):
        d = output_difference(run(*small), run(*rich), outs)
        worst = max(d, key=d.get)
        return {"model": _label(*small), "richer": _label(*rich), "difference": d,
                "largest": d[worst], "largest_output": worst, "agrees": d[worst] <= tol}

    report = {"tolerance": tol, "outputs": list(outs), "n_modes_auto": auto_n,
              "fidelity_auto": auto_f, "comparisons": []}
    reasons = []
    if auto_n:
        c = scene.controller
        verdicts = []
        for n in range(n_max + 1):
            mrp = max_real_part(linearisation(concrete(n, mode_fid)).params, c)
            verdicts.append({"n_modes": n, "max_real_part": mrp, "stable": mrp < 0})
        report["linear_verdicts"] = verdicts
        stable = [v["stable"] for v in verdicts]
        start = next(n for n in range(n_max + 1) if len(set(stable[n:])) == 1)
        if start > 0:
            richer = "stable" if stable[start] else "unstable"
            reasons.append(
                f"0..{start - 1} modes predict a {'stable' if stable[start - 1] else 'unstable'} "
                f"linearised loop, but {start}..{n_max} modes predict it {richer} (max real part "
                f"{verdicts[start - 1]['max_real_part']:+.3g} with {start - 1}, "
                f"{verdicts[start]['max_real_part']:+.3g} with {start}): too few modes predict "
                "stability wrongly")
        n, converged = start, False
        while n < n_max:
            cmp_ = compare((n, mode_fid), (n + 1, mode_fid))
            report["comparisons"].append(cmp_)
            reasons.append(f"{cmp_['model']} vs {cmp_['richer']}: {100 * cmp_['largest']:.3g} % "
                           f"({cmp_['largest_output']}) {'<=' if cmp_['agrees'] else '>'} "
                           f"{100 * tol:g} %")
            if cmp_["agrees"]:
                converged = True
                break
            n += 1
        if not converged:
            reasons.append(f"no model up to {n_max} modes agrees with the next richer one: the "
                           f"richest, {n_max} modes, is taken")
        report["converged"] = converged
    else:
        n = scene.plant.n_modes
    fid = scene.plant.fidelity
    if auto_f:
        ladder, refused = available_ladder(scene), refused_rungs(scene)
        fid = ladder[0]
        reasons.append(f"plant.fidelity = auto: starts on the lowest rung, {fid}")
        while monolithic:
            v = assess(run(n, fid), concrete(n, fid))
            nxt, why = climb(fid, v, tol, ladder, refused)
            reasons.append(f"{why} (monolithic run)")
            if nxt is None:
                break
            fid = nxt
        report["climb"] = reasons[1:] if monolithic else []
    if progress is not None:
        progress(1.0)
    report.update(n_modes=n, fidelity=fid, reason="; ".join(reasons))
    return concrete(n, fid), report
