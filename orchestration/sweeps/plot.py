"""The sweep's figure: a heat map, line plots or a histogram of the runs' largest growth rates
(the figures' one sign convention, :data:`~orchestration.report.figures.RATE_CONVENTION`: the
table's ``decay_rate`` with its sign turned). Each counts the runs' verdicts with "undetermined"
(no fit decides, or stopped early) apart from "unstable", and each quantity has an axis of its
own, with its unit.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..report.figures import RATE_CONVENTION, new_figure
from ..report.files import save_figure
from .plan import SweepPlan, design_worst_case

__all__ = ["plot_sweep", "sweep_figure", "column_figure", "verdict_text"]

#: The verdict strip of a line plot: category -> (colour, marker), in the strip's order.
_STRIP = {"stable": ("C2", "o"), "unstable": ("C3", "v"), "undetermined": ("0.5", "s"),
          "stopped early": ("k", "x"), "lost": ("m", "d")}


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


def _value(r, column):
    """A run's value of ``column`` (``-column``: its negative), NaN where it has none: a fit only
    from a completed run, the linearised loop's from any run that had one."""
    if column.startswith("-"):
        return -_value(r, column[1:])
    v = r.get(column) if r["status"] == "ok" or "linear" in column else None
    return math.nan if v is None else v


def _category(r) -> str:
    """A run's place in the verdict strip."""
    if r["status"] in ("failed", "lost"):
        return "stopped early" if r["status"] == "failed" else "lost"
    v = r.get("verdict") or "undetermined"
    return "undetermined" if v == "stopped" else v


def verdict_text(rows) -> str:
    """``verdicts: 3 stable, 1 unstable, 2 undetermined (1 whose fits do not decide, 1 stopped
    early)``."""
    cats = [_category(r) for r in rows]
    why = ", ".join(f"{n} {text}" for n, text in
                    ((cats.count("undetermined"), "whose fits do not decide"),
                     (cats.count("stopped early"), "stopped early")) if n)
    lost = cats.count("lost")
    return (f"verdicts: {cats.count('stable')} stable, {cats.count('unstable')} unstable, "
            f"{cats.count('undetermined') + cats.count('stopped early')} undetermined"
            + (f" ({why})" if why else "") + (f", {lost} lost" if lost else ""))


def _lines(ax, x, rows, series, ylabel):
    """Plot the ``(column, label, style)`` series that have a value; label the axis; a legend
    of the plotted ones only. False when none had a value."""
    drawn = False
    for col, label, style in series:
        y = [_value(r, col) for r in rows]
        if any(math.isfinite(v) for v in y):
            ax.plot(x, y, style, ms=4, lw=1.2, label=label)
            drawn = True
    ax.set_ylabel(ylabel, fontsize=8)
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=7)
    return drawn


def plot_sweep(plan: SweepPlan, rows, path: Path) -> Path | None:
    """Write :func:`sweep_figure` to ``path``; None when the sweep has no such figure."""
    fig = sweep_figure(plan, rows)
    return None if fig is None else save_figure(fig, path)


