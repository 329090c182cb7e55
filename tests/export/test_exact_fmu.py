"""The exact rung in the native FMUs (``plant.fidelity = "exact"``, issue 27): the FMU against the
kernel and the numpy specification, through the product's master and its monolithic reference;
FMI 2.0 against FMI 3.0; FMU states; what the rung refuses."""
from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import NativeFmu, fmi_status, opened_by

from orchestration import simulate
from orchestration.scene.keys import ConfigError
from orchestration.scene.schema import load_scene
from orchestration.studies.reference import exact_first_mode_tip
from plant_fmu.exact import ExactPlant, RadauIIA, StageForce
from plant_fmu.interface import PLANT_FMUS, plant_fmu_name
from plant_fmu.kernel import ExactKernel
from plant_fmu.params import PlantParams


NE = 4
#: a short run of the filtered scene on a coarse mesh (fidelity.max_modes <= n_elements), under
#: the exact rung's damping law (Kelvin-Voigt; the floating frame compared with it takes it too)
EXACT = {"plant.fidelity": "exact", "plant.n_elements": NE, "fidelity.max_modes": NE,
         "plant.damping": "kelvin-voigt"}
#: the exact rung in an FMU, with its damping law
XB = {"fidelity": "exact", "damping": "kelvin-voigt"}
OUTPUTS = ("x_o", "x_dot", "phi_o", "omega_o", "phi", "tip_deflection", "energy")


class Cs(NativeFmu):
    """A co-simulation (or Model Exchange) instance of the native plant through fmpy (FMI 2.0 or
    3.0), by name, initialised unless told not to; ``status``: that of the initialisation."""

    def __init__(self, unzipdir, version, initialize=True, model_exchange=False, **start):
        super().__init__(unzipdir, version, cs=not model_exchange, **start)
        if initialize:
            self.status = self.call(self.initialize, False)

    call = staticmethod(fmi_status)


@pytest.fixture(scope="module")
def plant_dirs(native, native3):
    """The native plant FMUs of both FMI versions, unpacked: (version, FMU name) -> folder."""
    import shutil

    from fmpy import extract

    dirs = {(v, name): extract(built[name]) for v, built in ((2, native), (3, native3))
            for name in PLANT_FMUS}
    yield dirs
    for d in dirs.values():
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def open_plant(plant_dirs):
    """Factory: ``open_plant(version, **start)``: an instance of the native plant FMU that runs
    the rung ``start["fidelity"]`` (one FMU per rung family, plant_fmu.interface.PLANT_FMUS)."""
    def make(version=2, **start):
        name = plant_fmu_name(start.get("fidelity", "nonlinear"))
        return Cs(plant_dirs[version, name], version, **start)
    yield from opened_by(make)


def forcing(k):
    """A force history that excites the beam (N)."""
    return 40.0 * math.sin(7.0 * k * 1e-3) + (15.0 if k % 50 < 25 else -15.0)


def drive(inst, n, k0=0, h=1e-3, derivatives=False):
    """``n`` steps of ``h`` from ``k0 h`` under :func:`forcing` (held, or with its rate as an
    input derivative); the outputs after each step."""
    rows = []
    for k in range(k0, k0 + n):
        inst.set(F_c=forcing(k))
        if derivatives:
            inst.fmu.setRealInputDerivatives(inst.vr("F_c"), [1], [3000.0 * math.cos(k)])
        assert inst.step(k * h, h) == 0, inst.messages()
        rows.append(inst.get(*OUTPUTS, "eta_1", "eta_8"))
    return np.array(rows)


