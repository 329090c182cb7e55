"""How the FMUs (and, later, systems) are made: the pythonfmu build and the reference results.

    build_fmus(out_dir=build/fmus, names=None, force=False) -> {"FlexiblePendulum": path, ...}

:mod:`.python_fmus` builds the pythonfmu FMUs (only when their sources changed);
:mod:`.references` writes and compares their reference results (FMI cross-check layout).
``build/build_fmus.py`` and ``flexpend build`` are thin front ends of this package.
"""
from .python_fmus import BuildError, build_fmus

__all__ = ["build_fmus", "BuildError"]
