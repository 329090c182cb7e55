"""What both renderers of the plotting vocabulary (:mod:`orchestration.report.plotting`)
share: the grid of panels, the superscript digits, the gap above a panel for its notes."""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Grid", "SUPERSCRIPT", "NOTE_GAP"]

#: The gap in points between a panel's frame and the notes above it (``panel.note``): a note
#: sits in the strip between two panels, never on the data.
NOTE_GAP = 2.0

#: Digits and signs as Unicode superscripts: ``"-2".translate(SUPERSCRIPT) == "⁻²"``.
SUPERSCRIPT = str.maketrans("-−0123456789", "⁻⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


@dataclass(frozen=True)
class Grid:
    """Rows and columns of panels in figure fractions, spaced as matplotlib's ``GridSpec``:
    ``wspace``/``hspace`` are fractions of a panel's width/height."""

    nrows: int
    ncols: int
    left: float = 0.125
    right: float = 0.9
    top: float = 0.88
    bottom: float = 0.11
    wspace: float = 0.2
    hspace: float = 0.2

    def box(self, row: int, col: int, colspan: int = 1) -> tuple:
        """``(x0, y0, x1, y1)`` of a cell (``colspan`` columns wide), figure fractions."""
        w = (self.right - self.left) / (self.ncols + self.wspace * (self.ncols - 1))
        h = (self.top - self.bottom) / (self.nrows + self.hspace * (self.nrows - 1))
        x0 = self.left + col * w * (1 + self.wspace)
        x1 = self.left + (col + colspan - 1) * w * (1 + self.wspace) + w
        y1 = self.top - row * h * (1 + self.hspace)
        return x0, y1 - h, x1, y1
