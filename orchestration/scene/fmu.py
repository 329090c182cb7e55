"""An FMU given by path (a scene's, an SSP's, ``flexpend check``'s, a sweep's), checked before any
of its code is loaded: no library outside the FMU is ever loaded.

    model_description(path, label, validate)  -> fmpy's ModelDescription, after the checks below
    unpack(path, dest=None, label=None)       -> the folder the FMU is unpacked into (checked)
    library_path(unzipdir, md, identifier, label) -> the shared library fmpy loads, inside the FMU
    check_unpacked(unzipdir, label)           -> the ModelDescription of an unpacked FMU, every
                                                 interface's library checked

fmpy loads ``binaries/<platform>/<modelIdentifier>.so`` (``.dll``, ``.dylib``) of the folder the
FMU is unpacked into, the identifier as the modelDescription.xml says it. The FMI standard (2.0
and 3.0, Co-Simulation and Model Exchange) makes ``modelIdentifier`` a C identifier (it prefixes
the FMU's C functions); one that is not, ``../../shared/Evil`` for instance, would have a library
outside the FMU loaded and its constructor run. So:

* the archive's members are checked before anything inflates one
  (:func:`orchestration.scene.archive.check_fmu_archive`: the limits, no absolute or ``..``
  member name, no symbolic link member);
* every ``modelIdentifier`` must match ``[A-Za-z_][A-Za-z0-9_]*``;
* the library's path, symbolic links resolved, must lie inside the folder the FMU is unpacked
  into (an FMU given as a folder may hold a ``binaries/...`` symbolic link out of it).

Every refusal is an :class:`FmuError` (a :class:`~orchestration.scene.keys.ConfigError`: one line
naming the FMU, exit 2 on the command line).
"""
from __future__ import annotations

import os
import re
import tempfile

from . import archive
from .keys import ConfigError

__all__ = ["FmuError", "IDENTIFIER", "model_description", "check_identifiers", "unpack",
           "library_path", "check_unpacked"]

#: A C identifier, as the FMI standard requires of a ``modelIdentifier`` (ASCII only).
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")

#: The interfaces of a modelDescription whose ``modelIdentifier`` names a library (fmpy's
#: attribute names; ``scheduledExecution`` is FMI 3.0's).
_INTERFACES = ("coSimulation", "modelExchange", "scheduledExecution")


class FmuError(ConfigError):
    """An FMU that is not loaded: a model identifier that is not a C identifier, or a library
    that lies outside the FMU."""


def _identifier(ident, label: str) -> str:
    """``ident`` if it is a C identifier, else an :class:`FmuError` naming it."""
    if not isinstance(ident, str) or not IDENTIFIER.fullmatch(ident):
        raise FmuError(f"{label}: modelIdentifier {ident!r} is not a C identifier "
                       "([A-Za-z_][A-Za-z0-9_]*, as the FMI standard requires); the FMU is not "
                       "loaded")
    return ident


def check_identifiers(md, label: str) -> None:
    """Every interface's ``modelIdentifier`` of the ModelDescription ``md`` is a C identifier;
    an :class:`FmuError` names the first that is not."""
    for attr in _INTERFACES:
        interface = getattr(md, attr, None)
        if interface is not None:
            _identifier(getattr(interface, "modelIdentifier", None), label)


def model_description(path, label: str | None = None, *, validate: bool = False):
    """fmpy's ModelDescription of the FMU at ``path`` (an archive or an unpacked folder), read
    after the archive's limits and member names are checked, its model identifiers checked
    (:func:`check_identifiers`). fmpy's own errors reading it pass through (each caller says
    what the FMU was for); ``validate``: fmpy's schema validation."""
    from fmpy import read_model_description

    label = label or str(path)
    archive.check_fmu_archive(path, label)
    md = read_model_description(os.fspath(path), validate=validate)
    check_identifiers(md, label)
    return md


def unpack(path, dest=None, label: str | None = None) -> str:
    """The FMU archive at ``path`` unpacked into ``dest`` (default: a new temporary folder),
    within the archive limits and with every member name checked
    (:func:`orchestration.scene.archive.extract`); the folder."""
    if dest is None:
        dest = tempfile.mkdtemp(prefix="flexpend_fmu_")
    return str(archive.extract(path, dest, label or str(path)))


def _binaries(md) -> str:
    """The ``binaries/`` subfolder fmpy loads from: FMI 3.0's platform tuple
    (``x86_64-linux``), else FMI 2.0's platform (``linux64``)."""
    import fmpy

    return fmpy.platform_tuple if str(md.fmiVersion).startswith("3") else fmpy.platform


def library_path(unzipdir, md, identifier: str, label: str | None = None) -> str:
    """The shared library fmpy loads for the interface of ``identifier`` of the FMU unpacked into
    ``unzipdir`` (ModelDescription ``md``): ``binaries/<platform>/<identifier><extension>``.
    An :class:`FmuError` when ``identifier`` is not a C identifier or when the path, symbolic
    links resolved, lies outside ``unzipdir``. A library that is missing is left to fmpy to
    report."""
    import fmpy

    label = label or str(unzipdir)
    rel = os.path.join("binaries", _binaries(md),
                       _identifier(identifier, label) + fmpy.sharedLibraryExtension)
    root = os.path.realpath(unzipdir)
    real = os.path.realpath(os.path.join(root, rel))
    if os.path.commonpath([root, real]) != root:
        raise FmuError(f"{label}: its library {rel} resolves to {real}, outside the FMU; the "
                       "FMU is not loaded")
    return os.path.join(os.fspath(unzipdir), rel)


def check_unpacked(unzipdir, label: str | None = None):
    """The ModelDescription of the FMU unpacked into ``unzipdir`` (:func:`model_description`),
    the library of each of its interfaces checked (:func:`library_path`): what a host that reads
    the folder itself (``fmpy.simulate_fmu``) may load."""
    label = label or str(unzipdir)
    md = model_description(unzipdir, label)
    for attr in _INTERFACES:
        interface = getattr(md, attr, None)
        if interface is not None:
            library_path(unzipdir, md, interface.modelIdentifier, label)
    return md
