"""Zip archives read within limits (SSP archives, FMUs): nothing is inflated before the archive's
table of contents has been checked, and nothing is inflated beyond what it declares.

    members(zf, label)              -> the members, checked against the limits below
    read_member(zf, info, label)    -> one member's bytes (at most MAX_TEXT_BYTES)
    copy_member(zf, info, dest)     -> one member written to a file, in chunks
    checked_archive(path, label)    -> (an open ZipFile, its checked members)
    member_path(info, label)        -> a member's relative path; its name and kind checked
    check_fmu_archive(path, label)  the limits and every member's name, on an FMU (a zip)
                                    before anything reads it
    extract(path, dest, label)      -> dest: the archive unpacked, within the limits

The limits (documented in docs/ssp_and_check.md) are far above what a system of FMUs needs (our
FMUs hold 4 members and 0.7 MB; an SSP of ours, 3 members) and far below what exhausts a machine:
a 2.4 MB zip bomb inflates to 2.4 GB. A member's size is checked as declared in the archive's
table of contents, then as read (in chunks, never past the declared size), and its compression
ratio is checked when it is large. A member is unpacked only if its name is a relative path
inside the archive and it is not a symbolic link (:func:`member_path`; every FMU, an SSP's and
``flexpend check``'s included, is checked the same way before anything reads it). Every refusal
is an :class:`ArchiveError` (a :class:`~orchestration.scene.keys.ConfigError`: one line, exit 2
on the command line).
"""
from __future__ import annotations

import errno
import stat
import zipfile
import zlib
from contextlib import contextmanager
from pathlib import Path, PurePosixPath

from .keys import ConfigError

__all__ = ["ArchiveError", "MAX_MEMBERS", "MAX_MEMBER_BYTES", "MAX_TOTAL_BYTES", "MAX_RATIO",
           "RATIO_FLOOR", "MAX_TEXT_BYTES", "members", "read_member", "copy_member",
           "checked_archive", "member_path", "check_fmu_archive", "extract"]

#: The most members an archive may hold.
MAX_MEMBERS = 10_000
#: The largest member, inflated (bytes).
MAX_MEMBER_BYTES = 256 << 20
#: All the members together, inflated (bytes).
MAX_TOTAL_BYTES = 1 << 30
#: The largest compression ratio (inflated / compressed size) of a member larger than
#: :data:`RATIO_FLOOR`: deflate reaches about 1030 on repeated bytes; text compresses about 10
#: times, binaries 2 to 3 times.
MAX_RATIO = 100
RATIO_FLOOR = 1 << 20
#: The largest member read into memory (an XML file: an SSD, an SSV, a modelDescription.xml).
MAX_TEXT_BYTES = 16 << 20
_CHUNK = 1 << 20


class ArchiveError(ConfigError):
    """An archive that is not read: beyond a limit, damaged, or with an unsafe member name."""


def _mib(n: int) -> str:
    return f"{n / (1 << 20):.4g} MiB" if n >= 1 << 20 else f"{n} bytes"


def members(zf: zipfile.ZipFile, label: str) -> list[zipfile.ZipInfo]:
    """The members of ``zf``, after checking their number, their declared sizes, their total and
    their compression ratios against the limits (an :class:`ArchiveError` names the first one
    beyond)."""
    infos = zf.infolist()
    if len(infos) > MAX_MEMBERS:
        raise ArchiveError(f"{label}: {len(infos)} members; the limit is {MAX_MEMBERS}")
    total = 0
    for info in infos:
        size = info.file_size
        if size > MAX_MEMBER_BYTES:
            raise ArchiveError(f"{label}: member {info.filename!r} inflates to {_mib(size)}; "
                               f"the limit is {_mib(MAX_MEMBER_BYTES)} per member")
        if size > RATIO_FLOOR and size > MAX_RATIO * max(info.compress_size, 1):
            raise ArchiveError(f"{label}: member {info.filename!r} inflates "
                               f"{size / max(info.compress_size, 1):.0f} times (to "
                               f"{_mib(size)}); the limit is {MAX_RATIO} times for a member "
                               f"over {_mib(RATIO_FLOOR)} (a zip bomb?)")
        total += size
        if total > MAX_TOTAL_BYTES:
            raise ArchiveError(f"{label}: the members inflate to more than "
                               f"{_mib(MAX_TOTAL_BYTES)} together; that is the limit")
    return infos


