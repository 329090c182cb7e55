"""How the FMUs and systems are made and checked.

    build_fmus(out_dir=build/fmus, names=None, force=False) -> {"FlexiblePendulum": path, ...}

:mod:`.python_fmus` builds the pythonfmu FMUs (only when their sources changed);
:mod:`.flavours` gives the FMUs of a flavour by name (``python``; ``native`` to come);
:mod:`.ssp` writes a scene as an SSP 1.0 archive and reads one back (``flexpend export``,
``flexpend run FILE.ssp``);
:mod:`.check` regresses an FMU against reference results in the FMI cross-check layout and writes
them (``flexpend check``; the project's own references in ``tests/reference/``).
``build/build_fmus.py`` and ``flexpend build`` are thin front ends of this package.
"""
from .python_fmus import BuildError, build_fmus

__all__ = ["build_fmus", "BuildError"]
