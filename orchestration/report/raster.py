"""The raster renderer of the plotting vocabulary (:mod:`orchestration.report.plotting`): PNG
files drawn with Pillow, without importing matplotlib (``flexpend run``'s figures, each in a few
tens of milliseconds instead of one or two hundred).

A :class:`RasterCanvas` records what a figure function draws and draws it all in
:meth:`RasterCanvas.save`: the insides of the panels and the legends at twice the resolution
asked, reduced by averaging (antialiased lines, markers and edges), frames and ticks on whole
pixels, text by FreeType at the resolution asked; with matplotlib's defaults where the
vocabulary leaves a choice (5 % margins around the data, 3.5 pt ticks outside the frame, labels
4 pt beyond the tick labels, the tab10 colours, DejaVu Sans), ticks on 1-2-5 steps
(:func:`nice_ticks`), decades on log and symmetric-log axes (:func:`log_ticks`,
:func:`symlog_ticks`). Sizes are in points and inches, as matplotlib's."""
from __future__ import annotations

import math
from contextlib import contextmanager
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .layout import NOTE_GAP, SUPERSCRIPT, Grid

__all__ = ["RasterCanvas", "RasterPanel", "nice_ticks", "log_ticks", "symlog_ticks",
           "tick_text", "font_path", "rgb", "DPI", "OVERSAMPLE"]

#: Dots per inch of the PNG (as ``save_figure``'s default), and the factor it is drawn larger by.
DPI = 110
OVERSAMPLE = 2

#: matplotlib's default colour cycle (tab10), ``"C0"``..``"C9"``.
TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
         "#bcbd22", "#17becf")
_NAMED = {"k": (0, 0, 0), "black": (0, 0, 0), "w": (255, 255, 255), "white": (255, 255, 255)}
#: matplotlib's defaults, in points: tick length, width and pad; axis label pad; title pad; frame.
TICK, TICK_W, MINOR, MINOR_W, TICK_PAD, LABEL_PAD, TITLE_PAD, FRAME_W = (
    3.5, 0.8, 2.0, 0.6, 3.5, 4.0, 6.0, 0.8)
#: The grid: matplotlib's #b0b0b0 at alpha 0.3, as it shows on white (drawn opaque: no layer).
GRID_COLOR, GRID_W, MARGIN = "#e7e7e7", 0.8, 0.05
#: The line width of an outlined span (``xspan(outline=True)``), points.
OUTLINE_W = 1.0
#: (on, off) lengths of a line style, in line widths (matplotlib's, scaled by the width).
DASHES = {"--": (3.7, 1.6), ":": (1.0, 1.65), "-.": (6.4, 1.6, 1.0, 1.6)}


def rgb(color) -> tuple:
    """An RGB triple of a colour named as matplotlib names it: ``"C3"``, ``"0.3"`` (grey level),
    ``"k"``, ``"#d62728"``."""
    c = str(color)
    if c in _NAMED:
        return _NAMED[c]
    if len(c) == 2 and c[0] == "C" and c[1].isdigit():
        c = TAB10[int(c[1])]
    if c.startswith("#") and len(c) == 7:
        return tuple(int(c[i:i + 2], 16) for i in (1, 3, 5))
    try:
        level = float(c)
    except ValueError:
        level = math.nan
    if not 0.0 <= level <= 1.0:
        raise ValueError(f"colour {color!r} is not allowed; allowed: 'C0'..'C9', a grey level "
                         "'0'..'1', 'k', 'w', '#rrggbb'")
    return (round(255 * level),) * 3


@lru_cache(maxsize=1)
def font_path() -> str | None:
    """DejaVu Sans as matplotlib ships it, found without importing matplotlib; None without
    it."""
    import importlib.util
    from pathlib import Path

    try:
        spec = importlib.util.find_spec("matplotlib")
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec else []:
        path = Path(folder) / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"
        if path.is_file():
            return str(path)
    return None


@lru_cache(maxsize=64)
def _font(px: int):
    path = font_path()
    if path is not None:
        try:
            return ImageFont.truetype(path, px, layout_engine=ImageFont.Layout.BASIC)
        except OSError:
            pass
    return ImageFont.load_default(px)


@lru_cache(maxsize=64)
def _metrics(px: int) -> tuple:
    """``(ascent, descent)`` in pixels of the font at ``px`` (Pillow's bitmap font, the last
    fallback, has none: its height above the baseline)."""
    font = _font(px)
    if hasattr(font, "getmetrics"):
        return font.getmetrics()
    return font.getbbox("Ag")[3], 0


@lru_cache(maxsize=2048)
def _line(px: int, text: str) -> tuple:
    """``(width, mask)`` of one line of ``text`` at ``px`` pixels: its advance and its glyphs as
    an "L" image whose top left is the line's (the ascender's) top left. Kept: tick labels and
    axis labels repeat across the panels and figures of a run."""
    font = _font(px)
    ascent, descent = _metrics(px)
    width = font.getlength(text)
    _, _, right, bottom = font.getbbox(text)
    mask = Image.new("L", (max(1, math.ceil(max(width, right)) + 1),
                           max(1, math.ceil(max(bottom, ascent + descent)) + 1)), 0)
    ImageDraw.Draw(mask).text((0, 0), text, font=font, fill=255)
    return width, mask


