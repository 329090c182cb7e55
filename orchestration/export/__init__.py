"""How the FMUs and systems are made and checked.

    build_fmus(flavour="native" | "python", fmi_version=2) -> {"FlexiblePendulum": path, ...}

:mod:`.python_fmus` builds the pythonfmu FMUs (FMI 2.0; only when their sources changed) into
``build/fmus/``; :mod:`.native_fmus` the native ones (C, FMI 2.0 and 3.0, linux64 and win64) into
``build/fmus/native/fmi2/`` and ``build/fmus/native/fmi3/``;
:mod:`.flavours` gives the FMUs of a flavour by name (``python``, ``native``);
:mod:`.ssp` writes a scene as an SSP 1.0 archive and reads one back (``flexpend export``,
``flexpend run FILE.ssp``);
:mod:`.check` regresses an FMU against reference results in the FMI cross-check layout and writes
them (``flexpend check``; the project's own references in ``tests/reference/``).
``build/build_fmus.py`` and ``flexpend build`` are thin front ends of this package.
"""
from pathlib import Path

from .native_fmus import NativeBuildError, build_native_fmus
from .python_fmus import BuildError

__all__ = ["build_fmus", "BuildError", "FMU_FLAVOURS", "fmu_pair"]

#: The two flavours of the FMUs: compiled C (the default of ``flexpend run``) and pythonfmu.
FMU_FLAVOURS = ("native", "python")


def build_fmus(out_dir=None, names=None, force: bool = False, *, flavour: str = "python",
               fmi_version: int = 2) -> dict:
    """Build (if stale) the FMUs of a flavour and return ``{model name: path}``.

    ``flavour``: ``"python"`` (pythonfmu, FMI 2.0 only; ``out_dir`` default ``build/fmus``) or
    ``"native"`` (C; ``fmi_version`` 2 or 3; ``out_dir`` default ``build/fmus/native``, the FMUs in
    its ``fmi2``/``fmi3`` folder). Raises :class:`BuildError` when a build fails and ValueError
    on a bad argument."""
    if flavour not in FMU_FLAVOURS:
        raise ValueError(f"flavour = {flavour!r}; allowed: {', '.join(FMU_FLAVOURS)}")
    if fmi_version not in (2, 3) or (flavour == "python" and fmi_version != 2):
        raise ValueError(f"fmi_version = {fmi_version!r}; allowed: 2 (both flavours), 3 (native)")
    if flavour == "python":
        from .python_fmus import DEFAULT_OUT, build_fmus as build_python
        return build_python(Path(out_dir) if out_dir else DEFAULT_OUT, names, force)
    try:
        return build_native_fmus(Path(out_dir) if out_dir else None, names, force, fmi_version)
    except NativeBuildError as exc:
        raise BuildError(str(exc)) from None


def fmu_pair(paths: dict) -> dict:
    """``{"plant": ..., "controller": ...}`` from :func:`build_fmus`' result (the master's names)."""
    return {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"]}
