"""Figures that say what ran: titles from the scene's records (never its fixed text), labels
inside the figure, one rail window covering the cart's travel, one deflection scale, each run
of the overview on its own time axis, the bending fit shaded on the bending oscillation, and the
new figures (the plant's cantilever modes, the closed-loop roots) holding the model's numbers."""
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.patches import Polygon, Rectangle
from matplotlib.text import Text

from orchestration.job import Run, paper_figures, run_scene
from orchestration.report import figures, mpl_canvas
from orchestration.scene.schema import PAPER_SCENES, load_scene
from orchestration.studies.analysis import first_bending_frequency, loop_roots
from orchestration.studies.summary import report_facts
from plant_fmu.beam import beam_model


@pytest.fixture(scope="module")
def paper_runs(native):
    """The paper's three scenes, co-simulated on the native FMUs with their summaries."""
    paths = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    return {name: run_scene(load_scene(name), paths, progress=False) for name in PAPER_SCENES}


def drawn(fig):
    """``fig`` drawn on an Agg canvas of its own; its renderer."""
    FigureCanvasAgg(fig)
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def texts(fig):
    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def assert_labels_fit(fig):
    """Everything drawn lies inside the figure (the axes with their titles, labels, tick labels
    in view and legends; the figure's title, texts and legends), a text written inside an axes
    stays inside it, a panel's note (``panel.note``, above the frame) inside the figure and off
    every axes' drawing area, and no title (the figure's or an axes') overlaps another title or
    an axes' drawing area."""
    renderer = drawn(fig)
    box = fig.bbox

    def inside(b, what):
        assert (b.x0 >= box.x0 - 1 and b.x1 <= box.x1 + 1 and b.y0 >= box.y0 - 1
                and b.y1 <= box.y1 + 1), f"cut by the border: {what}"
    for ax in fig.axes:
        if ax.get_visible():
            inside(ax.get_tightbbox(renderer), f"axes {ax.get_title() or ax.get_ylabel()!r}")
            frame = ax.get_window_extent(renderer)
            for t in ax.texts:                      # a text inside the axes stays inside them
                b = t.get_window_extent(renderer)
                if t.get_gid() == "note":           # a note: off every axes' data
                    inside(b, f"note {t.get_text()!r}")
                    for other in fig.axes:
                        assert not (other.get_visible()
                                    and b.overlaps(other.get_window_extent(renderer))), \
                            f"note on an axes: {t.get_text()!r}"
                    continue
                assert (b.x0 >= frame.x0 - 1 and b.x1 <= frame.x1 + 1 and b.y0 >= frame.y0 - 1
                        and b.y1 <= frame.y1 + 1), f"crosses the axes' border: {t.get_text()!r}"
    for t in [fig._suptitle, *fig.texts, *fig.legends]:
        if t is not None and t.get_visible():
            inside(t.get_window_extent(renderer), repr(t))
    titles = [fig._suptitle] if fig._suptitle is not None else []
    titles += [t for ax in fig.axes if ax.get_visible()
               for t in (ax.title, ax._left_title, ax._right_title) if t.get_text()]
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in titles]
    for i, (a, ba) in enumerate(boxes):
        for b, bb in boxes[i + 1:]:
            assert not ba.overlaps(bb), f"titles overlap: {a!r} and {b!r}"
        for ax in fig.axes:
            if ax.get_visible():
                assert not ba.overlaps(ax.get_window_extent(renderer)), \
                    f"title {a!r} overlaps an axes"


# ---------------------------------------------------------------------- titles from the records
def title_of(scene) -> str:
    """The title of ``scene``'s figures before it runs (no summary), from its facts."""
    return figures.scene_title(scene, facts=report_facts(scene))


