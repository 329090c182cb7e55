"""The raster renderer (:mod:`orchestration.report.raster`): data land on the pixels the axes'
mapping puts them on (linear, log, symmetric log), ticks are 1-2-5 steps covering the view,
decades on log axes as matplotlib places them, the PNG decodes to the size asked and to the
image drawn, and a failed write leaves no file."""
import math

import numpy as np
import pytest
from PIL import Image

from orchestration.files import OutputError
from orchestration.report import raster
from orchestration.report.files import save_figure
from orchestration.report.plotting import canvas

RED = (214, 39, 40)                 # "C3"


def one_panel(**limits):
    """A 2 x 2 in canvas at 100 dpi whose one panel spans pixels 20..180 both ways, no ticks."""
    fig = canvas(2.0, 2.0, "raster")
    grid = fig.grid(1, 1, left=0.1, right=0.9, bottom=0.1, top=0.9)
    (ax,), = fig.panels(grid)
    ax.ticks(x=(), y=())
    for axis, lim in limits.items():
        getattr(ax, f"{axis}lim")(*lim)
    return fig, ax


def red_centre(fig, axis: int) -> float:
    """The mean column (``axis=1``) or row (``axis=0``) of the red pixels, weighted by redness."""
    img = np.asarray(fig.image(100)).astype(float)
    w = np.clip(img[..., 0] - img[..., 1], 0, None) * (img[..., 0] > 120)
    assert w.sum() > 0, "nothing red drawn"
    idx = np.indices(w.shape)[axis] + 0.5               # pixel centres
    return float((idx * w).sum() / w.sum())


@pytest.mark.parametrize("x", [2.5, 7.1])
def test_a_vertical_line_lands_on_its_computed_column(x):
    fig, ax = one_panel(x=(0.0, 10.0), y=(0.0, 1.0))
    ax.vline(x, color="C3", lw=1.0)
    expected = 20 + (x - 0.0) / 10.0 * 160
    assert red_centre(fig, axis=1) == pytest.approx(expected, abs=0.75)


def test_data_coordinates_map_linearly_and_on_a_log_axis():
    fig, ax = one_panel(x=(-1.0, 3.0), y=(1.0, 1000.0))
    ax.yscale("log")
    ax.line([-1.0, 3.0], [10.0, 10.0], color="C3", lw=1.0)     # one decade of three up
    assert red_centre(fig, axis=0) == pytest.approx(180 - 160 / 3, abs=0.75)
    fig, ax = one_panel(x=(-1.0, 3.0), y=(0.0, 4.0))
    ax.line([0.0, 0.0], [0.0, 4.0], color="C3", lw=1.0)        # x = 0: a quarter across
    assert red_centre(fig, axis=1) == pytest.approx(20 + 160 / 4, abs=0.75)


def test_symlog_axis_is_linear_inside_linthresh_and_logarithmic_beyond():
    """matplotlib's symlog (base 10, linscale 1): 0..linthresh takes 1/(1 - 1/10) decades."""
    lt, adj = 1.0, 1 / 0.9
    u = lambda v: math.copysign(lt * (adj + math.log10(abs(v) / lt)), v) \
        if abs(v) > lt else v * adj                                          # noqa: E731
    for x in (-30.0, 0.5, 7.0):
        fig, ax = one_panel(x=(-100.0, 10.0), y=(0.0, 1.0))
        ax.xscale("symlog", linthresh=lt)
        ax.vline(x, color="C3", lw=1.0)
        expected = 20 + (u(x) - u(-100.0)) / (u(10.0) - u(-100.0)) * 160
        assert red_centre(fig, axis=1) == pytest.approx(expected, abs=0.75)


def test_panels_without_limits_cover_their_data_with_five_percent_margins():
    fig, ax = one_panel()
    ax.line([2.0, 12.0], [-1.0, 1.0], color="C3")
    fig.image(100)
    p = fig.panels_made[0]
    assert p.lim["x"] == pytest.approx((2.0 - 0.5, 12.0 + 0.5))
    assert p.lim["y"] == pytest.approx((-1.1, 1.1))


# ---------------------------------------------------------------------- ticks
@pytest.mark.parametrize("lo,hi,nbins", [(0.0, 2.5, 5), (-0.43, 0.53, 6), (-2.7, 0.1, 4),
                                         (1e-6, 3.7e-6, 5), (-265.0, 212.0, 5), (0.0, 2500.0, 7),
                                         (-1.35, 0.25, 5), (99.0, 101.0, 9), (3.0, 3.2, 1)])
def test_ticks_are_one_two_five_steps_covering_the_view(lo, hi, nbins):
    t = raster.nice_ticks(lo, hi, nbins)
    step = np.diff(t)
    assert len(t) >= 2 and len(t) <= nbins + 1
    np.testing.assert_allclose(step, step[0], rtol=1e-9)
    mantissa = step[0] / 10 ** math.floor(math.log10(step[0]))
    assert min(abs(mantissa - m) for m in (1, 2, 5)) < 1e-9
    assert lo - 1e-12 <= t[0] < lo + step[0] and hi - step[0] < t[-1] <= hi + 1e-12
    np.testing.assert_allclose(t / step[0], np.round(t / step[0]), atol=1e-9)  # multiples
    # at most nbins intervals enclose the view; the next smaller 1-2-5 step needs more
    def intervals(h):
        return math.ceil(hi / h - 1e-9) - math.floor(lo / h + 1e-9)
    assert intervals(step[0]) <= nbins
    smaller = {1: 0.5, 2: 1, 5: 2}[round(mantissa)] * 10 ** math.floor(math.log10(step[0]))
    assert intervals(smaller) > nbins


