"""Reading scenes: scene files (TOML), dicts and ``--set`` items into a validated
:class:`~orchestration.scene.records.Scene`.

A scene file is TOML whose tables flatten to dotted keys (``[plant] n_modes = 4`` is
``plant.n_modes``); the keys are those of :data:`~orchestration.scene.records.KEYS`, with the
defaults of the records. Every key is checked once, when the records are made: an unknown key, or
a bad value, is a :class:`~orchestration.scene.keys.ConfigError` whose one-line message names it
(and the file, or ``--set``, it came from).
"""
from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path

import tomllib

from controller_fmu.pd_lowpass import ControllerParams
from fmu_common.checks import shown
from fmu_common.variables import start_values as _start_values
from plant_fmu.params import PlantParams

from .keys import ConfigError, ConfigTypeError, check_known, config_error, parse_override
from .records import (
    AUTO,
    KEYS,
    FidelitySettings,
    InitialState,
    MasterSettings,
    OutputSettings,
    PlantSetup,
    Scene,
)

__all__ = ["SCENE_DIR", "PAPER_SCENES", "known_keys", "scene_from_config", "load_scene",
           "list_scenes", "OverrideError", "start_values", "MAX_SCENE_BYTES"]

SCENE_DIR = Path(__file__).parent / "files"
#: The paper's sample, in the order of its figures: rigid + PD, flexible + PD, flexible + filter.
PAPER_SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")
#: The largest scene file read (a scene is a few hundred bytes).
MAX_SCENE_BYTES = 1 << 20


class OverrideError(ConfigError):
    """A bad override (a ``--set`` item): reported without the scene file's name; the command
    line says ``--set: `` before it (:attr:`ConfigError.cli`)."""


def _override_error(exc: ConfigError) -> OverrideError:
    return exc.prefixed("", "--set: ", OverrideError)


def known_keys() -> dict:
    """Every scene key with its default (a new dict: the caller may change it)."""
    if not _DEFAULTS:                 # read off the records once (a sweep plans 10,000 scenes)
        _DEFAULTS.update(_DEFAULT.config)
    return dict(_DEFAULTS)


#: every scene key's default, filled by the first :func:`known_keys`
_DEFAULTS: dict = {}


def _section(cfg: dict, prefix: str, cls) -> dict:
    return {f.name: cfg[f"{prefix}{f.name}"] for f in dataclasses.fields(cls)
            if f"{prefix}{f.name}" in cfg}


def _plant(cfg: dict) -> PlantSetup:
    n_modes = cfg["plant.n_modes"]
    auto = n_modes == AUTO
    if isinstance(n_modes, str) and not auto:
        raise ConfigTypeError(f"plant.n_modes = {shown(n_modes)} is not allowed; allowed: an "
                              f"integer 0..plant.n_elements or {AUTO!r}")
    physical = _section(cfg, "plant.", PlantParams)
    if auto:
        physical["n_modes"] = 0
    try:
        beam = PlantParams(**physical)
    except (TypeError, ValueError) as exc:
        raise config_error(exc, "plant.") from None
    settings = {f.name: cfg[f"plant.{f.name}"] for f in dataclasses.fields(PlantSetup)
                if f.name not in ("beam", "n_modes_auto")}
    return PlantSetup(beam, auto, **settings)


def _controller(cfg: dict) -> ControllerParams:
    try:
        return ControllerParams(**_section(cfg, "controller.", ControllerParams))
    except (TypeError, ValueError) as exc:
        raise config_error(exc, "controller.") from None


def _build(name: str, cfg: dict) -> Scene:
    """The records of a complete configuration (every key of :data:`KEYS`)."""
    return Scene(name=name, plant=_plant(cfg), controller=_controller(cfg),
                 fidelity=FidelitySettings(**_section(cfg, "fidelity.", FidelitySettings)),
                 output=OutputSettings(**_section(cfg, "", OutputSettings)),
                 initial=InitialState(**_section(cfg, "initial.", InitialState)),
                 master=MasterSettings(**_section(cfg, "master.", MasterSettings)),
                 connections=cfg["connections"], description=cfg["description"])