# ---------------------------------------------------------------------- ticks
def nice_ticks(lo: float, hi: float, nbins: int) -> np.ndarray:
    """The ticks in ``[lo, hi]`` on the smallest step of 1, 2 or 5 times a power of ten whose
    ticks enclosing ``[lo, hi]`` make at most ``nbins`` intervals (matplotlib's ``MaxNLocator``
    rule, on 1-2-5 steps)."""
    lo, hi = min(lo, hi), max(lo, hi)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.array([])
    power = 10.0 ** math.floor(math.log10((hi - lo) / max(int(nbins), 1)))
    for step in (m * power * f for f in (0.1, 1.0, 10.0, 100.0) for m in (1, 2, 5)):
        if math.ceil(hi / step - 1e-9) - math.floor(lo / step + 1e-9) <= max(int(nbins), 1):
            break
    first, last = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
    ticks = np.arange(first, last + 1) * step
    ticks[np.abs(ticks) < 1e-12 * step] = 0.0
    return ticks


def tick_text(values) -> list:
    """Labels of linear ticks as matplotlib writes them: one number of decimals for all (that of
    their step), a minus sign ``−``."""
    values = np.asarray(values, dtype=float)
    if len(values) == 0:
        return []
    step = np.min(np.diff(values)) if len(values) > 1 else abs(values[0]) or 1.0
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    out = []
    for v in values:
        s = f"{v:.{decimals}f}"
        if float(s) == 0:
            s = s.lstrip("-")
        out.append(s.replace("-", "−"))
    return out


def _decade(k: int, sign: str = "") -> str:
    return f"{sign}10{str(k).translate(SUPERSCRIPT)}"


def log_ticks(lo: float, hi: float, nbins: int) -> tuple:
    """``(major, labels, minor)`` of a log axis over ``[lo, hi]`` (both > 0): the decades
    (every second or more when they are many), labelled ``10⁻²``; the minor ticks at 2..9 times
    each decade."""
    k0, k1 = math.ceil(math.log10(lo) - 1e-9), math.floor(math.log10(hi) + 1e-9)
    stride = max(1, math.ceil((k1 - k0 + 1) / max(nbins, 1)))
    ks = [k for k in range(k0, k1 + 1) if k % stride == 0]
    minor = [m * 10.0 ** k for k in range(k0 - 1, k1 + 1) for m in range(2, 10)
             if lo <= m * 10.0 ** k <= hi] if stride == 1 else []
    return np.array([10.0 ** k for k in ks]), [_decade(k) for k in ks], np.array(minor)


def symlog_ticks(lo: float, hi: float, linthresh: float, nbins: int) -> tuple:
    """``(major, labels, minor)`` of a symmetric-log axis: 0 and the decades ``±10^k`` at or
    beyond ``linthresh`` in ``[lo, hi]`` (every second or more when they are many), labelled
    ``−10²``, ``0``, ``10⁰``; no minor ticks (as matplotlib draws it)."""
    k_lin = math.ceil(math.log10(linthresh) - 1e-9)
    top = max(abs(lo), abs(hi))
    k_top = math.floor(math.log10(top) + 1e-9) if top >= 10.0 ** k_lin else k_lin - 1
    ks = list(range(k_lin, k_top + 1))
    count = 2 * len(ks) + 1
    stride = max(1, math.ceil(count / max(nbins + 1, 1)))
    majors, labels = [], []
    for sign in (-1, 1):
        for i, k in enumerate(ks):
            v = sign * 10.0 ** k
            if lo <= v <= hi and i % stride == 0:
                majors.append(v)
                labels.append(_decade(k, "−" if sign < 0 else ""))
    if lo <= 0.0 <= hi:
        majors.append(0.0)
        labels.append("0")
    order = np.argsort(majors)
    return np.array(majors)[order], [labels[i] for i in order], np.array([])


class _Scale:
    """Data <-> a linear coordinate: ``linear``, ``log`` (base 10) or ``symlog`` (base 10,
    linear within ``linthresh``, matplotlib's ``linscale = 1``)."""

    def __init__(self, kind: str = "linear", linthresh: float = 1.0):
        if kind not in ("linear", "log", "symlog"):
            raise ValueError(f"scale {kind!r} is not allowed; allowed: 'linear', 'log', 'symlog'")
        self.kind, self.lt = kind, float(linthresh)
        self.adj = 1.0 / (1.0 - 0.1)

    def fwd(self, v):
        v = np.asarray(v, dtype=float)
        if self.kind == "linear":
            return v
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.kind == "log":
                return np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
            a = np.abs(v)
            out = np.sign(v) * self.lt * (self.adj + np.log10(np.maximum(a, self.lt) / self.lt))
            return np.where(a <= self.lt, v * self.adj, out)

    def inv(self, u):
        u = np.asarray(u, dtype=float)
        if self.kind == "linear":
            return u
        if self.kind == "log":
            return 10.0 ** u
        a = np.abs(u)
        inside = a <= self.lt * self.adj
        return np.where(inside, u / self.adj,
                        np.sign(u) * self.lt * 10.0 ** (a / self.lt - self.adj))


