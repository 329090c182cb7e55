"""Scenes read once into typed records: every record is made (and validated) once per run, every
connection parsed once, every FMU's modelDescription read once; the records reject bad values
naming the key, and read back through the keys they were made from."""
import dataclasses
import math

import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.cli import main
from orchestration.cosim import slave as slave_module
from orchestration.scene import records, schema, wiring
from orchestration.scene.keys import ConfigError
from orchestration.scene.records import (KEYS, FidelitySettings, InitialState, MasterSettings,
                                         OutputSettings, PlantSetup, Scene)
from orchestration.scene.schema import known_keys, load_scene, scene_from_config
from plant_fmu.params import PlantParams


RECORDS = (PlantParams, ControllerParams, PlantSetup, MasterSettings, InitialState,
           FidelitySettings, OutputSettings, Scene)


@pytest.fixture
def counts(monkeypatch):
    """Constructions of every record class, parses of connections, reads of modelDescriptions."""
    made = {cls.__name__: 0 for cls in RECORDS}
    made["parse_connection"] = made["read_model_description"] = 0
    for cls in RECORDS:
        original = cls.__post_init__

        def counted(self, _original=original, _name=cls.__name__):
            made[_name] += 1
            _original(self)
        monkeypatch.setattr(cls, "__post_init__", counted)
    parse = wiring.parse_connection

    def parse_counted(text):
        made["parse_connection"] += 1
        return parse(text)
    monkeypatch.setattr(records, "parse_connection", parse_counted)
    read = slave_module.model_description          # fmpy's reader, behind the FMU's checks

    def read_counted(path, *args, **kwargs):
        made["read_model_description"] += 1
        return read(path, *args, **kwargs)
    monkeypatch.setattr(slave_module, "model_description", read_counted)
    slave_module._describe.cache_clear()
    return made


def test_one_run_builds_each_record_once(native, counts, tmp_path):
    """``flexpend run`` of one scene, in this process: the scene's records once each, its four
    connections once each, the two FMUs' modelDescriptions once each (the wiring check and the
    master share them). Its companion run (the error figure's: the same scene on another
    plant model) is one scene more, built from these records: its plant's records are new, and
    its plant FMU's modelDescription (the stiffened rung's own FMU, FlexiblePendulumStiffened)
    is read once; nothing else is read or parsed again."""
    assert main(["run", "flexible_pd_lowpass", "--set", "stop_time=0.2", "--set",
                 "fidelity.companion=false", "--out", str(tmp_path)]) == 0
    assert {k: counts[k] for k in (c.__name__ for c in RECORDS)} == \
        {c.__name__: 1 for c in RECORDS}
    assert counts["parse_connection"] == len(records.DEFAULT_CONNECTIONS) == 4
    assert counts["read_model_description"] == 2
    for k in counts:
        counts[k] = 0
    assert main(["run", "flexible_pd_lowpass", "--set", "stop_time=0.2", "--out",
                 str(tmp_path)]) == 0
    plant = ("PlantParams", "PlantSetup")
    assert {k: counts[k] for k in (c.__name__ for c in RECORDS) if k not in plant} == \
        {c.__name__: 1 + (c.__name__ == "Scene") for c in RECORDS if c.__name__ not in plant}
    assert counts["parse_connection"] == 4 and counts["read_model_description"] == 1


def test_every_key_reads_back_what_made_the_records():
    """Keys -> records -> keys is the identity on the values given (normalised as the records
    normalise them: an int given for a real is a float)."""
    values = {"plant.n_modes": 3, "plant.EI": 900, "controller.kp": 450.5, "master.step": 1e-3,
              "master.algorithm": "jacobi", "initial.phi": 0.25, "stop_time": 2,
              "output_interval": 0.004, "fidelity.outputs": ["phi_o", "x"],
              "plant.phi_limit": math.inf, "description": "a test"}
    scene = scene_from_config("t", values)
    for key, value in values.items():
        got = scene.get(key)
        assert got == value and (type(got) is type(value) or isinstance(value, int)), key
    assert scene.plant.params.EI == 900.0 and isinstance(scene.plant.params.EI, float)
    assert set(scene.config) == set(KEYS) == set(known_keys())
    assert scene_from_config("t", dict(scene.config)) == scene


