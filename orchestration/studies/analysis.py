"""Linear analysis of the closed loop: plant linearised at the upright state plus the controller.

The plant ``(A, B, C)`` has the sensors ``y = [x_o, phi_o, omega_o]`` as outputs and the cart force
as input; the controller ``(Ac, Bc, Cc, Dc)`` maps ``y`` to ``F_c``. The closed loop is::

    d/dt [x; xc] = [[A + B Dc C, B Cc], [Bc C, Ac]] [x; xc]

With ``kx = 0`` the cart position and velocity are not fed back: they add a double eigenvalue at
zero (the cart drifts), which the stability verdict leaves aside, as the paper does. It is removed
structurally (the other states do not depend on ``x`` and ``x_dot``), not by a tolerance.

The loop broken at the force is ``L(s) = -K(s) G(s)`` (negative-feedback convention); its margins
come from python-control, and the range of loop-gain factors that keep the loop stable is checked
against closed-loop eigenvalues.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.spec import model_for as controller_model
from plant_fmu.beam import beam_model
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams, damping_text

if TYPE_CHECKING:
    import control

__all__ = ["closed_loop_matrix", "assemble_closed_loop", "loop_transfer", "frequency_response",
           "analyze", "Analysis", "margins", "roots_of", "max_real_part", "first_bending_frequency",
           "closed_loop_eigenvalues",
           "LoopRoots", "loop_roots", "Linearisation", "linearisation"]


@dataclass(frozen=True)
class Linearisation:
    """The linearised plant that a scene's rung is judged by (:func:`linearisation`).

    ``params``: the floating frame's plant linearised at the upright rest state; ``rung``: the
    scene's ``plant.fidelity``; ``own``: whether that loop is the rung's own linearisation
    (False for the exact rung, whose loop the floating frame's stands in for)."""

    params: PlantParams
    rung: str
    own: bool = True

    def text(self) -> str:
        """Which loop, in words, its damping law named: ``"the stiffened rung's linearisation (4
        modes, preloaded, modal damping 0.1 %)"``."""
        p = self.params
        loop = "rigid" if p.n_modes == 0 else \
            f"{p.n_modes} mode{'s' if p.n_modes != 1 else ''}"
        loop += ", preloaded" if p.gravity_preload else ""
        loop += f", {damping_text(p)}" if p.n_modes else ""
        if self.own:
            return f"the {self.rung} rung's linearisation ({loop})"
        return (f"the floating frame's linearisation ({loop}), standing in for the {self.rung} "
                f"rung's")


def linearisation(scene) -> Linearisation:
    """The linearisation of a scene's plant, for its rung: the one function that decides it,
    for the summary's linear roots, ``analyze``, ``stability``, ``design``, the figures, the
    sweeps' linear rates and design sets, and the choice of ``n_modes``. The damping law and every
    other physical parameter are the scene's (they are in the parameter record; while
    ``plant.n_modes`` is ``"auto"`` the record has 0 modes, and ``plant.fidelity = "auto"`` is
    linearised as the floating frame the scene sets).

    * ``linear``, ``nonlinear``: the plant as the scene sets it (``plant.gravity_preload``
      included);
    * ``stiffened``: the preload rung's (the stiffened rung's small-amplitude dynamics are
      those of the self-weight's geometric stiffness, ``tests/plant/test_stiffened.py``);
    * ``exact``: the exact beam's own linearisation is not taken here; the floating frame's
      preloaded loop (the exact beam stands compressed by its weight) with the scene's
      ``n_modes`` and damping law stands in for it (``own`` False: the analyses refuse it, the
      summary says which loop it compared with)."""
    rung, p = scene.plant.fidelity, scene.plant.beam
    if rung in ("stiffened", "exact"):
        p = p.replace(gravity_preload=True)
    return Linearisation(p, rung, own=rung != "exact")


def assemble_closed_loop(A, B, C, controller_ss, gain: float = 1.0) -> np.ndarray:
    """``[[A + B Dc C, B Cc], [Bc C, Ac]]`` for the plant ``(A, B, C)`` and the controller
    ``(Ac, Bc, Cc, Dc)``; ``A, B, C`` may be stacks (leading axes) of plants of one size."""
    Ac, Bc, Cc, Dc = controller_ss
    Cc, Dc = gain * Cc, gain * Dc
    top = np.concatenate([A + B @ Dc @ C, np.broadcast_to(B @ Cc, (*A.shape[:-1], Ac.shape[0]))],
                         axis=-1)
    bc = np.broadcast_to(Bc @ C, (*A.shape[:-2], Ac.shape[0], A.shape[-1]))
    bottom = np.concatenate([bc, np.broadcast_to(Ac, (*A.shape[:-2], *Ac.shape))], axis=-1)
    return np.concatenate([top, bottom], axis=-2)


#: plants and loops whose linear analyses are kept (a sweep's runs share plants or loops)
_CACHE = 1024


@lru_cache(maxsize=_CACHE)
def _plant_state_space(p: PlantParams) -> tuple:
    """``plant_model(p).state_space()``, once per plant (read-only arrays)."""
    out = plant_model(p).state_space()
    for m in out:
        m.setflags(write=False)
    return out


def closed_loop_matrix(p: PlantParams, c: ControllerParams, gain: float = 1.0) -> np.ndarray:
    """The closed-loop state matrix (plant states first, then the filter states).

    ``gain`` multiplies the controller's output (for margin scans); 1 is the nominal loop.
    """
    A, B, C, _ = _plant_state_space(p)
    return assemble_closed_loop(A, B, C, controller_model(c).state_space(), gain)


@lru_cache(maxsize=_CACHE)
def closed_loop_eigenvalues(p: PlantParams, c: ControllerParams) -> np.ndarray:
    """All eigenvalues of :func:`closed_loop_matrix` (the cart's drift roots included), once
    per loop (a read-only array)."""
    lam = np.linalg.eigvals(closed_loop_matrix(p, c))
    lam.setflags(write=False)
    return lam


def _drift_free(Acl: np.ndarray, p: PlantParams) -> np.ndarray:
    """``Acl`` without the cart position and velocity, when no other state depends on them
    (``Acl`` may be a stack of closed loops of plants with ``p.n_modes`` modes)."""
    nq = p.n_modes + 2
    drift = [0, nq]
    keep = [i for i in range(Acl.shape[-1]) if i not in drift]
    if np.any(Acl[..., keep, :][..., drift] != 0.0):
        return Acl  # the cart is fed back: its roots are part of the verdict
    return Acl[..., keep, :][..., keep]


@lru_cache(maxsize=_CACHE)
def max_real_part(p: PlantParams, c: ControllerParams, gain: float = 1.0) -> float:
    """Largest real part of the closed loop's eigenvalues, the cart's drift roots left aside."""
    return float(np.linalg.eigvals(_drift_free(closed_loop_matrix(p, c, gain), p)).real.max())


@lru_cache(maxsize=_CACHE)
def first_bending_frequency(p: PlantParams) -> float | None:
    """The plant's first open-loop oscillation (rad/s): its first bending mode with the hinge
    free (152.5 rad/s for the paper's beam; the cantilever's is 26.3 rad/s). The loop's root
    near it is the one the PD destabilises (docs/model.md); None for the rigid model."""
    if p.n_modes == 0:
        return None
    lam = np.linalg.eigvals(_plant_state_space(p)[0])
    return float(min(z.imag for z in lam if z.imag > 1.0))


@dataclass(frozen=True)
class LoopRoots:
    """The closed-loop roots of a plant and controller, the cart's drift roots left aside (when
    ``kx = 0``), sorted by frequency; ``bending``: the root nearest the first bending frequency
    (upper half-plane; None for the rigid model); ``slow``: the lowest oscillatory root below it
    (the rigid pendulum's), or None."""

    roots: np.ndarray
    bending: complex | None
    slow: complex | None
    bending_frequency: float | None

    @property
    def max_real_part(self) -> float:
        return float(self.roots.real.max())

    @property
    def stable(self) -> bool:
        return self.max_real_part < 0

    def growing(self) -> list:
        """The roots in the right half-plane (upper half and real axis), fastest first."""
        return sorted((z for z in self.roots if z.real >= 0 and z.imag >= 0),
                      key=lambda z: -z.real)


def loop_roots(p: PlantParams, c: ControllerParams) -> LoopRoots:
    """:class:`LoopRoots` of the linearised closed loop of ``p`` and ``c``."""
    lam = np.linalg.eigvals(_drift_free(closed_loop_matrix(p, c), p))
    return roots_of(lam, first_bending_frequency(p))


def roots_of(lam, wb: float | None) -> LoopRoots:
    """:class:`LoopRoots` of the closed-loop roots ``lam`` (s-plane) of a plant whose first
    bending frequency is ``wb`` (None: rigid): sorted by frequency, the bending and slow ones
    picked out."""
    lam = np.asarray(lam)
    lam = lam[np.argsort(np.abs(lam.imag), kind="stable")]
    up = lam[lam.imag > 1e-9]
    bending = complex(up[np.argmin(np.abs(up.imag - wb))]) if wb is not None and len(up) else None
    below = [z for z in up if wb is None or z.imag < 0.5 * wb]
    slow = complex(min(below, key=lambda z: z.imag)) if below else None
    return LoopRoots(lam, bending, slow, wb)


def loop_transfer(p: PlantParams, c: ControllerParams) -> control.StateSpace:
    """``L(s) = -K(s) G(s)``: the loop broken at the force, in python-control's convention
    (closed loop = ``L / (1 + L)``)."""
    import control          # here: python-control (with scipy.signal) costs 0.7 s to import

    A, B, C, D = plant_model(p).state_space()
    if c.kx == 0.0:
        # The cart's position and velocity are then neither fed back nor felt by the other
        # states: leave their two integrators out of the loop (they would cancel exactly).
        nq = p.n_modes + 2
        keep = [i for i in range(A.shape[0]) if i not in (0, nq)]
        A, B, C = A[np.ix_(keep, keep)], B[keep], C[:, keep]
    G = control.ss(A, B, C, D)
    K = control.ss(*controller_model(c).state_space())
    return -control.series(G, K)


def _response(L: control.StateSpace, w: np.ndarray) -> np.ndarray:
    """``L(jw)`` of a single-input single-output state-space system on the grid ``w``, by one
    linear solve per frequency (python-control's evaluation, without its overhead)."""
    A, B, C, D = (np.asarray(m, dtype=float) for m in (L.A, L.B, L.C, L.D))
    eye = np.eye(A.shape[0])
    # B stacked as the matrices are: a right-hand side of one dimension less is a vector under
    # numpy 2 but a stack of vectors under numpy 1 (numpy.linalg.solve's rule changed)
    rhs = np.broadcast_to(B.astype(complex), (len(w), *B.shape))
    return (C @ np.linalg.solve(1j * w[:, None, None] * eye - A, rhs))[:, 0, 0] + D[0, 0]


def frequency_response(p: PlantParams, c: ControllerParams, w) -> np.ndarray:
    """``L(jw)``, the loop broken at the force (:func:`loop_transfer`), at the frequencies ``w``
    (rad/s)."""
    return _response(loop_transfer(p, c), np.asarray(w, dtype=float))


def _crossings(f, w, v):
    """Roots of the real function ``f`` whose values on the grid ``w`` are ``v``, refined by
    Brent's method."""
    import scipy.optimize

    idx = np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]
    return [scipy.optimize.brentq(f, w[i], w[i + 1], xtol=1e-12, rtol=1e-13) for i in idx]


