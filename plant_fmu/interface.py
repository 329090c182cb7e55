"""The FMU interface of the plant, ``FlexiblePendulum``: one table of its variables.

This table is the one place where the FMU's variables are described: name, causality,
variability, type, start value, unit, description, and which scene key sets it. From it

* the pythonfmu slave (:mod:`plant_fmu.fmu`) registers its variables (the value reference of a
  variable is its position in the table, as pythonfmu numbers them in registration order);
* every ``modelDescription.xml`` is written (:mod:`orchestration.export.model_description`);
* the master maps a scene's keys to the FMU's start values (:func:`start_values`).

The table's type, :class:`fmu_common.variables.Variable`, is every model's. The module needs
nothing beyond the standard library and the parameter records, so that it ships in the FMUs and
serves the build alike.

Units are SI. The modal coordinates ``eta_j`` belong to mass-normalised modes
(``integral rhoA N_j^2 ds = 1``): ``N_j`` is in ``1/sqrt(kg)`` and ``eta_j`` in ``m sqrt(kg)``, so
that the deflection ``w = N eta`` is in metres.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from fmu_common.variables import (ModelInfo, Offers, Variable, independent, parameter,
                                  real_input, real_local, real_output)

from .params import PlantParams

__all__ = ["VARIABLES", "MODEL", "FMU_SETTINGS", "FIDELITIES", "OUTPUTS", "N_ETA_OUTPUTS",
           "INITIAL_STATE", "STATES", "MAX_OUTPUT_DERIVATIVE_ORDER", "PlantFmu", "PLANT_FMUS",
           "plant_fmu_name"]

FIDELITIES = ("nonlinear", "linear", "exact", "stiffened")

#: The FMU's settings beyond :class:`PlantParams`, with their defaults. The default integrator is
#: RK4 with four substeps per millisecond: at n_modes = 4 (largest |eigenvalue| 2512 rad/s)
#: h|lambda| = 0.63, far inside RK4's stability bound 2.83 (stable up to n_modes = 8 at the
#: default parameters); over a 1 ms communication step the sensors are within ~1e-5 (omega_o) and
#: ~4e-8 (phi_o) of a tight reference, at 4 x 4 right-hand sides per millisecond.
FMU_SETTINGS = {
    "fidelity": "nonlinear",
    "integrator": "rk4",
    "step": 2.5e-4,
    "rtol": 1e-6,
    "atol": 1e-9,
    "phi_limit": math.pi / 2,
    "energy_limit": 1e6,
}
#: The initial state (the beam undeformed): FMU parameter -> (scene key, default). The FMU alone
#: starts at the upright rest state (an equilibrium); a scene (or an SSP export of it) sets the
#: paper's pi/6.
INITIAL_STATE = {
    "phi0": ("initial.phi", 0.0),
    "x0": ("initial.x", 0.0),
    "phi_dot0": ("initial.phi_dot", 0.0),
    "x_dot0": ("initial.x_dot", 0.0),
}

#: PlantParams field -> (description, unit), from the record's fields (fmu_common.checks.Param);
#: the damping law has its own, longer description (_DAMPING)
_PARAMS = {f.name: (f.metadata["param"].meaning, f.metadata["param"].unit)
           for f in dataclasses.fields(PlantParams) if f.name != "damping"}
#: the damping law (plant_fmu.params.DAMPING_LAWS), after the table's first 72 variables
_DAMPING = ("damping law: modal (the ratio zeta in every cantilever mode, D = 2 zeta omega_j) or "
            "kelvin-voigt (material damping of the bending stiffness, beta = 2 zeta / omega_1: "
            "the ratio zeta omega_j / omega_1 in mode j)")
_SETTINGS = {
    "fidelity": ("nonlinear or linear (linearised at the upright rest state); stiffened: "
                 "nonlinear with the motion-dependent geometric stiffness; exact: the "
                 "geometrically exact beam on n_elements elements (the native "
                 "FlexiblePendulumExact FMU alone)",
                 None),
    "integrator": ("integration method: dopri5, euler, exponential, genalpha, radau, rk4, "
                   "symplectic_euler", None),
    "step": ("internal substep of the fixed-step methods (initial step of the adaptive ones)", "s"),
    "rtol": ("relative tolerance of the adaptive and implicit methods", None),
    "atol": ("absolute tolerance of the adaptive and implicit methods", None),
    "phi_limit": ("divergence bound on |phi| (inf, or the largest double: none)", "rad"),
    "energy_limit": ("divergence bound on |energy| (inf, or the largest double: none)", "J"),
}
_INITIAL = {
    "phi0": ("initial angle phi of the (undeformed) beam from the upward vertical", "rad"),
    "x0": ("initial cart position", "m"),
    "phi_dot0": ("initial angular rate", "rad/s"),
    "x_dot0": ("initial cart velocity", "m/s"),
}

#: Modal coordinates exposed as outputs (enough to draw the beam's shape).
N_ETA_OUTPUTS = 8
ETA_UNIT = "m.kg0.5"

#: Outputs, in registration order: name -> (description, unit, initial value depends on).
_ENERGY_DEPS = tuple(f for f in (*(f.name for f in dataclasses.fields(PlantParams)), "fidelity",
                                 *INITIAL_STATE) if f != "n_elements")
OUTPUTS = {
    "x_o": ("cart position", "m", ("x0",)),
    "x_dot": ("cart velocity", "m/s", ("x_dot0",)),
    "phi_o": ("angle of the beam's tip tangent from the upward vertical (counter-clockwise)",
              "rad", ("phi0",)),
    "omega_o": ("rate of phi_o", "rad/s", ("phi_dot0",)),
    "tip_deflection": ("transverse deflection of the tip in the floating frame", "m", ()),
    "eta_1": ("first modal coordinate (mass-normalised modes; 0 when n_modes = 0)", ETA_UNIT, ()),
    "energy": ("total energy T + V", "J", _ENERGY_DEPS),
    "phi": ("rotation of the floating frame (the beam at the hinge) from the upward vertical",
            "rad", ("phi0",)),
    **{f"eta_{j}": (f"modal coordinate {j} (0 when n_modes < {j})", ETA_UNIT, ())
       for j in range(2, N_ETA_OUTPUTS + 1)},
}

_DEFAULTS = {f.name: f.default for f in dataclasses.fields(PlantParams)}

# ---- Model Exchange (the native FMUs only) -------------------------------------------------
#: The continuous states of Model Exchange, in the order the FMUs declare them: the generalised
#: coordinates of N_ETA_OUTPUTS modes (the largest n_modes Model Exchange takes), then their
#: rates. The states of modes beyond the instance's n_modes stay 0 with derivative 0.
_ETAS = tuple(f"eta_{j}" for j in range(1, N_ETA_OUTPUTS + 1))
_ETA_DOTS = tuple(f"eta_dot_{j}" for j in range(1, N_ETA_OUTPUTS + 1))
STATES = ("x_o", "phi", *_ETAS, "x_dot", "phi_dot", *_ETA_DOTS)
#: The highest order of the exact output derivatives of the native FMUs
#: (fpm_model_max_output_derivative_order; maxOutputDerivativeOrder).
MAX_OUTPUT_DERIVATIVE_ORDER = 2
#: Nominal values of the states (fmi2GetNominalsOfContinuousStates), physical scales computed
#: from the parameters at initialisation (docs/fmus.md).
_NOMINALS = {
    "x_o": "nominal L (the beam's length)",
    "phi": "nominal 1 rad",
    "x_dot": "nominal sqrt(g L) (the pendulum's speed scale; L/s when g = 0)",
    "phi_dot": "nominal sqrt(g / L) (the pendulum's rate scale; 1/s when g = 0)",
    "eta": "nominal 0.01 L / |N_j(L)| (a tip deflection of 1 % of L)",
    "eta_dot": "nominal omega_j times the nominal of eta_j",
}
#: Structural dependencies (what the modal coupling gives; tests/export/test_native_me.py checks
#: them against the nonzero pattern of PlantModel.jacobian_numpy and output_jacobian_numpy at random
#: states): the accelerations depend on every state but x and x_dot, and on the force.
_ACC_STATES = ("phi", *_ETAS, "phi_dot", *_ETA_DOTS)
_OUTPUT_STATES = {
    "x_o": ("x_o",), "x_dot": ("x_dot",), "phi_o": ("phi", *_ETAS),
    "omega_o": (*_ETAS, "phi_dot", *_ETA_DOTS), "tip_deflection": _ETAS,
    "energy": tuple(s for s in STATES if s != "x_o"), "phi": ("phi",),
    **{e: (e,) for e in _ETAS},
}
#: the parameters the initial accelerations depend on
_ACC_INITIAL = tuple(f for f in (*(f.name for f in dataclasses.fields(PlantParams)), "fidelity",
                                 "phi0", "phi_dot0", "x_dot0"))


def _me_variables() -> tuple:
    """The Model-Exchange locals, after every other variable: the states that are no output
    (phi_dot, eta_dot_j), the derivatives der(<state>) in state order, and the event
    indicators."""
    rate = {"x_o": "x_dot", "phi": "phi_dot", **dict(zip(_ETAS, _ETA_DOTS))}
    unit = {"x_o": "m", "phi": "rad", "x_dot": "m/s", "phi_dot": "rad/s",
            **{e: ETA_UNIT for e in _ETAS}, **{e: ETA_UNIT + "/s" for e in _ETA_DOTS}}
    rate_unit = {"m": "m/s", "rad": "rad/s", ETA_UNIT: ETA_UNIT + "/s", "m/s": "m/s2",
                 "rad/s": "rad/s2", ETA_UNIT + "/s": ETA_UNIT + "/s2"}
    init = {"x_o": ("x_dot0",), "phi": ("phi_dot0",)}
    out = [real_local("phi_dot", f"angular rate of phi (state; {_NOMINALS['phi_dot']})", "rad/s",
                      state=True, initial_depends_on=("phi_dot0",))]
    out += [real_local(e, f"rate of modal coordinate {j} (state; {_NOMINALS['eta_dot']})",
                       ETA_UNIT + "/s", state=True)
            for j, e in enumerate(_ETA_DOTS, 1)]
    for s in STATES:
        if s in rate:                      # der(q) = qd
            out.append(real_local(f"der({s})", f"time derivative of {s}", rate_unit[unit[s]],
                                  der_of=s, state_depends_on=(rate[s],),
                                  initial_depends_on=init.get(s, ())))
        else:                              # the accelerations
            out.append(real_local(f"der({s})", f"time derivative of {s}", rate_unit[unit[s]],
                                  der_of=s, depends_on=("F_c",), state_depends_on=_ACC_STATES,
                                  initial_depends_on=("F_c", *_ACC_INITIAL)))
    out.append(real_local("phi_limit_indicator", "event indicator of the divergence bound: "
                          "1 - (phi/phi_limit)^2 (crosses 0 where |phi| reaches phi_limit)", None,
                          event_indicator=True, state_depends_on=("phi",),
                          initial_depends_on=("phi0", "phi_limit")))
    out.append(real_local("energy_limit_indicator", "event indicator of the divergence bound: "
                          "1 - (energy/energy_limit)^2 (crosses 0 where |energy| reaches "
                          "energy_limit)", None, event_indicator=True,
                          state_depends_on=_OUTPUT_STATES["energy"],
                          initial_depends_on=(*_ENERGY_DEPS, "energy_limit")))
    return tuple(out)


def _with_states(v: Variable) -> Variable:
    """An output as Model Exchange sees it: a state (x_o, x_dot, phi, eta_j) or not, and the
    states it depends on."""
    if v.causality != "output":
        return v
    note = _NOMINALS.get("eta" if v.name in _ETAS else v.name)
    return dataclasses.replace(
        v, state=v.name in STATES, state_depends_on=_OUTPUT_STATES[v.name],
        description=v.description + (f" (state; {note})" if v.name in STATES else ""))


#: The table, in value-reference order: inputs, outputs, parameters, the native FMUs'
#: Model-Exchange locals, FMI 3.0's ``time`` (value reference 71), then the variables added
#: since (``damping``, 72). A new variable goes at the end, so that no existing value reference
#: changes (:mod:`fmu_common.variables`).
VARIABLES: tuple[Variable, ...] = (
    real_input("F_c", "horizontal force on the cart (at the start of the step)", "N"),
    real_input("dF_c", "time derivative of F_c at the start of the step (polynomial input; "
                       "0: held)", "N/s", "F_c", 1),
    real_input("d2F_c", "second time derivative of F_c at the start of the step (polynomial "
                        "input)", "N/s2", "F_c", 2),
    *(real_output(n, d, u, (), deps) for n, (d, u, deps) in OUTPUTS.items()),
    *(parameter(n, _DEFAULTS[n], d, u, f"plant.{n}") for n, (d, u) in _PARAMS.items()),
    *(parameter(n, FMU_SETTINGS[n], d, u, f"plant.{n}") for n, (d, u) in _SETTINGS.items()),
    *(parameter(n, INITIAL_STATE[n][1], d, u, INITIAL_STATE[n][0])
      for n, (d, u) in _INITIAL.items()),
)
VARIABLES = (tuple(_with_states(v) for v in VARIABLES) + _me_variables()
             + (independent("time", "simulation time", "s"),
                parameter("damping", _DEFAULTS["damping"], _DAMPING, None, "plant.damping")))

_CART = "Cart with an elastic beam hinged on it (Tang & Ren 2009, corrected)"
_INPUT = "input: the force on the cart"
MODEL = ModelInfo(
    name="FlexiblePendulum",
    description=f"{_CART}: floating frame of reference with n_modes cantilever modes; {_INPUT}",
    version="0.2.0", start_time=0.0, stop_time=10.0, step_size=1e-3)


# ---- One native FMU per rung family --------------------------------------------------------
@dataclass(frozen=True)
class PlantFmu:
    """One native plant FMU: the rungs (``fidelity`` values) it runs, and what it offers at every
    one of them (its modelDescription's flags). Its table is :data:`VARIABLES` with its own
    ``fidelity`` (start: its first rung; the description names its rungs), so that every value
    reference is the same in every family; an FMU without Model Exchange declares no
    Model-Exchange local (:func:`fmu_common.variables.native_variables`)."""

    name: str
    fidelities: tuple
    offers: Offers
    summary: str

    @property
    def variables(self) -> tuple:
        rungs = "; ".join(f"{f} ({_RUNG_MEANING[f]})" for f in self.fidelities)
        others = ", ".join(f"{f.name} ({', '.join(f.fidelities)})" for f in PLANT_FMUS.values()
                           if f.name != self.name)
        fidelity = dataclasses.replace(
            _FIDELITY, start=self.fidelities[0],
            description=f"the rung this FMU runs: {rungs}; the other rungs are other FMUs: "
                        f"{others}")
        return tuple(fidelity if v.name == "fidelity" else v for v in VARIABLES)

    @property
    def model(self) -> ModelInfo:
        return dataclasses.replace(MODEL, name=self.name, description=self.summary)


_FIDELITY = next(v for v in VARIABLES if v.name == "fidelity")
_RUNG_MEANING = {"nonlinear": "n_modes cantilever modes in the floating frame",
                 "linear": "linearised at the upright rest state",
                 "stiffened": "nonlinear with the motion-dependent geometric stiffness",
                 "exact": "the geometrically exact beam on n_elements elements"}

#: The native plant FMUs, one per rung family: each declares only what it gives at each of its
#: rungs (docs/fmus.md, "One FMU per rung family"). The stiffened rung's kernel has no exact
#: Jacobian, so its FMU declares no derivatives; the exact beam steps implicitly inside its own
#: co-simulation step (Radau IIA), so its FMU offers co-simulation alone. The pythonfmu plant
#: (co-simulation, no derivatives) keeps the name FlexiblePendulum and runs the first three rungs.
PLANT_FMUS = {f.name: f for f in (
    PlantFmu("FlexiblePendulum", ("nonlinear", "linear"),
             Offers(output_derivative_order=MAX_OUTPUT_DERIVATIVE_ORDER),
             f"{MODEL.description} (the rungs nonlinear and linear)"),
    PlantFmu("FlexiblePendulumStiffened", ("stiffened",),
             Offers(directional_derivatives=False, output_derivative_order=0),
             f"{_CART}: floating frame of reference with n_modes cantilever modes and the "
             f"motion-dependent geometric stiffness (the stiffened rung); {_INPUT}; no "
             f"directional or output derivatives"),
    PlantFmu("FlexiblePendulumExact", ("exact",),
             Offers(model_exchange=False, directional_derivatives=False,
                    output_derivative_order=0),
             f"{_CART}: the geometrically exact beam on n_elements elements (the exact rung); "
             f"{_INPUT}; co-simulation only"),
)}
assert sorted(f for p in PLANT_FMUS.values() for f in p.fidelities) == sorted(FIDELITIES)


def plant_fmu_name(fidelity: str) -> str:
    """The native plant FMU that runs rung ``fidelity`` (a key of :data:`PLANT_FMUS`)."""
    for fmu in PLANT_FMUS.values():
        if fidelity in fmu.fidelities:
            return fmu.name
    raise ValueError(f"fidelity = {fidelity!r}; allowed: {', '.join(FIDELITIES)}")
