"""Build the FMU loader: the small C binary that stands in front of pythonfmu's library.

    loader_platforms()          -> ["linux64", "win64"]   (those this machine can build)
    build_loader(platform, model, table) -> Path of the model's loader (cached by digest)
    loader_files()              -> the sources (for the FMUs' digest)
    install_loader(entries, name, platforms, python) -> the zip entries of an FMU, completed

The sources are in ``fmu_common/loader/``: ``fmi2_loader.c`` (finding and starting a
Python, forwarding), ``guard.cpp`` (the C++ boundary: any exception of pythonfmu's C++ becomes
fmi2Error), ``fmi2_api.h`` and ``flexpend_loader.py`` (its Python half, shipped in the FMU's
resources). The checks of every FMI call are the native FMUs' guard
(``fmu_common/native/fpm_guard.c``: the same mode machine and masks, the same checks of
references, types and causalities) against the model's table generated into ``fpm_vars.h`` from
the same Python table as the native FMUs' (here the whole table, input-derivative variables
included): so a loader is built per model.

In an FMU (:func:`install_loader`), ``binaries/<platform>/<model>.so|.dll`` becomes the loader,
pythonfmu's library moves beside it as ``<model>_pythonfmu.so|.dll``, and the resources get
``flexpend_loader.py`` and ``flexpend_loader.txt`` (the model's name, its log categories, and the
interpreter recorded at build time; the variables are compiled into the loader).
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from . import places

__all__ = ["LOADER_DIR", "LoaderBuildError", "loader_platforms", "loader_files",
           "build_loader", "install_loader", "loader_table", "recorded_python", "SUFFIX"]

LOADER_DIR = Path(__file__).resolve().parents[2] / "fmu_common" / "loader"
#: the guard the loader shares with the native FMUs
GUARD_DIR = LOADER_DIR.parent / "native"
GUARD_FILES = ("fpm.h", "fpm_guard.c")
SUFFIX = {"linux64": ".so", "win64": ".dll"}

_CFLAGS = ["-O2", "-Wall", "-Wextra", "-Werror", "-Wno-format-truncation", "-fvisibility=hidden"]
_COMPILERS = {
    # platform -> (C compiler, C++ compiler, extra compile flags, link flags)
    "linux64": ("gcc", "g++", ["-fPIC"], ["-shared", "-ldl", "-lpthread"]),
    "win64": ("x86_64-w64-mingw32-gcc", "x86_64-w64-mingw32-g++", [],
              ["-shared", "-static-libgcc", "-static-libstdc++", "-Wl,--no-insert-timestamp"]),
}


class LoaderBuildError(RuntimeError):
    """The loader could not be compiled (the message holds the compiler's output)."""


def loader_files() -> list[Path]:
    own = sorted(p for p in LOADER_DIR.iterdir()
                 if p.suffix in (".c", ".cpp", ".h", ".py") and p.is_file())
    return own + [GUARD_DIR / f for f in GUARD_FILES] + [Path(__file__).resolve().parent
                                                         / "native_fmus.py"]


def loader_header(model: str, table) -> str:
    """``fpm_vars.h`` of the loader of ``model``: the variables of its pythonfmu FMU, from its
    whole ``table`` (value reference = position in the table)."""
    from .native_fmus import generate_header

    return generate_header(model, "", table=table, mode_tables=False)


def loader_platforms() -> list[str]:
    """The platforms whose compilers are installed (linux64 needs gcc and g++ on Linux)."""
    out = []
    for plat, (cc, cxx, _, _) in _COMPILERS.items():
        if plat == "linux64" and not sys.platform.startswith("linux"):
            continue
        if shutil.which(cc) and shutil.which(cxx):
            out.append(plat)
    return out


def _digest(platform: str, header: str) -> str:
    h = hashlib.sha256(f"{platform} {_COMPILERS[platform]} {_CFLAGS}\n{header}".encode())
    for p in loader_files():
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def build_loader(platform: str, model: str, table, cache_dir: Path | None = None) -> Path:
    """Compile the loader of ``model`` (its ``table``) for ``platform`` (or take it from the
    cache, :func:`.places.loader_cache` by default); return its path."""
    if platform not in _COMPILERS:
        raise ValueError(f"unknown platform {platform!r}; known: {', '.join(_COMPILERS)}")
    header = loader_header(model, table)
    target = (Path(cache_dir or places.loader_cache()) / platform / _digest(platform, header)
              / f"fmi2_loader{SUFFIX[platform]}")
    if target.is_file():
        return target
    cc, cxx, cflags, ldflags = _COMPILERS[platform]
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="flexpend_loader_") as tmp:
        (Path(tmp) / "fpm_vars.h").write_text(header)
        includes = [f"-I{tmp}", f"-I{GUARD_DIR}"]
        objs = []
        for src, comp, std in ((LOADER_DIR / "fmi2_loader.c", cc, "-std=c11"),
                               (GUARD_DIR / "fpm_guard.c", cc, "-std=c11"),
                               (LOADER_DIR / "guard.cpp", cxx, "-std=c++17")):
            obj = Path(tmp) / (src.stem + ".o")
            _run([comp, std, *_CFLAGS, *cflags, *includes, "-c", str(src), "-o", str(obj)])
            objs.append(str(obj))
        part = Path(tmp) / target.name
        _run([cxx, *objs, "-o", str(part), *ldflags])
        os.replace(part, target) if target.parent.exists() else None
    return target


def _run(cmd):
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise LoaderBuildError(f"{' '.join(cmd)} failed:\n{proc.stdout}{proc.stderr}")


def recorded_python() -> str:
    """The interpreter recorded in the FMU: this one (its virtual environment's, unresolved)."""
    return sys.executable


def loader_table(model: str, log_categories, python: str) -> str:
    """``resources/flexpend_loader.txt``: the model (the loader checks it is the one it was built
    for), the recorded interpreter and the log categories. The variables are compiled into the
    loader (:func:`loader_header`)."""
    lines = [f"model\t{model}", f"python\t{python}"]
    lines += [f"category\t{c}" for c in log_categories]
    return "\n".join(lines) + "\n"


def install_loader(entries: dict, model: str, table, log_categories, platforms=None,
                   python: str | None = None) -> dict:
    """Complete the zip entries of a pythonfmu FMU (name -> bytes) with the loader: for each
    platform built, the loader takes the binary's name and pythonfmu's library moves beside it."""
    platforms = loader_platforms() if platforms is None else list(platforms)
    if "linux64" not in platforms and sys.platform.startswith("linux"):
        raise LoaderBuildError("building the FMUs needs gcc and g++ (the linux64 loader)")
    for plat in platforms:
        ext = SUFFIX[plat]
        binary = f"binaries/{plat}/{model}{ext}"
        if binary not in entries:
            continue
        entries[f"binaries/{plat}/{model}_pythonfmu{ext}"] = entries[binary]
        entries[binary] = build_loader(plat, model, table).read_bytes()
    entries["resources/flexpend_loader.py"] = (LOADER_DIR / "flexpend_loader.py").read_bytes()
    entries["resources/flexpend_loader.txt"] = loader_table(
        model, log_categories, python or recorded_python()).encode()
    return entries


if __name__ == "__main__":  # pragma: no cover - a manual check
    from .model_description import TABLES
    for plat in loader_platforms():
        for name, (_, tab) in TABLES.items():
            print(plat, name, build_loader(plat, name, tab))
    print(sysconfig.get_platform())