# ---------------------------------------------------------------------- against the kernel
def test_the_product_master_reproduces_the_kernel_and_the_numpy_specification():
    """The product's master (plant first, held force) on the native plant at the exact rung,
    replayed with the force it recorded: the C kernel (the FMU's own code, Radau IIA) gives the
    same tip angle to the last bit, and the numpy specification to round-off (the kernel's own
    test holds the two together: tests/plant/test_exact_kernel.py)."""
    ov = {**EXACT, "stop_time": 0.3, "master.first": "plant", "master.extrapolation": 0,
          "master.input_derivatives": False, "master.step": 1e-3, "output_interval": 1e-3}
    run = simulate("flexible_pd_lowpass", ov)
    res, sc = run.result, run.scene
    assert run.completed and len(res) == 301
    # the summary's linear roots: the floating frame's preloaded loop of the same law, said so
    assert run.summary["linear_loop"] == (
        "the floating frame's linearisation (4 modes, preloaded, Kelvin-Voigt damping, 0.1 % in "
        "mode 1), standing in for the exact rung's")
    plant = ExactPlant(sc.plant.params)
    h = sc.plant.exact_step
    per = round(1e-3 / h)
    x0 = plant.initial_state(phi=sc.initial.phi)
    swing = np.ptp(res["phi_o"])
    assert swing > 0.5
    for ga, tol in ((ExactKernel(plant, h, method="radau"), 0.0), (RadauIIA(plant.system, h), 1e-11)):
        st = ga.start(x0[:plant.nq], x0[plant.nq:], res["F_c"][0])
        phi_o, energy = [plant.tip_angle(x0)[0]], [plant.energy(x0)]
        for k in range(len(res) - 1):
            for _ in range(per):
                st = ga.step(st, res["F_c"][k])
            x = np.concatenate(st[:2])
            phi_o.append(plant.tip_angle(x)[0])
            energy.append(plant.energy(x))
        assert np.max(np.abs(np.array(phi_o) - res["phi_o"])) <= tol * swing
        assert np.max(np.abs(np.array(energy) - res["energy"])) <= 1e-10 * np.ptp(energy) + \
            1e-12 * np.max(np.abs(energy))
    # no modal coordinates: eta_1 is the tip deflection in units of mode 1's, the rest 0
    n1 = exact_first_mode_tip(sc.plant.params)
    assert np.allclose(res["eta_1"] * n1, res["tip_deflection"], rtol=1e-15, atol=0)
    assert np.ptp(res["eta_1"]) > 0 and np.all(res["eta_2"] == 0.0)


def test_the_closed_loop_meets_the_exact_reference_as_the_floating_frame_meets_its_own():
    """The co-simulation at the exact rung against its monolithic reference (ExactLoop, Radau IIA
    at the same step, the filter in its stages): the coupling's error, which depends on the loop
    and the coupling, not on the rung. So the exact rung's error (at plant.exact_step, its
    communication step) is the floating frame's at that master step (against its DOP853
    reference) to within a factor 1.5, falls at least fourfold when the step halves, and both
    stay far below the gap between the two models (a plant that was not the reference's would
    show that gap)."""
    err, runs = {}, {}
    for fid in ("exact", "nonlinear"):
        for H in (4e-3, 2e-3):
            ov = {**EXACT, "plant.fidelity": fid, "stop_time": 1.0, "master.step": H,
                  "plant.exact_step": H, "output_interval": 4e-3}
            run = simulate("flexible_pd_lowpass", ov, reference=True)
            err[fid, H] = run.summary["max_error_phi_o"]
            runs[fid, H] = run.result["phi_o"]
    for H in (4e-3, 2e-3):
        assert err["exact", H] <= 1.5 * err["nonlinear", H]
    assert err["exact", 4e-3] >= 4 * err["exact", 2e-3]
    gap = np.max(np.abs(runs["exact", 2e-3] - runs["nonlinear", 2e-3]))
    assert gap >= 10 * err["exact", 2e-3]


