"""Scenes: what to run, as TOML files in ``orchestration/scene/files/``.

A scene is a flat mapping of dotted keys (TOML tables flatten to them: ``[plant] n_modes = 4`` is
``plant.n_modes``), validated here. ``plant.*`` and ``controller.*`` are the FMU parameters, with
the names of ``flexpend analyze``; the plant's solver settings are ``plant.integrator``,
``plant.step``, ``plant.rtol`` and ``plant.atol``.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from plant_fmu.interface import FMU_SETTINGS
from fmu_common.checks import check_bool, check_int, check_real

from .keys import (FIDELITIES, ConfigError, apply_overrides, check_known, controller_params,
                   default_config, plant_params)

__all__ = ["Scene", "SCENE_DIR", "SCENE_DEFAULTS", "load_scene", "scene_from_config",
           "list_scenes", "PAPER_SCENES", "ALGORITHMS", "validate_config"]

SCENE_DIR = Path(__file__).parent / "files"
#: The paper's sample, in the order of its figures: rigid + PD, flexible + PD, flexible + filter.
PAPER_SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
ALGORITHMS = ("gauss-seidel", "jacobi")
FIRST = ("controller", "plant")
#: the FMUs a scene runs on (orchestration.export.FLAVOURS)
FMU_FLAVOURS = ("native", "python")

AUTO = "auto"


#: Outputs that every model has (0 for the rigid model's deflection), by result column.
COMPARABLE_OUTPUTS = ("x", "x_dot", "phi_o", "omega_o", "F_c", "tip_deflection", "eta_1")


#: ``fidelity.*`` scene keys with their defaults.
FIDELITY_DEFAULTS = {
    "fidelity.tolerance": 0.05,
    "fidelity.max_modes": 8,
    "fidelity.outputs": ["x", "phi_o", "omega_o", "F_c"],
}


def validate_fidelity_keys(cfg: dict) -> None:
    """Check the ``fidelity.*`` keys in place (a :class:`ConfigError` names a bad one)."""
    from fmu_common.checks import check_int, check_real
    try:
        cfg["fidelity.tolerance"] = check_real("fidelity.tolerance", cfg["fidelity.tolerance"],
                                               low=0.0, high=1.0)
        n_el = cfg["plant.n_elements"] if isinstance(cfg["plant.n_elements"], int) else 24
        cfg["fidelity.max_modes"] = check_int("fidelity.max_modes", cfg["fidelity.max_modes"],
                                              low=1, high=n_el)
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    outs = cfg["fidelity.outputs"]
    if (not isinstance(outs, list) or not outs
            or not all(isinstance(o, str) and o in COMPARABLE_OUTPUTS for o in outs)):
        raise ConfigError(f"fidelity.outputs = {outs!r} is not allowed; allowed: a non-empty list "
                          f"of {', '.join(COMPARABLE_OUTPUTS)}")


def needs_selection(scene) -> bool:
    return AUTO in (scene["plant.n_modes"], scene["plant.fidelity"])


#: Scene keys beyond the plant and controller parameters, with their defaults.
SCENE_DEFAULTS = {
    "description": "",
    "stop_time": 10.0,
    "output_interval": 0.002,
    "initial.phi": math.pi / 6,
    "initial.x": 0.0,
    "initial.phi_dot": 0.0,
    "initial.x_dot": 0.0,
    "master.algorithm": "gauss-seidel",
    "master.first": "controller",
    "master.step": 2e-3,
    "master.extrapolation": 2,
    "master.adaptive": False,
    "master.tolerance": 1e-4,
    "master.min_step": 1e-6,
    "master.max_step": 2e-2,
    "master.input_derivatives": True,
    # which FMUs run: "native" (compiled C, FMI 2.0) or "python" (pythonfmu)
    "master.fmus": "native",
    # the master's fixed-step loop in C when the FMUs can take it ("auto": the native FMUs), or
    # always in Python (false); true: in C or an error saying why not
    "master.compiled": "auto",
    # wiring by variable name: "fmu.variable -> fmu.variable", FMUs "plant" and "controller"
    "connections": [
        "plant.x_o -> controller.x_o",
        "plant.phi_o -> controller.phi_o",
        "plant.omega_o -> controller.omega_o",
        "controller.F_c -> plant.F_c",
    ],
    # the plant FMU's solver settings and divergence bounds, with the FMU's own defaults
    **{f"plant.{k}": v for k, v in FMU_SETTINGS.items() if k != "fidelity"},
    # the choice of plant.n_modes = "auto" / plant.fidelity = "auto" (orchestration/studies/fidelity.py)
    **FIDELITY_DEFAULTS,
}


def _flatten(table: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _choice(key, value, allowed):
    if value not in allowed:
        raise ConfigError(f"{key} = {value!r} is not allowed; allowed: {', '.join(map(str, allowed))}")
    return value


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``config`` holds every key, defaults filled in."""

    name: str
    config: dict = field(repr=False)

    def __getitem__(self, key):
        return self.config[key]

    @property
    def plant(self):
        return plant_params(self.config)

    @property
    def controller(self):
        return controller_params(self.config)


