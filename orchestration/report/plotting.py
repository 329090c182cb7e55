"""The small plotting vocabulary the figures of a run are written in, and its two renderers.

Each figure of :mod:`orchestration.report.figures` that ``flexpend run`` draws is written once,
against this vocabulary; a renderer draws it:

* ``"matplotlib"`` (:class:`~orchestration.report.mpl_canvas.MplCanvas`): a matplotlib Figure
  of its own (the Python API's ``Run.plot()``, ``Run.plot_shapes()``; any format ``savefig``
  writes);
* ``"raster"`` (:class:`~orchestration.report.raster.RasterCanvas`): a PNG drawn with Pillow,
  in a few tens of milliseconds and without importing matplotlib (``flexpend run``'s default).

The grid and the superscripts both share are in :mod:`orchestration.report.layout`.

The vocabulary (sizes in points, figure sizes in inches, colours as matplotlib names them:
``"C0"``..``"C9"``, a grey level ``"0.3"``, ``"k"``):

* a canvas: ``grid(nrows, ncols, left=, right=, top=, bottom=, wspace=, hspace=)`` (a
  :class:`Grid`, figure fractions as matplotlib's ``GridSpec``), ``panels(grid, sharex=)`` (every
  cell, rows of panels; a shared x axis labelled under the last row only), ``panel(grid, row,
  col, colspan=, sharex=)``, ``title`` (the figure's, top at ``y``), ``text``, ``legend`` (of
  every panel's labelled items, across the top), ``locate(lo, hi, n)`` (at most ``n + 1`` nice
  ticks), ``result()`` (what the figure function returns);
* a panel: ``line``, ``markers``, ``hline``, ``vline``, ``xspan`` (filled, or with
  ``outline=True`` only its dashed edges), ``rect``, ``text`` (in
  ``"data"``, ``"axes"`` or ``"xaxis"`` coordinates: x in data, y in axes fraction),
  ``xlabel``, ``ylabel``, ``title``, ``xlim``, ``ylim``, ``xscale``/``yscale`` (``"linear"``,
  ``"log"``, ``"symlog"``), ``equal_aspect``, ``grid`` (at the ticks, or at given positions),
  ``ticks`` (fixed positions; empty: none), ``tick_labels(size)``, ``legend``, ``note`` (a
  note in the strip above the frame, right-aligned, off the data), ``hide``, ``box`` (its place
  in figure fractions).
"""
from __future__ import annotations

from .layout import SUPERSCRIPT, Grid

__all__ = ["RENDERERS", "check_renderer", "FIGURES", "check_figures", "canvas", "Grid",
           "SUPERSCRIPT"]

#: The renderers of :func:`canvas`.
RENDERERS = ("raster", "matplotlib")


def _one_of(name: str, value, allowed: tuple) -> str:
    """``value`` if it is one of ``allowed``, else a ValueError naming ``name`` and them."""
    if value not in allowed:
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: "
                         + ", ".join(repr(a) for a in allowed))
    return value


def check_renderer(renderer) -> str:
    """``renderer`` if it is one of :data:`RENDERERS`, else a ValueError naming it."""
    return _one_of("renderer", renderer, RENDERERS)


#: What ``flexpend run --figures`` (``Run.save(figures=)``) writes: the PNGs, or none (nothing
#: drawn; the CSV files and the summary are the same).
FIGURES = ("png", "none")


def check_figures(figures) -> str:
    """``figures`` if it is one of :data:`FIGURES`, else a ValueError naming it."""
    return _one_of("figures", figures, FIGURES)


def canvas(width: float, height: float, renderer: str = "matplotlib"):
    """A canvas of ``width`` x ``height`` inches drawn by ``renderer`` (one of
    :data:`RENDERERS`)."""
    if check_renderer(renderer) == "matplotlib":
        from .mpl_canvas import MplCanvas
        return MplCanvas(width, height)
    from .raster import RasterCanvas
    return RasterCanvas(width, height)
