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

import math
from dataclasses import dataclass

import control
import numpy as np

from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
from plant_fmu.beam import beam_model
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams

__all__ = ["closed_loop_matrix", "loop_transfer", "analyze", "Analysis", "margins"]


def closed_loop_matrix(p: PlantParams, c: ControllerParams, gain: float = 1.0) -> np.ndarray:
    """The closed-loop state matrix (plant states first, then the filter states).

    ``gain`` multiplies the controller's output (for margin scans); 1 is the nominal loop.
    """
    A, B, C, _ = plant_model(p).state_space()
    Ac, Bc, Cc, Dc = PDLowPassModel(c).state_space()
    Cc, Dc = gain * Cc, gain * Dc
    top = np.hstack([A + B @ Dc @ C, B @ Cc])
    bottom = np.hstack([Bc @ C, Ac])
    return np.vstack([top, bottom])


def _drift_free(Acl: np.ndarray, p: PlantParams) -> np.ndarray:
    """``Acl`` without the cart position and velocity, when no other state depends on them."""
    nq = p.n_modes + 2
    drift = [0, nq]
    keep = [i for i in range(Acl.shape[0]) if i not in drift]
    if np.any(Acl[np.ix_(keep, drift)] != 0.0):
        return Acl  # the cart is fed back: its roots are part of the verdict
    return Acl[np.ix_(keep, keep)]


def max_real_part(p: PlantParams, c: ControllerParams, gain: float = 1.0) -> float:
    """Largest real part of the closed loop's eigenvalues, the cart's drift roots left aside."""
    return float(np.linalg.eigvals(_drift_free(closed_loop_matrix(p, c, gain), p)).real.max())


def loop_transfer(p: PlantParams, c: ControllerParams) -> control.StateSpace:
    """``L(s) = -K(s) G(s)``: the loop broken at the force, in python-control's convention
    (closed loop = ``L / (1 + L)``)."""
    A, B, C, D = plant_model(p).state_space()
    if c.kx == 0.0:
        # The cart's position and velocity are then neither fed back nor felt by the other
        # states: leave their two integrators out of the loop (they would cancel exactly).
        nq = p.n_modes + 2
        keep = [i for i in range(A.shape[0]) if i not in (0, nq)]
        A, B, C = A[np.ix_(keep, keep)], B[keep], C[:, keep]
    G = control.ss(A, B, C, D)
    K = control.ss(*PDLowPassModel(c).state_space())
    return -control.series(G, K)


def margins(p: PlantParams, c: ControllerParams) -> dict:
    """Gain and phase margins of the loop broken at the force.

    ``gain_range`` is the interval of loop-gain factors around 1 for which the closed loop stays
    stable (the open loop is unstable, so there is a lower limit too); it comes from python-control's
    phase-crossover gains and is confirmed on the closed-loop eigenvalues.
    """
    L = loop_transfer(p, c)
    gm, pm, sm, wpc, wgc, wms = control.stability_margins(L, returnall=True)
    gm, wpc, pm, wgc = map(np.atleast_1d, (gm, wpc, pm, wgc))
    nominal_stable = max_real_part(p, c) < 0
    lower, upper = 0.0, math.inf
    lower_w = upper_w = None
    for g, w in zip(gm, wpc):
        # At a phase crossover the loop passes through -1 for the gain factor g.
        if not np.isfinite(g) or g <= 0:
            continue
        if g > 1 and g < upper:
            upper, upper_w = float(g), float(w)
        elif g < 1 and g > lower:
            lower, lower_w = float(g), float(w)
    result = {
        "nominal_stable": bool(nominal_stable),
        "gain_margin_upper": upper if nominal_stable else None,
        "gain_margin_upper_db": 20 * math.log10(upper) if nominal_stable and upper < math.inf else None,
        "gain_margin_upper_freq": upper_w if nominal_stable else None,
        "gain_margin_lower": lower if nominal_stable else None,
        "gain_margin_lower_db": 20 * math.log10(lower) if nominal_stable and lower > 0 else None,
        "gain_margin_lower_freq": lower_w if nominal_stable else None,
        "phase_margin_deg": None,
        "phase_margin_freq": None,
        "gain_crossovers": [[float(w), float(ph)] for w, ph in zip(wgc, pm) if np.isfinite(ph)],
        "stability_margin": float(np.min(sm)) if np.size(sm) else None,
    }
    finite = [(abs(ph), ph, w) for ph, w in zip(pm, wgc) if np.isfinite(ph)]
    if finite:
        _, ph, w = min(finite)
        result["phase_margin_deg"] = float(ph)
        result["phase_margin_freq"] = float(w)
    return result


@dataclass
class Analysis:
    cantilever_frequencies: list
    open_loop_eigenvalues: np.ndarray
    eigenvalues: np.ndarray
    max_real_part: float
    stable: bool
    margins: dict

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
        return {
            "cantilever_frequencies": self.cantilever_frequencies,
            "open_loop_eigenvalues": [[float(z.real), float(z.imag)] for z in self.open_loop_eigenvalues],
            "eigenvalues": [[float(z.real), float(z.imag)] for z in self.eigenvalues],
            "modes": [dict(zip(("real", "imag", "frequency", "damping_ratio"), r)) for r in self.modes()],
            "max_real_part": self.max_real_part,
            "stable": self.stable,
            "margins": self.margins,
        }


def analyze(p: PlantParams, c: ControllerParams) -> Analysis:
    """Eigenvalues, stability verdict, damping ratios and margins of the linearised closed loop."""
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
    )