def test_records_are_frozen_and_validate_on_their_own():
    scene = load_scene("rigid_pd")
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.master.step = 1.0
    with pytest.raises(ConfigError, match=r"^master.extrapolation = 3 is out of range"):
        MasterSettings(extrapolation=3)
    with pytest.raises(ConfigError, match=r"^initial.phi must be a real number"):
        InitialState(phi="up")
    with pytest.raises(ConfigError, match=r"^fidelity.outputs = \['phi'\] is not allowed"):
        FidelitySettings(outputs=["phi"])
    with pytest.raises(ConfigError, match="must be a positive multiple of output_interval"):
        OutputSettings(stop_time=0.015, output_interval=0.01)
    with pytest.raises(ConfigError, match="output_interval = 0.003 must be a multiple of "
                                          "master.step = 0.002"):
        Scene("s", output=OutputSettings(stop_time=0.006, output_interval=0.003))


def test_an_auto_model_must_be_chosen_before_its_parameters_are_used():
    scene = load_scene("flexible_pd", {"plant.n_modes": "auto"})
    assert not scene.resolved and scene.plant.n_modes == "auto"
    with pytest.raises(ConfigError, match="plant.n_modes = 'auto' is chosen by a run"):
        scene.plant.params
    chosen = scene.replace(plant=scene.plant.with_model(3, "nonlinear"))
    assert chosen.resolved and chosen.plant.params.n_modes == 3
    assert chosen.plant.params.EI == scene.plant.beam.EI


def test_load_scene_takes_names_paths_dicts_and_records(tmp_path):
    by_name = load_scene("rigid_pd")
    path = schema.SCENE_DIR / "rigid_pd.toml"
    assert load_scene(path) == load_scene(str(path)) == by_name
    assert load_scene(by_name) is by_name
    assert load_scene(by_name, {"controller.kp": 400}).controller.kp == 400.0
    assert load_scene({"controller.kp": 400}).controller.kp == 400.0
    with pytest.raises(TypeError, match="scene must be a name, a path, a dict"):
        load_scene(42)
    with pytest.raises(TypeError, match="overrides must be a dict"):
        load_scene("rigid_pd", "controller.kp=400")


@pytest.mark.parametrize("n_modes", [0, 4])
@pytest.mark.parametrize("fidelity", ["nonlinear", "linear"])
def test_initial_energy_is_the_plant_models(n_modes, fidelity):
    """The scene's energy check computes what the plant FMU's model computes at the start."""
    import numpy as np

    from plant_fmu.dynamics import linear_plant_model, plant_model

    p = PlantParams(n_modes=n_modes, EI=900.0, m=1.3, L=1.1, gravity_preload=True)
    model = (linear_plant_model if fidelity == "linear" else plant_model)(p)
    start = InitialState(phi=0.7, x=0.3, phi_dot=-1.2, x_dot=2.5)
    x = np.zeros(2 * model.nq)
    x[[0, 1, model.nq, model.nq + 1]] = start.x, start.phi, start.x_dot, start.phi_dot
    assert records.initial_energy(p, start, linear=fidelity == "linear") == \
        pytest.approx(model.energy(x), rel=1e-12)


@pytest.mark.parametrize("overrides,fragment", [
    ({"initial.phi": 2}, "initial.phi = 2 is beyond plant.phi_limit = 1.571 rad (90 deg)"),
    ({"initial.phi": -1.6}, "initial.phi = -1.6 is beyond plant.phi_limit = 1.571 rad"),
    ({"initial.phi": 0.6, "plant.phi_limit": 0.5},
     "initial.phi = 0.6 is beyond plant.phi_limit = 0.5 rad"),
    ({"initial.x_dot": 2000}, "beyond plant.energy_limit = 1e+06 J"),
    ({"initial.phi_dot": 500, "plant.energy_limit": 1e5, "plant.fidelity": "linear"},
     "beyond plant.energy_limit = 1e+05 J"),
])
def test_an_initial_state_beyond_the_plants_limits_is_rejected(overrides, fragment):
    """The plant FMU stops a run at once beyond its limits: the scene is refused when read, in
    one line naming the key and the limit."""
    with pytest.raises(ConfigError) as info:
        load_scene("rigid_pd", overrides)
    assert fragment in str(info.value) and "\n" not in str(info.value)


def test_an_initial_state_at_the_limit_or_without_one_is_accepted():
    assert load_scene("rigid_pd", {"initial.phi": math.pi / 2}).initial.phi == math.pi / 2
    assert load_scene("rigid_pd", {"initial.phi": 3, "plant.phi_limit": math.inf}).initial.phi == 3
    assert load_scene("rigid_pd", {"initial.x_dot": 2000,
                                   "plant.energy_limit": math.inf}).initial.x_dot == 2000