def _overrides(overrides) -> list:
    """``--set`` items (``"key=value"`` strings) or a dict as ``[(key, value)]``."""
    if overrides is None:
        return []
    if isinstance(overrides, dict):
        for k in overrides:
            if not isinstance(k, str):
                raise TypeError(f"overrides: a key must be a string, got {k!r}")
        return list(overrides.items())
    if isinstance(overrides, str):
        raise TypeError("overrides must be a dict of scene keys or a list of 'key=value' "
                        f"strings, got the string {overrides!r}")
    return [parse_override(o) if isinstance(o, str) else _bad_item(o) for o in overrides]


def _bad_item(item):
    raise TypeError(f"overrides: expected 'key=value', got {item!r}")


def scene_from_config(name: str, values: dict, overrides=None) -> Scene:
    """The scene of the keys ``values`` (the rest at their defaults), with ``overrides`` (``--set``
    items, or a dict) on top."""
    known = known_keys()
    check_known(values, known)
    pairs = _overrides(overrides)
    try:
        check_known([k for k, _ in pairs], known)
    except ConfigError as exc:
        raise _override_error(exc) from None
    cfg = {**known, **values, **dict(pairs)}
    try:
        return _build(name, cfg)
    except ConfigError as exc:
        if any(re.search(rf"(?<![\w.]){re.escape(k)}(?![\w.])", str(exc)) for k, _ in pairs):
            raise _override_error(exc) from None     # a check that involves an override
        raise


def _resolve(ref: str) -> Path:
    path = Path(ref)
    if path.suffix == ".toml" and (path.exists() or os.sep in ref or "/" in ref):
        return path
    candidate = SCENE_DIR / f"{ref}.toml"
    if candidate.exists():
        return candidate
    raise ConfigError(f"no scene {ref!r}; scenes: {', '.join(list_scenes())} (or a path to a "
                      ".toml file)")


def _flatten(table: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _read_toml(path: Path) -> dict:
    """The flattened keys of a scene file (a ConfigError names what is wrong with the file)."""
    label = path.name
    try:
        if not path.is_file():
            raise ConfigError(f"{label}: not a regular file" if path.exists()
                              else f"{label}: no such file")
        with open(path, "rb") as fh:
            data = fh.read(MAX_SCENE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{label}: cannot be read ({exc.strerror or exc})") from None
    if len(data) > MAX_SCENE_BYTES:
        raise ConfigError(f"{label}: larger than {MAX_SCENE_BYTES} bytes; a scene file is a few "
                          "hundred")
    try:
        return _flatten(tomllib.loads(data.decode("utf-8")))
    except UnicodeDecodeError:
        raise ConfigError(f"{label}: not valid TOML: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{label}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{label}: not valid TOML: nested too deeply") from None


def load_scene(ref, overrides=None) -> Scene:
    """A scene by name (a file of ``orchestration/scene/files/``), by path (a ``.toml`` file), from
    a dict of scene keys, or a :class:`Scene` itself; ``overrides`` (``--set`` items or a dict of
    scene keys) on top."""
    if isinstance(ref, Scene):
        return ref if not overrides else scene_from_config(ref.name, dict(ref.config), overrides)
    if isinstance(ref, dict):
        return scene_from_config("scene", ref, overrides)
    if not isinstance(ref, (str, os.PathLike)):
        raise TypeError(f"scene must be a name, a path, a dict of scene keys or a Scene, got "
                        f"{type(ref).__name__}")
    path = _resolve(os.fspath(ref))
    values = _read_toml(path)
    try:
        return scene_from_config(path.stem, values, overrides)
    except OverrideError:
        raise
    except ConfigError as exc:
        raise exc.prefixed(f"{path.name}: ") from None


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))


def start_values(scene: Scene, table) -> dict:
    """FMU start values of ``scene``: every parameter of the variable table ``table`` that a
    scene key sets (:attr:`fmu_common.variables.Variable.scene_key`), read off the records; at
    the exact rung the plant's ``step`` is ``plant.exact_step``."""
    values = {v.scene_key: scene.get(v.scene_key) for v in table
              if v.causality == "parameter" and v.scene_key in KEYS}
    if "plant.step" in values and scene.plant.fidelity == "exact":
        values["plant.step"] = scene.plant.exact_step        # the exact rung's Radau step
    return _start_values(values, table)


_DEFAULT = Scene(name="default")