def margins(p: PlantParams, c: ControllerParams, n_grid: int = 4000) -> dict:
    """Gain, phase and delay margins of the loop broken at the force.

    python-control's ``stability_margins`` goes through transfer-function polynomials, which
    overflow for the loops with several bending modes; the crossings are therefore found on the
    state-space frequency response ``L(jw)`` (evaluated by python-control), on a dense logarithmic
    grid refined by Brent's method.

    **Gain.** The open loop is unstable, so the gain margin has two sides: the loop stays stable
    for loop-gain factors in ``(gain_margin_lower, gain_margin_upper)``. A phase crossover
    (``L(jw)`` real and negative) at gain factor ``-1/L(jw)`` is a closed-loop pole on the
    imaginary axis, which the tests confirm on the closed-loop eigenvalues.

    **Phase.** The flexible loop crosses ``|L| = 1`` several times (near the slow mode and on
    each side of a bending resonance). At each gain crossover ``w_i`` the phase change that puts
    a closed-loop pole at ``j w_i``, ``L(j w_i) e^{-j theta_i} = -1``, is ``theta_i = arg L(j w_i)
    + 180 deg`` wrapped to ``[-180, 180)``: a lag when positive, a lead when negative. The phase
    margin is the smallest ``|theta_i|``: the loop with its gain multiplied by ``e^{-j theta}``
    keeps every closed-loop root in the left half-plane for ``|theta| <`` the margin, and has one
    on the imaginary axis at the margin (the tests check it on the eigenvalues of that loop).
    ``gain_crossovers`` lists every crossover with its ``phase_change_deg`` (``theta_i``); the
    phase margin is the smallest of their magnitudes, by definition the same numbers. The delay
    margin is the smallest time delay that puts a pole on the axis: ``(theta_i mod 360 deg) /
    w_i``, the smallest over the crossovers.

    A margin measures how far a *stable* loop is from instability: an unstable closed loop gets
    none (``None``), and ``note`` says so; its crossovers are still listed.
    """
    L = loop_transfer(p, c)

    def Ls(w):
        return complex(_response(L, np.array([w]))[0])

    wmax = 5.0 * max([abs(z) for z in np.linalg.eigvals(np.asarray(L.A))] + [10.0])
    w = np.logspace(-3, np.log10(wmax), n_grid)
    grid = _response(L, w)
    nominal_stable = max_real_part(p, c) < 0
    # Phase crossovers: Im L = 0 with Re L < 0; and w = 0 (a real root crossing the origin).
    phase_x = [(x, Ls(x).real) for x in _crossings(lambda x: Ls(x).imag, w, grid.imag)]
    phase_x.append((0.0, complex(L(0.0)).real))
    lower = upper = None
    for x, re in phase_x:
        if re >= 0:
            continue
        k = -1.0 / re
        if k > 1 and (upper is None or k < upper[0]):
            upper = (k, x)
        elif k < 1 and (lower is None or k > lower[0]):
            lower = (k, x)
    crossings = []
    for x in _crossings(lambda x: abs(Ls(x)) - 1.0, w, np.abs(grid) - 1.0):
        phase = float(np.degrees(np.angle(Ls(x))))
        change = (phase + 360.0) % 360.0 - 180.0
        crossings.append({"frequency": float(x), "phase_deg": phase,
                          "phase_change_deg": change,
                          "delay_s": math.radians(change % 360.0) / x})
    result = {
        "nominal_stable": bool(nominal_stable),
        "gain_margin_upper": None, "gain_margin_upper_db": None, "gain_margin_upper_freq": None,
        "gain_margin_lower": None, "gain_margin_lower_db": None, "gain_margin_lower_freq": None,
        "phase_margin_deg": None, "phase_margin_freq": None, "phase_margin_sense": None,
        "delay_margin_s": None, "delay_margin_freq": None,
        "gain_crossovers": crossings,
        "note": None,
    }
    if not nominal_stable:
        result["note"] = ("no margins: the closed loop is unstable (a margin measures how far a "
                          "stable loop is from instability)")
        return result
    if upper is None:
        result["gain_margin_upper"] = math.inf
    else:
        result.update(gain_margin_upper=upper[0], gain_margin_upper_db=20 * math.log10(upper[0]),
                      gain_margin_upper_freq=upper[1])
    if lower is None:
        result["gain_margin_lower"] = 0.0
    else:
        result.update(gain_margin_lower=lower[0], gain_margin_lower_db=20 * math.log10(lower[0]),
                      gain_margin_lower_freq=lower[1])
    if crossings:
        pm = min(crossings, key=lambda r: abs(r["phase_change_deg"]))
        dm = min(crossings, key=lambda r: r["delay_s"])
        result.update(phase_margin_deg=abs(pm["phase_change_deg"]),
                      phase_margin_freq=pm["frequency"],
                      phase_margin_sense="lag" if pm["phase_change_deg"] >= 0 else "lead",
                      delay_margin_s=dm["delay_s"], delay_margin_freq=dm["frequency"])
    else:
        result["phase_margin_deg"] = result["delay_margin_s"] = math.inf
        result["note"] = "|L(jw)| never crosses 1: no phase change or delay destabilises the loop"
    return result


