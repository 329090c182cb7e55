"""The variable table of an FMU: one :class:`Variable` per FMU variable, in value-reference order.

Each model describes its FMU in one table (``plant_fmu.interface.VARIABLES``,
``controller_fmu.interface.VARIABLES``). From it the pythonfmu slave registers its variables
(the value reference of a variable is its position in the table, as pythonfmu numbers them in
registration order), every ``modelDescription.xml`` is written, the native FMUs' C table is
generated, and the host maps a scene's keys to the FMU's start values (:func:`start_values`).
Standard library only: this module ships in the FMUs.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Variable", "ModelInfo", "CAUSALITIES", "TYPES", "parameter", "real_input",
           "real_output", "native_variables", "by_name", "value_references",
           "parameter_defaults", "start_values"]

CAUSALITIES = ("parameter", "input", "output")
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

    def __post_init__(self):
        if self.causality not in CAUSALITIES:
            raise ValueError(f"{self.name}: causality {self.causality!r}; allowed: {CAUSALITIES}")
        if self.type not in TYPES.values():
            raise ValueError(f"{self.name}: type {self.type!r}; allowed: {list(TYPES.values())}")
        if (self.start is None) != (self.causality == "output"):
            raise ValueError(f"{self.name}: parameters and inputs have a start value, outputs none")

    @property
    def initial(self) -> str | None:
        """FMI's ``initial`` attribute: outputs are calculated, parameters exact."""
        return {"output": "calculated", "parameter": "exact"}.get(self.causality)


@dataclass(frozen=True)
class ModelInfo:
    """What a ``modelDescription.xml`` says of the model besides its variables."""

    name: str
    description: str
    version: str
    start_time: float
    stop_time: float
    step_size: float


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


def native_variables(table) -> list:
    """``[(value reference, Variable)]`` of a native FMU: the table without the input-derivative
    variables (``derivative_of``), each variable at its value reference in the whole table."""
    return [(vr, v) for vr, v in enumerate(table) if v.derivative_of is None]


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
