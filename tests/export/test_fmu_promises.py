"""What every native FMU's modelDescription promises holds at every rung and parameter value it
accepts (issue 37): a host that picks its algorithm from the flags never meets a refusal.

The test reads each FMU as an importer does, from its modelDescription alone: the interfaces it
declares (CoSimulation, ModelExchange), ``providesDirectionalDerivative(s)``,
``maxOutputDerivativeOrder``, ``canInterpolateInputs``, ``canGetAndSetFMUstate`` and
``canSerializeFMUstate``, and every variable it declares. For each FMU, FMI version and
parameter set it accepts (each rung of its family, the structural parameters: the number of
modes, the damping law, the preload, each integrator, the filter order), it calls every
declared capability and reads every declared variable, after initialisation and after steps,
and sees each answer with OK and a finite value, with no Warning logged. The rungs an FMU does
not run it refuses at initialisation, naming the FMU that runs them (one FMU per rung family,
docs/fmus.md).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from fmpy import extract, read_model_description

from controller_fmu.interface import CONTROLLER_FMUS
from plant_fmu.interface import FIDELITIES, PLANT_FMUS

VERSIONS = (2, 3)
H = 1e-3                       # the communication step of the co-simulation checks
STEPS = 3


def _plant_variants(rungs) -> list:
    """The parameter sets of a plant FMU's checks: each rung with the default model, and with
    each structural parameter changed; the exact rung on a short mesh (its cost grows with it)."""
    out = []
    for f in rungs:
        base = {"fidelity": f, "phi0": 0.3, "phi_dot0": -0.5, "x_dot0": 0.2}
        if f == "exact":
            out += [{**base, "n_elements": 4}, {**base, "n_elements": 4, "damping": "kelvin-voigt"},
                    {**base, "n_elements": 6, "g": 0.0}]
            continue
        out += [base, {**base, "n_modes": 0}, {**base, "n_modes": 8},
                {**base, "damping": "kelvin-voigt"}, {**base, "n_modes": 2, "n_elements": 3}]
        if f != "stiffened":                       # the stiffened rung is always preloaded
            out.append({**base, "gravity_preload": True})
        for integrator in ("dopri5", "euler", "symplectic_euler"):
            out.append({**base, "integrator": integrator})
        if f == "linear":
            out.append({**base, "integrator": "exponential"})
    return out


CONTROLLER_VARIANTS = [{"phi_o": 0.1, "omega_o": -0.2, "x_o": 0.05, "filter_order": k}
                       for k in (0, 1, 2)] + \
    [{"phi_o": 0.3, "omega_o": 2.0, "x_o": 0.5, "kx": 20.0, "force_limit": 10.0}]


#: the sampled controller on the checks' grid (its ticks every H, the force after 0 or H)
SAMPLED_VARIANTS = [{**v, "sample_period": H, "delay": delay, "discretization": disc}
                    for v in CONTROLLER_VARIANTS for delay in (0.0, H)
                    for disc in ("tustin", "zoh") if delay == 0.0 or disc == "zoh"]


def _cases():
    names = [*PLANT_FMUS, *CONTROLLER_FMUS]
    for version in VERSIONS:
        for name in names:
            variants = (_plant_variants(PLANT_FMUS[name].fidelities) if name in PLANT_FMUS
                        else SAMPLED_VARIANTS if CONTROLLER_FMUS[name].sampled
                        else CONTROLLER_VARIANTS)
            for i, start in enumerate(variants):
                yield pytest.param(version, name, start, id=f"fmi{version}-{name}-{i}")


@pytest.fixture(scope="module")
def unpacked(native, native3):
    """``{(version, name): folder}`` of every native FMU built, unpacked once."""
    import shutil

    dirs = {(v, n): extract(str(p)) for v, built in ((2, native), (3, native3))
            for n, p in built.items()}
    yield dirs
    for d in dirs.values():
        shutil.rmtree(d, ignore_errors=True)


def test_every_native_fmu_is_walked(native, native3):
    """The walk covers every native FMU the build makes, and every rung one of them."""
    assert set(native) == set(native3) == {*PLANT_FMUS, *CONTROLLER_FMUS}
    assert sorted(f for fmu in PLANT_FMUS.values() for f in fmu.fidelities) == sorted(FIDELITIES)


def _flags(folder, version):
    """The capability flags as the modelDescription's attributes state them (the standard's
    names: FMI 2.0 ``providesDirectionalDerivative``, FMI 3.0 ``...Derivatives``)."""
    import xml.etree.ElementTree as ET
    from pathlib import Path

    root = ET.parse(Path(folder) / "modelDescription.xml").getroot()
    cs = root.find("CoSimulation").attrib

    def flag(key2, key3):
        return cs.get(key2 if version == 2 else key3, "false") == "true"
    return {"me": root.find("ModelExchange") is not None,
            "directional": flag("providesDirectionalDerivative",
                                "providesDirectionalDerivatives"),
            "order": int(cs.get("maxOutputDerivativeOrder", "0")),
            "interpolate": flag("canInterpolateInputs", "canInterpolateInputs"),
            "state": flag("canGetAndSetFMUstate", "canGetAndSetFMUState"),
            "serialize": flag("canSerializeFMUstate", "canSerializeFMUState")}


def _no_warning(inst, what):
    bad = [m for s, m in inst.logs if s >= 1]
    assert not bad, f"{what}: {bad}"


def _read_all(inst, what):
    """Read every declared variable, one call each, with its type's getter: OK, finite."""
    v2 = inst.version == 2
    getters = {"Real": "getReal", "Float64": "getFloat64", "Integer": "getInteger",
               "Int32": "getInt32", "Boolean": "getBoolean", "String": "getString"}
    for v in inst.md.modelVariables:
        if v.type == "Clock":     # read in event mode only (tests/export/test_sampled_clocks.py)
            continue
        if v.type == "Enumeration" or v.type not in getters:
            raise AssertionError(f"{what}: variable {v.name} of type {v.type} is not checked")
        try:
            value = getattr(inst.fmu, getters[v.type])([v.valueReference])[0]
        except Exception as exc:  # noqa: BLE001 - fmpy raises on Error: name the variable
            raise AssertionError(f"{what}: reading {v.name}: {exc}: {inst.messages(1)}") from None
        if v.type in ("Real", "Float64"):
            assert math.isfinite(value), f"{what}: {v.name} = {value}"
        _no_warning(inst, f"{what}: reading {v.name}")
    assert v2 or any(v.name == "time" for v in inst.md.modelVariables)


