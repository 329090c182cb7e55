"""Decay/growth rates and frequencies of the oscillations in a sampled signal.

The matrix-pencil method (Hua & Sarkar, IEEE Trans. ASSP 38(5), 1990) fits ``y_k = sum_i a_i
z_i^k`` to uniformly sampled data; each pole ``z_i = exp(s_i dt)`` gives a rate ``Re s_i`` (negative
= decay) and a frequency ``|Im s_i|``. The dominant pole of a frequency band is the one with the
largest contribution to the signal at the end of the window.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["matrix_pencil", "Oscillation", "dominant_oscillation"]


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
