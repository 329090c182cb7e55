"""``modelDescription.xml`` from the one table of variables of each model.

    TABLES["FlexiblePendulum"] -> (ModelInfo, variables)          (the pythonfmu FMUs)
    NATIVE["FlexiblePendulumExact"] -> (ModelInfo, variables, Offers)   (the native FMUs)
    fmi2_model_description(name, guid, ...) -> bytes      (pythonfmu and native FMUs)
    fmi3_model_description(name, token, ...) -> bytes     (native FMUs)

The tables are :mod:`plant_fmu.interface` and :mod:`controller_fmu.interface`; the value
reference of a variable is its position in its table, in every flavour (a flavour leaves out
the variables it has not). Units are declared in ``UnitDefinitions``
with their SI base units, start values are written exactly (``repr`` of the float, ``INF`` for
infinity in the pythonfmu FMUs; in the native FMUs an infinite start value, "no limit", is written
as the largest double, :data:`NO_LIMIT`), and ``ModelStructure`` carries the real dependencies of the outputs (pythonfmu writes
none, which makes importers see false algebraic loops).
"""
from __future__ import annotations

import datetime
import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from controller_fmu import interface as controller_interface
from fmu_common.variables import (derivatives, event_indicators, independent_variable,
                                  native_variables, parameter_defaults, python_entries, states)
from plant_fmu import interface as plant_interface

__all__ = ["TABLES", "NATIVE", "UNITS", "FMI3_TYPES", "fmi2_model_description",
           "fmi3_model_description", "xml_value", "generation_date", "NO_LIMIT", "state_nominals",
           "Clock", "CLOCKS", "CLOCK_VR_BASE"]

#: "No limit" (an infinite start value: force_limit, phi_limit, energy_limit) as the native FMUs'
#: descriptions write it: the largest double, 1.7976931348623157e+308. Every checker reads it
#: (fmpy validate, and both distributions of the FMI 2.0 VDM checker, whose "static" one stops on
#: ``INF``: XSD`POSITIVE_INFINITY is not in scope), and for the FMUs it means what infinity
#: means: no finite value exceeds it. Setting ``inf`` stays allowed.
NO_LIMIT = repr(sys.float_info.max)

#: model name -> (ModelInfo, table of variables): the pythonfmu FMUs
TABLES = {
    "FlexiblePendulum": (plant_interface.MODEL, plant_interface.VARIABLES),
    "PDLowPass": (controller_interface.MODEL, controller_interface.VARIABLES),
}
#: model name -> (ModelInfo, table of variables, what it offers): the native FMUs, the plant one
#: per rung family (plant_fmu.interface.PLANT_FMUS)
NATIVE = {
    **{name: (fmu.model, fmu.variables, fmu.offers)
       for name, fmu in plant_interface.PLANT_FMUS.items()},
    **{name: (fmu.model, fmu.variables, fmu.offers)
       for name, fmu in controller_interface.CONTROLLER_FMUS.items()},
}

#: The first value reference of the FMI 3.0 clocks: after every value reference of every table
#: (a table may grow by appending, fmu_common.variables, without moving a clock).
CLOCK_VR_BASE = 1000


@dataclass(frozen=True)
class Clock:
    """An FMI 3.0 clock of a native FMU, declared by its FMI 3.0 description only (FMI 2.0 has no
    clocks; the table of variables has no type for them). A time-based periodic input clock with
    ``intervalVariability = "fixed"`` and no ``intervalDecimal``: its interval is the parameter
    ``interval`` and its shift from the start time the parameter ``shift`` (None: 0), which the
    importer reads with ``fmi3GetIntervalDecimal`` and ``fmi3GetShiftDecimal`` in
    initialization mode (FMI 3.0, section 2.2.9, fixed periodic clocks). ``clocked``: the
    variables it clocks (their ``clocks`` attribute; they become ``discrete``); ``drives``: the
    outputs that depend on its activation besides its own (``ModelStructure``)."""

    name: str
    value_reference: int
    description: str
    interval: str
    shift: str | None
    clocked: tuple
    drives: tuple = ()


#: model name -> its clocks, in value-reference order (docs/fmus.md, "The sampled controller:
#: PDLowPassSampled"): the samples at t0 + k T and the force at t0 + tau + k T
CLOCKS = {
    "PDLowPassSampled": (
        Clock("sample_clock", CLOCK_VR_BASE,
              "the samples of the sensors: ticks at t0 + k sample_period", "sample_period", None,
              ("phi_o", "omega_o", "x_o"), drives=("F_c",)),
        Clock("force_clock", CLOCK_VR_BASE + 1,
              "the force of each sample takes over: ticks at t0 + delay + k sample_period",
              "sample_period", "delay", ("F_c",)),
    ),
}