def _outputs(md):
    return [v for v in md.modelVariables if v.causality == "output" and v.type in
            ("Real", "Float64")]


def _inputs(md):
    return [v for v in md.modelVariables if v.causality == "input" and v.type in
            ("Real", "Float64")]


def _check_output_derivatives(inst, order, what):
    outs = _outputs(inst.md)
    for k in range(1, order + 1):
        vrs = [v.valueReference for v in outs]
        if inst.version == 2:
            values = inst.fmu.getRealOutputDerivatives(vrs, [k] * len(vrs))
        else:
            values = inst.fmu.getOutputDerivatives(vrs, [k] * len(vrs))
        assert np.all(np.isfinite(values)), f"{what}: output derivatives of order {k}"
    _no_warning(inst, f"{what}: output derivatives")


def _check_directional(inst, unknowns, knowns, what):
    u = [v.valueReference for v in unknowns]
    k = [v.valueReference for v in knowns]
    for j in range(len(k)):
        seed = [0.0] * len(k)
        seed[j] = 1.0
        sens = inst.fmu.getDirectionalDerivative(u, k, seed)
        assert np.all(np.isfinite(sens)), f"{what}: directional derivative"
    _no_warning(inst, f"{what}: directional derivatives")


def _check_states(inst, flags, what):
    if flags["state"]:
        state = inst.fmu.getFMUState()
        if flags["serialize"]:
            data = inst.fmu.serializeFMUState(state)
            state2 = inst.fmu.deSerializeFMUstate(data) if inst.version == 2 else \
                inst.fmu.deserializeFMUState(data)
            inst.fmu.setFMUState(state2)
            inst.fmu.freeFMUState(state2)
        inst.fmu.setFMUState(state)
        inst.fmu.freeFMUState(state)
        _no_warning(inst, f"{what}: FMU states")


