"""Figures of a run: time histories (the paper's Figs. 3, 4, 6, 7) and beam snapshots (Figs. 5, 8);
of the paper's sample: the overview, the cantilever mode shapes, the closed-loop roots; of a
design: Bode plot, root locus, worst case.

The figures of a run (time histories, snapshots, overview, mode shapes, roots) are written once
in the plotting vocabulary of :mod:`orchestration.report.plotting` and drawn by the ``renderer``
asked: a matplotlib Figure of its own (the default; no pyplot: the process's backend is left
alone), or a raster canvas drawn with Pillow (``flexpend run``: no matplotlib imported), which
:func:`~orchestration.report.files.save_figure` writes alike. The design's figures are
matplotlib Figures. Titles say what ran, built from the scene's records (:func:`scene_title`),
never from a scene's fixed text. Margins are fixed in inches where a figure is drawn on every
run (a layout engine costs about a second per figure); symbols are plain Unicode (``φₒ``,
``10⁻²``), never mathtext, whose parser a run would otherwise build."""
from __future__ import annotations

import math

import numpy as np

from .layout import SUPERSCRIPT
from .mpl_canvas import new_figure, plain_log_labels, ticks_in_view
from .plotting import canvas

__all__ = ["time_histories", "snapshots", "beam_shape", "paper_overview", "mode_shapes",
           "root_map", "loop_bode", "root_locus", "worst_case", "new_figure", "scene_title",
           "plant_text", "controller_text", "initial_text", "loop_text", "outcome_text",
           "root_text", "RATE_CONVENTION", "bending_band", "DEFLECTION_SCALE", "ticks_in_view",
           "plain_log_labels", "SUPERSCRIPT"]


def _wrapped(text: str, width: int = 95) -> str:
    import textwrap
    return "\n".join(textwrap.wrap(text, width)) if text else ""


# ---------------------------------------------------------------------- what ran, in words
#: The physical parameters a title names when a scene changes them from the paper's Table 1
#: (those of a rigid model leave out what only the beam's bending depends on).
_PHYSICAL = ("m", "L", "rho", "EA", "E", "EI", "g", "gravity_preload", "n_elements")
_BENDING_ONLY = ("EI", "gravity_preload", "n_elements")


#: The sign convention of every rate a figure states, as the text summaries state it (``rate
#: -0.643 1/s``): the real part of a root; a figure that states rates names it once.
RATE_CONVENTION = "growth rate σ = Re(λ), 1/s; negative decays"


def root_text(z) -> str:
    """A root as ``-1.95 ± 153.2j`` (a real root: ``+6.23``)."""
    z = complex(z)
    if abs(z.imag) <= 1e-9 * max(1.0, abs(z)):
        return f"{z.real:+.3g}"
    return f"{z.real:+.3g} ± {abs(z.imag):.4g}j"


def plant_text(scene) -> str:
    """The plant that ran: rigid or its number of cantilever modes, the fidelity, its damping
    (the law named: every root and rate the title states depends on it) and the physical
    parameters that differ from the paper's Table 1."""
    from dataclasses import fields

    from plant_fmu.params import PlantParams, damping_text

    p = scene.plant.params
    table1 = {f.name: f.default for f in fields(PlantParams)}     # no record made for it
    exact = scene.plant.fidelity == "exact"
    if exact:
        out = f"geometrically exact beam, {p.n_elements} elements"
    elif p.n_modes == 0:
        out = "rigid pendulum"
    else:
        out = f"flexible beam, {p.n_modes} cantilever mode{'s' if p.n_modes > 1 else ''}"
    if scene.plant.fidelity == "linear":
        out += ", linearised plant"
    elif scene.plant.fidelity == "stiffened":
        out += ", stiffened rung"
    if p.n_modes or exact:
        out += f", {damping_text(p)}"
    changed = [f"{k} = {getattr(p, k):g}" if not isinstance(getattr(p, k), bool)
               else f"{k} = {str(getattr(p, k)).lower()}"
               for k in _PHYSICAL if getattr(p, k) != table1[k]
               and not (p.n_modes == 0 and not exact and k in _BENDING_ONLY)
               and not (exact and k in ("n_elements", "gravity_preload"))]
    return out + (f" ({', '.join(changed)})" if changed else "")


def controller_text(c) -> str:
    """The control law that ran: ``Fc = -(500 φₒ + 5 ωₒ)``, its filter and limit."""
    terms = [(c.kp, "φₒ"), (c.kd, "ωₒ"), (c.kx, "xₒ")]
    law = ""
    for k, sym in terms:
        if k == 0 and sym == "xₒ":
            continue
        sign = f" {'-' if k < 0 else '+'} " if law else ("-" if k < 0 else "")
        law += f"{sign}{abs(k):g} {sym}"
    out = f"PD Fc = -({law})"
    out += {0: ", no filter",
            1: f", 1st-order low-pass at {c.cutoff:g} rad/s",
            2: f", 2nd-order low-pass at {c.cutoff:g} rad/s (damping {c.filter_damping:g})"
            }[c.filter_order]
    if c.saturates:
        out += f", |Fc| ≤ {c.force_limit:g} N"
    if c.sampled:
        out += (f"; sampled every {1e3 * c.sample_period:g} ms ({c.discretization}), "
                f"delay {1e3 * c.delay:g} ms")
    return out