#: unit -> its SI base-unit exponents (FMI's BaseUnit); None: not a product of integer powers
#: (declared by name only).
UNITS = {
    "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1},
    "m/s": {"m": 1, "s": -1}, "m/s2": {"m": 1, "s": -2},
    "rad/s": {"rad": 1, "s": -1}, "rad/s2": {"rad": 1, "s": -2}, "rad/s3": {"rad": 1, "s": -3},
    "N": {"kg": 1, "m": 1, "s": -2}, "N/s": {"kg": 1, "m": 1, "s": -3},
    "N/s2": {"kg": 1, "m": 1, "s": -4}, "J": {"kg": 1, "m": 2, "s": -2},
    "Pa": {"kg": 1, "m": -1, "s": -2}, "kg/m3": {"kg": 1, "m": -3},
    "N.m2": {"kg": 1, "m": 3, "s": -2}, "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1},
    "N.s/rad": {"kg": 1, "m": 1, "s": -1, "rad": -1}, "N/m": {"kg": 1, "s": -2},
    "m.kg0.5": None,          # modal coordinate of a mass-normalised mode: m sqrt(kg)
    "m.kg0.5/s": None, "m.kg0.5/s2": None,
}


def xml_value(value, native: bool = False) -> str:
    """A start value as FMI writes it: exact floats, ``INF``/``-INF`` (a native FMU's
    description: :data:`NO_LIMIT` for ``inf``), ``true``/``false``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            if native:
                return NO_LIMIT if value > 0 else "-" + NO_LIMIT
            return "INF" if value > 0 else "-INF"
        return repr(value)
    return str(value)


def generation_date() -> str:
    """UTC now as the schema's ``xs:dateTime`` with ``Z`` (pythonfmu writes ``+00:00``, which the
    FMI 2.0 VDM checker rejects)."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _units(table) -> list[str]:
    used = sorted({v.unit for v in table if v.unit})
    unknown = [u for u in used if u not in UNITS]
    if unknown:
        raise ValueError(f"units {unknown} have no entry in UNITS")
    return used


def _entries(table, native: bool, model_exchange: bool = True) -> list:
    """``[(value reference, Variable)]`` written: a pythonfmu FMU's (co-simulation only) or a
    native FMU's (without the input-derivative variables; without the Model-Exchange locals when
    it offers co-simulation alone), each variable at its value reference."""
    if native:
        return native_variables(table, model_exchange)
    return python_entries(table)


def _me_structure(entries):
    """What Model Exchange adds to a native FMU's description: the state of each derivative
    (name -> name), the derivatives in state order, the event indicators."""
    table = [v for _, v in entries]
    return ({v.name: v.der_of for v in table if v.der_of}, derivatives(table),
            event_indicators(table), states(table))


def state_nominals(table) -> dict:
    """``{state: nominal}`` a native FMU's description declares (the ``nominal`` attribute of
    each continuous state): what ``fmi*GetNominalsOfContinuousStates`` returns after
    initialisation at the table's start values, from the model's Python twin of its C formulas
    (:func:`plant_fmu.nominals.state_nominals`, :func:`controller_fmu.nominals.state_nominals`;
    tests/export/test_native_nominals.py compares them with the binaries). The run-time call
    follows the parameters set, as the standard allows (the attribute is the value at the start
    values). {} for a table without states.

    The derivatives get no ``nominal``: the importers we know (fmpy's CVode, FMI4j, fmi-sim,
    libcosim, flexpend's model-exchange master) weight the integration error by the states'
    nominals only, and the scale of an acceleration is not a constant of the model (at an event
    it is many times the typical one), so a declared value would tell a solver that scales its
    residuals by it less than the states' nominals already do."""
    names = states(table)
    if not names:
        return {}
    from controller_fmu import nominals as controller_nominals
    from plant_fmu import nominals as plant_nominals
    for interface, module in ((plant_interface, plant_nominals),
                              (controller_interface, controller_nominals)):
        if tuple(names) == tuple(interface.STATES):
            found = module.state_nominals(parameter_defaults(table))
            return {n: found[n] for n in names}
    raise ValueError(f"no nominals are known for the continuous states {names}")


def _dependencies(v, native):
    """The variables an output or derivative depends on: its inputs, and in a native FMU (Model
    Exchange) its states."""
    return (*v.depends_on, *(v.state_depends_on if native else ()))


