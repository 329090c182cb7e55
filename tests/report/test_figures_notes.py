"""Notes never sit on data: a panel's note (``panel.note``, the red "measured range ... off this
scale" of the tip deflection) is drawn in the strip above its frame, outside every panel's data
area, in both renderers."""
import pytest

from orchestration import simulate
from orchestration.report.plotting import canvas


def _drawn(fig):
    """``fig`` (a matplotlib Figure of no pyplot) drawn by Agg, and its renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    return fig.canvas.get_renderer()


def _overlap(a, b) -> bool:
    """Whether boxes ``(left, top, right, bottom)`` (pixels, y down) share any area."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@pytest.fixture(scope="module")
def run_with_note(fmus):
    run = simulate("flexible_pd", {"stop_time": 1.0})
    lim = run.summary["validity"]["tip_deflection_limit"]
    assert abs(run.result["tip_deflection"]).max() < 0.3 * lim     # the note's case
    return run


def test_raster_note_is_off_every_panels_data_area(run_with_note):
    fig = run_with_note.plot("raster")
    fig.image()
    panels = [p for p in fig.panels_made if not p.hidden]
    noted = [p for p in panels if p.notes]
    assert [n[0] for p in noted for n in p.notes] == [
        f"measured range ±{run_with_note.summary['validity']['tip_deflection_limit']:.3g} m: "
        "off this scale"]
    for p in noted:
        assert len(p.note_boxes) == len(p.notes)
        for box in p.note_boxes:
            assert box[2] > box[0] and box[3] > box[1]          # drawn, with a size
            assert box[3] <= p.px[1]                            # above its own frame
            for other in panels:
                assert not _overlap(box, other.px), (box, other.px)


def test_matplotlib_note_is_off_every_axes(run_with_note):
    fig = run_with_note.plot("matplotlib")
    renderer = _drawn(fig)
    notes = [t for ax in fig.axes for t in ax.texts if "off this scale" in t.get_text()]
    assert len(notes) == 1
    box = notes[0].get_window_extent(renderer)
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        area = ax.get_window_extent(renderer)               # the data area, y up
        assert not box.overlaps(area), (box, area)


@pytest.mark.parametrize("renderer", ["raster", "matplotlib"])
def test_two_notes_stand_side_by_side_above_the_frame(renderer):
    fig = canvas(4.0, 3.0, renderer)
    (top,), (bottom,) = fig.panels(fig.grid(2, 1, hspace=0.4), sharex=True)
    for ax in (top, bottom):
        ax.line([0, 1], [0, 1])
    bottom.note("first note")
    bottom.note("second note", color="k")
    if renderer == "raster":
        fig.image()
        a, b = bottom.note_boxes
        assert b[2] <= a[0]                                     # the second left of the first
        for box in (a, b):
            for p in (top, bottom):
                assert not _overlap(box, p.px)
    else:
        mpl = fig.result()
        r = _drawn(mpl)
        a, b = (n.get_window_extent(r) for n in bottom.notes)
        assert b.x1 <= a.x0
        for box in (a, b):
            for ax in mpl.axes:
                assert not box.overlaps(ax.get_window_extent(r))


def test_a_stopped_runs_label_is_a_note_off_the_data(fmus):
    """A run the plant stops (kp = 50 cannot hold the rigid pendulum: it falls past
    plant.phi_limit) says where in a note above the first panel, off every panel's data area;
    the time is the summary's."""
    run = simulate("rigid_pd", {"controller.kp": 50, "stop_time": 3})
    stopped = run.summary["stopped"]
    assert stopped and stopped["time"] < 3
    fig = run.plot("raster")
    fig.image()
    panels = [p for p in fig.panels_made if not p.hidden]
    texts = [n[0] for p in panels for n in p.notes]
    assert texts == [f"stopped at t = {stopped['time']:.4g} s (the red line)"]
    for p in panels:
        for box in p.note_boxes:
            for other in panels:
                assert not _overlap(box, other.px), (box, other.px)