def test_fmi2_and_fmi3_agree_bit_for_bit_and_with_the_kernel(open_plant):
    """The same steps on both FMI versions give the same outputs to the last bit, and they are
    the kernel's Radau steps under the held force (``ExactKernel``, the same code), at the
    FMU's own default step (its ``step`` parameter, 2.5e-4 s: four substeps per doStep)."""
    start = dict(**XB, n_elements=NE, n_modes=0, phi0=0.3, x_dot0=0.2)
    ra, rb = drive(open_plant(2, **start), 100), drive(open_plant(3, **start), 100)
    assert np.array_equal(ra, rb)
    plant = ExactPlant(PlantParams(n_elements=NE, n_modes=0, damping="kelvin-voigt"))
    k = ExactKernel(plant, 2.5e-4, method="radau")
    x0 = plant.initial_state(phi=0.3, x_dot=0.2)
    st = k.start(x0[:plant.nq], x0[plant.nq:], forcing(0))
    for i in range(100):
        st = k.steps(st, forcing(i), 4)
    assert np.array_equal(ra[-1, :7], k.outputs(st))
    assert ra[-1, 5] != 0.0                         # the tip deflection at n_modes = 0 too
    assert np.all(ra[:, 8] == 0.0)                  # eta_8: no modal coordinates
    n1 = exact_first_mode_tip(plant.params)
    assert np.allclose(ra[:, 7] * n1, ra[:, 5], rtol=1e-15, atol=0)


def test_input_derivatives_give_the_force_at_each_stage_time(open_plant):
    """With fmi2SetRealInputDerivatives the force at each Radau stage of each substep is the
    input polynomial at the stage's time: the kernel stepped substep by substep with those
    forces gives the FMU's outputs to the last bit."""
    from plant_fmu.exact import RADAU_C

    rows = drive(open_plant(2, **XB, n_elements=NE, phi0=0.3), 50, derivatives=True)
    plant = ExactPlant(PlantParams(n_elements=NE, damping="kelvin-voigt"))
    h = 2.5e-4
    k = ExactKernel(plant, h, method="radau")
    x0 = plant.initial_state(phi=0.3)
    st = k.start(x0[:plant.nq], x0[plant.nq:], forcing(0))
    for i in range(50):
        u, du = forcing(i), 3000.0 * math.cos(i)
        for q in range(4):
            dt = [(0.0 + (4 * i + q) * h) - i * 1e-3 + c * h for c in RADAU_C]
            st = k.step(st, StageForce(tuple(u + d * (du + 0.5 * d * 0.0) for d in dt)))
    assert np.array_equal(rows[-1, :7], k.outputs(st))
    held = drive(open_plant(2, **XB, n_elements=NE, phi0=0.3), 50)
    assert np.max(np.abs(held[:, 2] - rows[:, 2])) > 1e-6      # the derivatives matter


def test_a_communication_step_off_the_plant_grid_is_taken_whole(open_plant):
    """A step that is not a multiple of plant.step ends with a shortened substep exactly at the
    communication point (the floating frame's grid)."""
    inst = open_plant(2, **XB, n_elements=NE, phi0=0.2)
    t = 0.0
    for h in (1e-3, 3.3e-4, 7.7e-4, 1e-3):
        inst.set(F_c=5.0)
        assert inst.step(t, h) == 0, inst.messages()
        t += h
    assert inst.fmu.getRealStatus(2) == t          # fmi2LastSuccessfulTime
    assert all(math.isfinite(v) for v in inst.get(*OUTPUTS))


# ---------------------------------------------------------------------- FMU states
def test_a_restored_state_continues_bit_for_bit(open_plant):
    """Save mid-run (in memory and serialised), run on, restore, run again: the same outputs to
    the last bit (the integrator's accelerations are in the state)."""
    inst = open_plant(2, **XB, n_elements=NE, phi0=0.3)
    drive(inst, 100, derivatives=True)
    mem = inst.fmu.getFMUstate()
    data = inst.fmu.serializeFMUstate(mem)
    first = drive(inst, 100, k0=100, derivatives=True)
    inst.fmu.setFMUstate(mem)
    assert np.array_equal(drive(inst, 100, k0=100, derivatives=True), first)
    other = open_plant(2, **XB, n_elements=NE, phi0=0.3)
    state = other.fmu.deSerializeFMUstate(data)
    other.fmu.setFMUstate(state)
    assert np.array_equal(drive(other, 100, k0=100, derivatives=True), first)
    inst.fmu.freeFMUstate(mem)
    other.fmu.freeFMUstate(state)


