"""Integration methods for the plant: one stepper contract, a registry of methods, pure numpy.

>>> stepper = make_stepper("rk4", model, 0.0, x0, h=1e-4)      # doctest: +SKIP
>>> stepper.u = 3.0                                            # doctest: +SKIP
>>> ok, message = stepper.advance(1e-3)                        # doctest: +SKIP

See :mod:`plant_fmu.integrators.base` for the contract and ``docs/integrators.md`` for the
methods' order, stability, cost and when to choose each.
"""
from __future__ import annotations

from .base import FAILED, RUNNING, IntegratorError, Stepper
from .exponential import ExactExponential
from .genalpha import GeneralizedAlpha, genalpha_parameters
from .radau import Radau5
from .rk import RK4, DormandPrince54, ExplicitEuler, ExplicitRungeKutta, SymplecticEuler

__all__ = ["REGISTRY", "make_stepper", "IntegratorError", "Stepper", "ExplicitRungeKutta",
           "ExplicitEuler", "SymplecticEuler", "RK4", "DormandPrince54", "Radau5",
           "GeneralizedAlpha", "ExactExponential", "genalpha_parameters", "RUNNING", "FAILED"]

#: method name -> stepper class
REGISTRY: dict[str, type[Stepper]] = {
    cls.name: cls for cls in (ExplicitEuler, SymplecticEuler, RK4, DormandPrince54, Radau5,
                              GeneralizedAlpha, ExactExponential)
}


def make_stepper(name, model, t0, y0, u=0.0, h=1e-3, rtol=1e-6, atol=1e-9, rho_inf=0.8,
                 **options) -> Stepper:
    """Build the stepper registered as ``name`` (see :data:`REGISTRY`).

    ``h`` is the fixed substep of the fixed-step methods and the initial step of the adaptive
    ones; ``rtol``/``atol`` are the error tolerances of the adaptive methods and the Newton
    tolerances of the implicit ones; ``rho_inf`` is used by "genalpha" only. Unknown options
    raise TypeError naming them; out-of-range values raise ValueError naming the field.
    """
    try:
        cls = REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown integration method {name!r}; allowed: "
                         f"{', '.join(REGISTRY)}") from None
    return cls(model, t0, y0, u=u, h=h, rtol=rtol, atol=atol, rho_inf=rho_inf, **options)
