"""A fit window marked unreliable is not shaded as a fit: it is outlined (dashed edges, no fill)
and the legend says so; a reliable fit's window stays shaded with its rate."""
import numpy as np
import pytest

from orchestration import simulate
from orchestration.report.plotting import canvas
from orchestration.report.raster import rgb


def _spans(fig) -> dict:
    """``{label: xspan item}`` of every panel of a raster figure."""
    return {d["label"]: d for p in fig.panels_made for kind, _, d in p.items
            if kind == "xspan"}


@pytest.fixture(scope="module")
def flexible_pd(fmus):
    run = simulate("flexible_pd")
    # the case: the slow fit is unreliable, the bending one reliable (the summary says so)
    assert run.summary["slow"]["fit"] and not run.summary["slow"]["reliable"]
    assert run.summary["bending"]["fit"] and run.summary["bending"]["reliable"]
    return run


def test_unreliable_window_is_outlined_and_labelled_so(flexible_pd):
    spans = _spans(flexible_pd.plot("raster"))
    (slow,) = [d for label, d in spans.items() if label.startswith("slow")]
    (bending,) = [d for label, d in spans.items() if label.startswith("bending")]
    assert slow["outline"] and "unreliable" in slow["label"] and "outlined" in slow["label"]
    assert "1/s" not in slow["label"]                        # no rate for an unreliable fit
    assert (slow["lo"], slow["hi"]) == tuple(flexible_pd.summary["slow"]["fit"]["window"])
    assert not bending["outline"] and bending["alpha"] and "unreliable" not in bending["label"]
    assert f"{flexible_pd.summary['bending']['rate']:+.3g} 1/s" in bending["label"]


def test_matplotlib_draws_the_unreliable_window_unfilled(flexible_pd):
    fig = flexible_pd.plot("matplotlib")
    patches = {p.get_label(): p for ax in fig.axes for p in ax.patches}
    (slow,) = [p for label, p in patches.items() if label.startswith("slow")]
    (bending,) = [p for label, p in patches.items() if label.startswith("bending")]
    assert not slow.get_fill() and slow.get_linestyle() == "--"
    assert bending.get_fill()
    legends = [t.get_text() for ax in fig.axes if ax.get_legend()
               for t in ax.get_legend().get_texts()]
    assert any("unreliable" in t and "outlined" in t for t in legends)


def test_outlined_span_leaves_its_inside_unpainted():
    """In the raster image: a filled span paints its inside, an outlined one only its edges."""
    images = {}
    for outline in (False, True):
        fig = canvas(3.0, 2.0, "raster")
        (ax,), = fig.panels(fig.grid(1, 1))
        ax.xlim(0.0, 10.0)
        ax.ylim(0.0, 1.0)
        ax.xspan(3.0, 7.0, color="C2", alpha=0.5, outline=outline)
        img = np.asarray(fig.image(100)).astype(int)
        xs, _ = ax.to_px([3.0, 5.0, 7.0], [0.5, 0.5, 0.5])
        row = int(round((ax.px[1] + ax.px[3]) / 2)) + 3      # off the grid line at y = 0.5
        images[outline] = (img, [int(round(x)) for x in xs], row, ax.px)
    img, (x_lo, x_mid, x_hi), row, _ = images[False]
    assert tuple(img[row, x_mid]) != (255, 255, 255)          # filled
    img, (x_lo, x_mid, x_hi), row, (_, top, _, bottom) = images[True]
    assert tuple(img[row, x_mid]) == (255, 255, 255)          # not filled
    green = np.array(rgb("C2"))
    edge = img[int(top) + 2:int(bottom) - 2, x_lo - 1:x_lo + 2]
    assert np.abs(edge - green).sum(axis=-1).min() < 60       # the edge drawn in its colour