def test_a_restored_stiffened_state_continues_bit_for_bit_in_any_instance(open_plant):
    """The stiffened rung adds no state: its mass points are made from the parameters. A state
    saved mid-run and restored, in its own instance or serialised into another instance of its
    FMU (FlexiblePendulumStiffened) opened on another mesh (twice: the mass points rebuilt, then
    taken over from the live model), continues as the stiffened run to the last bit, and not as
    the nonlinear rung with the preload (the same stiffness without the mass points)."""
    start = {"fidelity": "stiffened", "n_elements": 6, "n_modes": 3, "phi0": 0.3}
    inst = open_plant(2, **start)
    drive(inst, 50)
    mem = inst.fmu.getFMUstate()
    data = inst.fmu.serializeFMUstate(mem)
    first = drive(inst, 100, k0=50)
    inst.fmu.setFMUstate(mem)
    assert np.array_equal(drive(inst, 100, k0=50), first)
    other = open_plant(2, fidelity="stiffened", n_elements=9, n_modes=2)
    state = other.fmu.deSerializeFMUstate(data)
    for _ in range(2):                  # rebuilt, then (equal parameters now) taken over
        other.fmu.setFMUstate(state)
        assert np.array_equal(drive(other, 100, k0=50), first)
    pre = open_plant(2, **{**start, "fidelity": "nonlinear", "gravity_preload": True})
    drive(pre, 50)
    assert np.max(np.abs(drive(pre, 100, k0=50) - first)[:, 2]) > 1e-6    # phi_o
    inst.fmu.freeFMUstate(mem)
    other.fmu.freeFMUstate(state)


