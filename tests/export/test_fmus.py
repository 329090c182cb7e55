"""The two FMUs as FMI 2.0 co-simulation units: validity, interface, start values, structure, build."""
import dataclasses
import math
import os

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from controller_fmu.pd_lowpass import ControllerParams
from plant_fmu.params import PlantParams

MODELS = ["FlexiblePendulum", "PDLowPass"]

PLANT_OUTPUTS = ["x_o", "x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1", "energy", "phi",
                 "eta_2", "eta_3", "eta_4", "eta_5", "eta_6", "eta_7", "eta_8"]
PLANT_SETTINGS = {"fidelity": "nonlinear", "integrator": "rk4", "step": 2.5e-4, "rtol": 1e-6,
                  "atol": 1e-9, "phi_limit": math.pi / 2, "energy_limit": 1e6, "phi0": 0.0,
                  "x0": 0.0, "phi_dot0": 0.0, "x_dot0": 0.0}


def _start(v):
    """A modelDescription start value as the Python value it stands for."""
    if v.type == "Real":
        return float(v.start)
    if v.type == "Integer":
        return int(v.start)
    if v.type == "Boolean":
        return v.start in ("true", "1", True)
    return v.start


@pytest.mark.parametrize("name", MODELS)
def test_fmpy_validate_finds_no_problems(fmus, name):
    assert validate_fmu(fmus[name]) == []


@pytest.mark.parametrize("name", MODELS)
def test_fmi2_cosimulation_with_state(fmus, name):
    md = read_model_description(fmus[name])
    cs = md.coSimulation
    assert md.fmiVersion == "2.0" and md.modelExchange is None
    assert cs.modelIdentifier == name
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert cs.canHandleVariableCommunicationStepSize


def test_plant_interface(fmus):
    md = read_model_description(fmus["FlexiblePendulum"])
    by = {c: [v.name for v in md.modelVariables if v.causality == c]
          for c in ("input", "output", "parameter")}
    # the force, then its time derivatives (FMI input derivatives as variables)
    assert by["input"] == ["F_c", "dF_c", "d2F_c"]
    assert by["output"] == PLANT_OUTPUTS
    assert set(by["parameter"]) == {f.name for f in dataclasses.fields(PlantParams)} | set(
        PLANT_SETTINGS)


def test_controller_interface(fmus):
    md = read_model_description(fmus["PDLowPass"])
    by = {c: [v.name for v in md.modelVariables if v.causality == c]
          for c in ("input", "output", "parameter")}
    sensors = ["phi_o", "omega_o", "x_o"]
    assert by["input"] == sensors + [f"d{n}" for n in sensors] + [f"d2{n}" for n in sensors]
    assert by["output"] == ["F_c"]
    assert by["parameter"] == [f.name for f in dataclasses.fields(ControllerParams)]


@pytest.mark.parametrize("name, defaults", [
    ("FlexiblePendulum", {**{f.name: f.default for f in dataclasses.fields(PlantParams)},
                          **PLANT_SETTINGS}),
    ("PDLowPass", {f.name: f.default for f in dataclasses.fields(ControllerParams)}),
], ids=MODELS)
def test_start_values_equal_the_dataclass_defaults(fmus, name, defaults):
    md = read_model_description(fmus[name])
    params = {v.name: v for v in md.modelVariables if v.causality == "parameter"}
    assert set(params) == set(defaults)
    for key, default in defaults.items():
        v = params[key]
        assert v.variability == "fixed"
        assert type(_start(v)) is type(default), key          # Real/Integer/Boolean/String
        assert _start(v) == default, key                      # exact (no limit: DBL_MAX)


def test_plant_defaults_match_the_fmu_module():
    from plant_fmu.fmu import FMU_DEFAULTS

    assert FMU_DEFAULTS == PLANT_SETTINGS


