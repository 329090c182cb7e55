"""The one table of FMU variables: it is what the built FMUs declare, its units are consistent SI,
and it maps the scene keys to the FMUs' start values."""
import dataclasses
import os
import re
import stat
import zipfile

import pytest
from fmpy import read_model_description

from controller_fmu import interface as ctrl_if
from controller_fmu.pd_lowpass import ControllerParams
from orchestration.export.model_description import TABLES, UNITS
from fmu_common.variables import parameter_defaults, python_entries
from plant_fmu import interface as plant_if
from plant_fmu.params import PlantParams

MODELS = ["FlexiblePendulum", "PDLowPass"]


@pytest.mark.parametrize("name", MODELS)
def test_built_fmu_declares_exactly_the_table(fmus, name):
    md = read_model_description(fmus[name])
    entries = python_entries(TABLES[name][1])     # co-simulation only: no ME variables, no time
    declared = [(v.name, v.valueReference, v.causality, v.type, v.unit, v.description)
                for v in md.modelVariables]
    assert declared == [(v.name, vr, v.causality, v.type, v.unit if v.type == "Real" else None,
                         v.description) for vr, v in entries]
    assert {u.name for u in md.unitDefinitions} == {v.unit for _, v in entries if v.unit}


#: The value references of every variable before issue 34 (FMI 3.0's time included): a variable
#: is appended to a table, so none of these may change.
FROZEN = {
    "FlexiblePendulum": {
        **{n: i for i, n in enumerate(
            ["F_c", "dF_c", "d2F_c", "x_o", "x_dot", "phi_o", "omega_o", "tip_deflection",
             "eta_1", "energy", "phi", *(f"eta_{j}" for j in range(2, 9)), "m", "L", "rho",
             "EA", "EI", "E", "zeta", "g", "n_modes", "n_elements", "gravity_preload",
             "fidelity", "integrator", "step", "rtol", "atol", "phi_limit", "energy_limit",
             "phi0", "x0", "phi_dot0", "x_dot0", "phi_dot", *(f"eta_dot_{j}" for j in range(1, 9)),
             *(f"der({s})" for s in ("x_o", "phi", *(f"eta_{j}" for j in range(1, 9)), "x_dot",
                                     "phi_dot", *(f"eta_dot_{j}" for j in range(1, 9)))),
             "phi_limit_indicator", "energy_limit_indicator", "time"])}},
    "PDLowPass": {n: i for i, n in enumerate(
        ["phi_o", "omega_o", "x_o", "dphi_o", "domega_o", "dx_o", "d2phi_o", "d2omega_o",
         "d2x_o", "F_c", "kp", "kd", "kx", "filter_order", "cutoff", "filter_damping",
         "force_limit", "xc_1", "xc_2", "der(xc_1)", "der(xc_2)", "time"])},
}


@pytest.mark.parametrize("name", MODELS)
def test_no_value_reference_of_an_existing_variable_changes(name):
    """Every description (pythonfmu FMI 2.0, native FMI 2.0 and 3.0) keeps the references of
    :data:`FROZEN`; FMI 3.0's ``time`` keeps its own (71 for the plant); a variable added since
    takes a reference no existing one has."""
    import xml.etree.ElementTree as ET

    from orchestration.export.model_description import (fmi2_model_description,
                                                        fmi3_model_description)

    frozen = FROZEN[name]
    cs = {"modelIdentifier": name}
    docs = {"python": fmi2_model_description(name, "{g}", generation_tool="t", co_simulation=cs),
            "native2": fmi2_model_description(name, "{g}", generation_tool="t", co_simulation=cs,
                                              native=True, model_exchange=cs),
            "native3": fmi3_model_description(name, "{g}", generation_tool="t", co_simulation=cs,
                                              model_exchange=cs)}
    seen = set()
    for flavour, xml in docs.items():
        vrs = {v.get("name"): int(v.get("valueReference"))
               for v in ET.fromstring(xml).find("ModelVariables")}
        old = {n: vr for n, vr in vrs.items() if n in frozen}
        assert old == {n: frozen[n] for n in old}, flavour
        new = {n: vr for n, vr in vrs.items() if n not in frozen}
        assert not set(new.values()) & set(frozen.values()), (flavour, new)
        seen |= set(old)
    assert seen == set(frozen)            # every old variable is declared by some flavour
    time = [v for v in ET.fromstring(docs["native3"]).find("ModelVariables")
            if v.get("name") == "time"]
    assert [int(v.get("valueReference")) for v in time] == \
        [71 if name == "FlexiblePendulum" else 21]
    assert {n: vr for vr, v in enumerate(TABLES[name][1]) for n in [v.name] if n in frozen} \
        == frozen


def test_parameter_defaults_are_the_records_defaults():
    plant = parameter_defaults(plant_if.VARIABLES)
    for f in dataclasses.fields(PlantParams):
        assert plant[f.name] == f.default and type(plant[f.name]) is type(f.default), f.name
    ctrl = parameter_defaults(ctrl_if.VARIABLES)
    assert ctrl == {f.name: f.default for f in dataclasses.fields(ControllerParams)}
    # the product's controller is the robust filter of `flexpend design` (docs/spillover.md)
    assert (ctrl["filter_order"], ctrl["cutoff"], ctrl["filter_damping"]) == (2, 97.3, 0.1)