def sweep_figure(plan: SweepPlan, rows):
    """Heat map (2 swept axes), line plots (1 axis) or histogram (a sample) of the largest
    growth rate ``σ = max(fitted rate)`` (minus the table's ``decay_rate``; negative: every mode
    decays), the verdicts counted in the title; None when the sweep has no such shape."""

    title = f"flexpend sweep {plan.scene.name}" + (
        f" ({' '.join('--set ' + o for o in plan.overrides)})" if plan.overrides else "")
    if plan.columns is not None and not {"decay_rate", "verdict"} <= set(plan.columns):
        return column_figure(plan, rows, title)
    rates = f"rates: {RATE_CONVENTION}"
    if plan.samplers:
        fig = new_figure(8, 5)
        ax = fig.subplots()
        vals = np.array([_value(r, "-decay_rate") for r in rows])
        vals = vals[np.isfinite(vals)]
        lin = -np.array([r.get("linear_decay_rate") for r in rows if r["status"] == "ok"
                         and r.get("linear_decay_rate") is not None], dtype=float)
        design = design_worst_case(plan)
        marks = [*vals, *lin, *([] if design is None else [-design.decay])]
        if marks:
            lo, hi = min(marks), max(marks)
            pad = 0.05 * (hi - lo or 1.0)
            bins = np.linspace(lo - pad, hi + pad,
                               max(10, min(60, int(np.sqrt(max(len(vals), len(lin)))) * 2)))
            if len(vals):
                ax.hist(vals, bins=bins, color="C0", edgecolor="white",
                        label="co-simulation: max(fitted σ)")
            if len(lin):
                ax.hist(lin, bins=bins, histtype="step", color="C1", lw=1.5,
                        label="linearised loop: max Re(λ)")
            if len(vals):
                ax.axvline(vals.max(), color="C0", lw=1.2, ls=":",
                           label=f"worst fitted σ = {vals.max():+.4g} 1/s")
            if design is not None:
                ax.axvline(-design.decay, color="k", lw=1.2, ls="--",
                           label=f"flexpend design's worst case over the set (linear) "
                                 f"σ = {-design.decay:+.4g} 1/s")
            if lo - pad < 0 < hi + pad:
                ax.axvline(0.0, color="r", lw=1, label="0: grows to the right")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no run has a reliable fit or a linearised loop: no growth rate "
                    "to show", transform=ax.transAxes,
                    ha="center", va="center", fontsize=9, color="0.3")
        ax.set_xlabel("largest growth rate σ, 1/s")
        ax.set_ylabel("runs")
        from matplotlib.ticker import MaxNLocator
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        keys = ", ".join(s.key for s in plan.samplers)
        ax.set_title(f"{title}\n{len(rows)} runs ({len(plan.points) // max(plan.n_samples, 1)} "
                     f"x {plan.n_samples} samples of {keys}, seed {plan.seed})\n"
                     f"{verdict_text(rows)}\n{rates}", fontsize=9)
    elif len(plan.axes) == 1:
        axis = plan.axes[0]
        x = np.arange(len(axis.values))
        panels = [
            ([("-decay_rate", "co-simulation: max(fitted σ)", "k-o"),
              ("-linear_decay_rate", "linearised loop: max Re(λ)", "k:")],
             "largest growth rate\nσ, 1/s"),
            ([("slow_rate", "fitted", "C0-s"), ("slow_rate_linear", "linearised loop", "C0:")],
             "slow (rigid) mode:\nσ = Re(λ), 1/s"),
            ([("bending_rate", "fitted", "C1-^"),
              ("bending_rate_linear", "linearised loop", "C1:")],
             "bending mode:\nσ = Re(λ), 1/s")]
        # a mode's panel only where some run has that mode (fitted or linear)
        panels = panels[:1] + [pn for pn in panels[1:] if any(
            math.isfinite(_value(r, col)) for r in rows for col, _, _ in pn[0])]
        fig = new_figure(8, 2.2 * len(panels) + 1.6)
        axes = fig.subplots(len(panels) + 1, 1, sharex=True,
                            gridspec_kw={"height_ratios": [3] * len(panels) + [1.3]})
        for ax, (series, ylabel) in zip(axes, panels):
            if not _lines(ax, x, rows, series, ylabel):
                ax.text(0.5, 0.5, "no run has a value", transform=ax.transAxes, ha="center",
                        va="center", fontsize=8, color="0.4")
        axes[0].axhline(0.0, color="0.5", lw=0.8)
        strip = axes[-1]
        cats = [c for c in _STRIP if c != "lost" or any(r["status"] == "lost" for r in rows)]
        for i, r in enumerate(rows):
            colour, marker = _STRIP[_category(r)]
            strip.plot(i, cats.index(_category(r)), marker, color=colour, ms=6)
        strip.set_yticks(range(len(cats)))
        strip.set_yticklabels(cats, fontsize=7)
        strip.set_ylim(len(cats) - 0.5, -0.5)
        strip.set_ylabel("verdict", fontsize=8)
        strip.grid(alpha=0.3, axis="x")
        _ticks(strip, axis, axis.values, "x")
        axes[0].set_title(f"{title}\n{verdict_text(rows)}\n{rates}", fontsize=9)
    elif len(plan.axes) == 2:
        from matplotlib.colors import TwoSlopeNorm
        ax0, ax1 = plan.axes
        grid = np.array([_value(r, "-decay_rate") for r in rows]).reshape(len(ax0.values),
                                                                           len(ax1.values))
        fig = new_figure(9, 6.5)
        ax = fig.subplots()
        finite = grid[np.isfinite(grid)]
        # colours up to the 5th/95th percentile (one outlier does not wash out the rest); the
        # cells of a small grid carry their values
        lim = max(float(np.percentile(np.abs(finite), 95)) if finite.size else 1.0, 1e-12)
        from matplotlib import colormaps
        im = ax.imshow(np.ma.masked_invalid(grid.T), origin="lower", aspect="auto",
                       cmap=colormaps["RdBu_r"].with_extremes(bad="0.8"),
                       norm=TwoSlopeNorm(vmin=-lim, vcenter=0.0, vmax=lim))
        if grid.size <= 150:
            for (i, j), v in np.ndenumerate(grid):
                if np.isfinite(v):
                    ax.text(i, j, f"{v:+.3g}", ha="center", va="center", fontsize=7,
                            color="w" if abs(v) > 0.6 * lim else "k")
        for r in rows:
            i, j = divmod(r["run"], len(ax1.values))
            if r["status"] != "ok":
                ax.plot(i, j, "kx", ms=9, mew=2)
            elif not np.isfinite(grid[i, j]) and grid.size <= 150:
                ax.text(i, j, "no\nverdict", ha="center", va="center", fontsize=6,
                        color="0.25")
        _ticks(ax, ax0, ax0.values, "x")
        _ticks(ax, ax1, ax1.values, "y")
        fig.colorbar(im, ax=ax, extend="both",
                     label="largest growth rate σ = max(fitted rate), 1/s (red: grows)")
        ax.set_title(f"{title}\n{verdict_text(rows)}\ngrey: undetermined (no fit decides); "
                     f"x: stopped early\n{rates}", fontsize=9)
    else:
        return None
    fig.tight_layout()
    return fig


