"""Where the FMUs and the build's caches go.

In a source checkout (``pyproject.toml`` beside the packages) they go into its ``build/``
folder: ``build/fmus/`` (pythonfmu FMUs), ``build/fmus/native/fmi2/`` and ``fmi3/`` (native FMUs)
and ``build/loader/`` (the pythonfmu FMUs' compiled loader), as docs/guide/build.md says. An
installed flexpend (a wheel in site-packages) writes nothing beside its packages: it builds into
``$FLEXPEND_HOME`` when set, else into the user's cache folder
(``$XDG_CACHE_HOME/flexpend/<version>``, by default ``~/.cache/flexpend/<version>``), whatever
the current folder. ``FLEXPEND_HOME`` also redirects a checkout's builds.
"""
from __future__ import annotations

import os
import threading
from contextlib import contextmanager
from pathlib import Path

#: The folder holding the packages: a checkout, or an installation's site-packages (this
#: module's own place: in the pythonfmu builder's child process, fmu_common may come from the
#: FMU's staging folder).
ROOT = Path(__file__).resolve().parents[2]

__all__ = ["ROOT", "in_checkout", "home", "fmu_dir", "native_fmu_dir", "loader_cache",
           "build_lock"]


def in_checkout() -> bool:
    """Whether the packages run from a source checkout (not from an installation)."""
    return (ROOT / "pyproject.toml").is_file() and (ROOT / "orchestration").is_dir()


def home() -> Path:
    """The folder that holds the built FMUs and the build's caches."""
    env = os.environ.get("FLEXPEND_HOME")
    if env:
        return Path(env).expanduser()
    if in_checkout():
        return ROOT / "build"
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("flexpend")
    except PackageNotFoundError:
        v = "unknown"
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "flexpend" / v


def fmu_dir() -> Path:
    """The pythonfmu FMUs' folder (``build/fmus`` in a checkout)."""
    return home() / "fmus"


def native_fmu_dir() -> Path:
    """The native FMUs' folder, holding ``fmi2/`` and ``fmi3/`` (``build/fmus/native``)."""
    return home() / "fmus" / "native"


def loader_cache() -> Path:
    """The compiled loaders of the pythonfmu FMUs, by source digest (``build/loader``)."""
    return home() / "loader"


@contextmanager
def build_lock():
    """Hold the builds' lock (``<home>/.build.lock``): two processes that build the same FMUs at
    once (two ``flexpend run``, the workers of a test session) take turns, and the second finds
    them up to date. Without ``fcntl`` (Windows) builds are not serialised; each file is still
    written atomically."""
    try:
        import fcntl
    except ImportError:
        fcntl = None
    if fcntl is None or _held.depth:              # not serialised here, or already held
        _held.depth += 1
        try:
            yield
        finally:
            _held.depth -= 1
        return
    folder = home()
    folder.mkdir(parents=True, exist_ok=True)
    from ..files import open_in_place
    fd = open_in_place(folder / ".build.lock", os.O_RDWR | os.O_CREAT | os.O_APPEND)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        _held.depth += 1
        try:
            yield
        finally:
            _held.depth -= 1
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


class _Depth(threading.local):
    depth = 0


_held = _Depth()
