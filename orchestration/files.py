"""Output files that are complete or absent: each is written to a temporary name beside its place
and renamed into it, so a failed or interrupted write never leaves half a file, nor destroys a
good file of the same name. A write that fails (a full disk, a read-only folder) raises
:class:`OutputError`, one line naming the file; :func:`folder_lock` keeps a second run out of an
output folder in use."""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["OutputError", "output_error", "atomic_path", "folder_lock", "LOCK_FILE", "write_text",
           "write_json", "write_csv", "json_safe", "check_folder", "FILE_SUFFIXES"]

#: The lock file :func:`folder_lock` holds in an output folder.
LOCK_FILE = ".flexpend.lock"


class OutputError(OSError):
    """An output that cannot be written: a full disk, a folder that refuses the file, a folder in
    use by another run. Its text is one line naming the file or folder (the CLI prints it, exit
    code 2); ``errno`` is the system's."""

    def __str__(self):
        return str(self.strerror)


def output_error(path, exc: OSError) -> OutputError:
    """``exc`` (an OSError while writing ``path``) as an :class:`OutputError` naming ``path``."""
    if isinstance(exc, OutputError):
        return exc
    return OutputError(exc.errno, f"cannot write {path}: {exc.strerror or exc}")


class atomic_path:
    """``with atomic_path(path) as tmp:`` write ``tmp``; on success it is synced to the disk and
    replaces ``path`` (so after a crash of the machine ``path`` is the old file or the new one,
    whole), on any exception it is removed and ``path`` is left as it was (an OSError is raised
    as an :class:`OutputError` naming ``path``)."""

    def __init__(self, path, suffix: str = ""):
        self.path = Path(path)
        self.suffix = suffix or self.path.suffix

    def __enter__(self) -> Path:
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.",
                                       suffix=f".part{self.suffix}", dir=self.path.parent)
        except OSError as exc:
            raise output_error(self.path, exc) from None
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                os.chmod(self.tmp, 0o644)
                fd = os.open(self.tmp, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
                os.replace(self.tmp, self.path)
                return False
            except OSError as failed:
                exc = failed
        self.tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise output_error(self.path, exc) from exc
        return False


@contextlib.contextmanager
def folder_lock(folder):
    """``with folder_lock(folder):`` this process is the only one writing ``folder``: it holds
    ``folder/.flexpend.lock`` (an exclusive ``flock``, which the system releases however the
    process ends, even killed), removed on the way out; another process that asks for it
    meanwhile gets an :class:`OutputError` at once. Where ``flock`` does not exist (Windows) the
    folder is not locked."""
    try:
        import fcntl
    except ImportError:             # pragma: no cover - not POSIX
        yield
        return
    path = Path(folder) / LOCK_FILE
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise output_error(path, exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip()
            os.close(fd)
            raise OutputError(errno.EBUSY, f"{folder}: in use by another flexpend run"
                              + (f" (process {holder})" if holder.isdigit() else "")
                              + "; wait for it to end or choose another folder") from None
        try:                        # still the file at that name (its holder did not remove it)
            if os.path.samestat(os.fstat(fd), os.stat(path)):
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        with contextlib.suppress(OSError):      # who holds it, for the message above
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)         # while still held: a process waiting on it tries again
        os.close(fd)


def json_safe(obj):
    """``obj`` with NaN as null and infinities as the strings ``"inf"``/``"-inf"`` (strict
    JSON), numpy scalars as Python numbers."""
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        if math.isnan(obj):
            return None
        if math.isinf(obj):
            return "inf" if obj > 0 else "-inf"
        return obj
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def write_text(path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json(path, obj) -> Path:
    return write_text(path, json.dumps(json_safe(obj), indent=2) + "\n")


def write_csv(path, result: np.ndarray) -> Path:
    """A structured array of float columns as CSV, the columns named in a header: fmpy's format
    (``fmpy.util.write_csv``: quoted names, each number as Python prints it, the shortest text
    that reads back to the same float), written in one block."""
    names = result.dtype.names
    rows = np.column_stack([result[c] for c in names]).tolist() if len(result) else []
    text = ",".join(f'"{n}"' for n in names) + "\n" \
        + "".join(",".join(map(repr, row)) + "\n" for row in rows)
    return write_text(path, text)


#: Suffixes that name a file, not a folder: a ``save(folder)`` given one was handed a file name.
FILE_SUFFIXES = frozenset((".csv", ".json", ".jsonl", ".png", ".pdf", ".svg", ".txt", ".md",
                           ".parquet", ".toml", ".ssp", ".fmu", ".zip", ".xml", ".npz", ".npy",
                           ".h5", ".html"))


def check_folder(folder) -> Path:
    """``folder`` as a Path, or a ValueError naming it when it names an existing file or has a
    file's suffix (:data:`FILE_SUFFIXES`: ``save("x.csv")`` would make a folder ``x.csv``)."""
    if isinstance(folder, bool) or not isinstance(folder, (str, os.PathLike)):
        raise TypeError(f"folder must be a path (str or os.PathLike), got {type(folder).__name__}")
    path = Path(folder)
    if path.exists() and not path.is_dir():
        raise ValueError(f"folder = {str(path)!r} is a file; allowed: a folder, where the files "
                         "are written (it is made if missing)")
    if path.suffix.lower() in FILE_SUFFIXES:
        raise ValueError(f"folder = {str(path)!r} names a {path.suffix} file; allowed: a folder, "
                         "where the files are written (it is made if missing)")
    return path