@dataclass
class Analysis:
    """The linearised closed loop of ``plant`` and ``controller`` (:func:`analyze`)."""

    cantilever_frequencies: list
    open_loop_eigenvalues: np.ndarray
    eigenvalues: np.ndarray
    max_real_part: float
    stable: bool
    margins: dict
    plant: PlantParams | None = None
    controller: ControllerParams | None = None
    loop: str | None = None            # which loop, a scene's (Linearisation.text)
    #: a sampled controller's (``controller.sample_period > 0``) discrete-time loop at its
    #: sample period, delay and discretization
    #: (:class:`~orchestration.studies.sampled.SampledPoles`); None for a continuous one. The
    #: fields above are then the continuous controller's (``T -> 0``), for comparison.
    sampled: object | None = None

    def __repr__(self) -> str:
        """One line: the verdict, the largest real part, the number of roots, the loop."""
        loop = self.loop or (f"{self.plant.n_modes} modes" if self.plant is not None else "")
        if len(loop) > 80:
            loop = loop[:77] + "..."
        return (f"Analysis({'stable' if self.stable else 'unstable'}: max Re(lambda) = "
                f"{self.max_real_part:.4g} 1/s, {len(self.eigenvalues)} closed-loop roots"
                f"{'; ' + loop if loop else ''})")

    def modes(self):
        """One row per oscillatory closed-loop mode (upper half-plane) or real root:
        ``(real, imag, frequency rad/s, damping ratio)``."""
        rows = []
        for lam in self.eigenvalues:
            if lam.imag < 0:
                continue
            wn = abs(lam)
            zeta = -lam.real / wn if wn > 0 else float("nan")
            rows.append((float(lam.real), float(lam.imag), float(wn), float(zeta)))
        return sorted(rows, key=lambda r: r[2])

    def to_json(self) -> dict:
        """What ``flexpend analyze --json`` prints: the loop, the plant's and the controller's
        parameters, the cantilever frequencies, the open- and closed-loop eigenvalues as
        ``[real, imag]``, the modes, ``max_real_part``, ``stable`` and the margins; for a sampled
        controller also ``"sampled"`` (:meth:`~orchestration.studies.sampled.SampledPoles.to_json`:
        the z-plane poles, their s-plane equivalents, the spectral radius, margin and verdict)."""
        out = {"loop": self.loop} if self.loop else {}
        if self.plant is not None:
            out["plant"] = dataclasses.asdict(self.plant)
        if self.controller is not None:
            out["controller"] = dataclasses.asdict(self.controller)
        return out | {
            "cantilever_frequencies": self.cantilever_frequencies,
            "open_loop_eigenvalues": [[float(z.real), float(z.imag)] for z in self.open_loop_eigenvalues],
            "eigenvalues": [[float(z.real), float(z.imag)] for z in self.eigenvalues],
            "modes": [dict(zip(("real", "imag", "frequency", "damping_ratio"), r)) for r in self.modes()],
            "max_real_part": self.max_real_part,
            "stable": self.stable,
            "margins": self.margins,
        } | ({"sampled": self.sampled.to_json()} if self.sampled is not None else {})


def analyze(p: PlantParams, c: ControllerParams, loop: str | None = None) -> Analysis:
    """Eigenvalues, stability verdict, damping ratios and margins of the linearised closed loop
    (``loop``: which loop it is, :meth:`Linearisation.text`), of the continuous controller
    (:func:`orchestration.api.analyze` adds a sampled one's discrete-time loop,
    :attr:`Analysis.sampled`)."""
    A = plant_model(p).state_space()[0]
    Acl = closed_loop_matrix(p, c)
    eig = np.linalg.eigvals(Acl)
    eig = eig[np.lexsort((eig.imag, -eig.real))]
    mrp = float(np.linalg.eigvals(_drift_free(Acl, p)).real.max())
    ol = np.linalg.eigvals(A)
    return Analysis(
        cantilever_frequencies=[float(w) for w in beam_model(p).frequencies],
        open_loop_eigenvalues=ol[np.lexsort((ol.imag, -ol.real))],
        eigenvalues=eig,
        max_real_part=mrp,
        stable=mrp < 0,
        margins=margins(p, c),
        plant=p,
        controller=c,
        loop=loop,
    )
