"""Matrix-pencil fit against signals with known poles."""
import numpy as np
import pytest

from orchestration.studies.fit import dominant_oscillation

T = np.arange(0, 5, 0.01)
SIGNAL = (0.5 * np.exp(-0.765 * T) * np.cos(10.13 * T + 0.3)
          + 0.01 * np.exp(1.64 * T) * np.sin(151.3 * T) + 0.02)


@pytest.mark.parametrize("noise", [0.0, 1e-4], ids=["exact", "noisy"])
def test_recovers_slow_and_bending_poles(noise):
    y = SIGNAL + noise * np.random.default_rng(0).standard_normal(T.size)
    slow = dominant_oscillation(T, y, (1, 50))
    bend = dominant_oscillation(T, y, (50, 300))
    tol = 1e-9 if noise == 0 else 1e-4
    assert slow.rate == pytest.approx(-0.765, abs=tol * 10) and slow.frequency == pytest.approx(10.13, abs=tol * 10)
    assert bend.rate == pytest.approx(1.64, abs=tol * 10) and bend.frequency == pytest.approx(151.3, abs=tol * 10)


def test_empty_band_gives_none():
    y = 0.5 * np.exp(-0.765 * T) * np.cos(10.13 * T)
    assert dominant_oscillation(T, y, (50, 300)) is None
