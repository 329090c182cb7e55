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
           "PERIODS", "SAMPLES_PER_PERIOD", "PENCIL"]


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
    window (s), and the fit's uncertainty: the largest of how far the rate and the frequency move
    when only the first or only the second half of the window is fitted, or the whole at the
    next order, how far the fit's residual can move them, and how far a drifting frequency
    strays over the window (None when a half is too short)."""

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
#: The pencil parameter: the Hankel matrix has ``PENCIL * N`` columns for ``N`` samples.
PENCIL = 1 / 3
#: Singular values below this fraction of the largest are not counted in the Hankel matrix's
#: rank (what the Gram matrix resolves: its eigenvalues carry errors of 1e-16 of the largest).
RANK_TOL = 3e-7
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
    whose exponentials reproduce ``x`` to a quarter of ``residual`` (else the one that
    reproduces it best, or ``order``); ``(log z, amplitudes, order, relative RMS residual, the
    exponentials, the residual's norm, the same six of the next order or None)``.

    Looking for the best order (``residual = 0``), an order whose residual cannot beat the best
    one found is not fitted: the Hankel matrix of ``m`` exponentials has rank ``m``, so by
    Eckart-Young its distance from ``x``'s Hankel matrix is at least the norm of ``x``'s
    singular values beyond the ``m``-th, and each sample stands in at most
    ``min(L + 1, N - L)`` of its entries: the residual's norm at order ``m`` is at least
    ``sqrt(sum_{i > m} sigma_i^2 / min(L + 1, N - L))``. The orders are tried from the highest
    (usually the best) down; the result is the one the full scan gives."""
    N = x.size
    top = order or max_order
    L = max(top + 1, int(PENCIL * N))
    if N - L < top:
        raise ValueError(f"{N} samples are too few for order {top}")
    # the fit of x scaled by a power of two to a largest magnitude in [0.5, 1): exact, and the
    # squares of a tiny signal (a decayed one, 1e-160) do not underflow to zero
    peak = float(np.max(np.abs(x)))
    shift = math.frexp(peak)[1] if 0 < peak < math.inf else 0
    if shift:
        x = _ldexp(x, -shift)
    out = _pencil_scaled(x, max_order, residual, order, N, L)
    if shift:
        out = _unscaled(out[:6], shift) + (None if out[6] is None else
                                           _unscaled(out[6][:6], shift),)
    return out


def _ldexp(x, e: int):
    """``x * 2**e``, real or complex, exactly (no power of two is formed: it could overflow)."""
    if not np.iscomplexobj(x):
        return np.ldexp(x, e)
    out = np.empty_like(x)
    out.real, out.imag = np.ldexp(x.real, e), np.ldexp(x.imag, e)
    return out


def _unscaled(fit, shift: int):
    """A fit of ``x / 2**shift`` as the fit of ``x``: its amplitudes and residual times
    ``2**shift`` (the poles, the order and the relative residual are those of ``x``)."""
    logz, amp, m, rel, Z, err = fit
    return logz, _ldexp(amp, shift), m, rel, Z, math.ldexp(err, shift)


def _pencil_scaled(x, max_order, residual, order, N, L):
    """:func:`_pencil` on ``x`` whose largest magnitude is about 1."""
    top = order or max_order
    Y = np.lib.stride_tricks.sliding_window_view(x, L + 1)
    # the row space of the Hankel matrix from its Gram matrix (a tenth of the cost of the SVD;
    # exact for the few largest singular values, which are all a fit of at most max_order uses)
    lam, E = np.linalg.eigh(Y.conj().T @ Y)
    lam, E = lam[::-1], E[:, ::-1].conj()
    rank = int(np.sum(lam > lam[0] * RANK_TOL ** 2))
    k = np.arange(N)[:, None]
    scale = float(np.sqrt(np.mean(np.abs(x) ** 2)))
    xc = x.astype(complex)

    def fit(m):
        V = E[:, :m]                   # spans the rows of the Hankel matrix
        z = np.linalg.eigvals(_shift_operator(V))
        logz = np.log(z[np.abs(z) > 0])
        # each exponential scaled to a largest magnitude of 1 over the window: a growing pole
        # would otherwise dwarf the others and wreck the least squares
        Z = np.exp(k * logz[None, :] - np.maximum(0.0, (N - 1) * logz.real)[None, :])
        amp = np.linalg.lstsq(Z, xc, rcond=None)[0]
        err = float(np.linalg.norm(Z @ amp - x))
        return logz, amp, m, err / (scale * math.sqrt(N)), Z, err

    step = 1 if np.iscomplexobj(x) else 2
    ms = []                            # the orders of the scan, each model size once
    for o in ([order] if order else range(step, max_order + 1, step)):
        m = min(o, rank)
        if ms and m == ms[-1]:
            break
        ms.append(m)
    fits = {}
    if residual <= 0 and len(ms) > 1:
        # the best order, without fitting those that cannot be it (see above)
        floors = _residual_floors(lam, N)
        fits[ms[-1]] = fit(ms[-1])
        best = fits[ms[-1]][5]
        for m in reversed(ms[:-1]):
            if floors[m] > best:
                continue
            fits[m] = fit(m)
            best = min(best, fits[m][5])
        if best > 0:
            i = min((j for j, m in enumerate(ms) if m in fits), key=lambda j: fits[ms[j]][3])
            if i + 1 < len(ms) and ms[i + 1] not in fits:
                fits[ms[i + 1]] = fit(ms[i + 1])
            return fits[ms[i]] + (fits[ms[i + 1]] if i + 1 < len(ms) else None,)
    seq = []                           # the scan in order, stopping as ``residual`` says
    for m in ms:
        seq.append(fits[m] if m in fits else fit(m))
        if len(seq) >= 2 and seq[-2][3] <= 0.25 * residual:
            break                      # the one after the first good enough, for its spread
    good = [i for i, f in enumerate(seq) if f[3] <= 0.25 * residual]
    i = good[0] if good else min(range(len(seq)), key=lambda j: seq[j][3])
    return seq[i] + (seq[i + 1] if i + 1 < len(seq) else None,)


