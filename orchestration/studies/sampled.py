"""The sampled-data closed loop: the PD + low-pass controller as it runs on hardware
(``docs/design/MODEL.md`` section 8), on the plant linearised at the upright rest state.

The controller samples the sensors ``y = [x_o, phi_o, omega_o]`` at ``t_k = k T``, computes its
force ``F_k`` and applies it after the computation delay ``tau`` (``0 <= tau <= T``), holding it
until the next change (zero-order hold). Over ``[kT, kT + tau)`` the plant is driven by the
previous force ``F_{k-1}``, over ``[kT + tau, (k+1)T)`` by ``F_k``; with
``Phi(h) = exp(A h)`` and ``Gamma(h) = int_0^h exp(A s) ds B`` (both from one exponential of the
augmented matrix ``[[A, B], [0, 0]] h``) the plant's exact discretisation is::

    x_{k+1} = Phi(T) x_k + Phi(T - tau) Gamma(tau) F_{k-1} + Gamma(T - tau) F_k

so the previous force is one more state of the loop. It is left out when ``tau = 0`` (nothing
depends on it then; it would only add an eigenvalue 0). With ``tau = T`` the new force first acts
one period later: one step of delay, ``z^-1``.

The controller computes ``e_k = kx x_o + kp phi_o + kd omega_o`` and ``F_k = -H_d(z) e_k``, the
filter ``H`` (``controller_fmu/pd_lowpass.py``) made a difference equation by
:data:`DISCRETIZATIONS`:

* ``"tustin"`` (the default): the bilinear map with prewarping at the cutoff. It keeps the
  filter's cutoff (and, for the second-order filter, its resonant peak) at the frequency the
  continuous design put it, and adds no lag of its own (its error is of second order in ``T``),
  so the sampled controller is the continuous design plus the unavoidable half period of the
  hold. The prewarp needs the cutoff below the Nyquist frequency, ``cutoff * T < pi``.
* ``"zoh"``: the filter's zero-order-hold equivalent (a strictly proper difference equation). It
  adds half a sample of lag on top of the hold's: a slower controller, hence a smaller stable
  sample period.

With order 0 (no filter) both are the same controller.

With ``kx = 0`` the cart's position and velocity are neither fed back nor felt by the other
states: they would add a double eigenvalue ``z = 1`` (the cart drifts), which the verdict leaves
aside as the continuous analysis does (:mod:`~orchestration.studies.analysis`); they are removed
structurally before discretising, not by a tolerance.

The verdict: stable iff every pole is inside the unit circle, the margin ``1 - max |z|``. The
poles are also given as s-plane equivalents ``log(z) / T`` (principal branch: a pole above the
Nyquist frequency is aliased), which tend to the continuous loop's as ``T -> 0``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.spec import model_for as controller_model
from plant_fmu.params import PlantParams

from .analysis import _plant_state_space, linearisation

__all__ = ["DISCRETIZATIONS", "DEFAULT_DISCRETIZATION", "MIN_PERIOD", "T_RANGE",
           "FIGURE_T_RANGE", "XTOL", "GRID_POINTS", "SampledPoles", "StableIntervals",
           "plant_discretisation", "filter_discretisation",
           "sampled_loop", "sampled_poles", "controller_poles", "sampled_margins", "stable_intervals", "boundaries",
           "critical_periods",
           "stability_region_figure"]

#: how the filter becomes a difference equation (see the module's docstring)
DISCRETIZATIONS = ("tustin", "zoh")
#: Tustin with prewarping: the cutoff and the peak stay where the continuous design put them
DEFAULT_DISCRETIZATION = "tustin"
#: the smallest sample period scanned (s): far below every scene's boundary
MIN_PERIOD = 1e-4
#: the sample periods :func:`stable_intervals` scans by default (s)
T_RANGE = (MIN_PERIOD, 0.05)
#: the sample periods :func:`stability_region_figure` shows (s): where the boundaries lie
FIGURE_T_RANGE = (1e-3, 0.05)
#: the relative precision of every boundary of :func:`stable_intervals`
XTOL = 1e-9
#: points of the logarithmic grid that :func:`stable_intervals` scans before bisecting
GRID_POINTS = 400


def _params(loop) -> tuple[PlantParams, ControllerParams]:
    """``(plant, controller)`` of ``loop``: a pair of parameter records, or a scene (name, path,
    dict of keys or Scene), whose plant is its rung's linearisation
    (:func:`~orchestration.studies.analysis.linearisation`; for the exact rung the floating
    frame's preloaded loop that stands in for it)."""
    if isinstance(loop, tuple) and len(loop) == 2 and isinstance(loop[0], PlantParams) \
            and isinstance(loop[1], ControllerParams):
        return loop
    from ..scene.schema import load_scene
    scene = load_scene(loop)
    return linearisation(scene).params, scene.controller


def _check(T, tau, discretization) -> tuple[float, float]:
    """``(T, tau)`` as floats, or ValueError naming the bad argument."""
    try:
        T = float(T)
    except (TypeError, ValueError):
        raise ValueError(f"sample period T must be a number (s), got {T!r}") from None
    if not (math.isfinite(T) and T > 0):
        raise ValueError(f"sample period T must be finite and > 0 (s), got {T!r}")
    try:
        tau = float(tau)
    except (TypeError, ValueError):
        raise ValueError(f"delay tau must be a number (s), got {tau!r}") from None
    if not (0.0 <= tau <= T):
        raise ValueError(f"delay tau must be in [0, T] = [0, {T!r}] s, got {tau!r}")
    if discretization not in DISCRETIZATIONS:
        raise ValueError(f"discretization must be one of {', '.join(DISCRETIZATIONS)}, got "
                         f"{discretization!r}")
    return T, tau


def _reduced_plant(p: PlantParams, c: ControllerParams):
    """The plant's ``(A, B, C)`` without the cart's position and velocity when ``kx = 0`` and no
    other state depends on them (as ``analysis.loop_transfer`` does)."""
    A, B, C, _ = _plant_state_space(p)
    if c.kx == 0.0:
        nq = p.n_modes + 2
        drift = [0, nq]
        keep = [i for i in range(A.shape[0]) if i not in drift]
        if not np.any(A[np.ix_(keep, drift)]) and not np.any(C[1:, drift]):
            A, B, C = A[np.ix_(keep, keep)], B[keep], C[:, keep]
    return A, B, C


def _hold(A, B, h: float):
    """``(Phi(h), Gamma(h))``: the plant over ``h`` with its input held, from the exponential of
    ``[[A, B], [0, 0]] h``."""
    import scipy.linalg

    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A * h
    aug[:n, n:] = B * h
    E = scipy.linalg.expm(aug)
    return E[:n, :n], E[:n, n:]


def plant_discretisation(A, B, T: float, tau: float = 0.0):
    """``(Phi, Gamma_prev, Gamma_new)``: the plant ``x' = A x + B u`` over one period ``T`` whose
    input is ``F_{k-1}`` over ``[0, tau)`` and ``F_k`` over ``[tau, T)``:
    ``x_{k+1} = Phi x_k + Gamma_prev F_{k-1} + Gamma_new F_k``. With ``tau = 0`` ``(Phi,
    Gamma_new)`` is the zero-order-hold discretisation and ``Gamma_prev`` is 0."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    Phi_tau, Gam_tau = _hold(A, B, tau)
    Phi_rest, Gam_rest = _hold(A, B, T - tau)
    return Phi_rest @ Phi_tau, Phi_rest @ Gam_tau, Gam_rest


@lru_cache(maxsize=1024)
def filter_discretisation(c: ControllerParams, T: float,
                          discretization: str = DEFAULT_DISCRETIZATION):
    """``(Ad, Bd, Cd, Dd)``: the filter ``H`` (unit DC gain, input ``e``, output the filtered
    error) as a difference equation over ``T``, by python-control's ``c2d``: ``"tustin"``
    prewarped at the cutoff, or ``"zoh"``. Order 0 is ``H = 1`` (no state)."""
    m = controller_model(c)
    if c.filter_order == 0:
        return m.Af, m.Bf, m.Cf, m.Df
    if discretization == "tustin" and not c.cutoff * T < math.pi:
        raise ValueError(f"sample period T = {T!r} s: the Tustin filter prewarped at the cutoff "
                         f"{c.cutoff!r} rad/s needs the cutoff below the Nyquist frequency, "
                         f"T < pi / cutoff = {math.pi / c.cutoff:.6g} s (discretization 'zoh' "
                         f"has no such limit)")
    import control          # here: python-control (with scipy.signal) costs 0.7 s to import

    H = control.ss(m.Af, m.Bf, m.Cf, m.Df)
    if discretization == "tustin":
        Hd = control.c2d(H, T, "tustin", prewarp_frequency=c.cutoff)
    else:
        Hd = control.c2d(H, T, "zoh")
    out = tuple(np.array(M, dtype=float) for M in (Hd.A, Hd.B, Hd.C, Hd.D))
    for M in out:
        M.setflags(write=False)
    return out


def sampled_loop(loop, T: float, tau: float = 0.0,
                 discretization: str = DEFAULT_DISCRETIZATION) -> np.ndarray:
    """The closed loop's z-plane matrix ``M``, ``s_{k+1} = M s_k`` over one sample period.

    ``loop``: a scene (name, path, dict or Scene) or a pair ``(PlantParams, ControllerParams)``.
    The state is the plant's (without the cart's drift states when ``kx = 0``), then the
    filter's, then (when ``tau > 0``) the force applied before the delay runs out, ``F_{k-1}``.
    ValueError for ``T <= 0``, ``tau`` outside ``[0, T]``, an unknown ``discretization``."""
    T, tau = _check(T, tau, discretization)
    p, c = _params(loop)
    return _loop_matrix(p, c, T, tau, discretization)


def _loop_matrix(p, c, T, tau, discretization, gain=1.0) -> np.ndarray:
    """The loop matrix; ``gain`` multiplies the controller's output (the loop gain; complex:
    ``k e^{-j theta}``, a gain and a phase change, for the margins)."""
    return _assemble(_loop_parts(p, c, T, tau, discretization), gain)


def _loop_parts(p, c, T, tau, discretization):
    """What :func:`_loop_matrix` is assembled from: the plant's discretisation over the period,
    the filter's difference equation, the error signal's row and whether there is a delay."""
    A, B, C = _reduced_plant(p, c)
    Phi, G_prev, G_new = plant_discretisation(A, B, T, tau)
    Ad, Bd, Cd, Dd = filter_discretisation(c, T, discretization)
    ge = controller_model(c).gains @ C                 # e_k = ge x_k
    return Phi, G_prev, G_new, Ad, Bd, Cd, Dd, ge, tau > 0.0


def _assemble(parts, gain=1.0) -> np.ndarray:
    Phi, G_prev, G_new, Ad, Bd, Cd, Dd, ge, prev = parts
    Kx, Kf = -gain * (Dd @ ge), -gain * Cd             # F_k = Kx x_k + Kf xf_k
    n, nf = Phi.shape[0], Ad.shape[0]
    N = n + nf + (1 if prev else 0)
    M = np.zeros((N, N), dtype=complex if np.iscomplexobj(gain) else float)
    M[:n, :n] = Phi + G_new @ Kx
    M[:n, n:n + nf] = G_new @ Kf
    M[n:n + nf, :n] = Bd @ ge
    M[n:n + nf, n:n + nf] = Ad
    if prev:
        M[:n, N - 1:] = G_prev
        M[N - 1:, :n] = Kx
        M[N - 1:, n:n + nf] = Kf
    return M


@dataclass(frozen=True)
class SampledPoles:
    """The poles of the sampled loop (:func:`sampled_poles`): ``z`` in the z-plane (largest
    modulus first), ``s = log(z) / T`` their s-plane equivalents (principal branch; ``-inf`` for
    ``z = 0``), the verdict and the margin ``1 - max |z|``; ``margins``: the loop's gain, phase
    and delay margins (:func:`sampled_margins`) where asked for."""

    T: float
    tau: float
    discretization: str
    z: np.ndarray
    s: np.ndarray = field(repr=False)
    #: :func:`sampled_margins` of the same loop, where asked for (``flexpend analyze``)
    margins: dict | None = field(default=None, repr=False)

    @property
    def spectral_radius(self) -> float:
        return float(np.abs(self.z).max()) if len(self.z) else 0.0

    @property
    def margin(self) -> float:
        """``1 - max |z|``: positive when the loop is stable."""
        return 1.0 - self.spectral_radius

    @property
    def stable(self) -> bool:
        return self.spectral_radius < 1.0

    def to_json(self) -> dict:
        """``T``, ``tau``, ``discretization``, the poles ``z`` and ``s`` as ``[real, imag]`` (the
        same order; ``s`` of ``z = 0`` is ``[-inf, 0]``), ``spectral_radius``, ``margin``,
        ``stable`` and ``margins`` (:func:`sampled_margins`, or None)."""
        def pairs(v):
            return [[float(x.real), float(x.imag) if math.isfinite(x.real) else 0.0] for x in v]

        return {"T": self.T, "tau": self.tau, "discretization": self.discretization,
                "z": pairs(self.z), "s": pairs(self.s),
                "spectral_radius": self.spectral_radius, "margin": self.margin,
                "stable": self.stable, "margins": self.margins}


def sampled_poles(loop, T: float, tau: float = 0.0,
                  discretization: str = DEFAULT_DISCRETIZATION) -> SampledPoles:
    """:class:`SampledPoles` of :func:`sampled_loop` (same arguments)."""
    M = sampled_loop(loop, T, tau, discretization)
    z = np.linalg.eigvals(M)
    z = z[np.lexsort((z.imag, -np.abs(z)))]
    with np.errstate(divide="ignore"):
        s = np.log(z.astype(complex)) / float(T)
    return SampledPoles(float(T), float(tau), discretization, z, s)


def controller_poles(p: PlantParams, c: ControllerParams) -> SampledPoles:
    """:func:`sampled_poles` of the plant ``p`` under the sampled controller ``c``, at its own
    sample period, delay and discretization."""
    return sampled_poles((p, c), c.sample_period, c.delay, c.discretization)


def _radius(p, c, T, tau, discretization, gain=1.0) -> float:
    return float(np.abs(np.linalg.eigvals(_loop_matrix(p, c, T, tau, discretization,
                                                       gain))).max())


def _first_crossing(radius, xs, xtol=1e-9):
    """The first ``x`` of the sequence ``xs`` (from the nominal outwards) where ``radius(x)``
    reaches 1, bisected between grid points; None when it never does."""
    prev = xs[0]
    for x in xs[1:]:
        if radius(x) >= 1.0:
            a, b = prev, x
            while abs(b - a) > xtol * max(abs(a), abs(b), 1.0):
                mid = 0.5 * (a + b)
                if radius(mid) >= 1.0:
                    b = mid
                else:
                    a = mid
            return 0.5 * (a + b)
        prev = x
    return None


def sampled_margins(loop, T: float, tau: float = 0.0,
                    discretization: str = DEFAULT_DISCRETIZATION) -> dict:
    """Gain, phase and delay margins of the sampled loop, on its exact discrete-time model: the
    smallest changes of the controller's output that put a closed-loop pole on the unit circle.

    * gain: the loop-gain factors ``k`` around 1 for which the loop stays stable,
      ``(gain_margin_lower, gain_margin_upper)`` (0 and inf when no factor below or above 1
      destabilises it, up to 1e3 and down to 1e-3), in dB too;
    * phase: the smallest phase change ``theta`` of the loop gain (``e^{-j theta}``: a lag for
      ``theta > 0``, a lead below 0) that puts a pole on the unit circle, ``phase_margin_deg``
      with its sense and the frequency ``angle(z) / T`` of that pole; the delay margin, the lag
      over that frequency (s), as the continuous loop's (:func:`~orchestration.studies.analysis.
      margins`).

    Found on the closed-loop eigenvalues (the spectral radius of :func:`sampled_loop` with the
    controller's output multiplied by ``k`` or ``e^{-j theta}``, scanned and bisected), not on
    transfer-function polynomials (which overflow with several bending modes); the tests compare
    a small loop's with python-control's ``stability_margins`` of its discrete ``L(z)``. An
    unstable loop gets none (``note`` says why)."""
    T, tau = _check(T, tau, discretization)
    p, c = _params(loop)
    out = {"T": T, "tau": tau, "discretization": discretization, "nominal_stable": None,
           "gain_margin_lower": None, "gain_margin_lower_db": None,
           "gain_margin_upper": None, "gain_margin_upper_db": None,
           "phase_margin_deg": None, "phase_margin_sense": None, "phase_margin_freq": None,
           "delay_margin_s": None, "note": None}
    parts = _loop_parts(p, c, T, tau, discretization)

    def radius(gain):
        return float(np.abs(np.linalg.eigvals(_assemble(parts, gain))).max())

    rho = radius(1.0)
    out["nominal_stable"] = rho < 1.0
    if not rho < 1.0:
        out["note"] = ("no margins: the sampled loop is unstable (a margin measures how far a "
                       "stable loop is from instability)")
        return out

    def by_gain(k):
        return radius(k)

    up = _first_crossing(by_gain, np.geomspace(1.0, 1e3, 241))
    lo = _first_crossing(by_gain, np.geomspace(1.0, 1e-3, 241))
    out.update(gain_margin_upper=math.inf if up is None else up,
               gain_margin_upper_db=math.inf if up is None else 20 * math.log10(up),
               gain_margin_lower=0.0 if lo is None else lo,
               gain_margin_lower_db=-math.inf if lo is None else 20 * math.log10(lo))

    def by_phase(theta_deg):
        return radius(np.exp(-1j * math.radians(theta_deg)))

    best = None
    for sense, grid in (("lag", np.linspace(0.0, 180.0, 361)),
                        ("lead", np.linspace(0.0, -180.0, 361))):
        th = _first_crossing(by_phase, grid)
        if th is not None and (best is None or abs(th) < abs(best[0])):
            best = (th, sense)
    if best is None:
        out.update(phase_margin_deg=math.inf, delay_margin_s=math.inf,
                   note="no phase change of the loop gain destabilises the loop")
        return out
    th, sense = best
    z = np.linalg.eigvals(_assemble(parts, np.exp(-1j * math.radians(th))))
    z1 = z[np.argmin(np.abs(np.abs(z) - 1.0))]
    w = abs(float(np.angle(z1))) / T
    out.update(phase_margin_deg=abs(th), phase_margin_sense=sense, phase_margin_freq=w,
               delay_margin_s=math.radians(abs(th)) / w if sense == "lag" and w > 0 else None)
    return out


@dataclass(frozen=True)
class StableIntervals:
    """The sample periods at which the sampled loop is stable (:func:`stable_intervals`).

    ``intervals``: the stable ``(T_low, T_high)`` inside ``scanned`` (an end of the scanned range
    is not a boundary); ``critical``: the upper end of the interval holding the smallest period
    scanned, the largest sample period up to which the loop stays stable (None when it is
    unstable there, ``scanned[1]`` when stable throughout). ``scanned`` is ``T_range``, its upper
    end lowered below ``pi / cutoff`` for the prewarped Tustin filter."""

    intervals: list
    critical: float | None
    scanned: tuple
    tau_fraction: float | None
    tau: float | None
    discretization: str


def stable_intervals(loop, T_range=T_RANGE, tau_fraction: float | None = None,
                     tau: float | None = None, discretization: str = DEFAULT_DISCRETIZATION,
                     xtol: float = XTOL, n_grid: int = GRID_POINTS) -> StableIntervals:
    """The intervals of ``T`` in ``T_range`` where the sampled loop is stable at the delay
    ``tau_fraction * T`` or, given ``tau`` (s), at that fixed delay (then only ``T >= tau``).
    Neither given: no delay.

    The spectral radius on a logarithmic grid of ``n_grid`` points, every change of the verdict
    bisected to the relative tolerance ``xtol``. A stable or unstable window narrower than the
    grid's spacing can be missed."""
    if tau_fraction is not None and tau is not None:
        raise ValueError("give tau_fraction or tau, not both")
    if tau_fraction is not None and not 0.0 <= float(tau_fraction) <= 1.0:
        raise ValueError(f"tau_fraction must be in [0, 1], got {tau_fraction!r}")
    if tau is not None and not (math.isfinite(float(tau)) and float(tau) >= 0.0):
        raise ValueError(f"delay tau must be finite and >= 0 (s), got {tau!r}")
    lo, hi = (float(v) for v in T_range)
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ValueError(f"T_range must be (T_min, T_max) with 0 < T_min < T_max, got "
                         f"{tuple(T_range)!r}")
    _check(hi, 0.0, discretization)
    p, c = _params(loop)
    if discretization == "tustin" and c.filter_order > 0:
        hi = min(hi, math.pi / c.cutoff * (1.0 - 1e-6))
    if tau is not None:
        lo = max(lo, float(tau))
    if not lo < hi:
        raise ValueError(f"T_range {tuple(T_range)!r} holds no sample period that the delay "
                         f"and the filter allow")

    def delay(T):
        if tau is not None:
            return float(tau)
        return min(T, T * float(tau_fraction or 0.0))

    def stable(T):
        return _radius(p, c, T, delay(T), discretization) < 1.0

    Ts = np.geomspace(lo, hi, n_grid)
    flags = [stable(T) for T in Ts]
    edges = []
    for i in range(len(Ts) - 1):
        if flags[i] != flags[i + 1]:
            a, b = Ts[i], Ts[i + 1]
            while b - a > xtol * a:
                mid = 0.5 * (a + b)
                if stable(mid) == flags[i]:
                    a = mid
                else:
                    b = mid
            edges.append(0.5 * (a + b))
    bounds = [lo, *edges, hi]
    intervals, on = [], flags[0]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if on:
            intervals.append((float(a), float(b)))
        on = not on
    critical = intervals[0][1] if flags[0] else None
    return StableIntervals(intervals, critical, (lo, hi),
                           None if tau is not None else float(tau_fraction or 0.0),
                           None if tau is None else float(tau), discretization)


def boundaries(loop, tau_fraction: float = 0.0, discretization: str = DEFAULT_DISCRETIZATION,
               min_width: float = 0.1, max_probe: float = 0.05) -> list:
    """``[(T, stable_below, probe)]``: each boundary ``T`` of the stable intervals of the sample
    period at the delay ``tau_fraction * T`` (:func:`stable_intervals`; the scanned range's
    ends are not boundaries, and a stable window narrower than ``min_width`` of its lower end is
    left out), whether the loop is stable just below it, and how far (relative) a run may probe
    either side and stay between it and its neighbours: ``max_probe``, or 0.4 of the gap to the
    nearest other boundary."""
    si = stable_intervals(loop, tau_fraction=tau_fraction, discretization=discretization)
    lo_s, hi_s = si.scanned
    every = sorted(b for iv in si.intervals for b in iv if lo_s < b < hi_s)
    out = []
    for lo, hi in si.intervals:
        if hi - lo < min_width * lo:
            continue
        for edge, below in ((lo, False), (hi, True)):
            if lo_s < edge < hi_s:
                gap = min([abs(b - edge) / edge for b in every if b != edge]
                          + [max_probe / 0.4])
                out.append((edge, below, 0.4 * gap))
    return out


def critical_periods(loop, discretization: str = DEFAULT_DISCRETIZATION,
                     T_range=T_RANGE) -> dict:
    """The largest stable sample period (:attr:`StableIntervals.critical`) with no delay and with
    a full period's delay: ``{"tau=0": T0, "tau=T": T1}``."""
    return {"tau=0": stable_intervals(loop, T_range, 0.0, discretization=discretization).critical,
            "tau=T": stable_intervals(loop, T_range, 1.0, discretization=discretization).critical}


def stability_region_figure(path, scenes=None, T_range=FIGURE_T_RANGE,
                            discretization: str = DEFAULT_DISCRETIZATION,
                            n_T: int = 100, n_fraction: int = 21):
    """A PNG at ``path``: one panel per scene, the stability region of its sampled loop in the
    plane of the sample period ``T`` (log scale) and the delay ``tau / T``, shaded where ``max
    |z| < 1`` on a grid of ``n_T`` by ``n_fraction`` points, its boundary the contour ``max |z| =
    1`` (up to ``pi / cutoff`` for the Tustin filter, dashed); the scene's largest stable ``T``
    at ``tau = 0`` and ``tau = T`` (:func:`critical_periods`, bisected, not read off the grid)
    marked. ``scenes``: names, paths or Scenes (a Scene's panel is titled by its name), the
    paper's three by default. The file is complete or absent
    (:class:`~orchestration.files.atomic_path`). Returns ``{scene: critical_periods}``."""
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..scene.schema import PAPER_SCENES, load_scene

    scenes = list(PAPER_SCENES if scenes is None else scenes)
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.0 * len(scenes), 3.8), sharey=True,
                             squeeze=False)
    fractions = np.linspace(0.0, 1.0, n_fraction)
    out = {}
    for i, (name, ax) in enumerate(zip(scenes, axes[0])):
        p, c = _params(load_scene(name) if isinstance(name, str) else name)
        label = name if isinstance(name, str) else getattr(name, "name", None) or f"scene {i + 1}"
        hi = T_range[1]
        if discretization == "tustin" and c.filter_order > 0:
            hi = min(hi, math.pi / c.cutoff * (1.0 - 1e-6))
        Ts = np.geomspace(T_range[0], hi, n_T)
        rho = np.array([[_radius(p, c, T, f * T, discretization) for T in Ts]
                        for f in fractions])
        ax.contourf(Ts, fractions, rho, levels=[0.0, 1.0], colors=["tab:green"], alpha=0.25)
        ax.contour(Ts, fractions, rho, levels=[1.0], colors=["tab:green"], linewidths=1.2)
        if hi < T_range[1]:
            ax.axvline(hi, color="0.5", linestyle="--", linewidth=1)
            ax.text(hi, 0.97, " pi / cutoff ", rotation=90, ha="right", va="top", fontsize=7,
                    color="0.4")
        crit = critical_periods((p, c), discretization, (MIN_PERIOD, hi))
        out[label] = crit
        for frac, key, marker in ((0.0, "tau=0", "o"), (1.0, "tau=T", "s")):
            if crit[key] is not None:
                ax.plot([crit[key]], [frac], marker, color="k", markersize=6, clip_on=False,
                        label=f"{key}: T = {1e3 * crit[key]:.3g} ms")
        if crit["tau=0"] is None:
            ax.text(0.03, 0.5, "unstable as T -> 0\n(the continuous loop is)",
                    transform=ax.transAxes, fontsize=8)
        else:
            ax.legend(fontsize=7, loc="center left", title="largest stable T",
                      title_fontsize=7)
        ax.set_xscale("log")
        ax.set_xlim(T_range[0], T_range[1])
        ticks = [t for t in (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1)
                 if T_range[0] <= t <= T_range[1]]
        ax.set_xticks(ticks, [f"{1e3 * t:g}" for t in ticks])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("sample period T (ms)")
        ax.set_title(label, fontsize=9)
    axes[0][0].set_ylabel("delay tau / T")
    axes[0][0].set_ylim(0.0, 1.0)
    fig.suptitle(f"Sampled PD + filter ({discretization} filter): stable where shaded",
                 fontsize=10)
    fig.tight_layout()
    from ..files import atomic_path
    try:
        with atomic_path(path) as tmp:           # complete or absent
            fig.savefig(tmp, dpi=120, format=Path(path).suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return out
