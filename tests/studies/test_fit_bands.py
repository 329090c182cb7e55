"""fit_mode on its band: synthetic damped oscillations with known poles (closed form), a second
mode, a slow motion to ride on, noise; and on the paper's scenes against the linearised loop."""
import math

import numpy as np
import pytest

from orchestration.studies.fit import fit_mode


def signal(t, noise=0.0, seed=0):
    """A slow mode, a bending mode, a second one in the bending band's reach, a drift."""
    y = (0.5 * np.exp(-0.765 * t) * np.cos(10.13 * t + 0.3)
         + 0.01 * np.exp(-1.95 * t) * np.sin(153.2 * t)
         + 0.004 * np.exp(-7.7 * t) * np.cos(94.9 * t + 1.0)
         + 0.002 * np.exp(-1.5 * t) * np.cos(426.4 * t)
         + 0.02 * np.exp(-0.05 * t))
    return y + noise * np.random.default_rng(seed).standard_normal(t.size)


@pytest.mark.parametrize("dt", [1e-3, 2e-3])
@pytest.mark.parametrize("noise", [0.0, 1e-5], ids=["exact", "noisy"])
def test_recovers_the_slow_and_the_bending_poles(dt, noise):
    t = np.arange(0, 6, dt)
    y = signal(t, noise)
    slow = fit_mode(t, y, (0.5, 60.0))
    bend = fit_mode(t, y, (60.0, math.pi / dt), near=152.5)
    for f, rate, freq in ((slow, -0.765, 10.13), (bend, -1.95, 153.2)):
        # within 0.1 % (the fit stops at the lowest order that reproduces the band to 0.5 %:
        # what leaks in from outside the band is not all modelled), and within the stated
        # uncertainty
        assert f.rate == pytest.approx(rate, rel=1e-3) and f.frequency == pytest.approx(freq, rel=1e-4)
        assert f.residual <= 0.02


@pytest.mark.parametrize("dt", [1e-3, 2e-3])
def test_the_stated_uncertainty_covers_the_error_of_a_clean_signal(dt):
    """What leaks in from outside the band and is left unmodelled (the fit stops at a residual
    of 0.5 %) biases the poles; the stated uncertainty covers that bias."""
    t = np.arange(0, 6, dt)
    for f, rate, freq in ((fit_mode(t, signal(t), (60.0, math.pi / dt), near=152.5), -1.95, 153.2),
                          (fit_mode(t, signal(t), (0.5, 60.0)), -0.765, 10.13)):
        assert abs(f.rate - rate) <= f.rate_uncertainty
        assert abs(f.frequency - freq) <= f.frequency_uncertainty


@pytest.mark.parametrize("dt", [1e-2, 2e-3])
def test_an_amplitude_dependent_frequency_gives_the_small_amplitude_pole(dt):
    """A pendulum's frequency moves with its amplitude squared: w(t) = w0 + c A(t)^2 with
    A = a exp(sigma t) (the paper scenes' slow oscillation, from |phi| = 0.2 rad, starts 1.6 %
    below its linear frequency). Expanded, exp(i phase) is a sum of poles sigma + 2 k sigma +
    i w0: the linearised loop's is the k = 0 one, the largest; merging its neighbours into one
    oscillation would report the amplitude-weighted mean frequency (10.09 here)."""
    sigma, w0, a, c = -0.765, 10.13, 0.2, -4.0
    t = np.arange(0, 8.6, dt)
    y = a * np.exp(sigma * t) * np.cos(w0 * t + c * a**2 * np.expm1(2 * sigma * t) / (2 * sigma))
    f = fit_mode(t, y, (0.5, 60.0))
    assert abs(f.frequency - w0) <= f.frequency_uncertainty
    assert f.frequency == pytest.approx(w0, rel=1e-4) and f.rate == pytest.approx(sigma, rel=1e-3)


