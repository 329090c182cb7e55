"""The nominal values of the plant's Model-Exchange states, in Python (issue 37, 4).

    state_nominals(values) -> {state name: nominal}       (in the order of interface.STATES)

The formulas of ``fpm_model_nominals`` in ``plant_fmu/native/plant_model.c`` (docs/fmus.md,
"Nominals"; :data:`plant_fmu.interface._NOMINALS`), with the same operations in the same order on
the same modal data (the unit beam's tables, :func:`plant_fmu.beam.unit_beam`, scaled as
:class:`plant_fmu.beam.Scales` scales them), so that the values agree to the last bit. The
modelDescription writer declares them at the table's start values as the states' ``nominal``
attributes (:mod:`orchestration.export.model_description`); at run time the FMU computes them
from the parameters it was initialised with.
"""
from __future__ import annotations

import dataclasses
import math

from .interface import N_ETA_OUTPUTS, STATES
from .params import PlantParams

__all__ = ["state_nominals"]

_DEFAULTS = {f.name: f.default for f in dataclasses.fields(PlantParams)}


def _positive_or_1(v: float) -> float:
    return v if math.isfinite(v) and v > 0.0 else 1.0


def state_nominals(values=None) -> dict:
    """``{state: nominal}`` at the parameter values ``values`` (FMU parameter name -> value; the
    ones missing: :class:`PlantParams`'s defaults): ``x_o`` L, ``phi`` 1, ``eta_j`` 0.01 L /
    |N_j(L)|, ``x_dot`` sqrt(g L) (L when g = 0), ``phi_dot`` sqrt(g / L) (1 when g = 0),
    ``eta_dot_j`` omega_j times the nominal of eta_j; the states of modes beyond ``n_modes``
    1."""
    from .beam import Scales, unit_beam     # numpy: only where nominals are computed

    p = {**_DEFAULTS, **(values or {})}
    L, g, n = float(p["L"]), float(p["g"]), int(p["n_modes"])
    rhoA = float(p["rho"]) * float(p["EA"]) / float(p["E"])
    sc = Scales.of(L, float(p["EI"]), rhoA, g)
    u = unit_beam(int(p["n_elements"]), n)
    out = dict.fromkeys(STATES, 1.0)
    out["x_o"] = _positive_or_1(L)
    out["x_dot"] = _positive_or_1(math.sqrt(g * L) if g > 0.0 else L)
    out["phi_dot"] = _positive_or_1(math.sqrt(g / L) if g > 0.0 else 1.0)
    for j in range(min(n, N_ETA_OUTPUTS)):
        K = float(u.lam[j]) * sc.lam
        eta = _positive_or_1(0.01 * L / abs(float(u.tip_deflection[j]) * sc.w))
        out[f"eta_{j + 1}"] = eta
        out[f"eta_dot_{j + 1}"] = _positive_or_1(math.sqrt(K) * eta)
    return out