def _numeric(rows, column) -> bool:
    """Whether ``column`` holds a number (not a flag) in some completed run."""
    return any(isinstance(r.get(column), (int, float)) and not isinstance(r.get(column), bool)
               for r in rows if r["status"] == "ok")


def column_figure(plan: SweepPlan, rows, title: str = ""):
    """The figure of a sweep asked for some columns only (``--columns`` without both
    ``decay_rate`` and ``verdict``): the first numeric column asked for, as a histogram (a
    sample), a line (1 axis) or a heat map (2 axes) over the completed runs; None when no
    column asked for holds a number."""
    from .columns import RESULT_COLUMNS

    column = next((c for c in plan.columns if _numeric(rows, c)), None)
    if column is None:
        return None
    label = f"{column}: {RESULT_COLUMNS[column]}"
    vals = np.array([_value(r, column) for r in rows], dtype=float)
    finite = vals[np.isfinite(vals)]
    missing = len(rows) - finite.size
    counts = f"{len(rows)} runs" + (f", {missing} without a value" if missing else "")
    if "verdict" in plan.columns:
        counts += f"; {verdict_text(rows)}"
    if plan.samplers:
        fig = new_figure(8, 5)
        ax = fig.subplots()
        bins = max(10, min(60, int(np.sqrt(finite.size)) * 2))
        ax.hist(finite, bins=bins, color="C0", edgecolor="white")
        if finite.size:
            worst = int(np.nanargmax(vals))
            ax.axvline(finite.max(), color="C3", lw=1.2, ls=":",
                       label=f"largest: {finite.max():.4g} (run {rows[worst]['run']})")
            ax.axvline(float(np.median(finite)), color="k", lw=1.2, ls="--",
                       label=f"median: {float(np.median(finite)):.4g}")
            ax.legend(fontsize=8)
        ax.set_xlabel(label)
        ax.set_ylabel("runs")
        from matplotlib.ticker import MaxNLocator
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        keys = ", ".join(s.key for s in plan.samplers)
        ax.set_title(f"{title}\n{counts} ({len(plan.points) // max(plan.n_samples, 1)} x "
                     f"{plan.n_samples} samples of {keys}, seed {plan.seed})", fontsize=9)
    elif len(plan.axes) == 1:
        axis = plan.axes[0]
        fig = new_figure(8, 4.5)
        ax = fig.subplots()
        ax.plot(np.arange(len(vals)), vals, "C0-o", ms=4, lw=1.2)
        stopped = [i for i, r in enumerate(rows) if r["status"] != "ok"]
        if stopped:                     # on the axis' foot: the runs without a value
            from matplotlib.transforms import blended_transform_factory
            ax.plot(stopped, [0.03] * len(stopped), "x", color="C3", ms=7, mew=2,
                    transform=blended_transform_factory(ax.transData, ax.transAxes),
                    label="stopped early or lost (no value)")
            ax.legend(fontsize=8)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(alpha=0.3)
        _ticks(ax, axis, axis.values, "x")
        ax.set_title(f"{title}\n{counts}", fontsize=9)
    elif len(plan.axes) == 2:
        ax0, ax1 = plan.axes
        grid = vals.reshape(len(ax0.values), len(ax1.values))
        fig = new_figure(9, 6.5)
        ax = fig.subplots()
        from matplotlib import colormaps
        im = ax.imshow(np.ma.masked_invalid(grid.T), origin="lower", aspect="auto",
                       cmap=colormaps["viridis"].with_extremes(bad="0.8"))
        if grid.size <= 150:
            lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0, 1)
            for (i, j), v in np.ndenumerate(grid):
                if np.isfinite(v):           # dark on viridis' light end
                    light = hi > lo and (v - lo) / (hi - lo) > 0.6
                    ax.text(i, j, f"{v:.3g}", ha="center", va="center", fontsize=7,
                            color="k" if light else "w")
        for r in rows:
            if r["status"] != "ok":
                i, j = divmod(r["run"], len(ax1.values))
                ax.plot(i, j, "kx", ms=9, mew=2)
        _ticks(ax, ax0, ax0.values, "x")
        _ticks(ax, ax1, ax1.values, "y")
        fig.colorbar(im, ax=ax, label=label)
        ax.set_title(f"{title}\n{counts}" + ("; grey: no value (x: stopped early or lost)"
                                              if missing else ""), fontsize=9)
    else:
        return None
    fig.tight_layout()
    return fig
