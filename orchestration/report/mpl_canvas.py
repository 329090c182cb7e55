"""The matplotlib renderer of the plotting vocabulary (:mod:`orchestration.report.plotting`):
a Figure of its own (no pyplot), and the helpers its saving and its log axes use."""
from __future__ import annotations

import re
from contextlib import contextmanager

import numpy as np

from .layout import NOTE_GAP, SUPERSCRIPT, Grid

__all__ = ["new_figure", "MplCanvas", "MplPanel", "ticks_in_view", "plain_log_labels"]


def new_figure(width: float, height: float):
    """A matplotlib Figure of its own (no pyplot: the process's backend and pyplot's figures are
    left alone); :func:`orchestration.report.files.save_figure` writes it."""
    from matplotlib.figure import Figure
    return Figure(figsize=(width, height))


@contextmanager
def ticks_in_view(fig):
    """Within the block, each axis of ``fig`` has a fixed locator holding the ticks its own
    locators give that lie in view (the ticks drawn), and the locators are put back after it.
    The figure draws the same, and matplotlib makes no tick beyond the view: each tick costs
    about a millisecond to make (its lines and labels), and about a quarter lie beyond the view.
    ``save_figure`` saves inside it."""
    from matplotlib.ticker import FixedLocator

    saved = []
    for ax in fig.axes:
        for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            lo, hi = min(lo, hi), max(lo, hi)
            tol = 1e-9 * (hi - lo)
            for which in ("major", "minor"):
                ticker = getattr(axis, which)          # shared by the axes of a shared axis
                if isinstance(ticker.locator, FixedLocator):
                    continue
                locs = np.asarray(ticker.locator(), dtype=float)
                saved.append((ticker, ticker.locator))
                ticker.locator = FixedLocator(locs[(locs >= lo - tol) & (locs <= hi + tol)])
                ticker.locator.set_axis(axis)
    try:
        yield fig
    finally:
        for ticker, locator in reversed(saved):
            ticker.locator = locator


