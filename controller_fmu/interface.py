"""The FMU interface of the controller, ``PDLowPass``: one table of its variables.

The counterpart of :mod:`plant_fmu.interface` (:mod:`fmu_common.variables` says what the table
feeds). The
parameters are the fields of :class:`~controller_fmu.pd_lowpass.ControllerParams`, whose defaults
(the PD of the paper and the robust low-pass filter chosen by ``flexpend design``) are the start
values.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from fmu_common.variables import (ModelInfo, Offers, Variable, independent, parameter,
                                  real_input, real_local, real_output)

from .pd_lowpass import SAMPLED_FIELDS, ControllerParams

__all__ = ["VARIABLES", "MODEL", "SENSORS", "STATES", "MAX_OUTPUT_DERIVATIVE_ORDER", "OFFERS",
           "ControllerFmu", "CONTROLLER_FMUS", "controller_fmu_name", "SAMPLED_START"]

#: Model Exchange (the native FMUs only): the filter state xc' = Af xc + Bf e (pd_lowpass.py),
#: xc_1 the filter's output, xc_2 its rate (order 2); states beyond the filter order stay 0 with
#: derivative 0.
STATES = ("xc_1", "xc_2")
#: The highest order of the exact output derivatives of the native FMUs: F_c's first four, from
#: the filter's equations differentiated with the error signal's value and first two derivatives
#: (the inputs and input derivatives set now; the sensors' polynomial is of degree 2). The
#: Hermite coupling (``master.coupling = "hermite"``) reads all four.
MAX_OUTPUT_DERIVATIVE_ORDER = 4
#: What the native PDLowPass offers at every parameter value (fmu_common.variables.Offers).
OFFERS = Offers(output_derivative_order=MAX_OUTPUT_DERIVATIVE_ORDER)

#: The sensors the controller reads: name -> (description, unit, unit of the 1st and 2nd time
#: derivative).
SENSORS = {
    "phi_o": ("tip tangent angle from the upward vertical", "rad", "rad/s", "rad/s2"),
    "omega_o": ("rate of phi_o", "rad/s", "rad/s2", "rad/s3"),
    "x_o": ("cart position", "m", "m/s", "m/s2"),
}

#: the parameters: name -> (description, unit), from the record's fields (fmu_common.checks.Param)
_PARAMS = {f.name: (f.metadata["param"].meaning, f.metadata["param"].unit)
           for f in dataclasses.fields(ControllerParams) if f.name not in SAMPLED_FIELDS}
_SAMPLED = {f.name: (f.metadata["param"].meaning, f.metadata["param"].unit)
            for f in dataclasses.fields(ControllerParams) if f.name in SAMPLED_FIELDS}
_DEFAULTS = {f.name: f.default for f in dataclasses.fields(ControllerParams)}
_DER_INITIAL = (*SENSORS, "kp", "kd", "kx", "filter_order", "cutoff", "filter_damping")

#: The table, in value-reference order: the sensors, their first and second time derivatives
#: (FMI's input derivatives as variables), the force, the parameters, the native FMUs'
#: Model-Exchange locals, FMI 3.0's ``time``, then the sampled controller's parameters. A new
#: variable goes at the end, so that no existing value reference changes
#: (:mod:`fmu_common.variables`).
VARIABLES: tuple[Variable, ...] = (
    *(real_input(n, d, u) for n, (d, u, _, _) in SENSORS.items()),
    *(real_input(f"d{n}", f"time derivative of {n} at the start of the step (polynomial input; "
                          f"0: held)", du, n, 1) for n, (_, _, du, _) in SENSORS.items()),
    *(real_input(f"d2{n}", f"second time derivative of {n} at the start of the step", d2u, n, 2)
      for n, (_, _, _, d2u) in SENSORS.items()),
    # direct feedthrough (only with filter_order = 0, but the parameter is set at run time)
    real_output("F_c", "force on the cart", "N", depends_on=tuple(SENSORS),
                initial_depends_on=(*SENSORS, "kp", "kd", "kx", "filter_order", "force_limit")),
    *(parameter(n, _DEFAULTS[n], d, u, f"controller.{n}") for n, (d, u) in _PARAMS.items()),
    # Model Exchange: the filter state and its derivatives (no event indicators: the saturation
    # acts on the output alone, which stays continuous in time; see docs/fmus.md)
    real_local("xc_1", "filter state 1: the filtered error signal (state; nominal: the "
                       "smaller of |kp| x 1 rad and force_limit)", "N", state=True),
    real_local("xc_2", "filter state 2: the rate of xc_1 (order 2; state; nominal: cutoff "
                       "times the nominal of xc_1)", "N/s", state=True),
    real_local("der(xc_1)", "time derivative of xc_1", "N/s", der_of="xc_1",
               depends_on=tuple(SENSORS), state_depends_on=STATES,
               initial_depends_on=_DER_INITIAL),
    real_local("der(xc_2)", "time derivative of xc_2", "N/s2", der_of="xc_2",
               depends_on=tuple(SENSORS), state_depends_on=STATES,
               initial_depends_on=_DER_INITIAL),
    independent("time", "simulation time", "s"),
    *(parameter(n, _DEFAULTS[n], d, u, f"controller.{n}") for n, (d, u) in _SAMPLED.items()),
)
# F_c = -sat(xc_1) in Model Exchange (filter order 0: -sat(e), the inputs)
VARIABLES = tuple(dataclasses.replace(v, state_depends_on=("xc_1",)) if v.name == "F_c" else v
                  for v in VARIABLES)

MODEL = ModelInfo(
    name="PDLowPass",
    description=("PD on the tip angle and rate (plus an optional cart-position term) followed by "
                 "a unit-DC-gain low-pass filter of order 0, 1 or 2, discretised exactly over "
                 "each communication step"),
    version="0.2.0", start_time=0.0, stop_time=10.0, step_size=1e-3)


# ---- One native controller FMU per law's family (as the plant's rung families) ---------------
#: The sample period the sampled FMU starts with (s): a positive one, as its clock needs.
SAMPLED_START = 1e-3


@dataclass(frozen=True)
class ControllerFmu:
    """One native controller FMU: the continuous controller (``sample_period = 0``; Model
    Exchange, directional and output derivatives) or the sampled one (``sample_period > 0``;
    co-simulation on the ticks' grid, nothing else: its force is piecewise constant). Each
    refuses the other's sample periods, naming the FMU that runs them; both keep every value
    reference of :data:`VARIABLES`."""

    name: str
    sampled: bool
    offers: Offers
    summary: str

    @property
    def variables(self) -> tuple:
        if not self.sampled:
            return VARIABLES
        return tuple(dataclasses.replace(
            v, start=SAMPLED_START,
            description=f"{v.description}; this FMU runs sample_period > 0, PDLowPass runs 0")
            if v.name == "sample_period" else v for v in VARIABLES)

    @property
    def model(self) -> ModelInfo:
        return dataclasses.replace(MODEL, name=self.name, description=self.summary)


CONTROLLER_FMUS = {f.name: f for f in (
    ControllerFmu("PDLowPass", False, OFFERS, MODEL.description),
    ControllerFmu("PDLowPassSampled", True,
                  Offers(model_exchange=False, directional_derivatives=False,
                         output_derivative_order=0, interpolates_inputs=False),
                  "The PD + low-pass controller as it runs on hardware: it samples the tip "
                  "angle and rate every sample_period, computes the force by the filter's "
                  "difference equation (tustin or zoh) and holds it from delay after the "
                  "sample on; co-simulation on a grid that lands on every sample and every "
                  "sample + delay"),
)}


def controller_fmu_name(params) -> str:
    """The native controller FMU that runs the ControllerParams ``params``."""
    return "PDLowPassSampled" if params.sample_period > 0 else "PDLowPass"
