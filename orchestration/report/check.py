"""The figure of ``flexpend check --plot``: a check's report
(:class:`~orchestration.export.check.CheckReport`), each signal over its band."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .mpl_canvas import new_figure
from .files import save_figure

__all__ = ["plot_check", "check_figure"]


def plot_check(report, path) -> Path:
    """Write :func:`check_figure` of ``report`` to ``path`` (PNG, or the format of its
    suffix)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(check_figure(report), path)
    return path


def check_figure(report):
    """Each signal over its band: the reference, the band, the result, the samples outside, of
    a check's report (:class:`~orchestration.export.check.CheckReport`), a matplotlib Figure.
    Every axis is labelled with its unit (the signal's in the FMU's model description, "1"
    when it has none)."""

    signals = list(report.signals.values())
    n = max(1, len(signals))
    fig = new_figure(9, 1.9 * n + 0.8)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)
    res = report.run.result
    ref = report.reference
    t_ref = ref[ref.dtype.names[0]]
    for ax, s in zip(axes[:, 0], signals):
        if s.band:
            ax.fill_between(s.band[0], s.band[1], s.band[2], color="tab:green", alpha=0.25,
                            lw=0, label="band")
        ax.plot(t_ref, ref[s.name], color="black", lw=0.8, label="reference")
        if res is not None and s.name in (res.dtype.names or ()):
            t = res[res.dtype.names[0]]
            ax.plot(t, res[s.name], color="tab:blue", lw=0.8, ls="--", label="result")
            if s.band and s.outliers:
                lo = np.interp(t, s.band[0], s.band[1])
                hi = np.interp(t, s.band[0], s.band[2])
                bad = ~((res[s.name] >= lo) & (res[s.name] <= hi))
                ax.plot(t[bad], res[s.name][bad], ".", color="tab:red", ms=3, label="outside")
        ax.set_ylabel(f"{s.name} ({report.units.get(s.name, '1')})")
        ax.set_title(f"{s.name}: {'pass' if s.passed else 'FAIL'} ({s.outliers}/{s.samples} "
                     f"outside)", fontsize=8, loc="left")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time (s)")
    verdict = "PASSED" if report.passed else "FAILED"
    extra = f"; {report.failure}" if report.failure else ""
    fig.suptitle(f"{report.fmu.name}: {verdict} ({report.rule.describe()}){extra}"[:160],
                 fontsize=9)
    fig.tight_layout()
    return fig