def plain_log_labels(axis) -> None:
    """Label a log or symlog ``axis`` (after its scale is set) as matplotlib does, but in plain
    Unicode (``10⁻²``, ``2×10⁻³``, ``−10¹``) instead of mathtext: a figure drawn
    without mathtext never builds matplotlib's mathtext parser (about 0.3 s in a process)."""
    from matplotlib.ticker import LogFormatter, LogFormatterSciNotation

    class Plain(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            text = super().__call__(x, pos)
            math_ = re.fullmatch(r"\$\\mathdefault\{(.*)\}\$", text)
            if math_ is None:
                return text
            body = re.sub(r"\^\{([^}]*)\}", lambda m: m.group(1).translate(SUPERSCRIPT),
                          math_.group(1))
            return body.replace("\\times", "×").replace("-", "−")

    for which in ("major", "minor"):
        f = getattr(axis, f"get_{which}_formatter")()
        if isinstance(f, LogFormatter):                 # the same settings, plain labels
            plain = Plain.__new__(Plain)
            plain.__dict__.update(vars(f))
            getattr(axis, f"set_{which}_formatter")(plain)


class MplCanvas:
    """The vocabulary on a matplotlib Figure (``result()``)."""

    def __init__(self, width: float, height: float):
        self.figure = new_figure(width, height)
        self._specs = {}

    def grid(self, nrows, ncols, **spacing) -> Grid:
        return Grid(nrows, ncols, **spacing)

    def _spec(self, grid: Grid):
        if grid not in self._specs:
            self._specs[grid] = self.figure.add_gridspec(
                grid.nrows, grid.ncols, left=grid.left, right=grid.right, top=grid.top,
                bottom=grid.bottom, wspace=grid.wspace, hspace=grid.hspace)
        return self._specs[grid]

    def panels(self, grid: Grid, *, sharex: bool = False) -> list:
        axes = self._spec(grid).subplots(sharex=sharex, squeeze=False)
        return [[MplPanel(ax) for ax in row] for row in axes]

    def panel(self, grid: Grid, row: int, col: int, *, colspan: int = 1, sharex=None):
        spec = self._spec(grid)[row, col:col + colspan]
        return MplPanel(self.figure.add_subplot(spec, sharex=sharex.ax if sharex else None))

    def title(self, text: str, *, size: float, y: float):
        self.figure.suptitle(text, fontsize=size, y=y, va="top")

    def text(self, x: float, y: float, text: str, *, size: float, color="k", va="baseline"):
        self.figure.text(x, y, text, fontsize=size, color=color, va=va)

    def legend(self, *, ncol: int, size: float, y: float):
        self.figure.legend(loc="upper center", ncol=ncol, fontsize=size, frameon=False,
                           bbox_to_anchor=(0.5, y))

    @staticmethod
    def locate(lo: float, hi: float, n: int):
        from matplotlib.ticker import MaxNLocator

        t = np.asarray(MaxNLocator(n).tick_values(lo, hi))
        return t[(t >= lo) & (t <= hi)]

    def result(self):
        return self.figure


_COORDS = {"data": "transData", "axes": "transAxes"}


class MplPanel:
    """The vocabulary on a matplotlib Axes (``ax``)."""

    def __init__(self, ax):
        self.ax = ax
        self.notes: list = []           # the Annotations of :meth:`note`

    def line(self, x, y, *, color="C0", lw=1.0, style="-", alpha=None, label=None,
             butt=False):
        self.ax.plot(x, y, style, color=color, lw=lw, alpha=alpha, label=label,
                     **({"solid_capstyle": "butt"} if butt else {}))

    def markers(self, x, y, *, marker="o", color="C0", size=6.0, hollow=False, mew=None,
                alpha=None, label=None):
        self.ax.plot(x, y, marker, color=color, ms=size, mew=mew, alpha=alpha, label=label,
                     **({"mfc": "none"} if hollow else {}))

    def hline(self, y, *, color="k", lw=1.0, style="-", label=None):
        self.ax.axhline(y, color=color, lw=lw, ls=style, label=label)

    def vline(self, x, *, color="k", lw=1.0, style="-", label=None):
        self.ax.axvline(x, color=color, lw=lw, ls=style, label=label)

    def xspan(self, lo, hi, *, color="C2", alpha=None, label=None, outline=False):
        if outline:                     # its edges, dashed: not filled
            self.ax.axvspan(lo, hi, fill=False, edgecolor=color, ls="--", lw=1.0, label=label)
        else:
            self.ax.axvspan(lo, hi, color=color, alpha=alpha, lw=0, label=label)

    def rect(self, x, y, width, height, *, color="C1"):
        from matplotlib.patches import Rectangle
        self.ax.add_patch(Rectangle((x, y), width, height, color=color))

    def text(self, x, y, text, *, coords="data", size=8.0, color="k", ha="left",
             va="baseline"):
        transform = (self.ax.get_xaxis_transform() if coords == "xaxis"
                     else getattr(self.ax, _COORDS[coords]))
        self.ax.text(x, y, text, transform=transform, fontsize=size, color=color, ha=ha, va=va)

    def note(self, text, *, size=7.0, color="C3"):
        """A note in the strip above the panel's frame, right-aligned: never on the data (a
        second note ends where the one before begins)."""
        if self.notes:
            xy, xycoords, gap = (0.0, 1.0), (self.notes[-1], "axes fraction"), -size
        else:
            xy, xycoords, gap = (1.0, 1.0), "axes fraction", 0.0
        self.notes.append(self.ax.annotate(
            text, xy=xy, xycoords=xycoords, xytext=(gap, NOTE_GAP), textcoords="offset points",
            ha="right", va="bottom", fontsize=size, color=color, annotation_clip=False,
            gid="note"))

    def xlabel(self, text, *, size=8.0, pad=None):
        self.ax.set_xlabel(text, fontsize=size, labelpad=pad)

    def ylabel(self, text, *, size=8.0):
        self.ax.set_ylabel(text, fontsize=size)

    def title(self, text, *, size=9.0, loc="center", pad=None):
        self.ax.set_title(text, fontsize=size, loc=loc, pad=pad, y=1.0)

    def xlim(self, lo, hi):
        self.ax.set_xlim(lo, hi)

    def ylim(self, lo, hi):
        self.ax.set_ylim(lo, hi)

    def xscale(self, scale, *, linthresh=1.0):
        self._scale("x", scale, linthresh)

    def yscale(self, scale, *, linthresh=1.0):
        self._scale("y", scale, linthresh)

    def _scale(self, which, scale, linthresh):
        from matplotlib.ticker import NullFormatter

        getattr(self.ax, f"set_{which}scale")(
            scale, **({"linthresh": linthresh} if scale == "symlog" else {}))
        axis = getattr(self.ax, f"{which}axis")
        if scale == "log":                          # labelled decades, no crowded minor labels
            axis.set_minor_formatter(NullFormatter())
        if scale != "linear":
            plain_log_labels(axis)

    def equal_aspect(self):
        self.ax.set_aspect("equal", adjustable="box")

    def grid(self, x=None, y=None):
        """Grid lines at the ticks, or (``x``, ``y`` given) at those positions (one set of lines
        shared by panels whose ticks differ)."""
        if x is None and y is None:
            self.ax.grid(alpha=0.3)
            return
        from matplotlib import rcParams
        style = {"color": rcParams["grid.color"], "lw": rcParams["grid.linewidth"],
                 "alpha": 0.3, "zorder": 1.5}
        self.ax.vlines(x, 0, 1, transform=self.ax.get_xaxis_transform(), **style)
        self.ax.hlines(y, 0, 1, transform=self.ax.get_yaxis_transform(), **style)

    def ticks(self, x=None, y=None):
        from matplotlib.ticker import FixedLocator, NullLocator

        for axis, locs in ((self.ax.xaxis, x), (self.ax.yaxis, y)):
            if locs is not None:
                axis.set_major_locator(FixedLocator(locs) if len(locs) else NullLocator())

    def tick_labels(self, size):
        self.ax.tick_params(labelsize=size)

    def legend(self, *, loc="upper right", size=7.0, outside=False):
        if outside:                                 # beside the panel, top-aligned
            self.ax.legend(fontsize=size, loc="upper left", bbox_to_anchor=(1.03, 1.0),
                           borderaxespad=0)
        else:
            self.ax.legend(loc=loc, fontsize=size)

    def hide(self):
        self.ax.set_visible(False)

    @property
    def box(self) -> tuple:
        b = self.ax.get_position()
        return b.x0, b.y0, b.x1, b.y1
