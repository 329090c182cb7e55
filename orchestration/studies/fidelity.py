"""Fidelity selection: the smallest plant model a scene needs.

``plant.n_modes = "auto"`` and ``plant.fidelity = "auto"`` (in a scene or by ``--set``) are
resolved here, before the co-simulation, by measuring the scene's own outputs over the scene's own
run on the monolithic closed loop (:func:`orchestration.studies.reference.simulate_reference`, DOP853 at
``rtol = 1e-8``: its error is far below any sensible tolerance):

1. Modes (``n_modes = "auto"``). The linearised loop's stability verdict is computed for every
   ``n = 0 .. fidelity.max_modes``; a model whose verdict differs from that of any richer model is
   skipped (it predicts stability wrongly: one cantilever mode says the PD is stable, two say it is
   not). From the first model left, ``n`` and ``n + 1`` are simulated, and the first ``n`` whose
   outputs agree with ``n + 1`` to ``fidelity.tolerance`` is chosen. If none does up to
   ``fidelity.max_modes``, the richest is taken and the summary says the ladder did not converge.
   The modes are compared with the nonlinear model when the fidelity is also ``auto``.
2. Fidelity (``fidelity = "auto"``). At the chosen ``n`` the linear model is compared with the
   nonlinear one; linear is chosen when they agree to the tolerance.

Two runs agree when, for every output in ``fidelity.outputs``, the largest difference over the run
is at most ``tolerance`` times the largest magnitude of that output in the richer run.
"""
from __future__ import annotations

import numpy as np

from ..scene.keys import ConfigError
from ..scene.records import AUTO
from .analysis import max_real_part
from .reference import simulate_reference

__all__ = ["output_difference", "select_model"]

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


def _label(n: int, fid: str) -> str:
    return f"{n} mode{'' if n == 1 else 's'}, {fid}"


def select_model(scene, progress=None):
    """``(resolved scene, report)``: the scene with ``plant.n_modes`` and ``plant.fidelity``
    chosen, and a JSON-ready report of the choice and the differences measured."""
    tol, outs, n_max = scene.fidelity.tolerance, scene.fidelity.outputs, scene.fidelity.max_modes
    auto_n, auto_f = scene.plant.n_modes_auto, scene.plant.fidelity == AUTO
    mode_fid = "nonlinear" if auto_f else scene.plant.fidelity
    runs = {}
    total = (n_max + 2 if auto_n else 0) + (2 if auto_f else 0)

    def concrete(n, fid):
        return scene.replace(plant=scene.plant.with_model(n, fid))

    def run(n, fid):
        if (n, fid) not in runs:
            try:
                runs[(n, fid)] = simulate_reference(concrete(n, fid), rtol=RTOL, atol=ATOL)
            except RuntimeError as exc:
                raise ConfigError(f"{scene.name}: fidelity selection: the {_label(n, fid)} model "
                                  f"could not be solved ({exc})") from None
            if progress is not None:
                progress(min(1.0, len(runs) / max(total, 1)))
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
            mrp = max_real_part(scene.plant.beam.replace(n_modes=n), c)
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
        cmp_ = compare((n, "linear"), (n, "nonlinear"))
        report["comparisons"].append(cmp_)
        fid = "linear" if cmp_["agrees"] else "nonlinear"
        reasons.append(f"{cmp_['model']} vs {cmp_['richer']}: {100 * cmp_['largest']:.3g} % "
                       f"({cmp_['largest_output']}) {'<=' if cmp_['agrees'] else '>'} "
                       f"{100 * tol:g} %: {fid}")
    if progress is not None:
        progress(1.0)
    report.update(n_modes=n, fidelity=fid, reason="; ".join(reasons))
    return concrete(n, fid), report