def _initial_unknowns(entries, native):
    """Outputs, then (native) the states and derivatives that are calculated, in table order."""
    der = {v.der_of for _, v in entries if v.der_of} if native else set()
    return [v for _, v in entries if v.causality == "output" or
            (native and (v.der_of is not None or (v.name in der and v.initial)))]


def _header(root, model, units, log_categories, used):
    """UnitDefinitions, LogCategories and DefaultExperiment (the same in FMI 2.0 and 3.0)."""
    node = ET.SubElement(root, "UnitDefinitions") if used else None
    for u in used:
        unit = ET.SubElement(node, "Unit", name=u)
        if units[u]:
            ET.SubElement(unit, "BaseUnit", {k: str(e) for k, e in units[u].items()})
    if log_categories:
        cats = ET.SubElement(root, "LogCategories")
        for n, d in log_categories.items():
            ET.SubElement(cats, "Category", name=n, description=d)
    ET.SubElement(root, "DefaultExperiment", startTime=repr(model.start_time),
                  stopTime=repr(model.stop_time), stepSize=repr(model.step_size))


def fmi2_model_description(name: str, guid: str, *, generation_tool: str,
                           co_simulation: dict, log_categories: dict | None = None,
                           table=None, model=None, native: bool = False,
                           model_exchange: dict | None = None) -> bytes:
    """The FMI 2.0 ``modelDescription.xml`` of model ``name`` (a key of :data:`TABLES`).

    ``co_simulation``: the attributes of ``<CoSimulation>`` (modelIdentifier, capability flags,
    as strings); ``model_exchange``: those of ``<ModelExchange>`` (a native FMU: both
    interfaces); ``log_categories``: name -> description; ``native``: a native FMU's variables
    (:func:`fmu_common.variables.native_variables`: with the Model-Exchange locals, states,
    derivatives and event indicators)."""
    if table is None:
        model, table = TABLES[name]
    entries = _entries(table, native, model_exchange is not None)
    _, ders, indicators, _ = _me_structure(entries) if native else ({}, [], [], [])
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": model.name, "guid": guid,
        "description": model.description, "version": model.version,
        "generationTool": generation_tool, "generationDateAndTime": generation_date(),
        "variableNamingConvention": "structured",
        "numberOfEventIndicators": str(len(indicators))})
    if model_exchange is not None:
        ET.SubElement(root, "ModelExchange", model_exchange)
    ET.SubElement(root, "CoSimulation", co_simulation)
    _header(root, model, UNITS, log_categories, _units([v for _, v in entries]))
    mv = ET.SubElement(root, "ModelVariables")
    index = {v.name: i + 1 for i, (_, v) in enumerate(entries)}
    nominals = state_nominals([v for _, v in entries]) if native else {}
    for i, (vr, v) in enumerate(entries):
        attrs = {"name": v.name, "valueReference": str(vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.initial:
            attrs["initial"] = v.initial
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        typ = {}
        if v.type == "Real" and v.unit:
            typ["unit"] = v.unit
        if v.name in nominals:
            typ["nominal"] = repr(nominals[v.name])
        if v.der_of is not None:
            typ["derivative"] = str(index[v.der_of])
        if v.start is not None:
            typ["start"] = xml_value(v.start, native)
        ET.SubElement(sv, v.type, typ)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [v for _, v in entries if v.causality == "output"]
    byname = {v.name: v for _, v in entries}

    def deps(names):
        return " ".join(str(index[n]) for n in sorted(set(names), key=index.get))

    if outputs:
        node = ET.SubElement(structure, "Outputs")
        for v in outputs:
            ET.SubElement(node, "Unknown", index=str(index[v.name]),
                          dependencies=deps(_dependencies(v, native)))
    if ders:
        node = ET.SubElement(structure, "Derivatives")
        for d in ders:
            ET.SubElement(node, "Unknown", index=str(index[d]),
                          dependencies=deps(_dependencies(byname[d], native)))
    initial = _initial_unknowns(entries, native)
    if initial:
        node = ET.SubElement(structure, "InitialUnknowns")
        for v in initial:
            ET.SubElement(node, "Unknown", index=str(index[v.name]),
                          dependencies=deps(v.initial_depends_on))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


#: FMI 3.0 type names of the table's types
FMI3_TYPES = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}


def fmi3_model_description(name: str, token: str, *, generation_tool: str,
                           co_simulation: dict, log_categories: dict | None = None,
                           table=None, model=None, model_exchange: dict | None = None,
                           clocks=None) -> bytes:
    """The FMI 3.0 ``modelDescription.xml`` of the native FMU of model ``name``: the same variables
    and value references as its FMI 2.0 description, FMI 3.0 types (Float64, Int32), dependencies
    by value reference, and the independent variable ``time`` at its reference in the table.
    ``clocks``: its :class:`Clock` s (None: ``CLOCKS[name]``, if any), declared after every other
    variable; the variables they clock get the ``clocks`` attribute and ``discrete``
    variability."""
    if table is None:
        model, table, _ = NATIVE[name]
    if clocks is None:
        clocks = CLOCKS.get(name, ())
    entries = _entries(table, True, model_exchange is not None)
    if clocks and not min(c.value_reference for c in clocks) > max(vr for vr, _ in entries):
        raise ValueError(f"the clocks of {name} must come after every value reference")
    clocked_by = {}
    for c in clocks:
        for n in c.clocked:
            clocked_by.setdefault(n, []).append(c.value_reference)
    _, ders, indicators, _ = _me_structure(entries)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": model.name, "instantiationToken": token,
        "description": model.description, "version": model.version,
        "generationTool": generation_tool, "generationDateAndTime": generation_date(),
        "variableNamingConvention": "structured"})
    if model_exchange is not None:
        ET.SubElement(root, "ModelExchange", model_exchange)
    ET.SubElement(root, "CoSimulation", co_simulation)
    _header(root, model, UNITS, log_categories,
            sorted({"s", *_units([v for _, v in entries])}))     # "s": the unit of time
    mv = ET.SubElement(root, "ModelVariables")
    vrs = {v.name: vr for vr, v in entries}
    nominals = state_nominals([v for _, v in entries])
    time_vr, time = independent_variable(table)
    ET.SubElement(mv, "Float64", {"name": time.name, "valueReference": str(time_vr),
                                  "causality": "independent", "variability": "continuous",
                                  "description": time.description, "unit": time.unit})
    for vr, v in entries:
        attrs = {"name": v.name, "valueReference": str(vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.initial:
            attrs["initial"] = v.initial
        if v.name in clocked_by:                  # a clocked variable is discrete (2.4.7.4)
            attrs["variability"] = "discrete"
            attrs["clocks"] = " ".join(map(str, clocked_by[v.name]))
        if v.type == "Real" and v.unit:
            attrs["unit"] = v.unit
        if v.name in nominals:
            attrs["nominal"] = repr(nominals[v.name])
        if v.der_of is not None:
            attrs["derivative"] = str(vrs[v.der_of])
        if v.start is not None and v.type != "String":
            attrs["start"] = xml_value(v.start, True)
        node = ET.SubElement(mv, FMI3_TYPES[v.type], attrs)
        if v.start is not None and v.type == "String":
            ET.SubElement(node, "Start", value=str(v.start))
    for c in clocks:
        ET.SubElement(mv, "Clock", {"name": c.name, "valueReference": str(c.value_reference),
                                    "description": c.description, "causality": "input",
                                    "variability": "discrete", "intervalVariability": "fixed"})
        vrs[c.name] = c.value_reference
    structure = ET.SubElement(root, "ModelStructure")

    def deps(names):
        return " ".join(str(vrs[n]) for n in sorted(set(names), key=vrs.get))

    # a clocked output depends on its clocks, and on those whose activation drives it (the
    # standard's ModelStructure lists every dependency, a clocked variable's on its clocks too)
    clock_deps = {}
    for c in clocks:
        for n in (*c.clocked, *c.drives):
            clock_deps.setdefault(n, []).append(c.name)
    byname = {v.name: v for _, v in entries}
    outputs = [v for _, v in entries if v.causality == "output"]
    for v in outputs:
        ET.SubElement(structure, "Output", valueReference=str(vrs[v.name]),
                      dependencies=deps((*_dependencies(v, True), *clock_deps.get(v.name, ()))))
    for d in ders:
        ET.SubElement(structure, "ContinuousStateDerivative", valueReference=str(vrs[d]),
                      dependencies=deps(_dependencies(byname[d], True)))
    # a clocked output is initialised at its clock's first activation: no initial unknown (the
    # standard makes it optional; fmpy validate requires its absence)
    for v in (u for u in _initial_unknowns(entries, True) if u.name not in clocked_by):
        ET.SubElement(structure, "InitialUnknown", valueReference=str(vrs[v.name]),
                      dependencies=deps(v.initial_depends_on))
    for z in indicators:
        ET.SubElement(structure, "EventIndicator", valueReference=str(vrs[z]),
                      dependencies=deps(_dependencies(byname[z], True)))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)