# ---------------------------------------------------------------------- the canvas
class RasterCanvas:
    """A figure of ``width`` x ``height`` inches, drawn when saved (:meth:`save`, :meth:`image`);
    its panels (:attr:`panels`), title, texts and legend stay readable (the structure drawn)."""

    def __init__(self, width: float, height: float):
        self.width, self.height = float(width), float(height)
        self.panels_made: list = []
        self.suptitle = None                    # (text, size, y)
        self.texts: list = []                   # (x, y, text, size, color, va)
        self.fig_legend = None                  # (ncol, size, y)

    # the vocabulary
    def grid(self, nrows, ncols, **spacing) -> Grid:
        return Grid(nrows, ncols, **spacing)

    def panels(self, grid: Grid, *, sharex: bool = False) -> list:
        rows = [[self.panel(grid, r, c) for c in range(grid.ncols)] for r in range(grid.nrows)]
        if sharex:
            for row in rows:
                for p in row:
                    p.share(rows[0][0])
            for row in rows[:-1]:
                for p in row:
                    p.x_tick_labels = False             # labelled under the last row only
        return rows

    def panel(self, grid: Grid, row: int, col: int, *, colspan: int = 1, sharex=None):
        p = RasterPanel(grid.box(row, col, colspan))
        if sharex is not None:
            p.share(sharex)
        self.panels_made.append(p)
        return p

    def title(self, text, *, size, y):
        self.suptitle = (text, size, y)

    def text(self, x, y, text, *, size, color="k", va="baseline"):
        self.texts.append((x, y, text, size, color, va))

    def legend(self, *, ncol, size, y):
        self.fig_legend = (ncol, size, y)

    @staticmethod
    def locate(lo, hi, n):
        return nice_ticks(lo, hi, n)

    def result(self):
        return self

    # drawing
    def image(self, dpi: int = DPI) -> Image.Image:
        """The figure drawn at ``dpi`` (an RGB image of ``round(width * dpi)`` x
        ``round(height * dpi)`` pixels)."""
        w, h = round(self.width * dpi), round(self.height * dpi)
        pen = _Pen(Image.new("RGB", (w, h), "white"), dpi / 72.0)
        visible = [p for p in self.panels_made if not p.hidden]
        for p in visible:
            p.layout(pen)
        for p in visible:
            p.draw(pen)
        W, H = pen.img.size
        if self.suptitle is not None:
            text, size, y = self.suptitle
            pen.text(W / 2, (1 - y) * H, text, size, "k", "center", "top")
        for x, y, text, size, color, va in self.texts:
            pen.text(x * W, (1 - y) * H, text, size, color, "left", va)
        if self.fig_legend is not None:
            ncol, size, y = self.fig_legend
            entries = [e for p in visible for e in p.legend_entries()]
            pen.legend(entries, size, W / 2, (1 - y) * H, anchor="top", ncol=ncol, frame=False)
        pen.draw_texts()
        return pen.img

    def save(self, path, dpi: int = DPI, fmt: str = "png"):
        """Write the figure to ``path`` as PNG, by Pillow at ``files.PNG_COMPRESS_LEVEL``
        (:func:`~orchestration.report.files.save_figure` writes it under a temporary name and
        renames it into place)."""
        if fmt != "png":
            raise ValueError(f"the raster renderer writes PNG files, not {fmt!r}; use "
                             "renderer='matplotlib' for other formats")
        from .files import PNG_COMPRESS_LEVEL

        self.image(dpi).save(path, format="PNG", compress_level=PNG_COMPRESS_LEVEL)