def initial_text(initial) -> str:
    """The initial state: ``from φ₀ = 30 deg`` (the other initial values when not 0)."""
    out = f"from φ₀ = {math.degrees(initial.phi):.4g} deg"
    for value, sym, unit in ((initial.x, "x₀", "m"), (initial.x_dot, "ẋ₀", "m/s"),
                             (initial.phi_dot, "φ̇₀", "rad/s")):
        if value:
            out += f", {sym} = {value:g} {unit}"
    return out


def loop_text(facts) -> str:
    """What the linearised loop predicts: stable (its slowest root's rate σ = Re(λ), negative;
    every rate a figure states is signed so: negative decays, positive grows) or which roots
    grow; the bending root; from a run's facts (:class:`~orchestration.studies.summary.ReportFacts`: its
    loop's roots, :func:`~orchestration.studies.analysis.loop_roots`)."""
    r = facts.roots
    loop = "linearised loop" if facts.own else \
        "the floating frame's preloaded linearised loop (standing in for the exact rung's)"

    def name(z):
        if r.bending is not None and complex(z) == r.bending:
            return f"bending root {root_text(z)}"
        return f"{'real root' if complex(z).imag == 0 else 'root'} {root_text(z)}"

    if r.stable:
        out = f"{loop}: stable, slowest root's rate σ = Re(λ) = {r.max_real_part:+.3g} 1/s"
        if r.bending is not None:
            out += f"; {name(r.bending)}"
        return out
    grow = r.growing()
    out = f"{loop}: UNSTABLE, " + " and ".join(name(z) for z in grow[:2])
    out += (" grows" if len(grow) == 1 else f" grow{' (and more)' if len(grow) > 2 else ''}")
    if r.bending is not None and r.bending.real < 0:
        out += f"; {name(r.bending)}"
    return out


def outcome_text(summary, facts=None) -> str:
    """What the co-simulation did: its stop, or its verdict, and its error figure (what it
    compares with, or why there is none, in the words of ``facts.untrusted``); without one, its
    model-form error bound and whether it left its rung's measured range."""
    if summary is None:
        return ""
    stopped = summary.get("stopped")
    if stopped:
        at = f" at t = {stopped['time']:.4g} s" if stopped.get("time") is not None else ""
        return f"co-simulation STOPPED{at}: {stopped['reason']}"
    out = "co-simulation: " + {True: "stable (every oscillation's fit decays)",
                               False: "UNSTABLE (a fit grows)",
                               None: "undetermined (no fit decides)"}[summary.get("stable")]
    f = summary.get("error_figure")
    if f:
        c = f["companion"]
        against = (f"stiffened, {c['n_modes']} modes, {c['damping']}"
                   + ("" if c["zeta"] else ", undamped"))
        out += (f"; error vs the exact beam <= {f['figure']:.1e} rad (companion: {against})"
                if f["figure"] is not None
                else f"; no error figure: {facts.untrusted[f['untrusted']]}")
        return out
    v = summary.get("validity") or {}
    if v.get("model_form_error") is not None:
        out += f"; model-form error <= {v['model_form_error']:.1e} rad ({v['rung']})"
    if v.get("warnings"):
        out += "; it leaves the measured range"
    return out


def scene_title(scene, summary=None, *, facts) -> str:
    """A figure's title, from the records of the scene that ran, its facts
    (:class:`~orchestration.studies.summary.ReportFacts`) and its summary: the plant, the
    control law, the initial state, the linear prediction, the outcome."""
    lines = [f"{scene.name}: {plant_text(scene)}",
             f"{controller_text(scene.controller)}; {initial_text(scene.initial)}",
             loop_text(facts), outcome_text(summary, facts)]
    return "\n".join(_wrapped(line, 130) for line in lines if line)


def _title_height(title: str) -> float:
    """Inches a suptitle of ``title`` (fontsize 9) takes, with its margin."""
    return 0.2 + 0.17 * (title.count("\n") + 1)


# ---------------------------------------------------------------------- time histories
#: Time-history panels: column -> (quantity, unit) of the axis label (SI units; eta_j belong to
#: mass-normalised modes, in m kg^(1/2)); symbols in plain Unicode, no mathtext.
#: The colour of a fit window marked unreliable (outlined, not shaded: :func:`_fit_window`).
UNRELIABLE_COLOR = "0.45"

PANELS = {
    "phi_o": ("tip angle φₒ", "rad"),
    "eta_1": ("1st modal coord. η₁", "m·kg½"),
    "bending": ("η₁ above 60 rad/s:\nenvelope", "m·kg½"),
    "tip_deflection": ("tip deflection", "m"),
    "F_c": ("force Fc", "N"),
    "x": ("cart position x", "m"),
}