def test_output_dependencies_are_declared_as_they_are(fmus):
    """The plant has no direct feedthrough; the controller's F_c depends on its three inputs
    (it does when filter_order = 0). The initial outputs of the plant do not depend on F_c."""
    plant = read_model_description(fmus["FlexiblePendulum"])
    assert [u.variable.name for u in plant.outputs] == PLANT_OUTPUTS
    assert all(u.dependencies == [] for u in plant.outputs)
    init = {u.variable.name: [d.name for d in u.dependencies] for u in plant.initialUnknowns}
    assert set(init) == set(PLANT_OUTPUTS)
    assert init["phi_o"] == ["phi0"] and init["x_o"] == ["x0"] and init["eta_1"] == []
    assert all("F_c" not in deps for deps in init.values())

    ctrl = read_model_description(fmus["PDLowPass"])
    (out,) = ctrl.outputs
    assert out.variable.name == "F_c"
    assert sorted(d.name for d in out.dependencies) == ["omega_o", "phi_o", "x_o"]
    (init,) = ctrl.initialUnknowns
    assert {"phi_o", "omega_o", "x_o", "filter_order"} <= {d.name for d in init.dependencies}


def test_build_is_skipped_when_up_to_date(fmus):
    from orchestration.export.python_fmus import build_fmus, fmu_digest, is_stale, source_digest, SPECS

    mtimes = {n: os.stat(p).st_mtime_ns for n, p in fmus.items()}
    again = build_fmus()
    assert {n: os.stat(p).st_mtime_ns for n, p in again.items()} == mtimes
    for n, p in fmus.items():
        assert not is_stale(n)
        assert fmu_digest(p) == source_digest(SPECS[n])


def test_build_reruns_when_the_sources_change(tmp_path, monkeypatch):
    """A changed digest of the sources (as after an edit) makes the next build rebuild."""
    from orchestration.export import python_fmus as fmu_build

    path = fmu_build.build_fmu("PDLowPass", tmp_path)
    first = path.stat().st_mtime_ns
    assert fmu_build.build_fmu("PDLowPass", tmp_path).stat().st_mtime_ns == first
    real = fmu_build.source_digest
    monkeypatch.setattr(fmu_build, "source_digest", lambda spec: real(spec) + "-edited")
    assert fmu_build.is_stale("PDLowPass", tmp_path)
    rebuilt = fmu_build.build_fmu("PDLowPass", tmp_path)
    assert rebuilt.stat().st_mtime_ns != first
    assert not fmu_build.is_stale("PDLowPass", tmp_path)
    assert validate_fmu(str(rebuilt)) == []


def test_digest_covers_every_shipped_source():
    from orchestration.export.python_fmus import SPECS, source_files

    names = {p.name for p in source_files(SPECS["FlexiblePendulum"])}
    assert {"fmu.py", "dynamics.py", "beam.py", "params.py", "kernel.py", "kernels.py", "slave.py",
            "variables.py", "checks.py", "rk.py", "fp_plant.c", "fp_plant.h"} <= names
    ctrl = {p.relative_to(p.parents[1]).as_posix() for p in source_files(SPECS["PDLowPass"])}
    assert {"controller_fmu/pd_lowpass.py", "controller_fmu/fmu.py", "controller_fmu/kernel.py",
            "native/fp_filter.c", "native/fp_filter.h", "fmu_common/slave.py"} <= ctrl
    assert not any(n.startswith("plant_fmu/") for n in ctrl)     # only its own model


def test_fmus_hold_no_absolute_path_of_the_build_machine(fmus):
    """No file of the FMUs names the checkout, but for the one path the loader records on
    purpose: the interpreter that built them (``python`` in resources/flexpend_loader.txt, tried
    first, python3 on PATH else), which lies in the checkout when its venv does (``.venv/``)."""
    import zipfile

    from orchestration.export.python_fmus import ROOT

    for path in fmus.values():
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if info.filename.endswith((".py", ".xml", ".json", ".txt")):
                    data = zf.read(info)
                    if info.filename == "resources/flexpend_loader.txt":
                        recorded = [line for line in data.decode().splitlines()
                                    if line.startswith("python\t")]
                        assert len(recorded) == 1, recorded
                        interpreter = recorded[0].split("\t", 1)[1]
                        assert interpreter.startswith("/") and \
                            interpreter.rsplit("/", 1)[1].startswith("python"), interpreter
                        data = data.replace(recorded[0].encode(), b"")
                    assert str(ROOT).encode() not in data, info.filename
