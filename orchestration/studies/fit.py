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

__all__ = ["matrix_pencil", "Oscillation", "dominant_oscillation", "ModeFit", "fit_mode",
           "PERIODS", "SAMPLES_PER_PERIOD", "HANKEL_COLUMNS"]


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
    over the window, the model order used, the relative RMS residual of the whole fit, the
    window (s), and the fit's uncertainty: how far the rate and the frequency move when only the
    first or only the second half of the window is fitted, or the whole at the next order (None
    when a half is too short)."""

    rate: float
    frequency: float
    amplitude: float
    order: int
    residual: float
    window: tuple
    rate_uncertainty: float | None = None
    frequency_uncertainty: float | None = None


#: The window of a fit, in periods of the band's highest frequency.
PERIODS = 80
#: Samples per period of the band's half-width after decimation.
SAMPLES_PER_PERIOD = 4
#: Columns of the Hankel matrix (at most; a third of the samples when fewer).
HANKEL_COLUMNS = 24
#: Fewest samples left after decimation (a short window is decimated less).
MIN_SAMPLES = 48
#: ``near``: the band kept around that frequency, relative.
NEAR = 0.3
#: Boxcar stages of the decimating filter, and differences taken before a band away from 0.
_STAGES, _DIFFERENCES = 3, 2


def _decimate(x, q: int):
    """``x`` through ``_STAGES`` boxcars of ``q`` samples, then every ``q``-th sample (the
    valid part only). A sum of exponentials stays one, with the same poles."""
    for _ in range(_STAGES):
        c = np.cumsum(np.concatenate(([0.0], x)))
        x = (c[q:] - c[:-q]) / q
    return x[::q]


def _pencil(x, max_order: int, residual: float, order: int | None = None):
    """Matrix pencil of ``x`` (real: orders 2, 4, ...; complex: 1, 2, ...): the lowest order
    whose exponentials reproduce ``x`` to a quarter of ``residual`` (else the highest, or
    ``order``); ``(log z, amplitudes, order, relative RMS residual, the exponentials, the same
    five of the next order or None)``."""
    N = x.size
    top = order or max_order
    L = max(top + 1, min(N // 3, HANKEL_COLUMNS))
    if N - L < top:
        raise ValueError(f"{N} samples are too few for order {top}")
    Y = np.lib.stride_tricks.sliding_window_view(x, L + 1)
    _, sv, Vh = np.linalg.svd(Y, full_matrices=False)
    rank = int(np.sum(sv > sv[0] * 1e-10))
    k = np.arange(N)[:, None]
    scale = float(np.sqrt(np.mean(np.abs(x) ** 2)))
    step = 1 if np.iscomplexobj(x) else 2
    fits = []
    for o in ([order] if order else range(step, max_order + 1, step)):
        m = min(o, rank)
        if fits and m == fits[-1][2]:
            break
        V = Vh[:m].T                   # the rows of Vh span the rows of the Hankel matrix
        z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
        logz = np.log(z[np.abs(z) > 0])
        # each exponential scaled to a largest magnitude of 1 over the window: a growing pole
        # would otherwise dwarf the others and wreck the least squares
        Z = np.exp(k * logz[None, :] - np.maximum(0.0, (N - 1) * logz.real)[None, :])
        amp = np.linalg.lstsq(Z, x.astype(complex), rcond=None)[0]
        res = float(np.sqrt(np.mean(np.abs(Z @ amp - x) ** 2)) / scale)
        fits.append((logz, amp, m, res, Z))
        if len(fits) >= 2 and fits[-2][3] <= 0.25 * residual:
            break                      # the one after the first good enough, for its spread
    good = [i for i, f in enumerate(fits) if f[3] <= 0.25 * residual]
    i = good[0] if good else min(range(len(fits)), key=lambda j: fits[j][3])
    return fits[i] + (fits[i + 1] if i + 1 < len(fits) else None,)


def _one_oscillation(x, others, lz):
    """The one exponential ``exp(k lz)`` (with its conjugate when ``x`` is real) that fits
    ``x`` best in least squares beside the columns ``others`` (the fit's other exponentials);
    ``lz`` is the start. Gauss-Newton on (Re lz, Im lz) with the amplitudes projected out."""
    real = not np.iscomplexobj(x)
    k = np.arange(x.size)
    Q = np.linalg.qr(others)[0] if others.shape[1] else None

    def out(v):
        return v if Q is None else v - Q @ (Q.conj().T @ v)

    xp = out(x.astype(complex))

    def r(p):
        e = np.exp(k * complex(p[0], p[1]))
        E = out(np.column_stack([e, e.conj()]) if real else e[:, None])
        G = E.conj().T
        a = np.linalg.solve(G @ E, G @ xp)
        d = E @ a - xp
        return np.concatenate([d.real, d.imag])

    p = np.array([lz.real, lz.imag])
    h = 1e-7 * (1.0 + np.abs(p))
    for _ in range(10):
        r0 = r(p)
        J = np.column_stack([(r(p + h * np.eye(2)[j]) - r0) / h[j] for j in range(2)])
        dp = np.linalg.solve(J.T @ J, -(J.T @ r0))
        p = p + dp
        if np.all(np.abs(dp) <= 1e-10 * (1.0 + np.abs(p))):
            break
    return complex(p[0], p[1])


def _pick(fit, dt, centre, lo, hi, gain, target=None):
    """The oscillation in ``[lo, hi)`` with the largest contribution (or the one nearest the
    frequency ``target``), and that contribution. Poles closer to it than the window resolves
    (2 pi / its length) are one oscillation whose frequency drifts (a slow amplitude makes the
    bending frequency wander): they are replaced by the one oscillation that fits best."""
    logz, amp, _, _, Z = fit[:5]
    s = logz / dt + 1j * centre
    contrib = np.abs(amp / gain(s)) * np.sqrt(np.mean(np.abs(Z) ** 2, axis=0))
    inside = [i for i in range(s.size) if lo <= s[i].imag < hi]
    if not inside:
        return None
    i0 = (max(inside, key=lambda i: contrib[i]) if target is None else
          min(inside, key=lambda i: abs(s[i].imag - target)))
    span = (Z.shape[0] - 1) * dt
    near = [i for i in inside if abs(s[i].imag - s[i0].imag) < 2 * math.pi / span]
    if len(near) == 1:
        return s[i0], float(contrib[i0])
    x = Z @ amp                        # the fitted signal, then without the merged poles
    real = np.allclose(x.imag, 0.0, atol=1e-12 * np.abs(x).max())
    drop = set(near)
    if real:                           # and without their conjugates
        drop |= {j for j in range(s.size) for i in near
                 if abs(logz[j] - np.conj(logz[i])) <= 1e-9 * (1 + abs(logz[i]))}
    keep = [j for j in range(s.size) if j not in drop]
    lz = _one_oscillation(x.real if real else x, Z[:, keep], logz[i0])
    return lz / dt + 1j * centre, float(np.sum(contrib[near]))


def fit_mode(t, y, band, *, max_order: int = 12, residual: float = 0.02,
             near: float | None = None, periods: float = PERIODS) -> ModeFit | None:
    """The largest oscillation of ``y`` with frequency in ``band`` (rad/s), or None; with
    ``near``, the largest within 30 % of that frequency.

    The fit sees only the band, decimated to it, over a window of ``periods`` periods of the
    band's highest frequency (its start is kept):

    * a band from near 0 (the slow oscillation): ``y`` low-passed and decimated to
      ``SAMPLES_PER_PERIOD`` samples per period of the band's top;
    * a band around ``near`` (the bending oscillation): ``y`` differenced twice (the slow
      motion it rides on falls by ``(w dt)^2``), shifted down by the band's centre (times
      ``exp(-i w_c t)``) and decimated to ``SAMPLES_PER_PERIOD`` samples per period of the
      band's half-width, a complex signal.

    The decimating filter is three boxcars of the decimation's length: a sum of exponentials
    stays a sum of exponentials with the same poles (no transient is added, none is cut), so the
    fitted rates and frequencies are those of ``y``. The matrix pencil (Hankel matrix of at most
    ``HANKEL_COLUMNS`` columns) of the lowest order (up to ``max_order``) that reproduces the
    decimated signal to a quarter of ``residual`` (relative RMS) is kept (``residual`` reports how
    well; judge the fit by it). The largest oscillation is the pole in the band with the largest
    RMS contribution to ``y`` over the window; poles closer to it than the window resolves are
    merged into the one oscillation that fits them best. The uncertainty is how far the rate and
    frequency move when each half of the window is fitted alone, at the same order, or the
    whole window at the next order.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if y.size < 8:
        return None
    dt = float(t[1] - t[0])
    fs = 2 * math.pi / dt                    # rad/s
    lo, hi = band
    if near is not None:
        lo, hi = max(lo, (1 - NEAR) * near), min(hi, (1 + NEAR) * near)
    hi = min(hi, 0.5 * fs)
    if not lo < hi:
        return None
    n = min(y.size, int(periods * 2 * math.pi / (hi * dt)) + 1)
    t, y = t[:n], y[:n] - y[:n].mean()
    if near is not None:
        centre, half = 0.5 * (lo + hi), 0.65 * (hi - lo)
        x = np.diff(y, _DIFFERENCES) * np.exp(-1j * centre * dt * np.arange(n - _DIFFERENCES))
    else:
        centre, half, x = 0.0, hi, y
    q = max(1, min(int(fs / (SAMPLES_PER_PERIOD * half)), x.size // (MIN_SAMPLES + _STAGES)))
    if q > 1:
        x = _decimate(x, q)
    if x.size < 8 or not np.any(x):
        return None

    def gain(s):
        """What the differences and the boxcars multiply the pole ``s``'s amplitude by."""
        g = np.ones(s.size, dtype=complex)
        if near is not None:
            g *= (np.exp(s * dt) - 1) ** _DIFFERENCES
        if q > 1:
            zb = np.exp((s - 1j * centre) * dt)
            g *= ((1 - zb ** -q) / (q * (1 - zb ** -1))) ** _STAGES
        return g

    whole = _pencil(x, max_order, residual)
    pick = _pick(whole, q * dt, centre, lo, hi, gain)
    if pick is None:
        return None
    s, size = pick
    others = [] if whole[5] is None else [_pick(whole[5], q * dt, centre, lo, hi, gain,
                                               target=s.imag)]
    halves = []
    for part in (x[:x.size // 2], x[x.size // 2:]):
        try:
            h = _pick(_pencil(part, max_order, residual, order=whole[2]), q * dt, centre, lo, hi,
                      gain, target=s.imag)
        except (ValueError, np.linalg.LinAlgError):
            h = None
        if h is None:
            break
        halves.append(h[0])
    du = df = None
    if len(halves) == 2:
        moved = halves + [o[0] for o in others if o is not None]
        du = max(abs(h.real - s.real) for h in moved)
        df = max(abs(h.imag - s.imag) for h in moved)
    return ModeFit(float(s.real), float(s.imag), float(2.0 * size), whole[2], whole[3],
                   (float(t[0]), float(t[-1])), du, df)
