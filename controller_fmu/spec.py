"""The controller's specification: which law a parameter record asks for.

The counterpart of :func:`plant_fmu.dynamics.model_for`: the host (studies, references,
stability maps, the design) obtains the controller's model of a record with :func:`model_for`
and never names a model class, so a new law is a parameter record and a model class here, listed
in :data:`LAWS`. A model offers ``params``, ``nx`` (the length of its state),
``state_space() -> (A, B, C, D)`` (``xc' = A xc + B y``, ``F_c = C xc + D y`` before any
saturation, ``y = [x_o, phi_o, omega_o]``), ``initial_state()``, ``error_signal(y)``,
``output(xc, y)``, ``discretize(h)`` and ``discretize_polynomial(h)``
(:class:`~controller_fmu.pd_lowpass.PDLowPassModel` is the one law today).
"""
from __future__ import annotations

from .pd_lowpass import ControllerParams, PDLowPassModel

__all__ = ["LAWS", "model_for", "model_classes"]

#: The controller laws: the type of a parameter record -> the class of its model.
LAWS = {ControllerParams: PDLowPassModel}


def model_for(params):
    """The model of the controller that ``params`` (a parameter record of :data:`LAWS`) sets.
    A new model each call (its discretisations are cached on it). TypeError for any other
    type."""
    law = LAWS.get(type(params))
    if law is None:
        raise TypeError(f"controller parameters of type {type(params).__name__} are not "
                        f"allowed; allowed: {', '.join(t.__name__ for t in LAWS)}")
    return law(params)


def model_classes() -> tuple:
    """The classes of every controller law's model, in the order of :data:`LAWS`."""
    return tuple(LAWS.values())
