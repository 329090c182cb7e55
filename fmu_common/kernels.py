"""The compiled kernels: where they live, how they are built and how they are loaded (standard
library only).

A kernel is a plain C shared library (not a Python extension): the plant's in
``plant_fmu/native/``, the controller's in ``controller_fmu/native/``, the master's compiled loop
in ``orchestration/cosim/native/``. Each is built for a platform into
``<package>/native/lib/<platform>/`` (FMI's platform names: ``linux64``, ``win64``, ``darwin64``)
by :func:`build_kernel`: by ``pip install`` for the host (``setup.py`` calls
:func:`build_host_kernels`), and for the pythonfmu FMUs, which ship them and load them without
compiling (the native FMUs link the same sources).

Every library embeds the sha256 of the C sources it was built from (:func:`source_digest`). In a
checkout or installation (the FMU sources, ``fmu_common/native/``, sit beside the packages), a
library whose digest is not that of the sources beside it is stale and is rebuilt when loaded.
Elsewhere, that is inside an unpacked FMU (which ships this module but not those sources), the
library is loaded as shipped (its build checked it against its sources) and only its interface
version is checked: hashing there would import ``hashlib``, and OpenSSL's exit handlers then
corrupt the heap when pythonfmu finalises its interpreter at the exit of a non-Python host (a C
host aborted with "free(): corrupted unsorted chunks"). For the same reason the build's modules
(``subprocess``, ``tempfile``...) are imported only by the functions that build. A missing
library fails with a :class:`KernelError` that names the file and the platform: there is no
silent fallback to a slower implementation.

Platforms: ``linux64`` with the host's C compiler (``$CC``, else ``cc``, ``gcc``, ``clang``), and
``win64`` with the mingw-w64 cross-compiler ``x86_64-w64-mingw32-gcc`` (Debian:
``gcc-mingw-w64-x86-64``) when it is installed. The flags are fixed (:data:`CFLAGS`): ISO C99,
``-O2``, no floating-point contraction (the same arithmetic as numpy), only the ``FP_API``
functions exported, and every warning an error. The sources' digest is compiled into the
library (``FP_SOURCE_DIGEST``), which is how a library is matched with its sources.

``setup.py`` loads this module by its path, before anything is installed.
"""
from __future__ import annotations

import ctypes
import os
import struct
import sys
import threading
from pathlib import Path

__all__ = ["KernelError", "KERNELS", "ROOT", "host_platform", "library_name", "library_path",
           "native_dir", "source_files", "source_digest", "embedded_digest", "in_checkout",
           "load", "CFLAGS", "CROSS_COMPILERS", "KernelBuildError", "CompilerNotFound",
           "find_compiler", "available_platforms", "compile_command", "build_kernel",
           "ensure_kernel", "ensure_kernels", "build_host_kernels"]

#: The folder holding the packages (a checkout, an installation's site-packages, or an unpacked
#: FMU's resources).
ROOT = Path(__file__).resolve().parents[1]


class KernelError(RuntimeError):
    """A compiled kernel cannot be loaded (missing for this platform, stale, or wrong version)."""


