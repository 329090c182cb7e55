"""Compile the C kernels (plant and filter) into plain shared libraries, per platform.

    build_kernel("flexpend_plant", "linux64", out_path)      -> out_path
    ensure_kernels(platforms)                                -> {(kernel, platform): path}
    available_platforms()                                    -> ["linux64", "win64"?]

One build for every consumer: ``pip install`` (``setup.py`` calls :func:`build_host_kernels`),
the Python packages of a source checkout (a stale library is rebuilt when loaded, see
:mod:`plant_fmu._native`), the pythonfmu FMUs (:mod:`.python_fmus` ships the libraries of every
platform it can build) and, next, the native FMUs, which link the same sources.

Platforms: ``linux64`` with the host's C compiler (``$CC``, else ``cc``, ``gcc``, ``clang``), and
``win64`` with the mingw-w64 cross-compiler ``x86_64-w64-mingw32-gcc`` (Debian:
``gcc-mingw-w64-x86-64``) when it is installed. The flags are fixed (:data:`CFLAGS`): ISO C99,
``-O2``, no floating-point contraction (the same arithmetic as numpy), only the ``FP_API``
functions exported, and every warning an error. The sources' digest is compiled into the
library (``FP_SOURCE_DIGEST``), which is how a library is matched with its sources.

This module imports only the standard library and :mod:`plant_fmu._native` (``setup.py`` loads it
before anything is installed).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

try:
    from plant_fmu import _native
except ImportError:  # pragma: no cover - setup.py puts the project root on sys.path first
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from plant_fmu import _native

__all__ = ["ROOT", "native_dir", "CFLAGS", "CROSS_COMPILERS", "KernelBuildError", "CompilerNotFound", "find_compiler",
           "available_platforms", "build_kernel", "ensure_kernel", "ensure_kernels",
           "build_host_kernels", "compile_command"]

#: The checkout (or installation) this module belongs to: the packages are folders of it.
ROOT = Path(__file__).resolve().parents[2]


def native_dir(kernel: str) -> Path:
    """The folder of ``kernel``'s C sources in :data:`ROOT`."""
    return _native.native_dir(kernel, ROOT)


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
    env = os.environ if env is None else env
    platform = platform or _native.host_platform()
    path = env.get("PATH", os.defpath)
    if platform != _native.host_platform():
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
    plats = [_native.host_platform()]
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
    sources = _native.KERNELS[kernel][1]
    digest = _native.source_digest(kernel, native)
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
    platform = platform or _native.host_platform()
    native = native_dir(kernel) if native is None else Path(native)
    out = _native.library_path(kernel, platform, native) if out is None else Path(out)
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
    platform = platform or _native.host_platform()
    native = native_dir(kernel) if native is None else Path(native)
    path = _native.library_path(kernel, platform, native)
    digest = _native.source_digest(kernel, native)
    if digest is None or not _native.embedded_digest(path, digest):
        build_kernel(kernel, platform, path, native)
    return path


def ensure_kernels(platforms=None, kernels=None) -> dict:
    """Every kernel (or ``kernels``) for every platform (default: :func:`available_platforms`),
    built where stale; ``{(kernel, platform): path}``."""
    platforms = available_platforms() if platforms is None else list(platforms)
    kernels = list(_native.KERNELS) if kernels is None else list(kernels)
    return {(k, p): ensure_kernel(k, p) for k in kernels for p in platforms}


def build_host_kernels(src_root: Path, out_root: Path) -> list[Path]:
    """Compile every kernel for the host from the sources under ``src_root`` into the package
    folders under ``out_root`` (``setup.py``: the build folder, or the checkout itself for an
    editable install)."""
    out = []
    platform = _native.host_platform()
    for kernel in _native.KERNELS:
        native = _native.native_dir(kernel, src_root)
        target = _native.library_path(kernel, platform, _native.native_dir(kernel, out_root))
        out.append(build_kernel(kernel, platform, target, native))
    return out