def _dimension(unit):
    """Exponents of a unit written as a product/quotient of the table's base symbols."""
    base = {"kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "rad": {"rad": 1},
            "N": {"kg": 1, "m": 1, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
            "Pa": {"kg": 1, "m": -1, "s": -2}}
    out = {}
    num, _, den = unit.partition("/")
    for part, sign in ((num, 1), (den, -1)):
        for factor in filter(None, part.split(".")):
            sym, power = re.fullmatch(r"([a-zA-Z]+)(\d*)", factor).groups()
            for k, e in base[sym].items():
                out[k] = out.get(k, 0) + sign * e * int(power or 1)
    return {k: e for k, e in out.items() if e}


@pytest.mark.parametrize("unit", sorted(u for u, e in UNITS.items() if e is not None))
def test_base_units_are_what_the_unit_name_says(unit):
    assert UNITS[unit] == _dimension(unit)


def test_every_physical_variable_has_a_unit():
    dimensionless = {"zeta", "damping", "n_modes", "n_elements", "gravity_preload", "fidelity",
                     "integrator",
                     "rtol", "atol", "filter_order", "filter_damping", "discretization",
                     "phi_limit_indicator", "energy_limit_indicator"}
    for name, (_, table) in TABLES.items():
        for v in table:
            assert (v.unit is None) == (v.name in dimensionless), (name, v.name)


def test_modal_coordinates_carry_m_sqrt_kg():
    """w = N eta in metres with mass-normalised N (integral rhoA N^2 ds = 1, so N ~ 1/sqrt(kg))."""
    from plant_fmu.beam import beam_model

    b = beam_model(PlantParams(n_modes=2))
    p = PlantParams()
    # scaling rhoA by 4 halves N (N^2 rhoA L stays 1): N is in kg^-1/2, eta in m kg^1/2
    b4 = beam_model(PlantParams(n_modes=2, rho=4 * p.rho))
    ratio = b4.tip_deflection / b.tip_deflection
    assert ratio == pytest.approx([0.5, 0.5], rel=1e-12)
    units = {v.name: v.unit for v in plant_if.VARIABLES}
    assert units["eta_1"] == units["eta_8"] == "m.kg0.5" and units["tip_deflection"] == "m"


def test_scene_keys_map_to_start_values():
    from orchestration.job import controller_start_values, plant_start_values
    from orchestration.scene.schema import load_scene

    scene = load_scene("flexible_pd", ["plant.EI=900", "initial.phi=0.2", "controller.kp=400"])
    plant = plant_start_values(scene)
    assert plant["EI"] == 900 and plant["phi0"] == 0.2 and plant["n_modes"] == 4
    assert set(plant) == set(parameter_defaults(plant_if.VARIABLES))
    ctrl = controller_start_values(scene)
    assert ctrl["kp"] == 400 and set(ctrl) == {f.name for f in dataclasses.fields(ControllerParams)}


@pytest.mark.parametrize("name", MODELS)
def test_generation_date_is_schema_utc_and_file_is_readable(fmus, name):
    with zipfile.ZipFile(fmus[name]) as zf:
        xml = zf.read("modelDescription.xml").decode()
    date = re.search(r'generationDateAndTime="([^"]+)"', xml).group(1)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", date)
    mode = stat.S_IMODE(os.stat(fmus[name]).st_mode)
    assert mode & 0o044 == 0o044          # readable by group and others (was 0600)


@pytest.mark.parametrize("name", ["FlexiblePendulumStiffened", "FlexiblePendulumExact"])
def test_each_plant_family_keeps_the_plants_value_references(name):
    """One FMU per rung family (docs/fmus.md): each native plant FMU declares the variables of
    FlexiblePendulum it offers at FlexiblePendulum's frozen references (FMI 3.0's time at 71),
    and the Model-Exchange locals exactly when it offers Model Exchange."""
    import xml.etree.ElementTree as ET

    from orchestration.export.native_fmus import _model_description

    frozen = FROZEN["FlexiblePendulum"]
    me_only = {v.name for v in TABLES["FlexiblePendulum"][1] if v.me_only}
    for version in (2, 3):
        root = ET.fromstring(_model_description(name, version, "{g}"))
        vrs = {v.get("name"): int(v.get("valueReference")) for v in root.find("ModelVariables")}
        assert {n: vr for n, vr in vrs.items() if n in frozen} == \
            {n: vr for n, vr in frozen.items() if n in vrs}
        me = root.find("ModelExchange") is not None
        assert (me_only <= set(vrs)) if me else not (me_only & set(vrs)), (version, me)
        inputs = {"dF_c", "d2F_c"}               # the pythonfmu flavour's input derivatives
        assert set(frozen) - set(vrs) <= (set() if me else me_only) | {"time"} | inputs
        assert version == 2 or vrs["time"] == 71
