"""Where the compiled kernels live and how they are loaded (standard library only).

A kernel is a plain C shared library (not a Python extension): the plant's in
``plant_fmu/native/``, the controller's in ``controller_fmu/native/``. Each is built for a platform
into ``<package>/native/lib/<platform>/`` (FMI's platform names: ``linux64``, ``win64``,
``darwin64``), by ``pip install`` for the host and by :mod:`orchestration.export.kernel_build`
for the FMUs, which ship them and load them without compiling.

Every library embeds the sha256 of the C sources it was built from (:func:`source_digest`). In a
checkout or installation (the kernel build, ``orchestration/export/kernel_build.py``, sits beside
the package), a library whose digest is not that of the sources beside it is stale and is
rebuilt. Elsewhere, that is inside an unpacked FMU, the library is loaded as shipped (its build
checked it against its sources) and only its interface version is checked: hashing there would
import ``hashlib``, and OpenSSL's exit handlers then corrupt the heap when pythonfmu finalises
its interpreter at the exit of a non-Python host (a C host aborted with "free(): corrupted
unsorted chunks"). A missing library fails with a :class:`KernelError` that names the file and
the platform: there is no silent fallback to a slower implementation.

This module is also loaded by ``setup.py`` and :mod:`orchestration.export.kernel_build`, so it
imports nothing beyond the standard library.
"""
from __future__ import annotations

import ctypes
import struct
import sys
import threading
from pathlib import Path

__all__ = ["KernelError", "KERNELS", "host_platform", "library_name", "library_path",
           "source_files", "source_digest", "embedded_digest", "in_checkout", "load"]


class KernelError(RuntimeError):
    """A compiled kernel cannot be loaded (missing for this platform, stale, or wrong version)."""


#: kernel name -> (package, C sources, headers, ABI function, digest function, ABI version)
KERNELS = {
    "flexpend_plant": ("plant_fmu", ("fp_plant.c",), ("fp_plant.h",), "fp_plant_abi",
                       "fp_plant_source_digest", 1),
    "flexpend_filter": ("controller_fmu", ("fp_filter.c",), ("fp_filter.h",), "fpf_abi",
                        "fpf_source_digest", 1),
    # the master's compiled fixed-step loop (orchestration/compiled_master.py), for the host
    "flexpend_master": ("orchestration", ("fm_master.c",), ("fm_master.h",), "fm_abi",
                        "fm_source_digest", 1),
}


def host_platform() -> str:
    """The FMI platform name of this process: ``linux64``, ``win64``, ``darwin64``, ..."""
    bits = 8 * struct.calcsize("P")
    if sys.platform.startswith("win"):
        return f"win{bits}"
    if sys.platform == "darwin":
        return f"darwin{bits}"
    return f"linux{bits}"


def library_name(kernel: str, platform: str) -> str:
    """The file name of ``kernel``'s library on ``platform`` (``libX.so``, ``X.dll``, ``libX.dylib``)."""
    if platform.startswith("win"):
        return f"{kernel}.dll"
    if platform.startswith("darwin"):
        return f"lib{kernel}.dylib"
    return f"lib{kernel}.so"


def native_dir(kernel: str, root: Path | None = None) -> Path:
    """``<root>/<package>/native`` (``root``: the folder holding the packages; default: the one
    holding this package)."""
    package = KERNELS[kernel][0]
    if root is None:
        root = Path(__file__).resolve().parent.parent
    return Path(root) / package / "native"


def library_path(kernel: str, platform: str | None = None, native: Path | None = None) -> Path:
    """Where ``kernel``'s library for ``platform`` (default: the host's) is, under the folder
    ``native`` (default: :func:`native_dir`)."""
    platform = platform or host_platform()
    native = native_dir(kernel) if native is None else Path(native)
    return native / "lib" / platform / library_name(kernel, platform)


