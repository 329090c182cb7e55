"""Figures of a run: time histories (the paper's Figs. 3, 4, 6, 7) and beam snapshots (Figs. 5, 8)."""
from __future__ import annotations

import numpy as np

__all__ = ["time_histories", "snapshots", "beam_shape", "paper_overview", "loop_bode",
           "root_locus", "worst_case", "new_figure"]


def new_figure(width: float, height: float):
    """A matplotlib Figure of its own (no pyplot: the process's backend and pyplot's figures are
    left alone); :func:`orchestration.report.files.save_figure` writes it."""
    from matplotlib.figure import Figure
    return Figure(figsize=(width, height))


def _wrapped(text: str, width: int = 95) -> str:
    import textwrap
    return "\n".join(textwrap.wrap(text, width)) if text else ""


#: Time-history panels: column -> axis label (SI units; eta_j belong to mass-normalised modes).
PANELS = {
    "phi_o": "tip angle $\\varphi_o$ (rad)",
    "eta_1": "1st modal coordinate $\\eta_1$ (m kg$^{1/2}$)",
    "tip_deflection": "tip deflection (m)",
    "F_c": "force $F_c$ (N)",
    "x": "cart position $x$ (m)",
}


def time_histories(result, scene, reference=None, summary=None):
    """The paper's time histories (Figs. 3, 4, 6, 7): tip angle, first modal coordinate, tip
    deflection, force and cart position against time. The bending panels are left out for a
    rigid model. With a ``summary`` the fit windows are shaded, the validity bound of the tip
    deflection drawn and an early stop marked."""
    t = result["time"]
    cols = [c for c in PANELS if not (c in ("eta_1", "tip_deflection") and not np.any(result[c]))]
    height = 1.9 * len(cols) + 1.2
    fig = new_figure(9, height)
    axes = fig.subplots(len(cols), 1, sharex=True)
    # fixed margins (a layout engine costs a second per figure): 0.95 in at the top for the
    # two-line title, room for the labels on the left and below
    fig.subplots_adjust(left=0.1, right=0.98, top=1 - 0.95 / height, bottom=0.55 / height,
                        hspace=0.12)
    axes = np.atleast_1d(axes)
    for ax, col in zip(axes, cols):
        ax.plot(t, result[col], lw=0.7, color="C0", label="co-simulation")
        if reference is not None and col in reference.dtype.names:
            ax.plot(reference["time"], reference[col], "--", lw=0.7, color="C1",
                    label="monolithic reference")
        ax.set_ylabel(PANELS[col], fontsize=9)
        ax.grid(alpha=0.3)
    if summary is not None:
        for key, col in (("slow", "phi_o"), ("bending", "eta_1")):
            m = summary.get(key)
            if m and m.get("fit") and col in cols:
                ax = axes[cols.index(col)]
                lo, hi = m["fit"]["window"]
                ax.axvspan(lo, hi, color="C2", alpha=0.12, lw=0,
                           label=f"fit window ({key})" + ("" if m["reliable"] else ", unreliable"))
                ax.legend(loc="upper right", fontsize=7)
        v = summary.get("validity")
        if v and "tip_deflection" in cols:
            ax = axes[cols.index("tip_deflection")]
            for sign in (1, -1):
                ax.axhline(sign * v["tip_deflection_limit"], color="C3", ls=":", lw=0.8)
            ax.text(t[0], v["tip_deflection_limit"], " model's range", color="C3", fontsize=7,
                    va="bottom")
        if summary.get("stopped"):
            for ax in axes:
                ax.axvline(summary["stopped"]["time"], color="C3", lw=0.8)
            axes[0].text(summary["stopped"]["time"], axes[0].get_ylim()[1], " stopped",
                         color="C3", fontsize=8, va="top")
    if reference is not None:
        axes[0].legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{scene.name}\n{_wrapped(scene.description or scene.name)}", fontsize=9)
    return fig


def beam_shape(beam, x, phi, eta, scale: float = 1.0):
    """Global coordinates of the beam's nodes: ``r(s) = (x, 0) + s b1 + w(s) b2``."""
    s = beam.nodes
    n = min(len(eta), beam.shapes.shape[1])
    w = beam.shapes[:, :n] @ np.asarray(eta[:n]) * scale if n else np.zeros_like(s)
    b1 = np.array([-np.sin(phi), np.cos(phi)])
    b2 = np.array([-np.cos(phi), -np.sin(phi)])
    return x + s * b1[0] + w * b2[0], s * b1[1] + w * b2[1]


