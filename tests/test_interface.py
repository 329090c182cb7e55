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
from fmu_common.variables import parameter_defaults, python_variables
from plant_fmu import interface as plant_if
from plant_fmu.params import PlantParams

MODELS = ["FlexiblePendulum", "PDLowPass"]


@pytest.mark.parametrize("name", MODELS)
def test_built_fmu_declares_exactly_the_table(fmus, name):
    md = read_model_description(fmus[name])
    table = python_variables(TABLES[name][1])     # co-simulation only: no ME variables
    declared = [(v.name, v.valueReference, v.causality, v.type, v.unit, v.description)
                for v in md.modelVariables]
    assert declared == [(v.name, i, v.causality, v.type, v.unit if v.type == "Real" else None,
                         v.description) for i, v in enumerate(table)]
    assert {u.name for u in md.unitDefinitions} == {v.unit for v in table if v.unit}


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
    dimensionless = {"zeta", "n_modes", "n_elements", "gravity_preload", "fidelity", "integrator",
                     "rtol", "atol", "filter_order", "filter_damping",
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
