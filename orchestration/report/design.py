"""What ``flexpend design`` shows and writes: the worst case against the cutoff, the loop's Bode
plot with and without the chosen filter, the root locus over the cutoff (nominal beam), as
figures and files (``design.json``, ``design_sweep.csv`` and three PNGs)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plant_fmu.params import damping_text

from ..files import atomic_path, check_folder, write_json
from . import figures
from .files import save_figure
from .text import filter_text

__all__ = ["DesignReport"]


@dataclass
class DesignReport:
    """A design (:class:`~orchestration.studies.design.DesignResult`) of the filter of
    ``controller``'s PD on the nominal ``plant``, with its figures and files; ``curves``: what
    the figures draw, computed with the design
    (:class:`~orchestration.studies.design.DesignCurves`)."""

    result: object
    plant: object
    controller: object
    settings: dict
    curves: object = field(repr=False)
    written: list = field(default_factory=list)
    record: dict = field(default_factory=dict)     # design.json, once saved

    def to_json(self) -> dict:
        """What ``flexpend design --json`` prints: the chosen filter under its scene keys, its
        worst case, the best filter of each order, the loop without a filter and the given one."""
        return self.result.to_json()

    def figures(self) -> dict:
        """``{file name: Figure}``: the worst case against the cutoff, the Bode plot, the root
        locus."""
        r, p, c = self.result, self.plant, self.controller
        ch = r.chosen
        chosen_label = f"chosen: {filter_text(ch.filter_order, ch.cutoff, ch.filter_damping)}"
        ylabel = ("worst-case decay rate -max Re(lambda) (1/s)" if r.criterion == "decay"
                  else "worst-case damping ratio")
        uset = r.uncertainty.describe()
        out = {"design_worst_case.png": figures.worst_case(
            r.sweep, (ch.cutoff, r.worst.score(r.criterion), chosen_label), ylabel,
            f"worst case over n_modes {uset['n_modes'][0]}..{uset['n_modes'][1]}, zeta "
            f"{uset['zeta'][0]:g}..{uset['zeta'][1]:g} ({p.damping} law), EI "
            f"+-{100 * r.uncertainty.EI_spread:g} %, m +-{100 * r.uncertainty.m_spread:g} % "
            f"(PD kp = {c.kp:g}, kd = {c.kd:g})")}
        cv = self.curves
        w = cv.w
        labels = {"none": "PD, no filter", "chosen": chosen_label.replace("chosen: ", "PD + "),
                  "given": f"PD + given {filter_text(c.filter_order, c.cutoff, c.filter_damping)}"}
        loops = {labels[k]: L for k, L in cv.loops.items()}
        out["design_bode.png"] = figures.loop_bode(
            w, loops, f"loop broken at the force, L = -K G (PD kp = {c.kp:g}, kd = {c.kd:g}; "
                      f"nominal beam, {p.n_modes} modes, {damping_text(p)})",
            [(ch.cutoff, "cutoff")])
        wcs, roots = cv.cutoffs, cv.roots
        kind = "1st order" if ch.filter_order == 1 else f"2nd order, zf = {ch.filter_damping:g}"
        out["design_root_locus.png"] = figures.root_locus(
            wcs, roots, ch.cutoff, f"closed-loop roots as the cutoff varies ({kind}; nominal "
                                   f"beam, {p.n_modes} modes, {damping_text(p)})")
        return out

    def __repr__(self) -> str:
        """One line: the filter chosen, its worst case and the criterion."""
        r = self.result
        ch, w = r.chosen, r.worst
        return (f"DesignReport(chosen {filter_text(ch.filter_order, ch.cutoff, ch.filter_damping)}"
                f"; worst case decay rate {w.decay:.4g} 1/s, damping ratio {w.damping:.4g} over "
                f"{w.n_plants} plants; criterion {r.criterion})")

    def save(self, folder) -> list[Path]:
        """Write ``design.json``, ``design_sweep.csv`` and the figures into the folder
        ``folder`` (a ValueError for a path that names a file); the paths written (each file
        complete or absent)."""
        folder = check_folder(folder)
        folder.mkdir(parents=True, exist_ok=True)
        r = self.result
        labels = list(r.sweep)
        rows = np.column_stack([r.sweep[labels[0]][0]] + [r.sweep[k][1] for k in labels])
        header = "cutoff," + ",".join(k.replace(",", ";") for k in labels)
        written = []
        with atomic_path(folder / "design_sweep.csv") as tmp:
            np.savetxt(tmp, rows, delimiter=",", header=header, comments="")
        written.append(folder / "design_sweep.csv")
        plots = [save_figure(fig, folder / name, dpi=90) for name, fig in self.figures().items()]
        out = self.to_json()
        out["plots"] = [str(p) for p in sorted(plots, key=lambda p: p.name)]
        out["sweep_csv"] = str(written[0])
        written.insert(0, write_json(folder / "design.json", out))
        self.record = out
        self.written = written + sorted(plots, key=lambda p: p.name)
        return self.written
