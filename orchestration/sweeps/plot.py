"""The sweep's figure: a heat map, a line plot or a histogram of the decay rates.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..report.figures import new_figure
from ..report.files import save_figure
from .plan import SweepPlan, design_worst_case

__all__ = ["plot_sweep"]


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


def _decay(r):
    v = r.get("decay_rate") if r["status"] == "ok" else None
    return math.nan if v is None else v


def plot_sweep(plan: SweepPlan, rows, path: Path) -> Path | None:
    """Heat map (2 swept axes), line plot (1 axis) or histogram (a sample) of the decay rate
    ``-max(fitted rate)``; failed runs marked. None when the sweep has no such shape."""

    title = f"flexpend sweep {plan.scene.name}" + (
        f" ({' '.join('--set ' + o for o in plan.overrides)})" if plan.overrides else "")
    failed = [r for r in rows if r["status"] != "ok"]
    if plan.samplers:
        fig = new_figure(8, 5)
        ax = fig.subplots()
        vals = np.array([_decay(r) for r in rows])
        vals = vals[np.isfinite(vals)]
        lin = np.array([r.get("linear_decay_rate") for r in rows if r["status"] == "ok"
                        and r.get("linear_decay_rate") is not None], dtype=float)
        design = design_worst_case(plan)
        marks = [*vals, *lin, *([] if design is None else [design.decay])]
        if marks:
            lo, hi = min(marks), max(marks)
            pad = 0.05 * (hi - lo or 1.0)
            bins = np.linspace(lo - pad, hi + pad,
                               max(10, min(60, int(np.sqrt(max(len(vals), len(lin)))) * 2)))
            if len(vals):
                ax.hist(vals, bins=bins, color="C0", edgecolor="white",
                        label="co-simulation: -max(fitted rate)")
            if len(lin):
                ax.hist(lin, bins=bins, histtype="step", color="C1", lw=1.5,
                        label="linearised loop: -max Re(lambda)")
            if len(vals):
                ax.axvline(vals.min(), color="C0", lw=1.2, ls=":",
                           label=f"worst fitted {vals.min():+.4g} 1/s")
            if design is not None:
                ax.axvline(design.decay, color="k", lw=1.2, ls="--",
                           label=f"flexpend design's worst case over the set (linear) "
                                 f"{design.decay:+.4g} 1/s")
            if lo - pad < 0 < hi + pad:
                ax.axvline(0.0, color="r", lw=1, label="0: grows to the left")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no run has a reliable fit or a linearised loop: no decay rate "
                    "to show", transform=ax.transAxes,
                    ha="center", va="center", fontsize=9, color="0.3")
        ax.set_xlabel("decay rate, 1/s")
        ax.set_ylabel("runs")
        from matplotlib.ticker import MaxNLocator
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        keys = ", ".join(s.key for s in plan.samplers)
        ax.set_title(f"{title}\n{len(rows)} runs ({len(plan.points) // max(plan.n_samples, 1)} "
                     f"x {plan.n_samples} samples of {keys}, seed {plan.seed}); "
                     f"{len(failed)} failed, {len(rows) - len(failed) - len(vals)} without a fit",
                     fontsize=9)
    elif len(plan.axes) == 1:
        axis = plan.axes[0]
        fig = new_figure(8, 5)
        ax = fig.subplots()
        x = np.arange(len(axis.values))
        for col, label, style in (("decay_rate", "decay rate -max(fitted rate)", "k-o"),
                                  ("linear_decay_rate", "linearised loop: -max Re(lambda)",
                                   "k:"),
                                  ("slow_rate", "slow (rigid) rate, fitted", "C0--s"),
                                  ("bending_rate", "bending rate, fitted", "C1--^")):
            y = [math.nan if r["status"] != "ok" or r.get(col) is None else r[col] for r in rows]
            ax.plot(x, y, style, ms=4, lw=1.2, label=label)
        bad = [i for i, r in enumerate(rows) if r["status"] != "ok"]
        if bad:
            ax.plot(bad, [0.0] * len(bad), "rx", ms=9, mew=2, label="failed run")
        ax.axhline(0.0, color="0.5", lw=0.8)
        _ticks(ax, axis, axis.values, "x")
        ax.set_ylabel("1/s")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        ax.set_title(title, fontsize=9)
    elif len(plan.axes) == 2:
        from matplotlib.colors import TwoSlopeNorm
        ax0, ax1 = plan.axes
        grid = np.array([_decay(r) for r in rows]).reshape(len(ax0.values), len(ax1.values))
        fig = new_figure(9, 6.5)
        ax = fig.subplots()
        finite = grid[np.isfinite(grid)]
        # colours up to the 5th/95th percentile (one outlier does not wash out the rest); the
        # cells of a small grid carry their values
        lim = max(float(np.percentile(np.abs(finite), 95)) if finite.size else 1.0, 1e-12)
        from matplotlib import colormaps
        im = ax.imshow(np.ma.masked_invalid(grid.T), origin="lower", aspect="auto",
                       cmap=colormaps["RdBu"].with_extremes(bad="0.8"),
                       norm=TwoSlopeNorm(vmin=-lim, vcenter=0.0, vmax=lim))
        if grid.size <= 150:
            for (i, j), v in np.ndenumerate(grid):
                if np.isfinite(v):
                    ax.text(i, j, f"{v:+.3g}", ha="center", va="center", fontsize=7,
                            color="w" if abs(v) > 0.6 * lim else "k")
        for r in failed:
            i, j = divmod(r["run"], len(ax1.values))
            ax.plot(i, j, "kx", ms=9, mew=2)
        _ticks(ax, ax0, ax0.values, "x")
        _ticks(ax, ax1, ax1.values, "y")
        fig.colorbar(im, ax=ax, extend="both",
                     label="decay rate -max(fitted rate), 1/s (red: grows)")
        ax.set_title(title + "\nx: failed run; grey: no fit", fontsize=9)
    else:
        return None
    fig.tight_layout()
    return save_figure(fig, path)
    return path