@pytest.mark.parametrize("pencil", [0.4, 0.5])
def test_the_fit_moves_within_its_uncertainty_across_the_pencil_range(monkeypatch, pencil):
    """Hua & Sarkar's pencil parameter, L from N/3 to N/2 (the range of least variance): the
    fit does not depend on where in it the Hankel matrix is cut, beyond its uncertainty."""
    import orchestration.studies.fit as fit

    t = np.arange(0, 6, 1e-3)
    y = signal(t, 1e-5)
    fits = {}
    for p in (fit.PENCIL, pencil):
        monkeypatch.setattr(fit, "PENCIL", p)
        fits[p] = (fit_mode(t, y, (0.5, 60.0)), fit_mode(t, y, (60.0, math.pi / 1e-3), near=152.5))
    for a, b in zip(*fits.values()):
        assert abs(a.rate - b.rate) <= a.rate_uncertainty
        assert abs(a.frequency - b.frequency) <= a.frequency_uncertainty


def test_a_growing_bending_mode_under_a_large_slow_motion():
    t = np.arange(0, 1.5, 1e-3)
    y = 0.5 * np.exp(-0.79 * t) * np.cos(10.22 * t) + 1e-4 * np.exp(1.643 * t) * np.sin(151.17 * t)
    f = fit_mode(t, y, (60.0, math.pi / 1e-3), near=152.5)
    assert f.rate == pytest.approx(1.643, abs=1e-5) and f.frequency == pytest.approx(151.17, abs=1e-5)


def test_the_window_is_sized_in_periods_of_the_band():
    t = np.arange(0, 10, 1e-3)
    f = fit_mode(t, signal(t), (60.0, math.pi / 1e-3), near=152.5, periods=40)
    assert f.window[1] - f.window[0] == pytest.approx(40 * 2 * math.pi / (1.3 * 152.5), abs=2e-3)


def test_nothing_in_the_band_gives_none():
    t = np.arange(0, 5, 1e-3)
    y = 0.5 * np.exp(-0.765 * t) * np.cos(10.13 * t)
    assert fit_mode(t, y, (60.0, math.pi / 1e-3), near=152.5) is None


def test_a_drifting_frequency_is_one_oscillation_with_a_stated_uncertainty():
    """A chirp (frequency from 150 to 153 rad/s over the window, amplitude decaying at 2/s):
    the fit reports one oscillation near the mean, and its uncertainty covers the drift."""
    t = np.arange(0, 4, 2e-3)
    w = 150 + 3 * (1 - np.exp(-t))
    y = np.exp(-2.0 * t) * np.sin(np.cumsum(w) * 2e-3)
    f = fit_mode(t, y, (60.0, math.pi / 2e-3), near=152.5)
    assert 150 <= f.frequency <= 153
    assert f.rate == pytest.approx(-2.0, abs=max(0.1, f.rate_uncertainty))
    assert f.frequency_uncertainty > 0.1


@pytest.mark.slow
@pytest.mark.parametrize("name,key,rel", [("rigid_pd", "slow", 0.02),
                                          ("flexible_pd_lowpass", "slow", 0.02),
                                          ("flexible_pd_lowpass", "bending", 0.05)])
def test_paper_scene_fits_are_the_linear_loops_modes(fmus, name, key, rel):
    """The fitted rate and frequency on the paper scenes, against the linearised loop's
    eigenvalue nearest to them (computed independently, from the closed-loop matrix)."""
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    from orchestration.studies.analysis import closed_loop_matrix

    scene = load_scene(name)
    run = run_scene(scene, {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]},
                    progress=False)
    m = run.summary[key]
    assert m["reliable"], m["note"]
    lam = np.linalg.eigvals(closed_loop_matrix(scene.plant.params, scene.controller))
    lam = lam[lam.imag > 0]
    near = lam[np.argmin(np.abs(lam.imag - m["frequency"]))]
    assert m["rate"] == pytest.approx(near.real, rel=rel)
    assert m["frequency"] == pytest.approx(near.imag, rel=rel)
    assert m["fit"]["rate_uncertainty"] is not None
