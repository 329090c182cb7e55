"""Figures of a run: time histories (the paper's Figs. 3, 4, 6, 7) and beam snapshots (Figs. 5, 8)."""
from __future__ import annotations

import numpy as np

__all__ = ["plot_time_histories", "plot_snapshots", "beam_shape", "plot_paper_overview",
           "plot_loop_bode", "plot_root_locus", "plot_worst_case"]


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_time_histories(result, title: str, path, reference=None):
    """Tip angle, first modal coordinate and force against time."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    t = result["time"]
    for ax, col, label in zip(axes, ("phi_o", "eta_1", "F_c"),
                              ("tip angle phi_o (rad)", "first modal coordinate eta_1",
                               "force F_c")):
        ax.plot(t, result[col], lw=0.8, label="co-simulation")
        if reference is not None:
            ax.plot(reference["time"], reference[col], "--", lw=0.8, label="monolithic reference")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_title(title, fontsize=10)
    axes[-1].set_xlabel("time (s)")
    if reference is not None:
        axes[0].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def beam_shape(beam, x, phi, eta, scale: float = 1.0):
    """Global coordinates of the beam's nodes: ``r(s) = (x, 0) + s b1 + w(s) b2``."""
    s = beam.nodes
    n = min(len(eta), beam.shapes.shape[1])
    w = beam.shapes[:, :n] @ np.asarray(eta[:n]) * scale if n else np.zeros_like(s)
    b1 = np.array([-np.sin(phi), np.cos(phi)])
    b2 = np.array([-np.cos(phi), -np.sin(phi)])
    return x + s * b1[0] + w * b2[0], s * b1[1] + w * b2[1]


def plot_snapshots(beam, frames, title: str, path):
    """Beam shapes at several times, one panel per time centred on the cart (the cart drifts
    when its position is not fed back); ``frames``: list of ``(t, x, phi, eta)``."""
    plt = _pyplot()
    n = len(frames)
    fig, axes = plt.subplots(1, n, figsize=(1.6 * n + 0.6, 3.2), sharey=True, squeeze=False)
    L = beam.nodes[-1]
    for ax, (t, x, phi, eta) in zip(axes[0], frames):
        X, Y = beam_shape(beam, 0.0, phi, eta)              # relative to the cart
        rigid = beam_shape(beam, 0.0, phi, [])               # the floating frame's axis
        ax.plot(rigid[0], rigid[1], ":", color="0.6", lw=1)
        ax.plot(X, Y, color="C0", lw=2)
        ax.plot([-0.15 * L, 0.15 * L], [0, 0], color="C1", lw=5, solid_capstyle="butt")
        ax.set_xlim(-0.9 * L, 0.9 * L)
        ax.set_ylim(-0.15 * L, 1.1 * L)
        ax.set_aspect("equal")
        ax.set_title(f"t = {t:.2f} s\nx = {x:+.2f}", fontsize=8)
        ax.set_xticks([])
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("height")
    fig.suptitle(title + " (dotted: floating frame; deflection to scale)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_paper_overview(results: dict, path):
    """The paper's sample side by side: tip angle (Figs. 3, 4, 6) and eta_1 (Fig. 7)."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    for name, res in results.items():
        axes[0].plot(res["time"], res["phi_o"], lw=0.8, label=name)
        axes[1].plot(res["time"], res["eta_1"], lw=0.8, label=name)
    axes[0].set_ylabel("tip angle phi_o (rad)")
    axes[1].set_ylabel("first modal coordinate eta_1")
    axes[1].set_xlabel("time (s)")
    axes[0].set_ylim(-1.2, 1.2)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_title("Tang & Ren's sample from phi0 = pi/6: rigid + PD, flexible + PD, "
                      "flexible + PD + low-pass", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_loop_bode(w, loops: dict, title: str, path, marks=()):
    """Magnitude and phase of loop transfer functions ``{label: L(jw)}`` on ``w`` (rad/s);
    ``marks``: ``(frequency, label)`` drawn as vertical lines."""
    plt = _pyplot()
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
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
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_root_locus(cutoffs, roots, chosen_cutoff: float, title: str, path,
                    zoom=((-12.0, 2.0), (0.0, 500.0))):
    """Closed-loop roots (upper half-plane) as the cutoff varies, coloured by the cutoff; the
    chosen cutoff's roots as stars. Left: all roots; right: the part near the imaginary axis."""
    from matplotlib.colors import LogNorm
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
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
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_worst_case(sweeps: dict, chosen: tuple, ylabel: str, title: str, path):
    """Worst-case score against cutoff, one line per ``{label: (cutoffs, scores)}``;
    ``chosen = (cutoff, score, label)`` is marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.6))
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
    fig.savefig(path, dpi=90)
    plt.close(fig)