def test_tick_labels_share_the_decimals_of_their_step_and_a_true_minus():
    assert raster.tick_text(raster.nice_ticks(-0.43, 0.53, 6)) == \
        ["−0.4", "−0.2", "0.0", "0.2", "0.4"]
    assert raster.tick_text([0.0, 500.0, 1000.0]) == ["0", "500", "1000"]
    assert raster.tick_text([-0.0, 0.05]) == ["0.00", "0.05"]


def test_log_and_symlog_ticks_are_matplotlibs_decades():
    """Placed where matplotlib's locators place them (a second implementation), labelled in
    plain Unicode as the matplotlib figures label them."""
    from matplotlib.scale import SymmetricalLogTransform
    from matplotlib.ticker import LogLocator, SymmetricalLogLocator

    major, labels, minor = raster.log_ticks(2.7e-7, 5.6e-2, 5)
    expected = LogLocator(base=10).tick_values(2.7e-7, 5.6e-2)
    expected = expected[(expected >= 2.7e-7) & (expected <= 5.6e-2)]
    np.testing.assert_allclose(major, expected)
    assert labels == ["10⁻⁶", "10⁻⁵", "10⁻⁴", "10⁻³", "10⁻²"]
    assert len(minor) and all(round(m / 10 ** math.floor(math.log10(m)), 9) in range(2, 10)
                              for m in minor)
    major, labels, _ = raster.symlog_ticks(-158.0, 2.6, 1.0, 9)
    loc = SymmetricalLogLocator(transform=SymmetricalLogTransform(10, 1.0, 1.0))
    expected = np.asarray(loc.tick_values(-158.0, 2.6))
    np.testing.assert_allclose(major, expected[(expected >= -158.0) & (expected <= 2.6)])
    assert labels == ["−10²", "−10¹", "−10⁰", "0", "10⁰"]


# ---------------------------------------------------------------------- the file
def test_png_decodes_to_the_size_asked_and_to_the_image_drawn(tmp_path):
    fig = canvas(3.3, 2.1, "raster")
    (ax,), = fig.panels(fig.grid(1, 1))
    ax.line(np.linspace(0, 1, 50), np.sin(np.linspace(0, 6, 50)), color="C0")
    ax.xlabel("time (s)")
    ax.title("φₒ and η₁")
    path = save_figure(fig, tmp_path / "f.png", dpi=110)
    with Image.open(path) as png:
        assert png.format == "PNG" and png.size == (363, 231) and png.mode == "RGB"
        assert np.array_equal(np.asarray(png), np.asarray(fig.image(110)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png"]


def test_a_failed_write_leaves_the_earlier_file_whole(tmp_path, monkeypatch):
    fig = canvas(1.0, 1.0, "raster")
    fig.panels(fig.grid(1, 1))
    path = save_figure(fig, tmp_path / "f.png")
    before = path.read_bytes()

    def full_disk(img, p, **kwargs):
        with open(p, "wb") as f:
            f.write(b"\x89PNG half")
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(Image.Image, "save", full_disk)
    with pytest.raises(OutputError, match="f.png"):
        save_figure(fig, path)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["f.png"]


def test_the_font_is_found_without_importing_matplotlib():
    import subprocess
    import sys

    code = ("import sys; from orchestration.report import raster; p = raster.font_path(); "
            "assert p and p.endswith('DejaVuSans.ttf'), p; "
            "from orchestration.report.plotting import canvas; "
            "f = canvas(1, 1, 'raster'); f.panels(f.grid(1, 1))[0][0].title('x'); f.image(); "
            "assert 'matplotlib' not in sys.modules")
    from orchestration.export.places import ROOT

    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr


def test_colours_are_matplotlibs():
    assert raster.rgb("C3") == RED and raster.rgb("0.3") == (76, 76, 76)
    assert raster.rgb("k") == (0, 0, 0)
    with pytest.raises(ValueError, match="'mauve' is not allowed; allowed: 'C0'"):
        raster.rgb("mauve")


def test_an_unknown_renderer_is_named_with_the_allowed_ones():
    with pytest.raises(ValueError, match="renderer = 'svg' is not allowed; allowed: 'raster', "
                                         "'matplotlib'"):
        canvas(1.0, 1.0, "svg")


@pytest.mark.parametrize("fallback", ["freetype", "bitmap"])
def test_without_dejavu_the_figure_is_drawn_in_pillows_own_font(fallback, monkeypatch):
    """No DejaVu Sans (no matplotlib installed): Pillow's default font at the size asked, or its
    bitmap font where Pillow has no FreeType; the figure is drawn all the same."""
    from PIL import ImageFont

    monkeypatch.setattr(raster, "font_path", lambda: None)
    if fallback == "bitmap":
        monkeypatch.setattr(ImageFont, "load_default",
                            lambda size=None: ImageFont.load_default_imagefont())
    for cache in (raster._font, raster._metrics, raster._line):
        cache.cache_clear()
    try:
        fig, ax = one_panel(x=(0.0, 10.0), y=(0.0, 1.0))
        ax.ticks(x=[0.0, 5.0, 10.0], y=[0.0, 1.0])
        ax.xlabel("time (s)")
        ax.ylabel("tip angle (rad)")
        ax.title("a title\nof two lines")
        ax.vline(2.5, color="C3", lw=1.0)
        assert red_centre(fig, axis=1) == pytest.approx(60, abs=0.75)
    finally:
        for cache in (raster._font, raster._metrics, raster._line):
            cache.cache_clear()