def test_titles_follow_overridden_gains_and_modes():
    """`--set controller.kp=5` must not be titled '-500 phi_o'; `--set plant.n_modes=1` must not
    say '4 cantilever modes ... 151 rad/s grows' (its bending root is -0.052 +- 226.7j)."""
    kp5 = title_of(load_scene("rigid_pd", {"controller.kp": 5}))
    assert "-(5 φₒ + 5 ωₒ)" in kp5 and "500" not in kp5
    assert "UNSTABLE" in kp5 and "real root +6.23 grows" in kp5
    one = title_of(load_scene("flexible_pd", {"plant.n_modes": 1}))
    assert "flexible beam, 1 cantilever mode, modal damping 0.1 %\n" in one
    assert "4 cantilever" not in one and "151" not in one
    r = loop_roots(load_scene("flexible_pd", {"plant.n_modes": 1}).plant.params,
                   load_scene("flexible_pd").controller)
    assert r.bending.imag == pytest.approx(226.7, abs=0.1) and r.bending.real < 0
    assert f"bending root {figures.root_text(r.bending)}" in one
    assert "-0.0518 ± 226.7j" in one and "stable" in one
    default = title_of(load_scene("flexible_pd"))
    assert "4 cantilever modes" in default and "bending root +1.64 ± 151.2j" in default
    # the law that root belongs to is named, and the other law's root is its own
    assert "modal damping 0.1 %" in default
    kv = title_of(load_scene("flexible_pd", {"plant.damping": "kelvin-voigt"}))
    assert "Kelvin-Voigt damping, 0.1 % in mode 1" in kv and "bending root +1.21 ± 151.2j" in kv
    for name in PAPER_SCENES:                       # never the scene file's fixed text
        scene = load_scene(name)
        assert scene.description not in title_of(scene)


@pytest.mark.parametrize("overrides,fragments", [
    ({"controller.filter_order": 1, "controller.cutoff": 130}, ["1st-order low-pass at 130 rad/s"]),
    ({"controller.filter_order": 0, "controller.kx": -2}, ["no filter", "- 2 xₒ"]),
    ({"controller.force_limit": 300}, ["2nd-order low-pass at 97.3 rad/s (damping 0.1)",
                                       "|Fc| ≤ 300 N"]),
    ({"initial.phi": 0.1, "initial.x_dot": 0.5}, ["= 5.73 deg", "ẋ₀ = 0.5 m/s"]),
    ({"plant.EI": 900, "plant.fidelity": "linear"}, ["linearised plant", "EI = 900"]),
    ({"plant.damping": "kelvin-voigt", "plant.zeta": 0.002},
     ["Kelvin-Voigt damping, 0.2 % in mode 1"]),
    ({"plant.zeta": 0.0, "plant.fidelity": "stiffened"},
     ["stiffened rung, no structural damping"]),
    ({"plant.fidelity": "exact", "plant.damping": "kelvin-voigt"},
     ["geometrically exact beam, 24 elements, Kelvin-Voigt damping",
      "the floating frame's preloaded linearised loop (standing in for the exact rung's)"]),
])
def test_title_names_filter_limit_start_and_changed_parameters(overrides, fragments):
    title = title_of(load_scene("flexible_pd_lowpass", overrides))
    for f in fragments:
        assert f in title, (f, title)


def test_run_figures_carry_the_records_title(paper_runs):
    run = paper_runs["flexible_pd"]
    fig = run.plot()
    assert fig._suptitle.get_text() == figures.scene_title(run.scene, run.summary, facts=run.facts)
    assert "co-simulation: UNSTABLE" in fig._suptitle.get_text()


# ---------------------------------------------------------------------- time histories
def test_bending_fit_is_shaded_on_the_bending_band_not_on_the_slow_motion(paper_runs):
    run = paper_runs["flexible_pd_lowpass"]
    fig = run.plot()
    ylabels = [ax.get_ylabel() for ax in fig.axes]
    eta = fig.axes[next(i for i, y in enumerate(ylabels) if y.startswith("1st modal"))]
    band = fig.axes[next(i for i, y in enumerate(ylabels) if "above 60 rad/s" in y)]
    spans = lambda ax: [p for p in ax.patches if isinstance(p, (Polygon, Rectangle))]  # noqa
    assert spans(eta) == []                         # eta_1's trace there is the slow motion
    (span,) = spans(band)
    lo, hi = run.summary["bending"]["fit"]["window"]
    xs = (span.get_xy()[:, 0] if isinstance(span, Polygon)
          else [span.get_x(), span.get_x() + span.get_width()])
    assert min(xs) == pytest.approx(lo) and max(xs) == pytest.approx(hi)
    # the envelope decays at the fitted rate over the window: the drawn line and the trace agree
    assert band.get_yscale() == "log"
    fitted = [ln for ln in band.lines if ln.get_label().startswith("fitted rate")]
    assert len(fitted) == 1
    t = run.result["time"]
    _, env = figures.bending_band(t, run.result["eta_1"], 60.0, 152.5)
    inside = (t >= lo + 0.1) & (t <= hi - 0.1)
    slope = np.polyfit(t[inside], np.log(env[inside]), 1)[0]
    assert slope == pytest.approx(run.summary["bending"]["rate"], rel=0.05)