#: kernel name -> (package folder, relative to :data:`ROOT`; C sources; headers; ABI function;
#: digest function; ABI version)
KERNELS = {
    "flexpend_plant": ("plant_fmu", ("fp_plant.c",), ("fp_plant.h",), "fp_plant_abi",
                       "fp_plant_source_digest", 5),
    "flexpend_filter": ("controller_fmu", ("fp_filter.c",), ("fp_filter.h",), "fpf_abi",
                        "fpf_source_digest", 4),
    # the master's compiled fixed-step loop (orchestration/cosim/compiled.py), for the host
    "flexpend_master": ("orchestration/cosim", ("fm_master.c",), ("fm_master.h",), "fm_abi",
                        "fm_source_digest", 5),
    # the model-exchange master's integration loop (orchestration/cosim/compiled_me.py)
    "flexpend_me": ("orchestration/cosim", ("fm_me.c",), ("fm_me.h",), "fme_abi",
                    "fme_source_digest", 2),
    # the master's compiled adaptive loop (orchestration/cosim/compiled_adaptive.py)
    "flexpend_adaptive": ("orchestration/cosim", ("fm_adaptive.c",), ("fm_adaptive.h",),
                          "fa_abi", "fa_source_digest", 5),
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
    """``<root>/<package>/native`` (``root``: the folder holding the packages; default:
    :data:`ROOT`)."""
    return Path(ROOT if root is None else root) / KERNELS[kernel][0] / "native"


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


#: What marks a checkout or installation (the sources of the native FMUs' FMI layers), which an
#: unpacked FMU does not have.
CHECKOUT_MARK = Path("fmu_common") / "native" / "fpm.h"


def in_checkout(native: Path) -> bool:
    """Whether the folder ``native`` belongs to a checkout or installation, whose packages sit
    beside :data:`CHECKOUT_MARK` (not to an unpacked FMU)."""
    return any((up / CHECKOUT_MARK).is_file() for up in Path(native).resolve().parents[:3])


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
    this module belongs to."""
    state = "out of date (its C sources changed)" if path.is_file() else "missing"
    if native.resolve() != native_dir(kernel).resolve():
        raise KernelError(f"the compiled kernel {kernel} for this platform ({platform}) is "
                          f"{state}: {path} (reinstall flexpend, or rebuild the FMU, on a "
                          f"machine with a C compiler)")
    try:
        build_kernel(kernel, platform, path, native)
    except KernelBuildError as exc:
        raise KernelError(f"the compiled kernel {path} is {state} and building it failed: "
                          f"{exc}") from None


# ---------------------------------------------------------------------- building

#: Compiler flags of every build (besides the platform's: -fPIC on Linux).
CFLAGS = ("-std=c99", "-O2", "-ffp-contract=off", "-fvisibility=hidden", "-Wall", "-Wextra",
          "-Werror", "-pedantic")

#: platform -> cross-compiler used when the host is not that platform
CROSS_COMPILERS = {"win64": "x86_64-w64-mingw32-gcc"}


class KernelBuildError(RuntimeError):
    """A kernel could not be compiled (the message holds the compiler's output)."""


class CompilerNotFound(KernelBuildError):
    """No C compiler for the platform (the message names the one looked for)."""


def find_compiler(platform: str | None = None, env=None) -> str:
    """The C compiler for ``platform`` (default: the host's); raises :class:`CompilerNotFound`
    with one line naming what was looked for."""
    import shutil

    env = os.environ if env is None else env
    platform = platform or host_platform()
    path = env.get("PATH", os.defpath)
    if platform != host_platform():
        cross = CROSS_COMPILERS.get(platform)
        if cross is None:
            raise CompilerNotFound(f"no cross-compiler known for {platform}")
        found = shutil.which(cross, path=path)
        if found is None:
            raise CompilerNotFound(f"the C cross-compiler {cross} for {platform} was not found")
        return found
    cc = env.get("CC")
    if cc:
        found = shutil.which(cc.split()[0], path=path)
        if found is None:
            raise CompilerNotFound(f"the C compiler CC={cc} was not found: flexpend compiles its "
                                   f"kernel at install")
        return found
    for name in ("cc", "gcc", "clang"):
        found = shutil.which(name, path=path)
        if found:
            return found
    raise CompilerNotFound("no C compiler found (looked for $CC, cc, gcc, clang): flexpend "
                           "compiles its kernel at install; install one (e.g. apt-get install gcc)")


def available_platforms() -> list[str]:
    """The host platform, and the cross platforms whose compiler is installed."""
    plats = [host_platform()]
    for plat in CROSS_COMPILERS:
        if plat not in plats:
            try:
                find_compiler(plat)
            except CompilerNotFound:
                continue
            plats.append(plat)
    return plats


def compile_command(kernel: str, platform: str, out: Path, native: Path, cc: str) -> list[str]:
    """The compiler's command line for ``kernel`` on ``platform`` (run in ``native``)."""
    sources = KERNELS[kernel][1]
    digest = source_digest(kernel, native)
    if digest is None:
        raise KernelBuildError(f"the C sources of {kernel} are missing from {native}")
    cmd = [cc, *CFLAGS, f'-DFP_SOURCE_DIGEST="{digest}"']
    if platform.startswith("win"):
        cmd += ["-shared", "-static-libgcc", "-o", str(out), *sources]
    elif platform.startswith("darwin"):
        cmd += ["-fPIC", "-dynamiclib", "-o", str(out), *sources, "-lm"]
    else:
        cmd += ["-fPIC", "-shared", "-o", str(out), *sources, "-lm"]
    return cmd


def build_kernel(kernel: str, platform: str | None = None, out: Path | None = None,
                 native: Path | None = None) -> Path:
    """Compile ``kernel`` for ``platform`` from the sources in ``native`` (default: this
    checkout's) into ``out`` (default: ``native/lib/<platform>/<library>``), atomically."""
    import subprocess
    import tempfile

    platform = platform or host_platform()
    native = native_dir(kernel) if native is None else Path(native)
    out = library_path(kernel, platform, native) if out is None else Path(out)
    cc = find_compiler(platform)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, part = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent)
    os.close(fd)
    try:
        cmd = compile_command(kernel, platform, Path(part), native, cc)
        proc = subprocess.run(cmd, cwd=native, capture_output=True, text=True)
        if proc.returncode != 0:
            raise KernelBuildError(f"compiling {kernel} for {platform} failed:\n"
                                   f"{' '.join(cmd)}\n{proc.stdout}{proc.stderr}")
        os.replace(part, out)
    finally:
        if os.path.exists(part):
            os.unlink(part)
    return out


def ensure_kernel(kernel: str, platform: str | None = None, native: Path | None = None) -> Path:
    """``kernel``'s library for ``platform`` in ``native/lib/<platform>/``, built if missing or
    stale (the digest it embeds is not that of the sources)."""
    platform = platform or host_platform()
    native = native_dir(kernel) if native is None else Path(native)
    path = library_path(kernel, platform, native)
    digest = source_digest(kernel, native)
    if digest is None or not embedded_digest(path, digest):
        build_kernel(kernel, platform, path, native)
    return path


def ensure_kernels(platforms=None, kernels=None) -> dict:
    """Every kernel (or ``kernels``) for every platform (default: :func:`available_platforms`),
    built where stale; ``{(kernel, platform): path}``."""
    platforms = available_platforms() if platforms is None else list(platforms)
    kernels = list(KERNELS) if kernels is None else list(kernels)
    return {(k, p): ensure_kernel(k, p) for k in kernels for p in platforms}


def build_host_kernels(src_root: Path, out_root: Path) -> list[Path]:
    """Compile every kernel for the host from the sources under ``src_root`` into the package
    folders under ``out_root`` (``setup.py``: the build folder, or the checkout itself for an
    editable install)."""
    out = []
    platform = host_platform()
    for kernel in KERNELS:
        native = native_dir(kernel, src_root)
        target = library_path(kernel, platform, native_dir(kernel, out_root))
        out.append(build_kernel(kernel, platform, target, native))
    return out
