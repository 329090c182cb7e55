"""What a command says on stderr besides its results and its errors: notes ("flexible_pd:
running 0.2 s", "built linux64 with cc") and progress bars (:mod:`orchestration.report.progress`),
all silenced within :func:`quiet` (``flexpend --quiet``). Below every layer that speaks (the FMU
factory's builds, the reports' bars), as :mod:`orchestration.files` is below every layer that
writes. Errors and warnings are not notes: nothing here silences them."""
from __future__ import annotations

import contextlib
import sys

__all__ = ["quiet", "is_quiet", "note"]

_QUIET = [False]


def is_quiet() -> bool:
    """Whether notes and bars are silenced (:func:`quiet`)."""
    return _QUIET[0]


@contextlib.contextmanager
def quiet(on: bool = True):
    """Within it, no note and no progress bar is written (``flexpend --quiet``)."""
    before = _QUIET[0]
    _QUIET[0] = bool(on) or before
    try:
        yield
    finally:
        _QUIET[0] = before


def note(text: str, stream=None) -> None:
    """A line on stderr (what a command is about to do, what it built), unless :func:`quiet`."""
    if not _QUIET[0]:
        stream = stream or sys.stderr
        stream.write(text + "\n")
        stream.flush()