@pytest.mark.parametrize("dt", [0.002, 0.00025, 0.01])
def test_bending_band_is_scipys_zero_phase_butterworth_and_running_maximum(dt):
    """The band and its envelope, computed without scipy.signal and scipy.ndimage (their imports
    cost most of a run), are what those give: ``sosfiltfilt`` of a 4th-order Butterworth
    high-pass and ``maximum_filter1d``, on a random walk with a decaying bending oscillation."""
    import scipy.ndimage
    import scipy.signal

    t = np.arange(3001) * dt
    y = (np.random.default_rng(7).standard_normal(t.size).cumsum() * 1e-3
         + 1e-2 * np.exp(-2 * t) * np.sin(150 * t) + 0.3 * np.cos(10 * t))
    hp, env = figures.bending_band(t, y, 60.0, 152.5)
    fs = 2 * np.pi / dt
    ref = scipy.signal.sosfiltfilt(scipy.signal.butter(4, 60.0, "highpass", fs=fs,
                                                       output="sos"), y)
    size = max(3, int(round(fs / 152.5)) | 1)
    assert np.max(np.abs(hp - ref)) <= 1e-10 * np.max(np.abs(ref))
    assert np.max(np.abs(env - scipy.ndimage.maximum_filter1d(np.abs(ref), size=size,
                                                              mode="nearest"))) \
        <= 1e-10 * np.max(np.abs(ref))


def test_saving_makes_only_the_ticks_in_view_and_draws_the_same(paper_runs):
    """Inside ``ticks_in_view`` (where ``save_figure`` saves) the figure draws pixel for pixel as
    without it, matplotlib makes no tick beyond the view, and the locators are put back."""
    def draw(fig):
        FigureCanvasAgg(fig)
        fig.canvas.draw()
        ticks = sum(len(getattr(ax, a).majorTicks) + len(getattr(ax, a).minorTicks)
                    for ax in fig.axes for a in ("xaxis", "yaxis"))
        return np.asarray(fig.canvas.buffer_rgba()).copy(), ticks

    run = paper_runs["flexible_pd_lowpass"]
    for make in (run.plot, lambda: figures.paper_overview(list(paper_runs.values()))):
        plain, plain_ticks = draw(make())
        fig = make()
        locators = [(a.get_major_locator(), a.get_minor_locator())
                    for ax in fig.axes for a in (ax.xaxis, ax.yaxis)]
        with figures.ticks_in_view(fig):
            image, ticks = draw(fig)
            for ax in fig.axes:
                for axis, lim in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
                    locs = axis.get_majorticklocs()
                    assert np.all((locs >= min(lim) - 1e-9) & (locs <= max(lim) + 1e-9))
        assert np.array_equal(image, plain)
        assert ticks < plain_ticks
        assert locators == [(a.get_major_locator(), a.get_minor_locator())
                            for ax in fig.axes for a in (ax.xaxis, ax.yaxis)]


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_run_figures_labels_fit(paper_runs, name):
    run = paper_runs[name]
    assert_labels_fit(run.plot())
    assert_labels_fit(run.plot_shapes())


