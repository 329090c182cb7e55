"""Decay/growth rates and frequencies of the oscillations in a sampled signal.

The matrix-pencil method (Hua & Sarkar, IEEE Trans. ASSP 38(5), 1990) fits ``y_k = sum_i a_i
z_i^k`` to uniformly sampled data; each pole ``z_i = exp(s_i dt)`` gives a rate ``Re s_i`` (negative
= decay) and a frequency ``|Im s_i|``. The dominant pole of a frequency band is the one with the
largest contribution to the signal at the end of the window.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["matrix_pencil", "Oscillation", "dominant_oscillation", "ModeFit", "fit_mode"]


def matrix_pencil(y, dt: float, order: int, pencil: float = 0.33):
    """Poles ``s_i`` (rad/s, complex) and complex amplitudes of ``y`` (uniform step ``dt``).

    ``order`` is the number of exponentials (a real sinusoid needs two); ``pencil`` sets the
    pencil parameter ``L = pencil * N``.
    """
    y = np.asarray(y, dtype=float)
    N = y.size
    L = max(order + 1, int(pencil * N))
    if N - L < order:
        raise ValueError(f"matrix_pencil: {N} samples are too few for order {order}")
    Y = np.lib.stride_tricks.sliding_window_view(y, L + 1)       # (N - L, L + 1) Hankel
    _, sv, Vh = np.linalg.svd(Y, full_matrices=False)
    order = min(order, int(np.sum(sv > sv[0] * 1e-12)))
    V = Vh[:order].conj().T                                          # (L + 1, order)
    V1, V2 = V[:-1], V[1:]
    z = np.linalg.eigvals(np.linalg.pinv(V1) @ V2)
    z = z[np.abs(z) > 0]
    s = np.log(z) / dt
    # amplitudes by least squares on the Vandermonde matrix
    k = np.arange(N)[:, None]
    Z = np.exp(k * np.log(z)[None, :])
    amp = np.linalg.lstsq(Z, y.astype(complex), rcond=None)[0]
    return s, amp


@dataclass(frozen=True)
class Oscillation:
    rate: float        # 1/s, negative = decaying
    frequency: float   # rad/s
    amplitude: float   # peak contribution over the window


def dominant_oscillation(t, y, band, order: int = 12):
    """The pole with the largest contribution to ``y`` among those with ``|Im s|`` in ``band``
    (rad/s), or ``None`` when the band holds none. ``t`` must be uniformly spaced."""
    t = np.asarray(t, dtype=float)
    dt = float(t[1] - t[0])
    s, amp = matrix_pencil(y, dt, order)
    lo, hi = band
    best = None
    dur = t[-1] - t[0]
    for si, ai in zip(s, amp):
        w = abs(si.imag)
        if not lo <= w < hi or si.imag < 0 and w > 0:
            continue
        # its contribution at the end of the window: what the oscillation settles to (a fast
        # transient that is large at the start does not dominate the response)
        size = abs(ai) * np.exp(si.real * dur) * (2.0 if w > 0 else 1.0)
        if best is None or size > best.amplitude:
            best = Oscillation(float(si.real), float(w), float(size))
    return best


@dataclass(frozen=True)
class ModeFit:
    """The fit of one oscillation: its rate (1/s) and frequency (rad/s), its RMS contribution
    over the window, the model order used, the relative RMS residual of the whole fit and the
    window (s)."""

    rate: float
    frequency: float
    amplitude: float
    order: int
    residual: float
    window: tuple


def fit_mode(t, y, band, *, max_order: int = 12, residual: float = 0.02,
             max_samples: int = 1500, near: float | None = None) -> ModeFit | None:
    """The largest oscillation of ``y`` with frequency in ``band`` (rad/s), or None; with
    ``near``, the largest within 30 % of that frequency.

    A band with a finite upper edge (the slow oscillation) is first rid of faster content by a
    zero-phase low-pass (4th-order Butterworth at the edge, ``sosfiltfilt``), then
    subsampled to about 10 samples per period of that frequency; the window is cut to
    ``max_samples`` samples (its start is kept). The matrix pencil of the lowest order (2, 4, ...
    ``max_order``) that reproduces it to ``residual`` (relative RMS) is kept; if none does, that
    of ``max_order`` (judge the fit by its ``residual``). The largest oscillation is the pole
    with the largest RMS contribution over the window.
    """
    import scipy.signal

    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if y.size < 8:
        return None
    dt = float(t[1] - t[0])
    fs = 2 * np.pi / dt                      # rad/s
    lo, hi = band
    nyq = 0.5 * fs
    y = y - y.mean()
    if math.isfinite(hi) and hi < 0.9 * nyq:
        y = scipy.signal.sosfiltfilt(scipy.signal.butter(4, hi, fs=fs, output="sos"), y)
    if math.isfinite(hi):
        q = max(1, int(fs / (10 * hi)))
        t, y = t[::q], y[::q]
        dt = float(t[1] - t[0])
    t, y = t[:max_samples], y[:max_samples]
    scale = float(np.sqrt(np.mean(y * y)))
    if scale == 0.0 or y.size < 8:
        return None
    N = y.size
    Lp = max(max_order + 1, N // 3)
    Y = np.lib.stride_tricks.sliding_window_view(y, Lp + 1)
    _, sv, Vh = np.linalg.svd(Y, full_matrices=False)
    rank = int(np.sum(sv > sv[0] * 1e-10))
    k = np.arange(N)[:, None]
    for order in range(2, max_order + 1, 2):
        m = min(order, rank)
        V = Vh[:m].conj().T
        z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
        z = z[np.abs(z) > 0]
        # each exponential scaled to a largest magnitude of 1 over the window: a growing pole
        # would otherwise dwarf the others and wreck the least squares
        logz = np.log(z)
        Z = np.exp(k * logz[None, :] - np.maximum(0.0, (N - 1) * logz.real)[None, :])
        amp = np.linalg.lstsq(Z, y.astype(complex), rcond=None)[0]
        res = float(np.sqrt(np.mean(np.abs(Z @ amp - y) ** 2)) / scale)
        if res <= residual or m == rank:
            break
    s = np.log(z) / dt
    contrib = np.abs(amp) * np.sqrt(np.mean(np.abs(Z) ** 2, axis=0))
    pick = None
    for si, ci in zip(s, contrib):
        if not lo <= si.imag < hi or (near is not None and abs(si.imag - near) > 0.3 * near):
            continue
        if pick is None or ci > pick[1]:
            pick = (si, ci)
    if pick is None:
        return None
    return ModeFit(float(pick[0].real), float(pick[0].imag), float(2.0 * pick[1]), m, res,
                   (float(t[0]), float(t[-1])))