def _fnv(data: bytes) -> int:
    h = 14695981039346656037
    for byte in data:
        h = ((h ^ byte) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def _crafted(data: bytes, index: int, value: float) -> bytes:
    """The serialised state with the exact beam's state entry ``index`` (from the end of the
    payload: -1 is the last of [q, qd, qdd, jerk]) set to ``value``, its checksum recomputed."""
    b = bytearray(data)
    at = len(b) - 8 + 8 * index
    b[at:at + 8] = struct.pack("<d", value)
    b[-8:] = struct.pack("<Q", _fnv(bytes(b[:-8])))
    return bytes(b)


NQ = 4 * NE + 3


@pytest.mark.parametrize("index, value, why", [
    (-1, math.nan, "the exact beam's state = nan is not finite"),      # a jerk
    (-4 * NQ, math.inf, "the exact beam's state = inf is not finite"),  # the cart's x
    (-4 * NQ + 1, 1e150, "the state's norm"),                          # the root slope, huge
    (-4 * NQ + 2, -1.0, "exceeds phi_limit"),                          # the root turned over
], ids=["nan", "inf", "norm", "phi-limit"])
def test_crafted_exact_state_bytes_are_refused_and_change_nothing(open_plant, index, value,
                                                                    why):
    inst = open_plant(2, **XB, n_elements=NE, phi0=0.3)
    drive(inst, 20)
    mem = inst.fmu.getFMUstate()
    data = bytes(inst.fmu.serializeFMUstate(mem))
    inst.fmu.freeFMUstate(inst.fmu.deSerializeFMUstate(data))   # the untouched bytes load
    before = inst.get(*OUTPUTS)
    assert inst.call(inst.fmu.deSerializeFMUstate, _crafted(data, index, value)) == 3
    assert "not a valid state" in inst.messages(3) and why in inst.messages(3)
    assert inst.get(*OUTPUTS) == before
    on = drive(inst, 5, k0=20)
    inst.fmu.setFMUstate(mem)
    assert np.array_equal(drive(inst, 5, k0=20), on)
    inst.fmu.freeFMUstate(mem)


def test_a_zero_tip_slope_is_refused(open_plant):
    """A tip slope of zero length has no tangent angle: the restore says so."""
    inst = open_plant(2, **XB, n_elements=NE, phi0=0.3)
    drive(inst, 5)
    data = bytes(inst.fmu.serializeFMUstate(inst.fmu.getFMUstate()))
    q_end = -3 * NQ                                       # q[nq - 2], q[nq - 1] end here
    bad = _crafted(_crafted(data, q_end - 2, 0.0), q_end - 1, 0.0)
    assert inst.call(inst.fmu.deSerializeFMUstate, bad) == 3
    assert "would not be finite" in inst.messages(3)


# ---------------------------------------------------------------------- what it refuses
def test_model_exchange_is_refused_with_a_message(plant_dirs):
    """FlexiblePendulumExact declares no Model Exchange (docs/fmus.md, one FMU per rung family):
    an instantiation for it is refused (NULL) with a log line saying so."""
    from fmpy import read_model_description
    from fmpy.fmi2 import (FMU2Model, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFunctions,
                           fmi2CallbackFreeMemoryTYPE, fmi2CallbackLoggerTYPE, calloc, free)
    from fmpy.fmi3 import FMU3Model

    for version in (2, 3):
        folder = plant_dirs[version, "FlexiblePendulumExact"]
        md = read_model_description(folder)
        assert md.modelExchange is None
        said = []
        kw = dict(guid=md.guid, unzipDirectory=folder, instanceName="i",
                  modelIdentifier=md.coSimulation.modelIdentifier)
        if version == 2:
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(
                lambda env, name, status, category, message: said.append(message.decode()))
            cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            with pytest.raises(Exception):
                FMU2Model(**kw).instantiate(callbacks=cb, loggingOn=True)
        else:
            with pytest.raises(Exception):
                FMU3Model(**kw).instantiate(
                    loggingOn=True,
                    logMessage=lambda env, status, category, message:
                        said.append(message.decode()))
        assert any("FlexiblePendulumExact offers co-simulation only" in m for m in said), said


def test_directional_and_output_derivatives_are_refused_with_a_message(open_plant):
    inst = open_plant(2, **XB, n_elements=NE, phi0=0.3)
    drive(inst, 2)
    rc = inst.call(inst.fmu.getDirectionalDerivative, inst.vr("phi_o"), inst.vr("F_c"), [1.0])
    assert rc == 3 and "provides no directional derivatives" in inst.messages(3)
    rc = inst.call(inst.fmu.getRealOutputDerivatives, inst.vr("phi_o"), [1])
    assert rc == 3 and "gives no output derivatives" in inst.messages(3)
    drive(inst, 2, k0=2)                                  # and it steps on


@pytest.mark.parametrize("keys, what", [
    ({"master.fmus": "python"}, "master.fmus = 'python'"),
    ({"master.interface": "model-exchange"}, "model-exchange"),
    ({"master.output_derivatives": True}, "output_derivatives"),
])
def test_the_scene_refuses_what_the_exact_rung_cannot_give(keys, what):
    with pytest.raises(ConfigError, match=what):
        load_scene("rigid_pd", {"plant.fidelity": "exact", **keys})


def test_the_exact_rung_takes_the_modal_law(open_plant):
    """Under the modal law (zeta in every mode of the beam clamped in its root tangent's frame,
    plant_fmu.exact.FrameModalDamping) the scene runs, and the native FMU (both FMI versions)
    steps the kernel's Radau steps to the last bit and the numpy specification's to round-off;
    it differs from the Kelvin-Voigt law's run, and with zeta = 0 the two laws are one, bit for
    bit."""
    assert load_scene("rigid_pd", {"plant.fidelity": "exact"}).plant.fidelity == "exact"
    start = dict(fidelity="exact", n_elements=NE, n_modes=0, phi0=0.3, x_dot0=0.2, zeta=0.02)
    ra, rb = drive(open_plant(2, **start), 100), drive(open_plant(3, **start), 100)
    assert np.array_equal(ra, rb)
    plant = ExactPlant(PlantParams(n_elements=NE, n_modes=0, zeta=0.02))
    assert plant.modal is not None and plant.beta_kv == 0.0
    x0 = plant.initial_state(phi=0.3, x_dot=0.2)
    k, spec = ExactKernel(plant, 2.5e-4, method="radau"), RadauIIA(plant.system, 2.5e-4)
    sk = k.start(x0[:plant.nq], x0[plant.nq:], forcing(0))
    ss = spec.start(x0[:plant.nq], x0[plant.nq:], forcing(0))
    for i in range(100):
        sk = k.steps(sk, forcing(i), 4)
        for _ in range(4):
            ss = spec.step(ss, forcing(i))
    assert np.array_equal(ra[-1, :7], k.outputs(sk))
    assert abs(k.outputs(ss)[2] - ra[-1, 2]) <= 1e-10
    kv = drive(open_plant(2, **{**start, "damping": "kelvin-voigt"}), 100)
    assert np.max(np.abs(kv[:, 2] - ra[:, 2])) > 1e-7                 # phi_o
    undamped = dict(start, zeta=0.0)
    assert np.array_equal(drive(open_plant(2, **undamped), 20),
                          drive(open_plant(2, **undamped, damping="kelvin-voigt"), 20))


def test_fidelity_auto_climbs_to_the_exact_rung_under_either_law():
    from orchestration.studies.fidelity import available_ladder

    for keys in ({}, {"plant.damping": "kelvin-voigt"}, {"plant.zeta": 0.0}):
        assert available_ladder(load_scene("flexible_pd", keys))[-1] == "exact"


def test_the_pythonfmu_plant_refuses_the_exact_rung():
    pytest.importorskip("pythonfmu")
    from plant_fmu.fmu import FMU_DEFAULTS, FlexiblePendulum

    par = {**FlexiblePendulum.dataclass_defaults(PlantParams), **FMU_DEFAULTS,
           "fidelity": "exact"}
    with pytest.raises(ValueError, match="native FlexiblePendulum only"):
        FlexiblePendulum._validated(par)


def test_linear_studies_say_they_linearise_the_floating_frame():
    from orchestration import analyze
    with pytest.raises(ConfigError, match="floating frame"):
        analyze("rigid_pd", {"plant.fidelity": "exact", "plant.damping": "kelvin-voigt"})


def test_the_rigid_scene_runs_its_beam_exactly():
    """The rigid scene (n_modes = 0, a stiff beam): the exact rung ignores n_modes and runs the
    beam of n_elements elements; its tip deflects a little, and the swing is the rigid one's to
    within that deflection's angle."""
    ov = {**EXACT, "stop_time": 0.5}
    ex = simulate("rigid_pd", ov).result
    rigid = simulate("rigid_pd", {"stop_time": 0.5}).result
    assert np.max(np.abs(ex["tip_deflection"])) > 0.0
    assert np.max(np.abs(ex["phi_o"] - rigid["phi_o"])) < 0.01


@pytest.mark.parametrize("keys, fragment", [
    ({"controller.force_limit": 100.0}, "the exact reference has no force saturation"),
    ({"plant.exact_step": 3e-4}, "must be a multiple of plant.exact_step"),
])
def test_a_reference_the_exact_loop_cannot_take_is_refused_before_the_run(keys, fragment):
    with pytest.raises(ConfigError, match=fragment):
        simulate("rigid_pd", {**EXACT, "stop_time": 0.1, **keys}, reference=True)


# ---------------------------------------------------------------------- as a reference
@pytest.fixture(scope="module")
def undamped_reference():
    """The undamped filtered scene over 3 s from 0.2 rad (where a 2 ms coupling of a finely
    stepped beam used to alias its high modes worst), and its refined reference: the monolithic
    exact loop (Radau IIA, the filter in its stages) at 48 elements and 0.125 ms, itself within
    1.3e-5 rad of generalized alpha at 32 elements and 6.25 us (bench/exact_convergence.py)."""
    from orchestration.studies.exact_loop import exact_run

    keys = {"plant.fidelity": "exact", "plant.zeta": 0.0, "initial.phi": 0.2, "stop_time": 3.0}
    scene = load_scene("flexible_pd_lowpass", keys)
    return keys, exact_run(scene, 48, 1.25e-4, kernel=True)


@pytest.mark.slow
def test_refining_the_plant_never_makes_the_coupled_error_worse(undamped_reference):
    """Through the FMU and the product's master, the exact rung at its defaults (24 elements,
    1 ms) and refined (32 elements at 0.5 and 0.25 ms: the rung couples at its own step) is
    within 1e-4 rad of the refined reference, each refinement no worse than the one before; the
    run's stated numerical error (step doubling) is never below its measured error. Before, the
    plant refined to 32 elements and 25 us at the 2 ms coupling was 1.4e-3 rad off."""
    keys, ref = undamped_reference
    errors = []
    for ne, h in ((24, 1e-3), (32, 5e-4), (32, 2.5e-4)):
        run = simulate("flexible_pd_lowpass", {**keys, "plant.n_elements": ne,
                                               "plant.exact_step": h})
        assert run.completed
        err = float(np.max(np.abs(run.result["phi_o"] - ref)))
        stated = run.summary["numerical_error"]["phi_o"]
        assert err <= stated, (ne, h, err, stated)
        errors.append(err)
    assert errors[0] < 1e-4
    assert all(b <= a for a, b in zip(errors, errors[1:])), errors


# ---------------------------------------------------------------------- the work budget
def _budget():
    import re
    src = (Path(__file__).parents[2] / "plant_fmu/native/plant_model.c").read_text()
    return int(re.search(r"#define FPM_MAX_EXACT_WORK (\d+)L", src).group(1))


def test_a_step_whose_substeps_exceed_the_work_budget_is_refused_before_any_work(open_plant):
    """n_substeps * n_elements above FPM_MAX_EXACT_WORK (below the substep cap): Discard naming
    the budget and the count, the time and outputs unchanged, and a shorter step then runs."""
    budget, ne, h_plant = _budget(), 100, 2.5e-4
    H = 2.0 * budget / ne * h_plant                     # twice the budget's substeps
    inst = open_plant(2, **XB, n_elements=ne, step=h_plant, phi0=0.2)
    before = inst.get(*OUTPUTS)
    assert inst.step(0.0, H) == 2                       # fmi2Discard
    msg = inst.messages()
    assert f"budget of {budget} per doStep" in msg and f"on {ne} elements" in msg, msg
    assert f"{2 * budget}" in msg
    assert inst.get(*OUTPUTS) == before
    assert inst.step(0.0, 1e-3) == 0, inst.messages()
    fresh = open_plant(2, **XB, n_elements=ne, step=h_plant, phi0=0.2)
    assert fresh.step(0.0, 1e-3) == 0
    assert inst.get(*OUTPUTS) == fresh.get(*OUTPUTS)


@pytest.mark.slow
def test_a_step_whose_iterations_reach_the_work_budget_is_discarded_unchanged(open_plant):
    """Substeps within the budget whose Newton iterations (at least one each, usually more) reach
    it: Discard at the budget, with the state, time and outputs of the step's start."""
    budget, ne = _budget(), 100
    H = 0.9 * budget / ne * 1e-3                        # 0.9 of the budget at one iteration
    inst = open_plant(2, **XB, n_elements=ne, step=1e-3, phi0=0.2)
    assert inst.step(0.0, 1e-3) == 0
    before = inst.get(*OUTPUTS)
    assert inst.step(1e-3, H) == 2
    msg = inst.messages()
    assert f"budget of {budget} element-iterations per doStep ran out" in msg, msg
    assert inst.get(*OUTPUTS) == before
    assert inst.fmu.getRealStatus(2) == 1e-3            # fmi2LastSuccessfulTime