def _residual_floors(lam, N: int):
    """``floors[m]``: a lower bound of the residual's norm of any ``m`` exponentials fitted to
    the ``N`` samples whose Hankel matrix (``L + 1`` columns) has the Gram eigenvalues ``lam``
    (largest first): ``sqrt(sum_{i >= m} lam_i / min(L + 1, N - L))`` (see :func:`_pencil`),
    each eigenvalue first lowered by what rounding can have added to it (Weyl: at most the
    norm of the Gram product's error, ``(L + 1) (N - L) eps lam_0``)."""
    L = lam.size - 1
    slack = (L + 1) * (N - L) * np.finfo(float).eps * max(float(lam[0]), 0.0)
    tails = np.cumsum(np.maximum(lam[::-1] - slack, 0.0))[::-1]       # tails[m] = sum lam[m:]
    return np.sqrt(np.append(tails, 0.0) / min(L + 1, N - L))


def _shift_operator(V):
    """``pinv(V[:-1]) @ V[1:]`` for ``V`` with orthonormal columns: ``V[:-1]^H V[:-1] = I - r^H r``
    (``r`` the last row), whose inverse is ``I + r^H r / (1 - |r|^2)`` (Sherman-Morrison), so
    ``pinv(V[:-1]) = (I + r^H r / (1 - |r|^2)) V[:-1]^H``: the same matrix to round-off at a
    tenth of the cost of the SVD behind ``pinv``; ``pinv`` itself where ``V[:-1]`` is nearly
    rank-deficient."""
    r = V[-1:]
    c = 1.0 - float(np.vdot(r, r).real)
    if c < 1e-6:
        return np.linalg.pinv(V[:-1]) @ V[1:]
    A = V[:-1].conj().T @ V[1:]
    return A + r.conj().T @ (r @ A) / c