class RasterPanel:
    """One panel: what was drawn in it (``items``, in order) and how it is labelled."""

    def __init__(self, box):
        self.box = tuple(box)
        self.items: list = []                   # (kind, zorder, data: dict)
        self.x_label = self.y_label = None      # (text, size, pad)
        self.titles: dict = {}                  # loc -> (text, size, pad)
        self.limits = {"x": None, "y": None}
        self.scales = {"x": _Scale(), "y": _Scale()}
        self.fixed_ticks = {"x": None, "y": None}
        self.grid_at = None                     # True: at the ticks; (xs, ys): there
        self.label_size = 10.0
        self.legend_spec = None                 # (loc, size, outside)
        self.notes: list = []                   # (text, size, color): above the frame
        self.note_boxes: list = []              # their (left, top, right, bottom), drawn
        self.hidden = False
        self.equal = False
        self.x_tick_labels = True
        self.group = [self]                     # the panels sharing this one's x axis

    def share(self, other):
        if other.group is not self.group:
            other.group.extend(self.group)
            for p in self.group:
                p.group = other.group

    # the vocabulary
    def _add(self, kind, zorder, **data):
        self.items.append((kind, zorder, data))

    def line(self, x, y, *, color="C0", lw=1.0, style="-", alpha=None, label=None, butt=False):
        self._add("line", 2, x=np.asarray(x, float), y=np.asarray(y, float), color=color, lw=lw,
                  style=style, alpha=alpha, label=label)

    def markers(self, x, y, *, marker="o", color="C0", size=6.0, hollow=False, mew=None,
                alpha=None, label=None):
        self._add("markers", 2, x=np.asarray(x, float).ravel(), y=np.asarray(y, float).ravel(),
                  marker=marker, color=color, size=size, hollow=hollow,
                  mew=1.0 if mew is None else mew, alpha=alpha, label=label)

    def hline(self, y, *, color="k", lw=1.0, style="-", label=None):
        self._add("hline", 2, y=float(y), color=color, lw=lw, style=style, label=label)

    def vline(self, x, *, color="k", lw=1.0, style="-", label=None):
        self._add("vline", 2, x=float(x), color=color, lw=lw, style=style, label=label)

    def xspan(self, lo, hi, *, color="C2", alpha=None, label=None, outline=False):
        self._add("xspan", 1, lo=float(lo), hi=float(hi), color=color, alpha=alpha, label=label,
                  outline=bool(outline))

    def rect(self, x, y, width, height, *, color="C1"):
        self._add("rect", 1, x=float(x), y=float(y), w=float(width), h=float(height),
                  color=color)

    def text(self, x, y, text, *, coords="data", size=8.0, color="k", ha="left",
             va="baseline"):
        if coords not in ("data", "axes", "xaxis"):
            raise ValueError(f"coords = {coords!r} is not allowed; allowed: 'data', 'axes', "
                             "'xaxis'")
        self._add("text", 3, x=float(x), y=float(y), text=text, coords=coords, size=size,
                  color=color, ha=ha, va=va)

    def note(self, text, *, size=7.0, color="C3"):
        """A note in the strip above the panel's frame, right-aligned: never on the data."""
        self.notes.append((text, size, color))

    def xlabel(self, text, *, size=8.0, pad=None):
        self.x_label = (text, size, LABEL_PAD if pad is None else pad)

    def ylabel(self, text, *, size=8.0):
        self.y_label = (text, size, LABEL_PAD)

    def title(self, text, *, size=9.0, loc="center", pad=None):
        self.titles[loc] = (text, size, TITLE_PAD if pad is None else pad)

    def xlim(self, lo, hi):
        self.limits["x"] = (float(lo), float(hi))

    def ylim(self, lo, hi):
        self.limits["y"] = (float(lo), float(hi))

    def xscale(self, scale, *, linthresh=1.0):
        self.scales["x"] = _Scale(scale, linthresh)

    def yscale(self, scale, *, linthresh=1.0):
        self.scales["y"] = _Scale(scale, linthresh)

    def equal_aspect(self):
        self.equal = True

    def grid(self, x=None, y=None):
        self.grid_at = True if x is None and y is None else (x, y)

    def ticks(self, x=None, y=None):
        if x is not None:
            self.fixed_ticks["x"] = np.asarray(x, float)
        if y is not None:
            self.fixed_ticks["y"] = np.asarray(y, float)

    def tick_labels(self, size):
        self.label_size = float(size)

    def legend(self, *, loc="upper right", size=7.0, outside=False):
        self.legend_spec = (loc, size, outside)

    def hide(self):
        self.hidden = True

    # what is drawn
    def legend_entries(self) -> list:
        return [(kind, d) for kind, _, d in self.items
                if d.get("label") and not str(d["label"]).startswith("_")]

    def _extent(self, axis: str) -> list:
        """The data values of the items along ``axis`` (what autoscaling covers)."""
        out = []
        for kind, _, d in self.items:
            if kind in ("line", "markers"):
                out.append(d[axis])
            elif kind == "hline" and axis == "y":
                out.append([d["y"]])
            elif kind in ("vline",) and axis == "x":
                out.append([d["x"]])
            elif kind == "xspan" and axis == "x":
                out.append([d["lo"], d["hi"]])
            elif kind == "rect":
                v, size = (d["x"], d["w"]) if axis == "x" else (d["y"], d["h"])
                out.append([v, v + size])
        return out

    def _auto(self, axis: str, panels) -> tuple:
        scale = self.scales[axis]
        values = [np.asarray(v, float).ravel() for p in panels for v in p._extent(axis)]
        u = scale.fwd(np.concatenate(values)) if values else np.array([])
        u = u[np.isfinite(u)]
        if u.size == 0:
            lo, hi = 0.0, 1.0
        else:
            lo, hi = float(u.min()), float(u.max())
            if hi - lo <= 1e-12 * max(abs(lo), abs(hi), 1e-300):
                d = 0.05 * abs(lo) if lo else 0.05
                lo, hi = lo - d, hi + d
            pad = MARGIN * (hi - lo)
            lo, hi = lo - pad, hi + pad
        return tuple(float(v) for v in scale.inv([lo, hi]))

    def layout(self, pen):
        """The limits, the pixel box and the ticks (before any panel draws: a shared axis needs
        every panel's data)."""
        W, H = pen.img.size
        xs = [p for p in self.group if p.limits["x"] is not None]
        self.lim = {"x": xs[0].limits["x"] if xs else self._auto("x", self.group),
                    "y": self.limits["y"] or self._auto("y", [self])}
        x0, y0, x1, y1 = self.box
        left, right, top, bottom = x0 * W, x1 * W, (1 - y1) * H, (1 - y0) * H
        self.u = {a: self.scales[a].fwd(self.lim[a]) for a in "xy"}
        if self.equal:                          # lengths to scale: the box shrinks, centred
            dx, dy = abs(self.u["x"][1] - self.u["x"][0]), abs(self.u["y"][1] - self.u["y"][0])
            if dx > 0 and dy > 0:
                want = (bottom - top) / (right - left)
                if dy / dx < want:
                    h = (right - left) * dy / dx
                    top, bottom = (top + bottom - h) / 2, (top + bottom + h) / 2
                else:
                    w = (bottom - top) * dx / dy
                    left, right = (left + right - w) / 2, (left + right + w) / 2
        self.px = (left, top, right, bottom)
        self.tick_marks = {}
        for a in "xy":
            length = (right - left if a == "x" else bottom - top) / pen.scale
            nbins = int(np.clip(length // (self.label_size * (3 if a == "x" else 2)), 1, 9))
            lo, hi = sorted(self.lim[a])
            kind = self.scales[a].kind
            if self.fixed_ticks[a] is not None:
                major = self.fixed_ticks[a]
                major = major[(major >= lo - 1e-9 * (hi - lo)) & (major <= hi + 1e-9 * (hi - lo))]
                labels, minor = tick_text(major), np.array([])
            elif kind == "log":
                major, labels, minor = log_ticks(lo, hi, nbins)
            elif kind == "symlog":
                major, labels, minor = symlog_ticks(lo, hi, self.scales[a].lt, nbins)
            else:
                major = nice_ticks(lo, hi, nbins)
                labels, minor = tick_text(major), np.array([])
            self.tick_marks[a] = (major, labels, minor)

    def to_px(self, x, y, coords="data"):
        """Pixel coordinates of points (``coords``: ``"data"``, ``"axes"``, ``"xaxis"``)."""
        left, top, right, bottom = self.px
        if coords == "axes":
            fx = np.asarray(x, float)
        else:
            u = self.u["x"]
            fx = (self.scales["x"].fwd(x) - u[0]) / (u[1] - u[0])
        if coords in ("axes", "xaxis"):
            fy = np.asarray(y, float)
        else:
            u = self.u["y"]
            fy = (self.scales["y"].fwd(y) - u[0]) / (u[1] - u[0])
        return left + fx * (right - left), bottom - fy * (bottom - top)

    def draw(self, pen):
        left, top, right, bottom = self.px
        items = sorted(self.items + self._grid_items(), key=lambda it: it[1])
        with pen.fine(left, top, right, bottom, blank=True) as inner:   # clipped to the panel
            for kind, _, d in items:
                if kind != "text" and inner is not None:
                    self._draw_item(inner, kind, d)
        self._draw_frame(pen)
        for kind, _, d in items:
            if kind == "text":
                x, y = self.to_px(d["x"], d["y"], d["coords"])
                pen.text(float(x), float(y), d["text"], d["size"], d["color"], d["ha"], d["va"])
        self.note_boxes = []
        x = right
        for text, size, color in self.notes:            # right to left, above the frame
            y = top - NOTE_GAP * pen.scale
            w, h = pen.text(x, y, text, size, color, "right", "bottom")
            self.note_boxes.append((x - w, y - h, x, y))
            x -= w + pen.length("  ", size)
        if self.legend_spec is not None:
            entries = self.legend_entries()
            loc, size, outside = self.legend_spec
            if entries and outside:
                pen.legend(entries, size, right + 0.03 * (right - left), top, anchor="upper left",
                           pad=0.0)
            elif entries:
                pen.legend(entries, size, right if loc.endswith("right") else left, top,
                           anchor=loc)

    def _grid_items(self) -> list:
        if self.grid_at is None:
            return []
        xs, ys = ((self.tick_marks["x"][0], self.tick_marks["y"][0]) if self.grid_at is True
                  else self.grid_at)
        style = {"color": GRID_COLOR, "lw": GRID_W, "style": "-", "alpha": None}
        return [("grid", 1.5, {"xs": np.asarray(xs, float), "ys": np.asarray(ys, float),
                               **style})]

    def _draw_item(self, pen, kind, d):
        left, top, right, bottom = self.px
        if kind == "line":
            px, py = self.to_px(d["x"], d["y"])
            pen.polyline(px, py, d["color"], d["lw"], d["style"], d["alpha"])
        elif kind == "markers":
            px, py = self.to_px(d["x"], d["y"])
            pen.markers(px, py, d["marker"], d["color"], d["size"], d["hollow"], d["mew"],
                        d["alpha"])
        elif kind in ("hline", "vline"):
            if kind == "hline":
                _, y = self.to_px(0.0, d["y"])
                px, py = np.array([left, right]), np.array([y, y])
            else:
                x, _ = self.to_px(d["x"], 0.0)
                px, py = np.array([x, x]), np.array([top, bottom])
            pen.polyline(px, py, d["color"], d["lw"], d["style"], None)
        elif kind == "xspan" and d["outline"]:         # its edges, dashed: not filled
            (x0, x1), _ = self.to_px([d["lo"], d["hi"]], [0.0, 0.0])
            for x in (x0, x1):
                pen.polyline(np.array([x, x]), np.array([top, bottom]), d["color"], OUTLINE_W,
                             "--", None)
        elif kind == "xspan":
            (x0, x1), _ = self.to_px([d["lo"], d["hi"]], [0.0, 0.0])
            pen.box(x0, top, x1, bottom, d["color"], d["alpha"])
        elif kind == "rect":
            px, py = self.to_px([d["x"], d["x"] + d["w"]], [d["y"], d["y"] + d["h"]])
            pen.box(px[0], py[0], px[1], py[1], d["color"], None)
        elif kind == "grid":
            lines = []
            if len(d["xs"]):
                gx, _ = self.to_px(d["xs"], np.zeros(len(d["xs"])))
                lines += [((x, top), (x, bottom)) for x in gx]
            if len(d["ys"]):
                _, gy = self.to_px(np.zeros(len(d["ys"])), d["ys"])
                lines += [((left, y), (right, y)) for y in gy]
            pen.segments(lines, d["color"], d["lw"], d["alpha"])

    def _draw_frame(self, pen):
        left, top, right, bottom = self.px
        s = pen.scale
        pen.frame(left, top, right, bottom, FRAME_W)
        # x ticks under the frame, y ticks left of it
        widest = 0.0
        for a in "xy":
            major, labels, minor = self.tick_marks[a]
            if a == "x":
                at_major, _ = self.to_px(major, np.zeros(len(major)))
                at_minor, _ = self.to_px(minor, np.zeros(len(minor)))
                pen.segments([((x, bottom), (x, bottom + TICK * s)) for x in at_major], "k",
                             TICK_W, None)
                pen.segments([((x, bottom), (x, bottom + MINOR * s)) for x in at_minor], "k",
                             MINOR_W, None)
                if self.x_tick_labels:
                    for x, text in zip(at_major, labels):
                        pen.text(float(x), bottom + (TICK + TICK_PAD) * s, text,
                                 self.label_size, "k", "center", "top")
            else:
                _, at_major = self.to_px(np.zeros(len(major)), major)
                _, at_minor = self.to_px(np.zeros(len(minor)), minor)
                pen.segments([((left - TICK * s, y), (left, y)) for y in at_major], "k",
                             TICK_W, None)
                pen.segments([((left - MINOR * s, y), (left, y)) for y in at_minor], "k",
                             MINOR_W, None)
                for y, text in zip(at_major, labels):
                    w, _ = pen.text(left - (TICK + TICK_PAD) * s, float(y), text,
                                    self.label_size, "k", "right", "center")
                    widest = max(widest, w)
        labelled_x = self.x_tick_labels and len(self.tick_marks["x"][0])
        if self.x_label is not None:
            text, size, pad = self.x_label
            below = (TICK + TICK_PAD) * s + (pen.line_height(self.label_size)
                                               if labelled_x else 0.0)
            pen.text((left + right) / 2, bottom + below + pad * s, text, size, "k", "center",
                     "top")
        if self.y_label is not None:
            text, size, pad = self.y_label
            beside = (TICK + TICK_PAD) * s + widest if len(self.tick_marks["y"][0]) else 0.0
            pen.text(left - beside - pad * s, (top + bottom) / 2, text, size, "k", "right",
                     "center", rotate=True)
        for loc, (text, size, pad) in self.titles.items():
            x = {"left": left, "center": (left + right) / 2, "right": right}[loc]
            pen.text(x, top - pad * s, text, size, "k", loc, "bottom")


# ---------------------------------------------------------------------- pixels
class _Pen:
    """Drawing on an image, coordinates in the figure's pixels, sizes in points (``scale``
    pixels each on this image). A pen over a part of the figure (:meth:`fine`) draws at
    ``zoom`` times the figure's resolution: the figure's pixel ``(x, y)`` is its
    ``((x - ox) * zoom, (y - oy) * zoom)``, ``offset = (ox, oy)``."""

    def __init__(self, img, scale: float, offset=(0, 0), zoom: int = 1):
        self.img, self.scale, self.offset, self.zoom = img, scale, offset, zoom
        self.draw = ImageDraw.Draw(img)
        self.queued = []

    @contextmanager
    def fine(self, x0, y0, x1, y1, blank: bool = False):
        """A pen over the box ``(x0, y0)``-``(x1, y1)`` of this (unzoomed) pen's image at
        :data:`OVERSAMPLE` times its resolution, the box reduced back into the image when the
        block ends: antialiased lines, markers and edges. ``blank``: it starts white (else from
        the image's pixels)."""
        W, H = self.img.size
        b = (max(0, math.floor(x0)), max(0, math.floor(y0)), min(W, math.ceil(x1) + 1),
             min(H, math.ceil(y1) + 1))
        if b[2] <= b[0] or b[3] <= b[1]:
            yield None
            return
        k = OVERSAMPLE
        size = ((b[2] - b[0]) * k, (b[3] - b[1]) * k)
        img = (Image.new("RGB", size, "white") if blank
               else self.img.crop(b).resize(size, Image.Resampling.NEAREST))
        pen = _Pen(img, self.scale * k, offset=b[:2], zoom=k)
        yield pen
        self.img.paste(img.reduce(k), b[:2])

    def _map(self, x, y):
        ox, oy = self.offset
        z = self.zoom
        return ((np.asarray(x, float) - ox) * z, (np.asarray(y, float) - oy) * z)

    def _width(self, lw: float) -> int:
        return max(1, round(lw * self.scale))

    def _paint(self, alpha, xs, ys, margin, fn):
        """``fn(draw, dx, dy)`` draws in this image's pixels less ``(dx, dy)``: on the image
        itself, or (``alpha`` < 1) on a transparent layer over the bounding box of ``xs``,
        ``ys`` (this image's pixels, plus ``margin``), composited over the image."""
        if alpha is None or alpha >= 1:
            fn(self.draw, 0, 0)
            return
        W, H = self.img.size
        x0, y0 = max(0, math.floor(min(xs) - margin)), max(0, math.floor(min(ys) - margin))
        x1 = min(W, math.ceil(max(xs) + margin) + 1)
        y1 = min(H, math.ceil(max(ys) + margin) + 1)
        if x1 <= x0 or y1 <= y0:
            return
        layer = Image.new("RGBA", (x1 - x0, y1 - y0), (0, 0, 0, 0))
        fn(ImageDraw.Draw(layer), x0, y0)
        region = self.img.crop((x0, y0, x1, y1)).convert("RGBA")
        region.alpha_composite(layer)
        self.img.paste(region.convert("RGB"), (x0, y0))

    @staticmethod
    def _fill(color, alpha):
        c = rgb(color)
        return c if alpha is None or alpha >= 1 else (*c, round(255 * alpha))

    def polyline(self, px, py, color, lw, style, alpha):
        x, y = self._map(px, py)
        x, y = np.clip(x, -1e5, 1e5), np.clip(y, -1e5, 1e5)
        ok = np.isfinite(x) & np.isfinite(y)
        if not ok.any():
            return
        # runs of finite points, each drawn as one line (or its dashes)
        breaks = np.flatnonzero(np.diff(ok.astype(np.int8))) + 1
        runs = [r for r in np.split(np.arange(len(x)), breaks) if len(r) and ok[r[0]]]
        fill, width = self._fill(color, alpha), self._width(lw)
        pieces = []
        for r in runs:
            pieces += ([(x[r], y[r])] if style in ("-", "solid", None)
                       else _dashed(x[r], y[r], [v * lw * self.scale for v in DASHES[style]]))

        def fn(draw, dx, dy):
            for xs, ys in pieces:
                if len(xs) == 1:
                    xs, ys = np.repeat(xs, 2), np.repeat(ys, 2)
                draw.line(np.column_stack([xs - dx, ys - dy]).ravel().tolist(), fill=fill,
                          width=width, joint="curve" if width > 2 and len(xs) < 2000 else None)
        self._paint(alpha, x[ok], y[ok], width, fn)

    def segments(self, lines, color, lw, alpha):
        """Straight segments ``((x0, y0), (x1, y1))``."""
        if not lines:
            return
        fill, width = self._fill(color, alpha), self._width(lw)
        xs, ys = self._map([[x0, x1] for (x0, _), (x1, _) in lines],
                           [[y0, y1] for (_, y0), (_, y1) in lines])

        def fn(draw, dx, dy):
            for (x0, x1), (y0, y1) in zip(xs.tolist(), ys.tolist()):
                draw.line([(x0 - dx, y0 - dy), (x1 - dx, y1 - dy)], fill=fill, width=width)
        self._paint(alpha, xs.ravel(), ys.ravel(), width, fn)

    def box(self, x0, y0, x1, y1, color, alpha):
        """A filled axis-aligned rectangle (at ``alpha``: blended with what lies beneath)."""
        (x0, x1), (y0, y1) = self._map([x0, x1], [y0, y1])
        W, H = self.img.size
        x0, x1 = sorted((x0, x1))
        y0, y1 = sorted((y0, y1))
        b = (max(0, round(x0)), max(0, round(y0)), min(W, round(x1)), min(H, round(y1)))
        if b[2] <= b[0] or b[3] <= b[1]:
            return
        if alpha is None or alpha >= 1:
            self.draw.rectangle([b[0], b[1], b[2] - 1, b[3] - 1], fill=rgb(color))
            return
        region = self.img.crop(b)
        self.img.paste(Image.blend(region, Image.new("RGB", region.size, rgb(color)), alpha),
                       b[:2])

    def markers(self, px, py, marker, color, size, hollow, mew, alpha):
        x, y = self._map(px, py)
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        if not len(x):
            return
        fill = self._fill(color, alpha)
        r = size * self.scale / 2
        width = self._width(mew)
        style = {"outline": fill, "width": width} if hollow else {"fill": fill}

        def fn(draw, dx, dy):
            for cx, cy in zip(x - dx, y - dy):
                if marker == "o":
                    draw.ellipse([cx - r, cy - r, cx + r, cy + r], **style)
                else:
                    draw.polygon([(cx + r * u, cy - r * v) for u, v in _MARKERS[marker]],
                                 **style)
        self._paint(alpha, x, y, r + width, fn)

    def frame(self, left, top, right, bottom, lw):
        """A black rectangle's outline, ``lw`` points wide, on the pixels nearest its edges."""
        width = self._width(lw)
        (x0, x1), (y0, y1) = self._map([left, right], [top, bottom])
        x0, y0, x1, y1 = round(x0), round(y0), round(x1), round(y1)
        half = width // 2
        self.draw.rectangle([x0 - half, y0 - half, x1 - half + width - 1,
                             y1 - half + width - 1], outline=(0, 0, 0), width=width)

    def line_height(self, size: float) -> float:
        """The height in pixels of one line of text at ``size`` points."""
        return 1.2 * size * self.scale

    def _px(self, size: float) -> int:
        """The font size in pixels of ``size`` points (text is drawn at the figure's
        resolution: FreeType antialiases it, hinted at the size it is seen)."""
        return max(1, round(size * self.scale))

    def length(self, text: str, size: float) -> float:
        """The width in pixels of one line of ``text`` at ``size`` points."""
        return _line(self._px(size), text)[0]

    def text(self, x, y, text, size, color, ha, va, rotate=False) -> tuple:
        """Place ``text`` (lines centred or aligned by ``ha``) at ``(x, y)``, anchored by ``ha``
        (left/center/right) and ``va`` (top/center/bottom/baseline); ``rotate``: a quarter turn
        anticlockwise (``ha`` then places its bottom edge, its right when upright). Its
        ``(width, height)`` in pixels. Drawn by :meth:`draw_texts`, over everything else."""
        if not text:
            return 0.0, 0.0
        px = self._px(size)
        lines = text.split("\n")
        step = self.line_height(size)
        ascent, descent = _metrics(px)
        widths = [_line(px, line)[0] for line in lines]
        w, h = max(widths), step * (len(lines) - 1) + ascent + descent
        if rotate:
            w, h = h, w
        left = x - {"left": 0.0, "center": w / 2, "right": w}[ha]
        top = y - {"top": 0.0, "center": h / 2, "bottom": h, "baseline": h - descent}[va]
        self.queued.append((left, top, w, h, lines, widths, step, px, rgb(color), ha, rotate))
        return w, h

    def draw_texts(self):
        """Draw the texts placed (:meth:`text`)."""
        for left, top, w, h, lines, widths, step, px, color, ha, rotate in self.queued:
            for i, (line, lw) in enumerate(zip(lines, widths)):
                mask = _line(px, line)[1]
                if rotate:          # line i of the upright text, turned: from the left edge
                    self.img.paste(color, (round(left + i * step), round(top + (h - lw) / 2)),
                                   mask.transpose(Image.Transpose.ROTATE_90))
                    continue
                dx = {"left": 0.0, "center": (w - lw) / 2, "right": w - lw}[ha]
                self.img.paste(color, (round(left + dx), round(top + i * step)), mask)

    def legend(self, entries, size, x, y, anchor="upper right", ncol=1, frame=True,
               pad=None):
        """A legend of ``(kind, item)`` entries: ``anchor`` ``"upper right"``/``"upper left"``
        (inside a panel whose corner is ``(x, y)``, ``pad`` points in), or ``"top"`` (its top
        centre at ``(x, y)``, ``ncol`` entries a row); matplotlib's spacings."""
        if not entries:
            return
        s, fs = self.scale, size * self.scale
        handle, gap, border, spacing, colgap = 2.0 * fs, 0.8 * fs, 0.4 * fs, 0.5 * fs, 2.0 * fs
        pad = 0.5 * size if pad is None else pad
        ncol = max(1, min(ncol, len(entries)))
        rows = [entries[i:i + ncol] for i in range(0, len(entries), ncol)]
        widths = [handle + gap + self.length(str(d["label"]), size) for _, d in entries]
        col_w = [max(widths[i::ncol]) for i in range(ncol)]
        row_h = self.line_height(size) / 1.2
        W = sum(col_w) + colgap * (ncol - 1) + 2 * border
        H = len(rows) * row_h + (len(rows) - 1) * spacing + 2 * border
        if anchor == "top":
            x0, y0 = x - W / 2, y
        elif anchor.endswith("right"):
            x0, y0 = x - pad * s - W, y + pad * s
        else:
            x0, y0 = x + pad * s, y + pad * s
        places = []
        for r, row in enumerate(rows):
            cy = y0 + border + r * (row_h + spacing) + row_h / 2
            cx = x0 + border
            for c, (kind, d) in enumerate(row):
                places.append((kind, d, cx, cy))
                cx += col_w[c] + colgap
        with self.fine(x0 - 2, y0 - 2, x0 + W + 2, y0 + H + 2) as pen:
            if pen is not None and frame:   # matplotlib's: white at alpha 0.8, a grey edge
                (a, b), (c, e) = pen._map([x0, x0 + W], [y0, y0 + H])
                pen._paint(0.8, [a, b], [c, e], 2, lambda draw, dx, dy: draw.rounded_rectangle(
                    [a - dx, c - dy, b - dx, e - dy], radius=0.2 * fs * pen.zoom,
                    fill=(255, 255, 255, 204), outline=(204, 204, 204, 255),
                    width=pen._width(1.0)))
            for kind, d, cx, cy in places if pen is not None else ():
                pen._handle(kind, d, cx, cy, handle, fs)
        for kind, d, cx, cy in places:
            self.text(cx + handle + gap, cy, str(d["label"]), size, "k", "left", "center")

    def _handle(self, kind, d, x, y, length, fs):
        if kind == "xspan" and d.get("outline"):
            y0, y1 = y - 0.35 * fs, y + 0.35 * fs
            self.polyline(np.array([x, x + length, x + length, x, x]),
                          np.array([y0, y0, y1, y1, y0]), d["color"], OUTLINE_W, "--", None)
        elif kind == "xspan":
            self.box(x, y - 0.35 * fs, x + length, y + 0.35 * fs, d["color"], d["alpha"])
        elif kind == "markers":
            self.markers([x + length / 2], [y], d["marker"], d["color"], d["size"],
                         d["hollow"], d["mew"], d["alpha"])
        else:
            self.polyline(np.array([x, x + length]), np.array([y, y]), d["color"], d["lw"],
                          d.get("style", "-"), d.get("alpha"))


#: Marker outlines on a unit radius (y up): matplotlib's shapes.
_MARKERS = {
    "s": [(-1, -1), (1, -1), (1, 1), (-1, 1)],
    "^": [(0, 1), (-1, -1), (1, -1)],
    "v": [(0, -1), (-1, 1), (1, 1)],
    "<": [(-1, 0), (1, -1), (1, 1)],
    ">": [(1, 0), (-1, -1), (-1, 1)],
    "D": [(0, 1), (1, 0), (0, -1), (-1, 0)],
    "*": [(math.cos(math.pi / 2 + k * math.pi / 5) * (1 if k % 2 == 0 else 0.381966),
           math.sin(math.pi / 2 + k * math.pi / 5) * (1 if k % 2 == 0 else 0.381966))
          for k in range(10)],
}


def _dashed(x, y, pattern) -> list:
    """The pieces ``(xs, ys)`` of the polyline ``(x, y)`` that a dash ``pattern`` (on, off, ...
    lengths in pixels) keeps."""
    seg = np.hypot(np.diff(x), np.diff(y))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    period = float(sum(pattern))
    if period <= 0 or s[-1] == 0:
        return [(x, y)]
    offsets = np.cumsum([0.0] + list(pattern[:-1]))[::2]
    on = np.asarray(pattern[::2], float)
    base = np.arange(int(s[-1] // period) + 1)[:, None] * period
    a = (base + offsets).ravel()
    b = np.minimum(a + np.tile(on, len(base)), s[-1])
    keep = a < s[-1]
    a, b = a[keep], b[keep]
    xa, ya, xb, yb = np.interp(a, s, x), np.interp(a, s, y), np.interp(b, s, x), np.interp(b, s, y)
    first, last = np.searchsorted(s, a, "right"), np.searchsorted(s, b, "left")
    pieces = []
    for k in range(len(a)):
        if last[k] <= first[k]:                     # no vertex inside the dash
            pieces.append((np.array([xa[k], xb[k]]), np.array([ya[k], yb[k]])))
        else:
            inner = slice(first[k], last[k])
            pieces.append((np.concatenate([[xa[k]], x[inner], [xb[k]]]),
                           np.concatenate([[ya[k]], y[inner], [yb[k]]])))
    return pieces