def _validate(cfg: dict) -> None:
    def real(key, **kw):
        try:
            cfg[key] = check_real(key, cfg[key], **kw)
        except (TypeError, ValueError) as exc:
            raise ConfigError(str(exc)) from None

    n_modes = cfg["plant.n_modes"]
    if isinstance(n_modes, str) and n_modes != AUTO:
        raise ConfigError(f"plant.n_modes = {n_modes!r} is not allowed; allowed: an integer "
                          f"0..plant.n_elements or {AUTO!r}")
    plant_params({**cfg, "plant.n_modes": 0} if n_modes == AUTO else cfg)
    controller_params(cfg)
    _choice("plant.fidelity", cfg["plant.fidelity"], (*FIDELITIES, AUTO))
    validate_fidelity_keys(cfg)
    real("stop_time", low=0.0, high=1e6)
    real("output_interval", low=0.0, high=1e6)
    for k in ("initial.phi", "initial.x", "initial.phi_dot", "initial.x_dot"):
        real(k, low=-1e6, high=1e6)
    for k in ("master.step", "master.tolerance", "master.min_step", "master.max_step",
              "plant.step", "plant.rtol", "plant.atol"):
        real(k, low=0.0, high=1e6)
    for k in ("plant.phi_limit", "plant.energy_limit"):
        real(k, low=0.0, allow_inf=True)
    _choice("master.algorithm", cfg["master.algorithm"], ALGORITHMS)
    _choice("master.first", cfg["master.first"], FIRST)
    _choice("master.fmus", cfg["master.fmus"], FMU_FLAVOURS)
    if not (isinstance(cfg["master.compiled"], bool) or cfg["master.compiled"] == "auto"):
        raise ConfigError(f"master.compiled = {cfg['master.compiled']!r} is not allowed; "
                          f"allowed: 'auto', true, false")
    try:
        cfg["master.extrapolation"] = check_int("master.extrapolation", cfg["master.extrapolation"],
                                                low=0, high=2)
        cfg["master.adaptive"] = check_bool("master.adaptive", cfg["master.adaptive"])
        cfg["master.input_derivatives"] = check_bool("master.input_derivatives",
                                                     cfg["master.input_derivatives"])
    except (TypeError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    from plant_fmu.integrators import REGISTRY
    _choice("plant.integrator", cfg["plant.integrator"], sorted(REGISTRY))
    if cfg["plant.integrator"] == "exponential" and cfg["plant.fidelity"] != "linear":
        raise ConfigError("plant.integrator = 'exponential' integrates the linearised plant; it "
                          "needs plant.fidelity = 'linear'")
    conns = cfg["connections"]
    if not isinstance(conns, list) or not conns or not all(isinstance(c, str) for c in conns):
        raise ConfigError("connections must be a non-empty list of strings "
                          "'fmu.variable -> fmu.variable'")
    from .wiring import parse_connection
    for c in conns:
        try:
            conn = parse_connection(c)
        except ValueError as exc:
            raise ConfigError(f"connections {exc}") from None
        for fmu in (conn.src, conn.dst):
            if fmu not in ("plant", "controller"):
                raise ConfigError(f"connections {c!r} names FMU {fmu!r}; allowed: plant, "
                                  "controller")
    if not isinstance(cfg["description"], str):
        raise ConfigError("description must be a string")
    if cfg["master.min_step"] > cfg["master.max_step"]:
        raise ConfigError(f"master.min_step = {cfg['master.min_step']} exceeds master.max_step = "
                          f"{cfg['master.max_step']}")
    if cfg["master.step"] > cfg["stop_time"]:
        raise ConfigError(f"master.step = {cfg['master.step']} exceeds stop_time = "
                          f"{cfg['stop_time']}")
    n_out = cfg["stop_time"] / cfg["output_interval"]
    if n_out < 1 - 1e-9 or abs(n_out - round(n_out)) > 1e-9 * n_out:
        raise ConfigError(f"stop_time = {cfg['stop_time']} must be a positive multiple of "
                          f"output_interval = {cfg['output_interval']}")
    ratio = cfg["output_interval"] / cfg["master.step"]
    if not cfg["master.adaptive"] and abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(f"output_interval = {cfg['output_interval']} must be a multiple of "
                          f"master.step = {cfg['master.step']}")


#: Validates a scene's configuration in place (a :class:`ConfigError` names the bad key).
validate_config = _validate


def known_keys() -> dict:
    return {**default_config(), **SCENE_DEFAULTS}


def scene_from_config(name: str, values: dict, overrides=()) -> Scene:
    """Validate ``values`` (dotted keys) with ``--set`` overrides on top."""
    known = known_keys()
    check_known(values, known)
    try:
        cfg = apply_overrides({**known, **values}, overrides, known)
    except ConfigError as exc:
        raise OverrideError(f"--set: {exc}") from None
    try:
        _validate(cfg)
    except ConfigError as exc:
        from .keys import parse_override
        if any(str(exc).startswith(parse_override(o)[0] + " ") for o in overrides):
            raise OverrideError(f"--set: {exc}") from None
        raise
    return Scene(name, cfg)


class OverrideError(ConfigError):
    """A bad ``--set`` item (reported without the scene file's name)."""


def _resolve(ref: str) -> Path:
    path = Path(ref)
    if path.suffix == ".toml" and path.exists():
        return path
    candidate = SCENE_DIR / f"{ref}.toml"
    if candidate.exists():
        return candidate
    raise ConfigError(f"no scene {ref!r}; scenes: {', '.join(list_scenes())} (or a path to a "
                      ".toml file)")


def load_scene(ref: str, overrides=()) -> Scene:
    """Load a scene by name (a file in ``orchestration/scene/files/``) or by path."""
    path = _resolve(ref)
    try:
        values = _flatten(tomllib.loads(path.read_text()))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path.name}: not valid TOML: {exc}") from None
    try:
        return scene_from_config(path.stem, values, overrides)
    except OverrideError:
        raise
    except ConfigError as exc:
        raise ConfigError(f"{path.name}: {exc}") from None


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))
