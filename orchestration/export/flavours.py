"""The FMU flavours a system can be exported with, by name.

    fmu_paths("python")  -> {"plant": path, "controller": path}   (built if stale)

Each flavour is one function in :data:`FLAVOURS` that returns the paths of the plant and the
controller FMU, building them if needed; ``None`` marks a flavour this build does not have (the
command line says so and exits 2). ``python`` are the pythonfmu FMUs of :mod:`.python_fmus`,
``native`` the FMI 2.0 native FMUs of :mod:`.native_fmus`.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["FLAVOURS", "DEFAULT_FLAVOUR", "FlavourUnavailable", "fmu_paths"]


class FlavourUnavailable(ValueError):
    """The FMUs of this flavour cannot be had in this build (the message says why)."""


def _python_fmus() -> dict:
    from .python_fmus import build_fmus

    paths = build_fmus()
    return {"plant": Path(paths["FlexiblePendulum"]), "controller": Path(paths["PDLowPass"])}


def _native_fmus() -> dict:
    from .native_fmus import build_native_fmus

    paths = build_native_fmus(fmi_version=2)
    return {"plant": Path(paths["FlexiblePendulum"]), "controller": Path(paths["PDLowPass"])}


#: flavour -> function returning ``{"plant": path, "controller": path}``; ``None``: not in this
#: build.
FLAVOURS = {
    "native": _native_fmus,
    "python": _python_fmus,
}
#: The flavour ``flexpend export`` uses unless told otherwise.
DEFAULT_FLAVOUR = "native"


def fmu_paths(flavour: str = DEFAULT_FLAVOUR) -> dict:
    """``{"plant": path, "controller": path}`` of the FMUs of ``flavour`` (built if stale)."""
    if flavour not in FLAVOURS:
        raise ValueError(f"FMU flavour {flavour!r} is not known; known: {', '.join(FLAVOURS)}")
    build = FLAVOURS[flavour]
    if build is None:
        raise FlavourUnavailable(f"the {flavour} FMUs are not available in this build")
    return build()