def test_a_stopped_runs_figure_marks_the_stop_inside(native):
    paths = {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}
    run = run_scene(load_scene("flexible_pd_lowpass", ["controller.kp=0", "stop_time=1"]), paths,
                    progress=False)
    fig = run.plot()
    assert "STOPPED at t = 0.402 s: the beam tilted past plant.phi_limit" in \
        fig._suptitle.get_text()
    assert_labels_fit(fig)
    assert any(t.get_text().startswith("stopped at t = 0.402 s") for t in texts(fig))  # a note
    shapes = run.plot_shapes()                      # eight times over what ran, not one
    assert sum(ax.get_visible() for ax in shapes.axes) == 8


# ---------------------------------------------------------------------- shapes
def test_shapes_share_one_rail_window_that_covers_the_cart_travel(paper_runs):
    """Every panel has the same window; it holds the cart's whole travel over the run (also
    between the snapshot times) and every drawn beam."""
    run = paper_runs["rigid_pd"]
    res = run.result.copy()
    res["x"][len(res) // 3 + 7] = -4.0              # an excursion between two snapshots
    fig = Run(run.scene, res, run.summary, frames=run.frames).plot_shapes()
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == 8 and len({ax.get_xlim() for ax in panels}) == 1
    lo, hi = panels[0].get_xlim()
    L = run.scene.plant.params.L
    assert lo <= -4.0 - 0.15 * L and hi >= 0.15 * L
    for ax in panels:
        for line in ax.lines:
            if line.get_transform() != ax.transData:        # the rail: axes coordinates
                continue
            x = line.get_xdata()
            assert lo <= np.min(x) and np.max(x) <= hi
        assert ax.get_aspect() == 1.0               # lengths to scale


def test_every_shapes_figure_states_its_deflection_scale_the_same_way(paper_runs):
    flexible = [paper_runs[n].plot_shapes()._suptitle.get_text()
                for n in ("flexible_pd", "flexible_pd_lowpass")]
    stated = f"deflection drawn x{figures.DEFLECTION_SCALE:g}"
    assert all(stated in t for t in flexible)
    rigid = paper_runs["rigid_pd"].plot_shapes()._suptitle.get_text()
    assert "does not bend" in rigid and "deflection drawn" not in rigid
    assert "dotted" not in rigid and "floating frame" not in rigid


def test_shapes_draw_the_deflection_at_the_stated_scale(paper_runs):
    run = paper_runs["flexible_pd"]
    fig = run.plot_shapes()
    beam = beam_model(run.scene.plant.params)
    t, x, phi, eta = run.frames[-1]
    ax = [a for a in fig.axes if a.get_visible()][-1]
    (beam_line,) = [ln for ln in ax.lines if ln.get_linewidth() == 2]
    drawn_x = beam_line.get_xdata()
    expected = figures.beam_shape(beam, x, phi, eta, figures.DEFLECTION_SCALE)[0]
    np.testing.assert_allclose(drawn_x, expected)
    tip = beam.shapes[-1] @ np.asarray(eta)
    assert f"tip {1e3 * tip:+.1f} mm" in ax.get_title()


def test_shapes_make_ticks_only_where_they_are_labelled(paper_runs):
    """The panels share one grid (the rail window's, drawn in each panel); ticks, each costing
    about a millisecond to make, only on the axes that carry labels: the rail position under the
    last row, the height on the left column."""
    fig = paper_runs["flexible_pd"].plot_shapes()
    drawn(fig)
    panels = np.array(fig.axes).reshape(2, 4)
    for (row, col), ax in np.ndenumerate(panels):
        assert bool(len(ax.get_xticks())) == (row == 1)
        assert bool(len(ax.get_yticks())) == (col == 0)
        for c, c0 in zip(ax.collections, panels[0, 0].collections, strict=True):
            np.testing.assert_array_equal(c.get_segments(), c0.get_segments())  # one grid
    made = sum(len(ax.xaxis.majorTicks) + len(ax.yaxis.majorTicks) for ax in fig.axes)
    labelled = 4 * len(panels[1, 0].get_xticks()) + 2 * len(panels[0, 0].get_yticks())
    assert made <= labelled + 16              # matplotlib keeps one tick object on each axis


def test_shapes_leave_no_blank_band(paper_runs):
    """Fixed inches: the margins above, below and between the rows of panels are what the title
    and the tick labels need, whatever the rail window's aspect."""
    for name in PAPER_SCENES:
        fig = paper_runs[name].plot_shapes()
        drawn(fig)
        panels = [ax for ax in fig.axes if ax.get_visible()]
        rows = sorted({round(ax.get_position().y0, 6) for ax in panels})
        height = fig.get_figheight()
        panel_h = panels[0].get_position().height * height
        blank = height - len(rows) * panel_h
        assert blank <= 0.65 + 0.5 + 0.3 * (len(rows) - 1) + 1e-6, (name, blank)
        assert height <= 8.0


# ---------------------------------------------------------------------- the paper's figures
def test_overview_gives_each_run_its_own_time_axis_and_no_empty_panel(paper_runs):
    runs = [paper_runs[n] for n in PAPER_SCENES]
    fig = figures.paper_overview(runs)
    assert_labels_fit(fig)
    for ax in fig.axes:                              # every panel holds a curve
        assert ax.lines and len(ax.lines[0].get_xdata()) > 10
    by_run = {}
    for ax in fig.axes:
        end = ax.lines[0].get_xdata()[-1]
        by_run.setdefault(end, []).append(ax)
    for run in runs:
        axes = by_run[run.result["time"][-1]]
        lo, hi = axes[0].get_xlim()
        span = run.result["time"][-1]
        assert lo <= 0 and span <= hi <= 1.06 * span  # the run fills its own axis
    # the rigid run has no bending panel: its tip angle spans the row
    rigid = [ax for ax in fig.axes if ax.lines[0].get_xdata()[-1] == 10.0
             and ax.get_position().width > 0.6]
    assert len(rigid) == 1
    assert len(fig.axes) == 5


def test_mode_shapes_are_the_plants_with_their_frequencies():
    p = load_scene("flexible_pd").plant.params
    beam = beam_model(p)
    fig = figures.mode_shapes([("flexible_pd", p, first_bending_frequency(p))])
    assert_labels_fit(fig)
    (ax,) = [a for a in fig.axes if a.lines]
    modes = [ln for ln in ax.lines if ln.get_label().startswith("mode ")]
    assert len(modes) == p.n_modes
    for j, ln in enumerate(modes):
        w, s = ln.get_xdata(), ln.get_ydata()
        # at the nodes the curve is the model's shape, scaled to a tip deflection of 1
        at_nodes = np.interp(beam.nodes, s, w)
        np.testing.assert_allclose(at_nodes, beam.shapes[:, j] / beam.shapes[-1, j], atol=2e-3)
        assert w[-1] == pytest.approx(1.0)
        assert f"{beam.frequencies[j]:.4g} rad/s" in ln.get_label()
    assert "26.33 rad/s" in modes[0].get_label()
    assert figures.mode_shapes([("rigid", load_scene("rigid_pd").plant.params, None)]).axes


def test_root_map_holds_each_scenes_closed_loop_roots_and_marks_the_bending_root():
    scenes = [load_scene(n) for n in PAPER_SCENES]
    fig = figures.root_map(scenes, [report_facts(sc) for sc in scenes])
    assert_labels_fit(fig)
    ax = fig.axes[1]
    for k, sc in enumerate(scenes):
        r = loop_roots(sc.plant.params, sc.controller)
        points = [ln for ln in ax.lines if ln.get_color() == f"C{k}"]
        marks, circles = points[0], points[1:]
        up = r.roots[r.roots.imag >= -1e-9]
        np.testing.assert_allclose(marks.get_xdata(), up.real)
        np.testing.assert_allclose(marks.get_ydata(), np.abs(up.imag))
        if r.bending is None:
            assert circles == []
            continue
        (circle,) = circles
        assert circle.get_xdata()[0] == r.bending.real and circle.get_ydata()[0] == r.bending.imag
        assert any(f"{sc.name}: bending root {figures.root_text(r.bending)}" == t.get_text()
                   for t in ax.texts)
    text = " ".join(t.get_text() for t in ax.texts)
    assert "flexible_pd: bending root +1.64 ± 151.2j" in text
    assert "flexible_pd_lowpass: bending root -1.95 ± 153.2j" in text


def test_flexpend_run_writes_the_paper_figures_beside_the_overview(paper_runs, tmp_path):
    written = paper_figures([paper_runs[n] for n in PAPER_SCENES], tmp_path)
    assert [p.name for p in written] == ["paper_overview.png", "mode_shapes.png", "root_map.png"]
    assert all(p.stat().st_size > 10_000 for p in written)
    rigid_only = paper_figures([paper_runs["rigid_pd"]], tmp_path / "rigid")
    assert [p.name for p in rigid_only] == ["paper_overview.png", "root_map.png"]


def test_run_figures_use_no_mathtext(paper_runs, tmp_path, monkeypatch):
    """The nine figures of ``flexpend run`` write their symbols in plain Unicode (tip angle
    phi_o as "\u03c6\u2092", decades as "10\u207b\u00b2"): matplotlib never parses mathtext
    while it draws and saves them (its parser's grammar alone costs about 0.3 s to build), and
    no text drawn holds a "$"."""
    from matplotlib.mathtext import MathTextParser

    parsed = []
    parse = MathTextParser.parse
    monkeypatch.setattr(MathTextParser, "parse",
                        lambda self, s, *a, **k: parsed.append(s) or parse(self, s, *a, **k))
    made = []
    monkeypatch.setattr(mpl_canvas, "new_figure",
                        lambda *a, new=mpl_canvas.new_figure: made.append(new(*a)) or made[-1])
    written = [p for name in PAPER_SCENES
               for p in paper_runs[name].save(tmp_path, renderer="matplotlib")]
    written += paper_figures([paper_runs[n] for n in PAPER_SCENES], tmp_path, "matplotlib")
    assert sum(p.suffix == ".png" for p in written) == 9 == len(made)
    assert parsed == []
    dollars = [t.get_text() for fig in made for t in texts(fig) if "$" in t.get_text()]
    assert dollars == []
    # the test sees mathtext where there is some
    fig = figures.new_figure(2, 1)
    fig.text(0.1, 0.5, "$\\eta_1$")
    from orchestration.report.files import save_figure
    save_figure(fig, tmp_path / "math.png")
    assert set(parsed) == {"$\\eta_1$"}


def test_figures_leave_the_backend_alone(paper_runs, tmp_path):
    """The figures are Figures of their own: the process's backend stays what it was and pyplot
    holds no figure of theirs."""
    import subprocess
    import sys

    code = ("import matplotlib, sys; matplotlib.use('svg'); "
            "from orchestration.report import figures; from orchestration.scene.schema import "
            "load_scene; from orchestration.report.files import save_figure; "
            "from orchestration.studies.summary import report_facts; "
            f"d = {str(tmp_path)!r}; s = load_scene('flexible_pd'); f = report_facts(s); "
            "save_figure(figures.root_map([s], [f]), d + '/r.png'); "
            "save_figure(figures.mode_shapes([('a', s.plant.params, "
            "f.roots.bending_frequency)]), d + '/m.png'); "
            "assert matplotlib.get_backend() == 'svg', matplotlib.get_backend(); "
            "import matplotlib.pyplot as plt; assert plt.get_fignums() == []")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_design_figures_labels_fit():
    """The Bode plot's mark is labelled inside its axes and its -180 deg lines are where the
    phase is; the root locus and the worst case fit their figures."""
    from orchestration.studies.analysis import frequency_response
    from orchestration.studies.design import root_locus

    scene = load_scene("flexible_pd_lowpass")
    p, c = scene.plant.params, scene.controller
    w = np.logspace(0, 3.7, 600)
    fig = figures.loop_bode(w, {"PD": frequency_response(p, c.replace(filter_order=0), w),
                                "PD + filter": frequency_response(p, c, w)},
                            "loop broken at the force", [(c.cutoff, "cutoff")])
    assert_labels_fit(fig)
    phase = fig.axes[1]
    levels = sorted(ln.get_ydata()[0] for ln in phase.lines if len(set(ln.get_ydata())) == 1
                    and ln.get_transform() != phase.transData)
    assert all((lv + 180) % 360 == 0 for lv in levels) and -180 in levels and -900 in levels
    cut, roots = root_locus(p, c, np.geomspace(30, 1000, 40))
    assert_labels_fit(figures.root_locus(cut, roots, c.cutoff, "closed-loop roots"))
    wc = np.geomspace(30, 1000, 20)
    assert_labels_fit(figures.worst_case({"2nd order": (wc, np.sin(np.log(wc)))},
                                         (97.3, 0.5, "chosen"), "decay rate", "worst case"))


# ---------------------------------------------------------------------- one source, two renderers
def _mpl_structure(fig) -> dict:
    panels = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        legend = ax.get_legend()
        panels.append({
            "titles": {loc: t for loc, t in (("center", ax.get_title()),
                                             ("left", ax.get_title(loc="left"))) if t},
            "xlabel": ax.get_xlabel(), "ylabel": ax.get_ylabel(),
            "scales": (ax.get_xscale(), ax.get_yscale()),
            "legend": [t.get_text() for t in legend.get_texts()] if legend else [],
            "lines": len(ax.lines), "patches": len(ax.patches),
            "texts": sorted(t.get_text() for t in ax.texts)})
    return {"title": fig._suptitle.get_text() if fig._suptitle else None,
            "texts": [t.get_text() for t in fig.texts if t is not fig._suptitle],
            "panels": panels,
            "legend": [t.get_text() for leg in fig.legends for t in leg.get_texts()]}


def _raster_structure(fig) -> dict:
    panels = []
    for p in fig.panels_made:
        if p.hidden:
            continue
        kinds = [kind for kind, _, _ in p.items]
        panels.append({
            "titles": {loc: t[0] for loc, t in p.titles.items() if t[0]},
            "xlabel": p.x_label[0] if p.x_label else "",
            "ylabel": p.y_label[0] if p.y_label else "",
            "scales": (p.scales["x"].kind, p.scales["y"].kind),
            "legend": ([str(d["label"]) for _, d in p.legend_entries()] if p.legend_spec
                       else []),
            "lines": sum(k in ("line", "markers", "hline", "vline") for k in kinds),
            "patches": sum(k in ("xspan", "rect") for k in kinds),
            "texts": sorted([d["text"] for k, _, d in p.items if k == "text"]
                            + [n[0] for n in p.notes])})
    return {"title": fig.suptitle[0] if fig.suptitle else None,
            "texts": [t[2] for t in fig.texts], "panels": panels,
            "legend": ([str(d["label"]) for p in fig.panels_made if not p.hidden
                        for _, d in p.legend_entries()] if fig.fig_legend else [])}


def test_both_renderers_draw_the_same_panels_titles_labels_and_legends(paper_runs):
    """Each figure of ``flexpend run`` is written once (:mod:`orchestration.report.plotting`):
    what matplotlib's Figure holds (panels, titles, axis labels and scales, legend entries, the
    number of curves, patches and notes) is what the raster renderer was given to draw."""
    runs = [paper_runs[n] for n in PAPER_SCENES]
    labelled = [(runs[1].name, runs[1].scene.plant.params, runs[1].facts.roots.bending_frequency)]
    makers = [lambda r: runs[0].plot(r), lambda r: runs[1].plot(r),
              lambda r: runs[2].plot_shapes(r), lambda r: runs[0].plot_shapes(r),
              lambda r: figures.paper_overview(runs, renderer=r),
              lambda r: figures.mode_shapes(labelled, renderer=r),
              lambda r: figures.root_map([r_.scene for r_ in runs], [r_.facts for r_ in runs],
                                         renderer=r)]
    for make in makers:
        mpl, ras = _mpl_structure(make("matplotlib")), _raster_structure(make("raster"))
        assert mpl["panels"] and mpl == ras
    assert ras["legend"] and any(p["legend"] for p in _raster_structure(runs[1].plot("raster"))
                                 ["panels"])