def source_files(kernel: str, native: Path | None = None) -> list[Path]:
    """The C sources and headers of ``kernel``, in digest order."""
    _, sources, headers = KERNELS[kernel][:3]
    d = native_dir(kernel) if native is None else Path(native)
    return [d / f for f in sorted(sources + headers)]


def source_digest(kernel: str, native: Path | None = None) -> str | None:
    """sha256 (hex) of ``kernel``'s C sources (names and bytes), or None if they are absent."""
    import hashlib      # here: not imported inside an FMU (see the module's docstring)

    h = hashlib.sha256(f"{kernel}\n".encode())
    for path in source_files(kernel, native):
        try:
            data = path.read_bytes()
        except OSError:
            return None
        h.update(path.name.encode() + b"\0" + data + b"\0")
    return h.hexdigest()


def embedded_digest(path: Path, digest: str) -> bool:
    """Whether the library file at ``path`` was built from sources of digest ``digest`` (the
    digest is a string constant of the binary)."""
    try:
        return digest.encode() in Path(path).read_bytes()
    except OSError:
        return False


_lock = threading.Lock()
_loaded: dict = {}


def load(kernel: str, native: Path) -> ctypes.CDLL:
    """The host platform's library of ``kernel`` under the folder ``native`` (cached), checked:
    its interface version and, where the sources are present, its digest. A stale library in a
    source checkout is rebuilt first. Raises :class:`KernelError` with the reason."""
    key = (kernel, str(native))
    with _lock:
        lib = _loaded.get(key)
        if lib is None:
            lib = _loaded[key] = _load(kernel, Path(native))
        return lib


def in_checkout(native: Path) -> bool:
    """Whether the folder ``native`` belongs to a checkout or installation that has the kernel
    build beside its packages (not to an unpacked FMU)."""
    return (Path(native).parent.parent / "orchestration" / "export" / "kernel_build.py").is_file()


def _load(kernel: str, native: Path) -> ctypes.CDLL:
    platform = host_platform()
    path = library_path(kernel, platform, native)
    digest = source_digest(kernel, native) if in_checkout(native) else None
    if digest is not None and not embedded_digest(path, digest):
        _rebuild(kernel, platform, path, native)
    if not path.is_file():
        raise KernelError(f"the compiled kernel {kernel} for this platform ({platform}) is missing:"
                          f" {path} does not exist (reinstall flexpend with a C compiler, or "
                          f"rebuild the FMU on a machine with one)")
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        raise KernelError(f"the compiled kernel {path} cannot be loaded: {exc}") from None
    abi_fn, digest_fn, abi = KERNELS[kernel][3:]
    try:
        got_abi = getattr(lib, abi_fn)()
        getter = getattr(lib, digest_fn)
    except AttributeError as exc:
        raise KernelError(f"{path} is not a flexpend kernel: {exc}") from None
    if got_abi != abi:
        raise KernelError(f"{path} has interface version {got_abi}, this code needs {abi}: "
                          f"rebuild it")
    getter.restype = ctypes.c_char_p
    if digest is not None and getter().decode() != digest:
        raise KernelError(f"{path} was built from other sources than those beside it")
    return lib


def _rebuild(kernel: str, platform: str, path: Path, native: Path):
    """Rebuild a stale or missing library, only in the source checkout (or installation) that
    the build module belongs to."""
    state = "out of date (its C sources changed)" if path.is_file() else "missing"
    try:
        from orchestration.export import kernel_build
    except ImportError:
        kernel_build = None
    if kernel_build is None or native.resolve() != kernel_build.native_dir(kernel).resolve():
        raise KernelError(f"the compiled kernel {kernel} for this platform ({platform}) is "
                          f"{state}: {path} (reinstall flexpend, or rebuild the FMU, on a "
                          f"machine with a C compiler)")
    try:
        kernel_build.build_kernel(kernel, platform, path, native)
    except kernel_build.KernelBuildError as exc:
        raise KernelError(f"the compiled kernel {path} is {state} and building it failed: "
                          f"{exc}") from None