def _scaled(y, quantity: str, unit: str):
    """``(10^k, axis label)``: values far below 1e-3 or above 1e4 are drawn divided by a power of
    ten that the label names (no offset text above the axis, where titles sit); else 1."""
    top = float(np.max(np.abs(y))) if len(y) else 0.0
    if top == 0.0 or not math.isfinite(top) or 1e-3 <= top < 1e4:
        return 1.0, f"{quantity} ({unit})"
    k = int(math.floor(math.log10(top)))
    return 10.0 ** k, f"{quantity}\n(10{str(k).translate(SUPERSCRIPT)} {unit})"


def _highpass(n_fft: int, dt: float, low: float, order: int = 4) -> np.ndarray:
    """The response of scipy's digital Butterworth high-pass (``butter(order, low, "highpass",
    fs=2 pi / dt)``: the analog filter with its edge prewarped, by the bilinear transform) at the
    frequencies of numpy's ``rfft`` of ``n_fft`` points."""
    v = np.tan(np.fft.rfftfreq(n_fft) * math.pi) / math.tan(low * dt / 2)
    poles = np.exp(1j * math.pi * (2 * np.arange(1, order + 1) + order - 1) / (2 * order))
    jv = 1j * v[:, None]
    return np.prod(jv / (jv - 1 / poles), axis=1)


