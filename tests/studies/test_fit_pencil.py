"""The matrix pencil's shortcuts against the plain computations they replace: the shift operator
by Sherman-Morrison against ``pinv``, and the scan for the best order, which skips the orders
whose residual cannot win, against the full scan (every order fitted)."""
import math

import numpy as np
import pytest

from orchestration.studies import fit as F

from test_fit_bands import signal


def _windows():
    """Real and complex windows as fit_mode hands them to the pencil: the slow band decimated,
    the bending band differenced, shifted and decimated, noisy or not, long and short, and a
    growing oscillation."""
    t = np.arange(0, 6, 1e-3)
    out = []
    for noise in (0.0, 1e-5, 1e-3):
        y = signal(t, noise)
        out.append(F._decimate(y - y.mean(), 25)[:330])
        x = np.diff(y, 2) * np.exp(-1j * 152.5 * 1e-3 * np.arange(t.size - 2))
        out.append(F._decimate(x, 8)[:100])
        out.append(F._decimate(x, 8)[:40])
    g = np.exp(0.8 * t[:2000]) * np.cos(20 * t[:2000]) + 0.1 * np.cos(3 * t[:2000])
    out.append(F._decimate(g, 10))
    return out


@pytest.mark.parametrize("m", [1, 4, 12])
@pytest.mark.parametrize("dtype", [float, complex])
def test_the_shift_operator_is_pinv_of_the_truncated_basis_times_the_shifted_one(m, dtype):
    rng = np.random.default_rng(m)
    X = rng.standard_normal((40, m)) + (1j * rng.standard_normal((40, m)) if dtype is complex
                                        else 0.0)
    V = np.linalg.qr(X)[0]
    want = np.linalg.pinv(V[:-1]) @ V[1:]
    assert np.allclose(F._shift_operator(V), want, rtol=0, atol=1e-13)


def test_a_basis_whose_last_row_carries_everything_falls_back_to_pinv():
    V = np.zeros((5, 1))
    V[-1, 0] = 1.0                      # V[:-1] is zero: pinv gives zero, no division by 0
    assert np.array_equal(F._shift_operator(V), np.linalg.pinv(V[:-1]) @ V[1:])


@pytest.mark.parametrize("i", range(10))
def test_the_pruned_scan_picks_what_the_full_scan_picks(i):
    """``residual = 1e-300`` scans every order (none is good enough to stop at) and keeps the
    best: the full scan, fitting each order. The default (0) skips orders by the Eckart-Young
    floor; it must return the same order, poles, residual and next order."""
    x = _windows()[i]
    full = F._pencil(x, 12, 1e-300)
    fast = F._pencil(x, 12, 0.0)
    assert fast[2] == full[2]
    assert np.array_equal(fast[0], full[0]) and fast[3] == full[3]
    assert (fast[6] is None) == (full[6] is None)
    if full[6] is not None:
        assert fast[6][2] == full[6][2] and np.array_equal(fast[6][0], full[6][0])


@pytest.mark.parametrize("i", range(10))
def test_the_floor_is_below_every_orders_residual(i):
    """The bound the scan prunes by holds: at every order, the fitted residual's norm is at least
    ``sqrt(sum of the Gram eigenvalues beyond m / min(L + 1, N - L))``, the eigenvalues lowered
    by their rounding."""
    x = _windows()[i]
    N = x.size
    L = max(13, int(F.PENCIL * N))
    Y = np.lib.stride_tricks.sliding_window_view(x, L + 1)
    lam = np.sort(np.linalg.eigvalsh(Y.conj().T @ Y))[::-1]
    step = 1 if np.iscomplexobj(x) else 2
    floors = F._residual_floors(lam, N)
    assert floors[2] > 0                 # it can prune: not a floor of zeros
    for m in range(step, 13, step):
        err = F._pencil(x, 12, 0.0, order=m)[5]
        assert err >= floors[m], (m, err, floors[m])


@pytest.mark.parametrize("scale", [1e-160, 2.0 ** -1000, 1e-300, 1e150])
def test_a_tiny_or_huge_signal_fits_as_the_signal_itself(scale):
    """A fit does not depend on the signal's size: a decayed run's angle of 1e-160 (whose
    squares underflow to zero: the fit divided by zero before) fits as the same signal of size
    1. Powers of two scale exactly; others to rounding."""
    t = np.arange(0, 6, 1e-3)
    y = signal(t)
    for band, near in (((0.5, 60.0), None), ((60.0, math.pi / 1e-3), 152.5)):
        one = F.fit_mode(t, y, band, near=near)
        big = F.fit_mode(t, scale * y, band, near=near)
        assert big is not None
        if math.frexp(scale)[0] == 0.5:
            assert (big.rate, big.frequency, big.rate_uncertainty) == \
                (one.rate, one.frequency, one.rate_uncertainty)
            assert big.amplitude == scale * one.amplitude
        else:
            assert big.rate == pytest.approx(one.rate, rel=1e-6)
            assert big.frequency == pytest.approx(one.frequency, rel=1e-9)