@pytest.mark.parametrize("version, name, start", list(_cases()))
def test_every_declared_capability_answers(unpacked, version, name, start):
    from conftest import NativeFmu

    folder = unpacked[version, name]
    md = read_model_description(folder)
    flags = _flags(folder, version)
    what = f"{name} (FMI {version}.0, {start})"
    outs, ins = _outputs(md), _inputs(md)
    # co-simulation: every FMU declares it
    inst = NativeFmu(folder, version, cs=True, **start)
    try:
        inst.initialize(event=False)
        _no_warning(inst, f"{what}: initialisation")
        _read_all(inst, f"{what} (co-simulation, initialised)")
        if flags["interpolate"] and version == 2:
            for v in ins:
                inst.fmu.setRealInputDerivatives([v.valueReference], [1], [0.5])
        if flags["order"]:
            _check_output_derivatives(inst, flags["order"], what)
        if flags["directional"]:
            _check_directional(inst, outs, ins, f"{what} (co-simulation)")
        t = 0.0
        for _ in range(STEPS):
            assert inst.step(t, H) == 0, f"{what}: doStep: {inst.messages(1)}"
            t += H
        _read_all(inst, f"{what} (co-simulation, after {STEPS} steps)")
        if flags["order"]:
            _check_output_derivatives(inst, flags["order"], f"{what} after steps")
        if flags["directional"]:
            _check_directional(inst, outs, ins, f"{what} (co-simulation, after steps)")
        _check_states(inst, flags, f"{what} (co-simulation)")
    finally:
        inst.close()
    if not flags["me"]:
        return
    inst = NativeFmu(folder, version, **start)
    try:
        inst.initialize()
        _no_warning(inst, f"{what}: Model-Exchange initialisation")
        _read_all(inst, f"{what} (Model Exchange, initialised)")
        x, dx = inst.states(), inst.derivatives()
        nominal, z = inst.nominals(), inst.indicators()
        for a in (x, dx, nominal, z):
            assert np.all(np.isfinite(a)), what
        assert np.all(nominal > 0), what
        inst.set_time(H)
        inst.set_states(x + H * dx)
        if version == 2:
            inst.fmu.completedIntegratorStep()
        else:
            inst.fmu.completedIntegratorStep(noSetFMUStatePriorToCurrentPoint=True)
        _read_all(inst, f"{what} (Model Exchange, after a step)")
        if flags["directional"]:
            byname = {v.name: v for v in md.modelVariables}
            ders = [byname[d.variable.name] for d in md.derivatives]
            states = [d.variable.derivative for d in md.derivatives]
            _check_directional(inst, ders + outs, states + ins, f"{what} (Model Exchange)")
        _check_states(inst, flags, f"{what} (Model Exchange)")
    finally:
        inst.close()


@pytest.mark.parametrize("version", VERSIONS)
@pytest.mark.parametrize("name", list(PLANT_FMUS))
def test_a_plant_fmu_refuses_the_rungs_of_the_others_naming_their_fmu(unpacked, version, name):
    """A rung of another family is a parameter value the FMU does not accept: refused at
    initialisation (Error, nothing run), the message naming the FMU that runs it."""
    from conftest import NativeFmu

    for other, fmu in PLANT_FMUS.items():
        for f in fmu.fidelities if other != name else ():
            inst = NativeFmu(unpacked[version, name], version, cs=True, fidelity=f)
            try:
                with pytest.raises(Exception):
                    inst.initialize(event=False)
                msg = inst.messages(3)
                assert f"fidelity = '{f}'" in msg and other in msg, msg
            finally:
                inst.fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_what_an_fmu_does_not_declare_it_refuses_with_a_message(unpacked, version):
    """An FMU without Model Exchange refuses to be instantiated for it; one without derivatives
    refuses the calls (Error and a log line, never a crash): what a host that ignores the flags
    meets."""
    from conftest import NativeFmu

    exact = unpacked[version, "FlexiblePendulumExact"]
    md = read_model_description(exact)
    assert md.modelExchange is None and not md.derivatives
    assert (md.numberOfEventIndicators if version == 2 else len(md.eventIndicators)) == 0
    if version == 2:
        from fmpy.fmi2 import FMU2Model
        fmu = FMU2Model(guid=md.guid, unzipDirectory=exact,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="i")
    else:
        from fmpy.fmi3 import FMU3Model
        fmu = FMU3Model(guid=md.guid, unzipDirectory=exact,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="i")
    with pytest.raises(Exception):
        fmu.instantiate()
    stiff = unpacked[version, "FlexiblePendulumStiffened"]
    inst = NativeFmu(stiff, version, cs=True, phi0=0.2)
    try:
        inst.initialize(event=False)
        out = _outputs(inst.md)[0].valueReference
        f_c = _inputs(inst.md)[0].valueReference
        with pytest.raises(Exception):
            inst.fmu.getDirectionalDerivative([out], [f_c], [1.0])
        assert "provides no directional derivatives" in inst.messages(3)
        with pytest.raises(Exception):
            (inst.fmu.getRealOutputDerivatives if version == 2 else
             inst.fmu.getOutputDerivatives)([out], [1])
        assert "gives no output derivatives" in inst.messages(3)
    finally:
        inst.close()