def bending_band(t, y, low: float, frequency: float | None = None):
    """The part of ``y`` (uniform ``t``) above ``low`` rad/s, zero-phase, and its envelope (the
    largest magnitude within one period of ``frequency``, default ``low``, around each point):
    the bending oscillation without the slow motion it rides on.

    The filter is scipy's ``sosfiltfilt`` of a 4th-order Butterworth high-pass, computed without
    importing scipy.signal (0.7 s): the trace extended at each end by its odd reflection (15
    points), filtered forwards then backwards, each pass from its filter's steady state on the
    first value (for a high-pass: the convolution with its impulse response of the trace minus
    that value), each convolution by numpy's FFT over a length that holds the response until it
    has decayed below 1e-12."""
    y = np.asarray(y, dtype=float)
    dt = float(t[1] - t[0])
    fs = 2 * math.pi / dt
    if len(y) < 16 or low >= 0.45 * fs:
        return np.zeros_like(y), np.zeros_like(y)
    pad = 15
    x = np.concatenate([2 * y[0] - y[pad:0:-1], y, 2 * y[-1] - y[-2:-pad - 2:-1]])
    # the slowest pole decays as exp(-low sin(pi/8) t): below 1e-12 after 28 / that
    decay = int(28 / (low * math.sin(math.pi / 8) * dt)) + 1
    n_fft = 1 << (len(x) + decay - 1).bit_length()
    H = _highpass(n_fft, dt, low)

    def causal(s):
        return np.fft.irfft(np.fft.rfft(s - s[0], n_fft) * H, n_fft)[:len(s)]

    hp = causal(causal(x)[::-1])[::-1][pad:pad + len(y)]
    # the envelope: the largest |value| within one period of the band's lowest frequency around
    # each point (the ends held, no transform that wraps the run's end onto its start)
    size = min(max(3, int(round(fs / (frequency or low))) | 1), 2 * len(y) - 1)
    a = np.abs(hp)
    edge = np.concatenate([np.full(size // 2, a[0]), a, np.full(size // 2, a[-1])])
    return hp, np.lib.stride_tricks.sliding_window_view(edge, size).max(axis=1)


def time_histories(result, scene, reference=None, summary=None, *, facts,
                   renderer="matplotlib"):
    """The paper's time histories (Figs. 3, 4, 6, 7): tip angle, first modal coordinate, the
    envelope of its bending band, tip deflection, force and cart position against time; the
    bending panels are left out for a rigid model. The title says what ran (:func:`scene_title`).
    ``facts`` (:class:`~orchestration.studies.summary.ReportFacts`): the linearised loop's roots
    for the title, the bending band and the first bending frequency for its envelope.

    With a ``summary``: each fit window is shaded on the trace that was fitted, with the fitted
    rate: the slow fit on the tip angle, the bending fit on the envelope of ``eta_1``'s bending
    band (the slow motion ``eta_1`` also carries is not what that fit measures), where the
    fitted rate is drawn as a line (a straight line on the log scale when it holds); the
    deflection up to which the rung's error was measured is drawn when the trace comes near it
    (else stated); an early stop is marked. Drawn by ``renderer``
    (:func:`~orchestration.report.plotting.canvas`): a matplotlib Figure, or a raster canvas to
    save."""
    t = result["time"]
    flexible = scene.plant.params.n_modes > 0 and np.any(result["eta_1"]) and len(t) >= 16
    cols = [c for c in PANELS if flexible or c not in ("eta_1", "bending", "tip_deflection")]
    title = scene_title(scene, summary, facts=facts)
    top = _title_height(title)
    height = 1.55 * len(cols) + top + 0.5
    fig = canvas(9, height, renderer)
    # fixed margins (a layout engine costs a second per figure)
    grid = fig.grid(len(cols), 1, left=0.11, right=0.98, top=1 - top / height,
                    bottom=0.5 / height, hspace=0.14)
    axes = [row[0] for row in fig.panels(grid, sharex=True)]
    ax_of = dict(zip(cols, axes))
    for col, ax in ax_of.items():
        ax.tick_labels(8)
        ax.grid()
        if col == "bending":
            ax.ylabel(f"{PANELS[col][0]} ({PANELS[col][1]})", size=8)
            continue
        factor, label = _scaled(result[col], *PANELS[col])
        ax.ylabel(label, size=8)
        ax.line(t, result[col] / factor, lw=0.7, color="C0",
                label="co-simulation" if reference is not None else None)
        if reference is not None and col in reference.dtype.names:
            ax.line(reference["time"], reference[col] / factor, style="--", lw=0.7, color="C1",
                    label="monolithic reference")
    if flexible:
        ax = ax_of["bending"]
        _, env = bending_band(t, result["eta_1"], facts.bending_band,
                              facts.roots.bending_frequency)
        ax.yscale("log")
        ax.line(t, np.maximum(env, 1e-300), lw=0.7, color="C0")
        top_env = float(env.max()) if env.size else 0.0
        if top_env > 0:
            # two decades at least (labelled decades, no crowded minor labels), five at most
            low = min(top_env / 100, max(top_env * 1e-5, float(env[env > 0].min()) * 0.5))
            ax.ylim(low, top_env * 3)
    legend = {c: reference is not None for c in cols}
    if summary is not None:
        m = summary.get("slow")
        if m and m.get("fit"):
            _fit_window(ax_of["phi_o"], "slow", m)
            legend["phi_o"] = True
        m = summary.get("bending")
        if flexible and m and m.get("fit"):
            ax = ax_of["bending"]
            lo, hi = m["fit"]["window"]
            f = m["fit"]
            _fit_window(ax, "bending", m)
            inside = (t >= lo) & (t <= hi)
            if m["reliable"] and np.any(inside) and env[inside].max() > 0:
                # the fitted rate through the envelope's level at the window's start
                period = 2 * math.pi / f["frequency"]
                first = inside & (t <= lo + period)
                a0 = float(env[first].max()) if np.any(first) else float(env[inside][0])
                tt = np.array([lo, hi])
                ax.line(tt, a0 * np.exp(f["rate"] * (tt - lo)), style="--", color="C3", lw=1.0,
                        label=f"fitted rate σ = {f['rate']:+.3g} 1/s")
            legend["bending"] = True
        v = summary.get("validity")
        if v and v.get("tip_deflection_limit") and "tip_deflection" in ax_of:
            ax = ax_of["tip_deflection"]
            lim = v["tip_deflection_limit"]
            reach = float(np.max(np.abs(result["tip_deflection"]))) if len(t) else 0.0
            if reach >= 0.3 * lim:
                for sign in (1, -1):
                    ax.hline(sign * lim, color="C3", style=":", lw=0.8,
                             label=f"measured range ±{lim:.3g} m" if sign > 0 else None)
                legend["tip_deflection"] = True
            else:
                ax.note(f"measured range ±{lim:.3g} m: off this scale", color="C3", size=7)
        stopped = summary.get("stopped")
        if stopped and stopped.get("time") is not None:
            for ax in axes:
                ax.vline(stopped["time"], color="C3", lw=0.8)
            axes[0].note(f"stopped at t = {stopped['time']:.4g} s (the red line)", color="C3",
                         size=8)
    for col, ax in ax_of.items():
        if legend[col]:
            ax.legend(loc="upper left" if col == "tip_deflection" else "upper right", size=7)
    axes[-1].xlabel("time (s)", size=9)
    fig.title(title, size=9, y=1 - 0.08 / height)
    return fig.result()



def _fit_window(ax, mode: str, m: dict) -> None:
    """The window a mode's rate was fitted over: shaded, its rate in the legend, when the fit
    is reliable; else outlined only (dashed edges, grey), "unreliable: no rate" in the legend,
    so that it is not read as a fit."""
    lo, hi = m["fit"]["window"]
    if m["reliable"]:
        ax.xspan(lo, hi, color="C2", alpha=0.12, label=f"{mode} fit window: σ = "
                 f"{m['rate']:+.3g} 1/s at {m['frequency']:.4g} rad/s")
    else:
        ax.xspan(lo, hi, color=UNRELIABLE_COLOR, outline=True,
                 label=f"{mode} fit window (outlined): unreliable, no rate")


# ---------------------------------------------------------------------- shapes
#: Every shapes figure draws the beam's deflection magnified by this factor (a tip deflection of
#: 5 % of L is drawn as 25 % of L), so that figures can be compared by eye.
DEFLECTION_SCALE = 5.0


def beam_shape(beam, x, phi, eta, scale: float = 1.0):
    """Global coordinates of the beam's nodes: ``r(s) = (x, 0) + s b1 + w(s) b2``."""
    s = beam.nodes
    n = min(len(eta), beam.shapes.shape[1])
    w = beam.shapes[:, :n] @ np.asarray(eta[:n]) * scale if n else np.zeros_like(s)
    b1 = np.array([-np.sin(phi), np.cos(phi)])
    b2 = np.array([-np.cos(phi), -np.sin(phi)])
    return x + s * b1[0] + w * b2[0], s * b1[1] + w * b2[1]


def _tip(beam, eta) -> float:
    n = min(len(eta), beam.shapes.shape[1])
    return float(beam.shapes[-1, :n] @ np.asarray(eta[:n])) if n else 0.0


def snapshots(beam, frames, scene, travel=None, *, renderer="matplotlib"):
    """The beam and the cart at several times (the paper's Figs. 5 and 8), every panel on the
    same window of the rail, so that the cart's travel shows; lengths to scale, the deflection
    drawn ``DEFLECTION_SCALE`` times (the same in every shapes figure) and each panel's tip
    deflection given in mm. ``frames``: list of ``(t, x, phi, eta)``; ``travel``: ``(min, max)``
    of the cart's position over the run (default: over the frames), drawn on the rail and kept
    inside the window. Drawn by ``renderer``, as :func:`time_histories`."""
    n = len(frames)
    L = float(beam.nodes[-1])
    rigid = scene.plant.params.n_modes == 0
    scale = 1.0 if rigid else DEFLECTION_SCALE
    shapes = [beam_shape(beam, x, phi, eta, scale) for _, x, phi, eta in frames]
    xs = [x for _, x, _, _ in frames]
    travel = (min(xs), max(xs)) if travel is None else tuple(travel)
    x_lo = min([travel[0] - 0.15 * L] + [float(X.min()) for X, _ in shapes]) - 0.1 * L
    x_hi = max([travel[1] + 0.15 * L] + [float(X.max()) for X, _ in shapes]) + 0.1 * L
    y_lo = min([-0.15 * L] + [float(Y.min()) for _, Y in shapes]) - 0.05 * L
    y_hi = max([0.3 * L] + [float(Y.max()) for _, Y in shapes]) + 0.1 * L
    aspect = (x_hi - x_lo) / (y_hi - y_lo)
    # fixed inches: panels of the window's aspect, one title line above each, the rail's tick
    # labels under the last row only; the fewest columns that keep the figure under 8 in tall
    width, left, right, gap, row_gap, top, bottom = 10.0, 0.6, 0.15, 0.3, 0.3, 0.65, 0.5
    for ncol in [c for c in (1, 2, 4, 8) if c <= max(n, 1)] or [1]:
        pw = (width - left - right - gap * (ncol - 1)) / ncol
        ph = pw / aspect
        nrow = math.ceil(n / ncol)
        height = top + bottom + nrow * ph + (nrow - 1) * row_gap
        if height <= 8.0:
            break
    fig = canvas(width, height, renderer)
    grid = fig.grid(nrow, ncol, left=left / width, right=1 - right / width, top=1 - top / height,
                    bottom=bottom / height, wspace=gap / pw, hspace=row_gap / ph)
    rows = fig.panels(grid)
    axes = [ax for row in rows for ax in row]
    for ax in axes[n:]:
        ax.hide()
    # one set of grid lines for every panel; ticks (about a millisecond each to make) only on
    # the axes that carry labels: the rail position under the last row, the height on the left
    xt, yt = fig.locate(x_lo, x_hi, 5), fig.locate(y_lo, y_hi, 4)
    for row, panels in enumerate(rows):
        for col, ax in enumerate(panels):
            ax.ticks(x=xt if row == nrow - 1 else (), y=yt if col == 0 else ())
            ax.grid(x=xt, y=yt)
    for ax, (t, x, phi, eta), (X, Y) in zip(axes, frames, shapes):
        ax.hline(0.0, color="0.3", lw=0.8)                         # the rail
        ax.line(travel, [0.0, 0.0], color="C1", lw=4, alpha=0.25, butt=True)
        ax.rect(x - 0.15 * L, -0.1 * L, 0.3 * L, 0.1 * L, color="C1")
        if not rigid:
            undeformed = beam_shape(beam, x, phi, [])
            ax.line(undeformed[0], undeformed[1], style=":", color="0.5", lw=1)
        ax.line(X, Y, color="C0", lw=2)
        ax.markers([x], [0.0], marker="o", color="k", size=3)      # the hinge
        ax.xlim(x_lo, x_hi)
        ax.ylim(y_lo, y_hi)
        ax.equal_aspect()
        tip = "" if rigid else f", tip {1e3 * _tip(beam, eta):+.1f} mm"
        ax.title(f"t = {t:.3g} s, x = {x:+.2f} m{tip}", size=8, pad=3)
        ax.tick_labels(7)
    for panels in rows:
        panels[0].ylabel("height (m)", size=8)
    for ax in rows[-1]:
        ax.xlabel("rail position (m)", size=8)
    what = ("rigid model: the beam does not bend" if rigid else
            f"deflection drawn x{scale:g}, its tip value in mm (dotted: the undeformed beam)")
    fig.title(f"{scene.name}: the beam and the cart at {n} times on one window of the rail "
              f"(light band: the cart's travel)\nlengths to scale; {what}", size=9,
              y=1 - 0.06 / height)
    return fig.result()



# ---------------------------------------------------------------------- the paper's sample
def paper_overview(runs, *, renderer="matplotlib"):
    """The paper's sample side by side, one row per run (a :class:`~orchestration.job.Run`), each
    on its own time axis: tip angle (Figs. 3, 4, 6) and, for a flexible model, first modal
    coordinate (Fig. 7), so that no curve hides another; a rigid run's tip angle spans the row.
    Each row's title says what ran (:func:`plant_text`, :func:`controller_text`). Drawn by
    ``renderer``, as :func:`time_histories`."""
    n = len(runs)
    row_h, top, bottom = 2.05, 0.55, 0.45
    height = row_h * n + top + bottom
    fig = canvas(11, height, renderer)
    grid = fig.grid(n, 2, left=0.07, right=0.99, top=1 - top / height, bottom=bottom / height,
                    wspace=0.2, hspace=0.55)
    starts = {f"{r.scene.initial.phi:.6g}" for r in runs}
    for i, run in enumerate(runs):
        res, sc = run.result, run.scene
        flexible = sc.plant.params.n_modes > 0 and len(res) and np.any(res["eta_1"])
        row = [fig.panel(grid, i, 0, colspan=1 if flexible else 2)]
        if flexible:
            row.append(fig.panel(grid, i, 1, sharex=row[0]))
        factor, label = _scaled(res["phi_o"], "φₒ", PANELS["phi_o"][1])
        row[0].line(res["time"], res["phi_o"] / factor, lw=0.7, color="C0")
        row[0].ylabel(label, size=9)
        if flexible:
            factor, label = _scaled(res["eta_1"], "η₁", PANELS["eta_1"][1])
            row[1].line(res["time"], res["eta_1"] / factor, lw=0.7, color="C2")
            row[1].ylabel(label, size=9)
        stop = run.summary.get("stopped") if run.summary else None
        verdict = ("STOPPED" if stop else {True: "stable", False: "UNSTABLE",
                                           None: "undetermined"}[run.summary.get("stable")])
        row[0].title(f"{sc.name} ({verdict}): {plant_text(sc)}; "
                     f"{controller_text(sc.controller)}"
                     + ("" if len(starts) == 1 else f"; {initial_text(sc.initial)}"),
                     size=8.5, loc="left")
        for ax in row:
            ax.grid()
            ax.tick_labels(8)
            ax.xlabel("time (s)", size=8, pad=1)
            if stop and stop.get("time") is not None:
                ax.vline(stop["time"], color="C3", lw=0.8)
    first = runs[0].scene.initial if runs else None
    start = f" {initial_text(first)}" if first is not None and len(starts) == 1 else ""
    fig.title(f"Tip angle and first modal coordinate of each run{start}, each on its own "
              "time axis", size=10, y=1 - 0.1 / height)
    return fig.result()


def _hermite(nodes, values, slopes, s):
    """The cubic Hermite interpolant of ``values`` and ``slopes`` at ``nodes``, at ``s`` (inside
    the nodes): what a beam element's shape functions draw between its nodes."""
    i = np.clip(np.searchsorted(nodes, s, side="right") - 1, 0, len(nodes) - 2)
    h = nodes[i + 1] - nodes[i]
    u = (s - nodes[i]) / h
    return ((2 * u**3 - 3 * u**2 + 1) * values[i] + (u**3 - 2 * u**2 + u) * h * slopes[i]
            + (3 * u**2 - 2 * u**3) * values[i + 1] + (u**3 - u**2) * h * slopes[i + 1])


def mode_shapes(plants, *, renderer="matplotlib"):
    """The cantilever mode shapes a plant uses (:func:`plant_fmu.beam.beam_model`: ``nodes``,
    ``shapes``, ``slopes``, ``frequencies``), the beam upright as in the snapshots: one panel per
    plant of ``plants`` (a list of ``(label, PlantParams, its first bending frequency with the
    hinge free)``, :attr:`~orchestration.studies.analysis.LoopRoots.bending_frequency`; rigid
    ones are left out), each mode
    drawn between the nodes as the finite elements shape it (cubic Hermite, from the nodal
    deflections and slopes) and scaled to a tip deflection of 1 (the model's mass-normalised
    shapes differ only in scale), with its frequency. These are the modes clamped at the hinge;
    the loop's bending root sits near the first bending mode with the hinge free, not near them.
    Drawn by ``renderer``, as :func:`time_histories`."""
    from plant_fmu.beam import beam_model

    plants = [(label, p, wb) for label, p, wb in plants if p.n_modes > 0]
    n = max(len(plants), 1)
    panel, legend_w, left, top, bottom = 3.0, 2.6, 0.65, 0.75, 0.5
    width = left + n * (panel + legend_w)
    height = 4.6
    fig = canvas(width, height, renderer)
    grid = fig.grid(1, n, left=left / width, right=1 - legend_w / width, top=1 - top / height,
                    bottom=bottom / height, wspace=legend_w / panel)
    axes = fig.panels(grid)[0]
    for ax, (label, p, _) in zip(axes, plants):
        b = beam_model(p)
        s = np.linspace(0.0, b.nodes[-1], 40 * len(b.nodes))
        for j in range(p.n_modes):
            w = _hermite(b.nodes, b.shapes[:, j], b.slopes[:, j], s)
            w = w / w[-1] if w[-1] else w / np.max(np.abs(w))
            f = b.frequencies[j]
            ax.line(w, s, lw=1.4, color=f"C{j % 10}",
                    label=f"mode {j + 1}: {f:.4g} rad/s ({f / (2 * math.pi):.3g} Hz)")
        ax.vline(0.0, color="0.3", lw=0.8, style=":")
        ax.markers([0.0], [0.0], marker="o", color="k", size=4)
        ax.title(_wrapped(label, 42), size=8.5, loc="left")
        ax.xlabel("deflection w (tip = 1)", size=8)
        ax.ylim(-0.02 * p.L, 1.04 * p.L)
        ax.tick_labels(8)
        ax.grid()
        ax.legend(size=7.5, outside=True)
    for ax, (label, p, wb) in zip(axes, plants):         # beside the panel, under its legend
        x0, y0, x1, y1 = ax.box
        fig.text(x1 + 0.1 / width, y0, f"hinge free, the first bending\nmode is at "
                 f"{wb:.4g} rad/s:\nthe loop's bending root is\nnear it",
                 size=7.5, va="bottom", color="0.3")
    axes[0].ylabel("position along the beam s (m)", size=8)
    fig.title("The cantilever modes the plant uses\n(floating frame, clamped at the hinge)",
              size=10, y=1 - 0.06 / height)
    return fig.result()


def root_map(scenes, facts, *, renderer="matplotlib"):
    """The closed-loop roots of each scene's linearised loop (``facts``, one per scene:
    :class:`~orchestration.studies.summary.ReportFacts`, its roots by :func:`~orchestration.
    studies.analysis.loop_roots`, the cart's drift roots left aside), upper half-plane: left all of
    them (real axis symmetric-log), right the part near the imaginary axis up to twice the
    first bending frequency; each scene's bending root circled and labelled. Drawn by
    ``renderer``, as :func:`time_histories`."""
    from plant_fmu.params import damping_text

    roots = [(sc, f.roots) for sc, f in zip(scenes, facts, strict=True)]
    width, height = 11.0, 5.2
    fig = canvas(width, height, renderer)
    grid = fig.grid(1, 2, left=0.07, right=0.99, top=1 - 0.95 / height, bottom=0.6 / height,
                    wspace=0.17)
    axes = fig.panels(grid)[0]
    axes[0].xscale("symlog", linthresh=1.0)
    markers = "os^Dv<>"
    wb = [r.bending_frequency for _, r in roots if r.bending_frequency]
    zoom_hi = 2.0 * max(wb) if wb else 2.0 * max([abs(z.imag) for _, r in roots
                                                  for z in r.roots] + [10.0])
    near, labels = [], []
    for k, (sc, r) in enumerate(roots):
        up = r.roots[r.roots.imag >= -1e-9]
        for ax in axes:
            ax.markers(up.real, np.abs(up.imag), marker=markers[k % len(markers)],
                       color=f"C{k}", size=6, hollow=True, mew=1.3, label=f"{sc.name}: "
                       + ("stable" if r.stable else "UNSTABLE")
                       + f", {sc.plant.params.n_modes} modes"
                       + (f", {damping_text(sc.plant.params)}" if sc.plant.params.n_modes
                          else "") if ax is axes[0] else None)
        near += [z for z in up if abs(z.imag) <= zoom_hi]
        if r.bending is not None:
            for ax in axes:
                ax.markers([r.bending.real], [r.bending.imag], marker="o", color=f"C{k}",
                           size=14, hollow=True, mew=1.0, alpha=0.6)
            axes[1].text(0.02, 0.97 - 0.055 * len(labels), f"{sc.name}: bending root "
                         f"{root_text(r.bending)}", coords="axes", size=8, color=f"C{k}",
                         va="top")
            labels.append(sc.name)
    for ax in axes:
        ax.vline(0.0, color="C3", lw=0.8)
        ax.xlabel("real part (1/s)", size=9)
        ax.ylabel("imaginary part (rad/s)", size=9)
        ax.grid()
        ax.tick_labels(8)
    every = np.concatenate([r.roots.real for _, r in roots])
    axes[0].xlim(-1.6 * max(1.0, -every.min()), 1.6 * max(1.0, every.max()))
    axes[0].title("all roots (symmetric log scale of the real part)", size=9)
    re = [z.real for z in near] or [-1.0, 1.0]
    lo, hi = min(re + [-1.0]), max(re + [0.5])
    pad = 0.08 * (hi - lo)
    axes[1].xlim(lo - pad, hi + pad)
    axes[1].ylim(0.0, zoom_hi)
    axes[1].title(f"up to {zoom_hi:.0f} rad/s (large circles: bending roots)", size=9)
    fig.legend(ncol=len(roots), size=8.5, y=1 - 0.42 / height)
    fig.title("Closed-loop roots of the linearised loops, upper half-plane (the cart's drift "
              "roots at 0 left aside; right of the red line: growing)", size=10,
              y=1 - 0.08 / height)
    return fig.result()


def loop_bode(w, loops: dict, title: str, marks=()):
    """Magnitude and phase of loop transfer functions ``{label: L(jw)}`` on ``w`` (rad/s);
    ``marks``: ``(frequency, label)`` drawn as vertical lines, labelled inside the axes. The
    phase is unwrapped; the lines at -180 deg + k 360 deg are where ``L(jw)`` is real and
    negative (a phase crossover)."""
    from matplotlib.ticker import MultipleLocator
    from matplotlib.transforms import blended_transform_factory

    width, height = 8.0, 6.5
    fig = new_figure(width, height)
    am, ap = fig.subplots(2, 1, sharex=True)
    fig.subplots_adjust(left=0.8 / width, right=1 - 0.2 / width, top=1 - 0.4 / height,
                        bottom=0.55 / height, hspace=0.08)
    phases = []
    for label, L in loops.items():
        am.loglog(w, np.abs(L), lw=0.9, label=label)
        ph = np.degrees(np.unwrap(np.angle(L)))
        phases.append(ph)
        ap.semilogx(w, ph, lw=0.9, label=label)
    am.axhline(1.0, color="0.5", lw=0.6)
    lo, hi = min(p.min() for p in phases), max(p.max() for p in phases)
    for k in range(math.floor((lo - 180) / 360), math.ceil((hi - 180) / 360) + 1):
        if lo - 90 <= 180 + 360 * k <= hi + 90:
            ap.axhline(180.0 + 360 * k, color="0.5", lw=0.6)
    ap.yaxis.set_major_locator(MultipleLocator(180 if hi - lo <= 1440 else 360))
    for f, label in marks:
        for ax in (am, ap):
            ax.axvline(f, color="0.4", ls=":", lw=0.8)
        am.text(f, 0.03, f"{label} ", fontsize=7, rotation=90, va="bottom", ha="right",
                transform=blended_transform_factory(am.transData, am.transAxes))
    am.set_ylabel("|L(jw)|")
    ap.set_ylabel("phase of L(jw) (deg)")
    ap.set_xlabel("frequency (rad/s)")
    am.set_title(title, fontsize=10)
    am.legend(fontsize=8, loc="lower left")
    for ax in (am, ap):
        ax.grid(alpha=0.3, which="both")
    return fig


def root_locus(cutoffs, roots, chosen_cutoff: float, title: str,
               zoom=((-12.0, 2.0), (0.0, 500.0))):
    """Closed-loop roots (upper half-plane) as the cutoff varies, coloured by the cutoff; the
    chosen cutoff's roots as stars. Left: all roots; right: the part near the imaginary axis."""
    from matplotlib.colors import LogNorm
    width, height = 10.0, 4.6
    fig = new_figure(width, height)
    axes = fig.subplots(1, 2)
    fig.subplots_adjust(left=0.75 / width, right=1 - 1.05 / width, top=1 - 0.45 / height,
                        bottom=0.55 / height, wspace=0.2)
    cut = np.repeat(np.asarray(cutoffs)[:, None], roots.shape[1], axis=1)
    up = roots.imag >= 0
    i = int(np.argmin(np.abs(np.asarray(cutoffs) - chosen_cutoff)))
    for ax in axes:
        sc = ax.scatter(roots.real[up], roots.imag[up], c=cut[up], s=3, cmap="viridis",
                        norm=LogNorm(vmin=min(cutoffs), vmax=max(cutoffs)))
        r = roots[i][roots[i].imag >= 0]
        ax.plot(r.real, r.imag, "*", color="C3", ms=8, label=f"cutoff {cutoffs[i]:.4g} rad/s")
        ax.axvline(0.0, color="0.3", lw=0.7)
        ax.set_xlabel("real part (1/s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("imaginary part (rad/s)")
    axes[0].set_xscale("symlog", linthresh=10.0)
    axes[1].set_xlim(*zoom[0])
    axes[1].set_ylim(*zoom[1])
    axes[1].legend(fontsize=8, loc="upper left")
    cax = fig.add_axes([1 - 0.85 / width, 0.55 / height, 0.15 / width, 1 - 1.0 / height])
    fig.colorbar(sc, cax=cax, label="cutoff (rad/s)")
    fig.suptitle(title, fontsize=10, y=1 - 0.08 / height, va="top")
    return fig


def worst_case(sweeps: dict, chosen: tuple, ylabel: str, title: str):
    """Worst-case score against cutoff, one line per ``{label: (cutoffs, scores)}``;
    ``chosen = (cutoff, score, label)`` is marked."""
    fig = new_figure(8, 4.6)
    ax = fig.subplots()
    for label, (wc, v) in sweeps.items():
        ax.semilogx(wc, v, "-o", ms=2.5, lw=0.9, label=label)
    ax.axhline(0.0, color="0.3", lw=0.7)
    ax.plot([chosen[0]], [chosen[1]], "*", color="C3", ms=12, label=chosen[2])
    lo = min(min(v) for _, v in sweeps.values())
    ax.set_ylim(max(lo, -3.0 * abs(chosen[1])) * 1.05, abs(chosen[1]) * 1.3)
    ax.set_xlabel("cutoff (rad/s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
