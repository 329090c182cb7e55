"""flexpend's host side: scenes, the co-simulation master, studies, reports, sweeps and FMU
builds, with one front door.

    import orchestration as fp

    run = fp.simulate("flexible_pd_lowpass", {"controller.kp": 400, "stop_time": 2})
    run.summary["stable"], run.to_pandas(), run.plot(), run.save("out")
    fp.analyze(overrides={"plant.n_modes": 3}).eigenvalues
    fp.stability("flexible_pd_lowpass", max_step=0.03)["scene"]["intervals"]
    fp.design(progress=True).result.chosen
    fp.sweep("rigid_pd", grid={"controller.kp": (300, 700, 5)}, serial=True).to_pandas()
    fp.build_fmus("native")
    fp.scene_keys()           # every scene key: type, default, unit, allowed values, meaning

The names are loaded on first use (``import orchestration`` itself imports nothing heavy). Every
error in the input is a ``ValueError`` (:class:`ConfigError` for a scene key) or a ``TypeError``
(a value of the wrong type: a string for a number) whose one-line message names the bad key or
argument, what is allowed and, for an unknown key, the closest one; a co-simulation that an FMU
stops is not an error: its summary says when and why.

The layers, from the top (an import goes only downwards; ``tests/project/test_layers.py`` checks
it): ``cli`` -> this front door (``api``) -> ``sweeps`` -> ``job`` -> ``export`` -> ``report`` ->
``studies`` -> ``cosim`` -> ``scene`` -> ``files`` (output files, complete or absent) and
``notes`` (what a command says on stderr, silenced by ``--quiet``) -> the models (``plant_fmu``,
``controller_fmu``) -> ``fmu_common``.
"""
from __future__ import annotations

__all__ = ["simulate", "load_scene", "analyze", "stability", "design", "sweep", "build_fmus",
           "scene_keys", "Scene", "Run", "Analysis", "DesignReport", "Sweep", "KeySpec",
           "ConfigError", "CoSimulationError", "__version__"]

_API = {"simulate", "load_scene", "analyze", "stability", "design", "sweep", "build_fmus",
        "scene_keys", "Scene", "Run", "Analysis", "DesignReport", "Sweep", "KeySpec"}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("flexpend")
    except PackageNotFoundError:          # a checkout that is not installed
        return "0+unknown"


def __getattr__(name: str):
    if name in _API:
        from . import api
        return getattr(api, name)
    if name == "ConfigError":
        from .scene.keys import ConfigError
        return ConfigError
    if name == "CoSimulationError":
        from .cosim.slave import CoSimulationError
        return CoSimulationError
    if name == "__version__":
        return _version()
    raise AttributeError(f"module 'orchestration' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
