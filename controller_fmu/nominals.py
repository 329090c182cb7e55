"""The nominal values of the controller's Model-Exchange states, in Python (issue 37, 4).

    state_nominals(values) -> {"xc_1": ..., "xc_2": ...}

The formulas of ``fpm_model_nominals`` in ``controller_fmu/native/controller_model.c``
(docs/fmus.md, "Nominals"), which the modelDescription writer declares at the table's start
values as the states' ``nominal`` attributes; at run time the FMU computes them from the
parameters it was initialised with.
"""
from __future__ import annotations

import dataclasses
import math

from .pd_lowpass import ControllerParams

__all__ = ["state_nominals"]

_DEFAULTS = {f.name: f.default for f in dataclasses.fields(ControllerParams)}


def state_nominals(values=None) -> dict:
    """``{state: nominal}`` at the parameter values ``values`` (FMU parameter name -> value; the
    ones missing: :class:`ControllerParams`'s defaults): ``xc_1`` a force, the smaller of
    ``|kp| x 1 rad`` and ``force_limit`` (1 if that is not positive and finite); ``xc_2``
    ``cutoff`` times that; 1 for the states beyond ``filter_order``."""
    p = {**_DEFAULTS, **(values or {})}
    f = min(abs(float(p["kp"])), float(p["force_limit"]))
    if not (math.isfinite(f) and f > 0.0):
        f = 1.0
    rate = f * float(p["cutoff"])
    order = int(p["filter_order"])
    return {"xc_1": f if order >= 1 else 1.0,
            "xc_2": rate if order >= 2 and math.isfinite(rate) and rate > 0.0 else 1.0}