def snapshots(beam, frames, scene):
    """Beam shapes at several times (the paper's Figs. 5 and 8), two rows of panels; each
    panel's horizontal axis is the rail in metres, centred on the cart, which is drawn at its
    position. ``frames``: list of ``(t, x, phi, eta)``. A deflection that would not show (below
    2 % of L everywhere) is magnified, and the title says by how much."""
    import math

    from matplotlib.patches import Rectangle

    n = len(frames)
    L = beam.nodes[-1]
    defl = max((float(np.max(np.abs(beam_shape(beam, 0.0, 0.0, eta)[0]))) for *_, eta in frames),
               default=0.0)
    scale = 1.0
    if 0 < defl < 0.02 * L:
        scale = 10 ** math.floor(math.log10(0.1 * L / defl))
    ncol = min(n, 4)
    nrow = math.ceil(n / ncol)
    width, height = 2.45 * ncol + 0.4, 2.05 * nrow + 0.5
    fig = new_figure(width, height)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    fig.subplots_adjust(left=0.55 / width, right=1 - 0.1 / width, top=1 - 0.45 / height,
                        bottom=0.45 / height, wspace=0.3, hspace=0.35)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax, (t, x, phi, eta) in zip(axes.flat, frames):
        X, Y = beam_shape(beam, x, phi, eta, scale)
        rigid = beam_shape(beam, x, phi, [])                 # the floating frame's axis
        ax.axhline(0.0, color="0.3", lw=0.8)                 # the rail
        ax.add_patch(Rectangle((x - 0.15 * L, -0.1 * L), 0.3 * L, 0.1 * L, color="C1"))
        ax.plot(rigid[0], rigid[1], ":", color="0.5", lw=1)
        ax.plot(X, Y, color="C0", lw=2)
        ax.plot([x], [0.0], "o", color="k", ms=3)            # the hinge
        ax.set_xlim(x - 1.05 * L, x + 1.05 * L)
        ax.set_ylim(-0.15 * L, 1.1 * L)
        ax.set_aspect("equal")
        ax.set_title(f"t = {t:.2f} s, x = {x:+.3f} m", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[:, 0]:
        ax.set_ylabel("height (m)", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("rail position (m)", fontsize=8)
    magnified = f"deflection x {scale:g}" if scale != 1 else "deflection to scale"
    fig.suptitle(f"{scene.name}: beam shapes (dotted: floating frame; {magnified}; cart and "
                 "rail to scale)",
                 fontsize=9)
    return fig


def paper_overview(runs):
    """The paper's sample side by side, one row per run (a :class:`~orchestration.job.Run`): tip
    angle (Figs. 3, 4, 6) and first modal coordinate (Fig. 7), so that no curve hides another."""
    results = {r.name: r.result for r in runs}
    n = len(results)
    height = 2.3 * n + 0.8
    fig = new_figure(11, height)
    axes = fig.subplots(n, 2, sharex=True, squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.99, top=1 - 0.45 / height, bottom=0.5 / height,
                        wspace=0.18, hspace=0.3)
    for row, (name, res) in zip(axes, results.items()):
        row[0].plot(res["time"], res["phi_o"], lw=0.7, color="C0")
        row[0].set_ylabel("$\\varphi_o$ (rad)", fontsize=9)
        row[0].set_title(name, fontsize=9, loc="left")
        if np.any(res["eta_1"]):
            row[1].plot(res["time"], res["eta_1"], lw=0.7, color="C2")
        else:
            row[1].text(0.5, 0.5, "rigid model: no bending", transform=row[1].transAxes,
                        ha="center", va="center", fontsize=9, color="0.4")
            row[1].set_yticks([])
        row[1].set_ylabel("$\\eta_1$ (m kg$^{1/2}$)", fontsize=9)
        row[1].set_title(name, fontsize=9, loc="left")
        for ax in row:
            ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Tang & Ren's sample from phi0 = pi/6: rigid + PD, flexible + PD, flexible + PD "
                 "+ low-pass", fontsize=10)
    return fig


def loop_bode(w, loops: dict, title: str, marks=()):
    """Magnitude and phase of loop transfer functions ``{label: L(jw)}`` on ``w`` (rad/s);
    ``marks``: ``(frequency, label)`` drawn as vertical lines."""
    fig = new_figure(8, 6.5)
    am, ap = fig.subplots(2, 1, sharex=True)
    for label, L in loops.items():
        am.loglog(w, np.abs(L), lw=0.9, label=label)
        ap.semilogx(w, np.degrees(np.unwrap(np.angle(L))), lw=0.9, label=label)
    am.axhline(1.0, color="0.5", lw=0.6)
    for ph in (-180.0, 180.0):
        ap.axhline(ph, color="0.5", lw=0.6)
    for f, label in marks:
        for ax in (am, ap):
            ax.axvline(f, color="0.4", ls=":", lw=0.8)
        am.annotate(label, (f, am.get_ylim()[1]), fontsize=7, rotation=90, va="top", ha="right")
    am.set_ylabel("|L(jw)|")
    ap.set_ylabel("phase of L(jw) (deg)")
    ap.set_xlabel("frequency (rad/s)")
    am.set_title(title, fontsize=10)
    am.legend(fontsize=8)
    for ax in (am, ap):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def root_locus(cutoffs, roots, chosen_cutoff: float, title: str,
               zoom=((-12.0, 2.0), (0.0, 500.0))):
    """Closed-loop roots (upper half-plane) as the cutoff varies, coloured by the cutoff; the
    chosen cutoff's roots as stars. Left: all roots; right: the part near the imaginary axis."""
    from matplotlib.colors import LogNorm
    fig = new_figure(10, 4.6)
    axes = fig.subplots(1, 2)
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
    fig.colorbar(sc, ax=axes, label="cutoff (rad/s)")
    fig.suptitle(title, fontsize=10)
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