def _pick(fit, dt, centre, lo, hi, gain, target=None, spread=True):
    """The oscillation in ``[lo, hi)`` with the largest contribution (or the one nearest the
    frequency ``target``), that contribution, and its spread (complex: rate, frequency; with
    ``spread=False`` only the drift's part of it, for a fit whose pole alone is wanted).

    A mode whose frequency moves with an amplitude, ``w0 + c A(t)^2`` with ``A ~ exp(d t / 2)``
    (a pendulum's own amplitude; the slow motion's, for the bending frequency), is a chain of
    poles ``s0 + k d``, ``k = 0, 1, ...``, at nearly one frequency, with amplitudes like
    ``p^k / k!`` for a phase excursion ``p`` over the window. When the picked pole carries more
    than twice the rest of its chain (the poles closer to it in frequency than the window
    resolves, 2 pi / its length; ``p`` below about 0.4 rad), it is the ``k = 0`` term, the
    small-amplitude (linearised) pole, and is kept alone: merging its neighbours would report
    the amplitude-weighted mean frequency, biased to the large-amplitude start. Otherwise no
    pole is that term: the chain is one oscillation whose frequency drifts, reported by the
    slopes of its log-magnitude and phase over the window, its spread the farthest the
    instantaneous values stray from them. The spread is at least what the fit's residual can
    move the pole by (to first order, the residual all along the pole's derivative)."""
    logz, amp, _, _, Z, err = fit[:6]
    s = logz / dt + 1j * centre
    contrib = np.abs(amp / gain(s)) * np.sqrt(np.mean(np.abs(Z) ** 2, axis=0))
    inside = [i for i in range(s.size) if lo <= s[i].imag < hi]
    if not inside:
        return None
    i0 = (max(inside, key=lambda i: contrib[i]) if target is None else
          min(inside, key=lambda i: abs(s[i].imag - target)))
    span = (Z.shape[0] - 1) * dt
    near = [i for i in inside if abs(s[i].imag - s[i0].imag) < 2 * math.pi / span]
    # what the residual can move the pole by, at most (to first order): the residual all along
    # the pole's derivative, ``k a z^k``, once what the fit's exponentials absorb is removed
    bound = 0.0
    if spread:
        dz = amp[i0] * np.arange(Z.shape[0]) * Z[:, i0]
        Q = np.linalg.qr(Z)[0]
        bound = err / max(np.linalg.norm(dz - Q @ (Q.conj().T @ dz)), 1e-300) / dt
    if len(near) == 1 or sum(contrib[i] for i in near if i != i0) < 0.5 * contrib[i0]:
        return s[i0], float(contrib[i0]), complex(bound, bound)
    # the drifting oscillation: the poles' sum (one-sided, the analytic signal of the cluster);
    # its rate and frequency are the slopes of its log-magnitude and of its phase over the
    # window (a least-squares single exponential would take the drift for extra decay)
    xc = Z[:, near] @ amp[near]
    k = np.arange(xc.size)
    logmag, phase = np.log(np.abs(xc)), np.unwrap(np.angle(xc))
    (r, _), (w, _) = np.polyfit(k, logmag, 1), np.polyfit(k, phase, 1)
    # how far the instantaneous rate and frequency stray from those over the window
    drift = complex(np.abs(np.gradient(logmag) - r).max(), np.abs(np.gradient(phase) - w).max())
    return (complex(r, w) / dt + 1j * centre, float(np.sum(contrib[near])),
            complex(max(drift.real / dt, bound), max(drift.imag / dt, bound)))


def fit_mode(t, y, band, *, max_order: int = 12, residual: float = 0.0,
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
    fitted rates and frequencies are those of ``y``. The window holds about ``PERIODS *
    SAMPLES_PER_PERIOD`` samples whatever the output interval (up to twice as many where the
    decimation rounds down: 320 to 420 for the slow band, about 100 for the bending band), so
    the Hankel matrix stays small while its ``PENCIL * N`` columns sit where Hua & Sarkar's
    pencil parameter gives the least variance (``N/3`` to ``N/2``; the slow fit moves within its
    uncertainty across that range; the bending fit's rate in a few runs by more, to a worse fit
    with a larger uncertainty: ``bench/fit_pencil.py``). The matrix pencil of the lowest order that
    reproduces the decimated signal to a quarter of ``residual`` (relative RMS) is kept; by
    default (0) the best of them, the highest order the Hankel matrix's rank allows: the nonlinear corrections and harmonics a mode
    carries need poles of their own, or they bias its pole (on the paper's rigid scene, order 6
    puts the slow rate 1 % off the linearised loop's, order 12 within 0.01 %). The fit's
    ``residual`` reports how well it reproduces the band; judge the fit by it. The largest oscillation is the pole in the band with the largest RMS
    contribution to ``y`` over the window, or the drifting oscillation its close neighbours
    make with it (see :func:`_pick`). The uncertainty is the largest of: its spread (the
    drift, and what the residual can move it by), and how far the rate and frequency move
    when each half of the window is fitted alone, at the same order, or the
    whole window at the next order.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if y.size < 8:
        return None
    # y scaled by a power of two to a largest magnitude about 1 (exact): the differences and
    # the filter of a decayed signal (1e-300) would otherwise lose digits to underflow
    peak = float(np.max(np.abs(y)))
    shift = math.frexp(peak)[1] if 0 < peak < math.inf else 0
    y = np.ldexp(y, -shift)
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
    s, size, spread = pick
    others = [] if whole[6] is None else [_pick(whole[6], q * dt, centre, lo, hi, gain,
                                               target=s.imag, spread=False)]
    halves = []
    for part in (x[:x.size // 2], x[x.size // 2:]):
        try:
            h = _pick(_pencil(part, max_order, residual, order=whole[2]), q * dt, centre, lo, hi,
                      gain, target=s.imag, spread=False)
        except (ValueError, np.linalg.LinAlgError):
            h = None
        if h is None:
            break
        halves.append(h[0])
    du = df = None
    if len(halves) == 2:
        moved = halves + [o[0] for o in others if o is not None]
        du = max([abs(h.real - s.real) for h in moved] + [spread.real])
        df = max([abs(h.imag - s.imag) for h in moved] + [spread.imag])
    return ModeFit(float(s.real), float(s.imag), math.ldexp(2.0 * size, shift), whole[2], whole[3],
                   (float(t[0]), float(t[-1])), du, df)
