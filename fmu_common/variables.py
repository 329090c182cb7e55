"""The variable table of an FMU: one :class:`Variable` per FMU variable, in value-reference order.

Each model describes its FMU in one table (``plant_fmu.interface.VARIABLES``,
``controller_fmu.interface.VARIABLES``). From it the pythonfmu slave registers its variables
(the value reference of a variable is its position in the table, as pythonfmu numbers them in
registration order), every ``modelDescription.xml`` is written, the native FMUs' C table is
generated, and the host maps a scene's keys to the FMU's start values (:func:`start_values`).
Standard library only: this module ships in the FMUs.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["Variable", "ModelInfo", "Offers", "CAUSALITIES", "TYPES", "parameter", "real_input",
           "real_output", "real_local", "independent", "native_variables", "python_variables",
           "python_entries", "independent_variable", "states", "derivatives", "event_indicators",
           "by_name", "value_references", "parameter_defaults", "start_values"]

#: "local": a variable of the native FMUs' Model Exchange interface only (a continuous state
#: that is no output, a state derivative, an event indicator); see ``Variable.me_only``.
#: "independent": FMI 3.0's ``time``, which only the native FMUs' FMI 3.0 descriptions declare:
#: it is in the table so that it keeps its value reference when variables are appended after it.
CAUSALITIES = ("parameter", "input", "output", "local", "independent")
TYPES = {float: "Real", int: "Integer", bool: "Boolean", str: "String"}


@dataclass(frozen=True)
class Variable:
    """One FMU variable.

    ``start`` is the start value of parameters and inputs (None for outputs, which are
    calculated). ``scene_key`` is the scene key whose value sets the variable (None: no key).
    ``depends_on`` lists, for an output, the inputs it depends on directly; ``initial_depends_on``
    the inputs and parameters its initial value depends on. ``derivative_of`` names the input
    whose time derivative of order ``derivative_order`` this input is: FMI's input derivatives as
    variables, which only the pythonfmu FMUs have (the native FMUs take them through
    ``fmi2SetRealInputDerivatives`` and leave these variables out, keeping every other variable's
    value reference).

    Model Exchange (the native FMUs only). ``state``: the variable is a continuous state (its
    position among the states is its position among the table's states). ``der_of``: this local
    is the time derivative of the state of that name. ``state_depends_on``: the states an output
    or a derivative depends on (its ``depends_on`` lists the inputs). ``event_indicator``: a local
    that is an event indicator. ``me_only``: the variable exists in the native FMUs only: the
    pythonfmu FMUs (co-simulation only) leave it out.
    """

    name: str
    causality: str
    type: str
    description: str
    unit: str | None = None
    start: object = None
    variability: str = "continuous"
    scene_key: str | None = None
    depends_on: tuple = ()
    initial_depends_on: tuple = ()
    derivative_of: str | None = None
    derivative_order: int = 0
    state: bool = False
    der_of: str | None = None
    state_depends_on: tuple = ()
    event_indicator: bool = False
    me_only: bool = False

    def __post_init__(self):
        if self.causality not in CAUSALITIES:
            raise ValueError(f"{self.name}: causality {self.causality!r}; allowed: {CAUSALITIES}")
        if self.type not in TYPES.values():
            raise ValueError(f"{self.name}: type {self.type!r}; allowed: {list(TYPES.values())}")
        if (self.start is None) != (self.causality in ("output", "local", "independent")):
            raise ValueError(f"{self.name}: parameters and inputs have a start value, outputs, "
                             f"locals and the independent variable none")
        if self.causality == "local" and not self.me_only:
            raise ValueError(f"{self.name}: a local is a Model-Exchange variable (me_only)")

    @property
    def initial(self) -> str | None:
        """FMI's ``initial`` attribute: outputs and locals are calculated, parameters exact."""
        return {"output": "calculated", "local": "calculated",
                "parameter": "exact"}.get(self.causality)


@dataclass(frozen=True)
class ModelInfo:
    """What a ``modelDescription.xml`` says of the model besides its variables."""

    name: str
    description: str
    version: str
    start_time: float
    stop_time: float
    step_size: float


@dataclass(frozen=True)
class Offers:
    """What a native FMU offers, declared in its ``modelDescription.xml`` and honoured at every
    parameter value it accepts (docs/fmus.md, "One FMU per rung family"): the Model Exchange
    interface (besides co-simulation, which every FMU has), directional derivatives, exact
    output derivatives up to ``output_derivative_order`` (0: none), and input derivatives."""

    model_exchange: bool = True
    directional_derivatives: bool = True
    output_derivative_order: int = 2
    #: FMI 2.0 co-simulation's canInterpolateInputs: the FMU follows input derivatives over a
    #: step (the sampled controller samples values at its ticks: it does not)
    interpolates_inputs: bool = True


def parameter(name, default, description, unit=None, scene_key=None) -> Variable:
    """A fixed parameter typed by its default."""
    return Variable(name, "parameter", TYPES[type(default)], description, unit, default,
                    variability="fixed", scene_key=scene_key)


def real_input(name, description, unit, derivative_of=None, order=0) -> Variable:
    return Variable(name, "input", "Real", description, unit, 0.0, derivative_of=derivative_of,
                    derivative_order=order)


def real_output(name, description, unit, depends_on=(), initial_depends_on=()) -> Variable:
    return Variable(name, "output", "Real", description, unit, None, depends_on=depends_on,
                    initial_depends_on=initial_depends_on)


def real_local(name, description, unit, *, state=False, der_of=None, depends_on=(),
               state_depends_on=(), initial_depends_on=(), event_indicator=False) -> Variable:
    """A Model-Exchange local of the native FMUs: a state, a state derivative or an event
    indicator."""
    return Variable(name, "local", "Real", description, unit, None, depends_on=depends_on,
                    initial_depends_on=initial_depends_on, state=state, der_of=der_of,
                    state_depends_on=state_depends_on, event_indicator=event_indicator,
                    me_only=True)


def independent(name, description, unit) -> Variable:
    """FMI 3.0's independent variable (``time``), which the native FMUs' FMI 3.0 descriptions
    declare at its position in the table."""
    return Variable(name, "independent", "Real", description, unit, None)


def python_entries(table) -> list:
    """``[(value reference, Variable)]`` of a pythonfmu FMU (co-simulation, FMI 2.0): the table
    without the native FMUs' Model-Exchange variables (``me_only``) and ``time``, each variable
    at its value reference (its position) in the whole table."""
    return [(vr, v) for vr, v in enumerate(table)
            if not v.me_only and v.causality != "independent"]


def python_variables(table) -> list:
    """The variables of a pythonfmu FMU, in value-reference order (:func:`python_entries`)."""
    return [v for _, v in python_entries(table)]


def independent_variable(table) -> tuple:
    """``(value reference, Variable)`` of the table's independent variable (``time``)."""
    found = [(vr, v) for vr, v in enumerate(table) if v.causality == "independent"]
    if len(found) != 1:
        raise ValueError(f"a table has one independent variable (time), not {len(found)}")
    return found[0]


def states(table) -> list:
    """The continuous states' names in the order the FMUs declare them: the order of their
    derivatives in the table."""
    out = [v.der_of for v in table if v.der_of is not None]
    if not out:                          # a co-simulation-only table (pythonfmu): no states
        return []
    if sorted(out) != sorted(v.name for v in table if v.state):
        raise ValueError("every state needs one derivative, every derivative a state")
    return out


def derivatives(table) -> list:
    """The state derivatives' names, in the order of their states."""
    return [v.name for v in table if v.der_of is not None]


def event_indicators(table) -> list:
    return [v.name for v in table if v.event_indicator]


def native_variables(table, model_exchange: bool = True) -> list:
    """``[(value reference, Variable)]`` of a native FMU: the table without the input-derivative
    variables (``derivative_of``) and ``time`` (which the FMI 3.0 description adds on its own,
    :func:`independent_variable`), each variable at its value reference in the whole table.
    ``model_exchange`` False (an FMU that offers co-simulation alone): without the Model-Exchange
    locals either, and with no variable marked a state (the value references of the others
    stay)."""
    out = [(vr, v) for vr, v in enumerate(table)
           if v.derivative_of is None and v.causality != "independent"]
    if not model_exchange:
        out = [(vr, replace(v, state=False, state_depends_on=())) for vr, v in out
               if not v.me_only]
    return out


def by_name(table) -> dict:
    return {v.name: v for v in table}


def value_references(table) -> dict:
    """name -> value reference (the position in the table)."""
    return {v.name: i for i, v in enumerate(table)}


def parameter_defaults(table) -> dict:
    """name -> default of every parameter."""
    return {v.name: v.start for v in table if v.causality == "parameter"}


def start_values(config: dict, table) -> dict:
    """FMU start values from a scene configuration (dotted keys): every parameter whose scene
    key is in ``config``."""
    return {v.name: config[v.scene_key] for v in table
            if v.causality == "parameter" and v.scene_key in config}