def _chunks(zf: zipfile.ZipFile, info: zipfile.ZipInfo, label: str, limit: int):
    """The member's bytes in chunks, never more than ``limit`` nor than it declares."""
    cap = min(limit, info.file_size)
    read = 0
    try:
        with zf.open(info) as fh:
            while chunk := fh.read(min(_CHUNK, cap + 1 - read)):
                read += len(chunk)
                if read > cap:
                    raise ArchiveError(f"{label}: member {info.filename!r} inflates to more than "
                                       f"{'it declares' if cap == info.file_size else _mib(limit)}")
                yield chunk
    except ArchiveError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError,
            ValueError) as exc:           # damaged, encrypted, an unknown compression
        raise ArchiveError(f"{label}: member {info.filename!r} cannot be read: {exc}") from None


def read_member(zf: zipfile.ZipFile, info, label: str, limit: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of member ``info`` (a ZipInfo or a name), at most ``limit``."""
    if not isinstance(info, zipfile.ZipInfo):
        info = zf.getinfo(info)
    if info.file_size > limit:
        raise ArchiveError(f"{label}: member {info.filename!r} inflates to {_mib(info.file_size)}; "
                           f"the limit is {_mib(limit)} for a file read whole")
    return b"".join(_chunks(zf, info, label, limit))


def copy_member(zf: zipfile.ZipFile, info, dest, label: str) -> Path:
    """Member ``info`` (a ZipInfo or a name) written to the file ``dest``, in chunks."""
    if not isinstance(info, zipfile.ZipInfo):
        info = zf.getinfo(info)
    dest = Path(dest)
    with open(dest, "wb") as out:
        for chunk in _chunks(zf, info, label, MAX_MEMBER_BYTES):
            out.write(chunk)
    return dest


@contextmanager
def checked_archive(path, label: str | None = None):
    """``(ZipFile, members)`` of the archive at ``path``, its members checked (:func:`members`);
    an :class:`ArchiveError` if it is not a zip file."""
    label = label or Path(path).name
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise ArchiveError(f"{label}: not a zip archive: {exc}") from None
    with zf:
        yield zf, members(zf, label)


def check_fmu_archive(path, label: str | None = None) -> None:
    """The limits and every member's name and kind (:func:`member_path`) checked on the FMU at
    ``path`` before anything (fmpy's reader, an extraction) inflates a member of it; an FMU that
    is an unpacked folder is not an archive and passes (the library it holds is checked when it
    is loaded: :func:`orchestration.scene.fmu.library_path`)."""
    if Path(path).is_dir():
        return
    label = label or Path(path).name
    with checked_archive(path, label) as (_, infos):
        for info in infos:
            member_path(info, label)


def member_path(info: zipfile.ZipInfo, label: str) -> PurePosixPath:
    """The relative path of member ``info`` inside the folder it is unpacked into; an
    :class:`ArchiveError` when its name leaves that folder (absolute, ``..``, a drive, a
    backslash) or when it is a symbolic link (its target could point anywhere)."""
    name = info.filename
    parts = PurePosixPath(name).parts
    if ("\\" in name or ":" in name or "\0" in name or name.startswith("/") or not parts
            or ".." in parts):
        raise ArchiveError(f"{label}: member {name!r} is not a relative path inside the archive")
    if stat.S_ISLNK(info.external_attr >> 16):
        raise ArchiveError(f"{label}: member {name!r} is a symbolic link; an archive's members "
                           "must be files or folders")
    return PurePosixPath(*parts)


def extract(path, dest, label: str | None = None) -> Path:
    """The archive at ``path`` unpacked into the folder ``dest`` (created), within the limits;
    a member named outside ``dest`` (absolute, ``..``, a drive) or that is a symbolic link is
    refused (:func:`member_path`)."""
    label = label or Path(path).name
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    with checked_archive(path, label) as (zf, infos):
        for info in infos:
            target = dest / member_path(info, label)
            try:
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                copy_member(zf, info, target, label)
            except OSError as exc:
                if exc.errno in _FULL:      # a full disk stays a full disk
                    raise
                # a member that cannot be a file there: its name also a folder of another
                # member's ('a' and 'a/b'), too long for the file system...
                raise ArchiveError(f"{label}: member {info.filename!r} cannot be unpacked: "
                                   f"{exc.strerror or exc}") from None
    return dest


#: errno of a write refused for want of room: not the archive's fault
_FULL = {getattr(errno, n) for n in ("ENOSPC", "EDQUOT", "EFBIG") if hasattr(errno, n)}
