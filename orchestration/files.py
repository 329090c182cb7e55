"""Output files that are complete or absent: each is written to a temporary name beside its place
and renamed into it, so a failed or interrupted write never leaves half a file, nor destroys a
good file of the same name. A write that fails (a full disk, a read-only folder) raises
:class:`OutputError`, one line naming the file; :func:`folder_lock` keeps a second run out of an
output folder in use.

Nothing is written through a link: a symbolic link planted at an output's name (or at the lock's,
or the journal's) could point at any file the user can write, so :func:`refuse_link` refuses it
before anything is written, and the files kept open in place (the lock, a sweep's journal) are
opened by :func:`open_in_place`: never through a symbolic link (``O_NOFOLLOW``), and only as a
regular file with no other hard link. The output folder itself may be a link: the user named it.
"""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import stat
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["OutputError", "output_error", "atomic_path", "folder_lock", "LOCK_FILE", "write_text",
           "write_json", "write_csv", "json_safe", "check_folder", "FILE_SUFFIXES", "refuse_link",
           "open_in_place"]

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


def _link_refused(path) -> OutputError:
    return OutputError(errno.ELOOP, f"{path}: is a link, and flexpend does not write through "
                       "links (it could point at any file); remove it or choose another folder")


def refuse_link(path) -> None:
    """An :class:`OutputError` naming ``path`` when it is a symbolic link (nothing is written
    through one); nothing when it is anything else or absent."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise output_error(path, exc) from None
    if stat.S_ISLNK(st.st_mode):
        raise _link_refused(path)


def open_in_place(path, flags: int, mode: int = 0o644) -> int:
    """``os.open(path, flags)`` for a file written in place (a lock, a journal), refusing what
    could be another file under this name: a symbolic link (``O_NOFOLLOW``), a hard link (a
    second name of a file elsewhere), anything not a regular file. An :class:`OutputError`
    naming ``path`` otherwise."""
    try:
        fd = os.open(path, flags | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0),
                     mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP or os.path.islink(path):
            raise _link_refused(path) from None
        raise output_error(path, exc) from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_nlink > 1:     # 0: just removed by its holder
        os.close(fd)
        what = "not a regular file" if not stat.S_ISREG(st.st_mode) else \
            f"a file with {st.st_nlink} names (a hard link)"
        raise OutputError(errno.EPERM, f"{path}: is {what}, and flexpend writes only a file of "
                          "its own there; remove it or choose another folder")
    return fd


class atomic_path:
    """``with atomic_path(path) as tmp:`` write ``tmp``; on success it is synced to the disk and
    replaces ``path`` (so after a crash of the machine ``path`` is the old file or the new one,
    whole), on any exception it is removed and ``path`` is left as it was (an OSError is raised
    as an :class:`OutputError` naming ``path``). A symbolic link at ``path`` is refused first
    (:func:`refuse_link`): the rename would not follow it, but the user meant its target."""

    def __init__(self, path, suffix: str = ""):
        self.path = Path(path)
        self.suffix = suffix or self.path.suffix

    def __enter__(self) -> Path:
        refuse_link(self.path)
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
        fd = open_in_place(path, os.O_RDWR | os.O_CREAT)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip()
            os.close(fd)
            raise OutputError(errno.EBUSY, f"{folder}: in use by another flexpend run"
                              + (f" (process {holder})" if holder.isdigit() else "")
                              + "; wait for it to end or choose another folder") from None
        try:                        # still the file at that name (its holder did not remove it)
            if os.path.samestat(os.fstat(fd), os.lstat(path)):
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
