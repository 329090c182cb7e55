"""Build the two pythonfmu FMUs, only when their sources changed.

    build_fmus(out_dir)          -> {"FlexiblePendulum": path, "PDLowPass": path}

The reference results are :mod:`orchestration.export.check`.

What the build does beyond ``pythonfmu build``:

* the slave module inside each FMU has the model's name (``FlexiblePendulum.py``, a re-export of
  the class, see :data:`_SLAVE_MODULE`): pythonfmu imports it by its bare name, so two FMUs whose
  modules are both called ``fmu`` cannot be loaded into one process; it also works around two
  pythonfmu 0.7.0 problems (a reference-count bug and packages left by deleted unpack folders);
* the project packages are copied as ``.py`` files only (no caches), and the FMUs can get, set and
  serialise their state;
* ``modelDescription.xml`` is written from the model's table of variables
  (:mod:`orchestration.export.model_description`): units, exact start values, the real output
  dependencies (pythonfmu writes none, which makes importers see false algebraic loops and
  ``fmpy validate`` fail), a schema-valid ``generationDateAndTime``;
* the compiled kernels of the packages it ships (:mod:`fmu_common.kernels`: the plant's and, in the
  controller, the filter's) for linux64 and, when the mingw-w64 cross-compiler is installed, win64,
  under ``resources/<package>/native/lib/<platform>/``, beside their C sources: the FMU loads them
  without compiling, and refuses to instantiate on a platform it has no kernel for;
* ``resources/flexpend_build.json`` records a digest of every source file that went in (Python and
  C), of the build scripts and of the platforms built; an FMU is rebuilt only when that digest
  changes (or when asked to).

The pythonfmu builder runs in a child process: it imports the slave module by its bare name and
leaves it on ``sys.path``/``sys.modules``, which must not leak into the caller (a test session).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from fmu_common import kernels

from ..files import atomic_path
from . import loader_build, places

__all__ = ["ROOT", "SPECS", "FmuSpec", "BuildError", "build_fmus", "build_fmu",
           "is_stale", "source_digest", "fmu_digest", "spec_kernels"]

ROOT = Path(__file__).resolve().parents[2]
STAMP = "resources/flexpend_build.json"
#: Bump to force a rebuild when the build itself changes in a way the sources do not show.
BUILD_FORMAT = 4


class BuildError(RuntimeError):
    """The FMU could not be built (the message holds the builder's output)."""


@dataclass(frozen=True)
class FmuSpec:
    """One FMU: its model identifier (= class name), the module of the class, the packages it ships."""

    name: str
    module: str
    packages: tuple


SPECS = {
    "FlexiblePendulum": FmuSpec("FlexiblePendulum", "plant_fmu.fmu", ("plant_fmu", "fmu_common")),
    # each FMU carries its own model and what every FMU shares, nothing of the other model
    "PDLowPass": FmuSpec("PDLowPass", "controller_fmu.fmu", ("controller_fmu", "fmu_common")),
}


# ---------------------------------------------------------------------- sources and staleness
def package_files(pkg: str) -> list[Path]:
    """The modules of a project package (the ``.py`` files of its Python packages, recursively;
    folders without an ``__init__.py``, such as ``fmu_common/loader``, are not modules) and the C
    sources of the kernels it owns."""
    root = ROOT / pkg
    py = [p for p in root.rglob("*.py") if "__pycache__" not in p.parts
          and all((d / "__init__.py").is_file() for d in p.parents if d.is_relative_to(root))]
    c = [f for k, v in kernels.KERNELS.items() if v[0] == pkg for f in kernels.source_files(k)]
    return sorted(py + c)


def spec_kernels(spec: FmuSpec) -> list[str]:
    """The compiled kernels of the packages an FMU ships."""
    return [k for k, v in kernels.KERNELS.items() if v[0] in spec.packages]


def source_files(spec: FmuSpec) -> list[Path]:
    return [f for pkg in spec.packages for f in package_files(pkg)]


def source_digest(spec: FmuSpec, platforms=None) -> str:
    """sha256 of the FMU's inputs: its sources (Python and C), the build scripts (this one and
    the kernels'), the platforms its kernels are built for (default: those this machine can
    build) and the pythonfmu version."""
    import pythonfmu

    platforms = kernels.available_platforms() if platforms is None else list(platforms)
    h = hashlib.sha256(f"{BUILD_FORMAT} {spec} pythonfmu {pythonfmu.__version__} kernels "
                       f"{' '.join(platforms)} loader {' '.join(loader_build.loader_platforms())} "
                       f"python {loader_build.recorded_python()}\n".encode())
    for path in [Path(__file__).resolve(), ROOT / "orchestration" / "export" / "model_description.py",
                 Path(kernels.__file__).resolve(),
                 Path(loader_build.__file__).resolve(), *loader_build.loader_files(),
                 *source_files(spec)]:
        h.update(path.relative_to(ROOT).as_posix().encode() + b"\0")
        h.update(path.read_bytes() + b"\0")
    return h.hexdigest()


def fmu_digest(path: Path) -> str | None:
    """The source digest recorded in a built FMU, or None."""
    try:
        with zipfile.ZipFile(path) as zf:
            return json.loads(zf.read(STAMP))["digest"]
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None


def is_stale(name: str, out_dir: Path | None = None) -> bool:
    path = Path(out_dir or places.fmu_dir()) / f"{name}.fmu"
    return fmu_digest(path) != source_digest(SPECS[name])


# ---------------------------------------------------------------------- build
def build_fmu(name: str, out_dir: Path | None = None, force: bool = False,
              progress=None) -> Path:
    """Build one FMU into ``out_dir`` (default: :func:`.places.fmu_dir`) unless it is up to
    date; return its path. ``progress(fraction, label)``: told each step (compiling the
    kernels, packaging with pythonfmu)."""
    spec = SPECS[name]
    out_dir = Path(out_dir or places.fmu_dir())
    target = out_dir / f"{name}.fmu"
    platforms = kernels.available_platforms()
    digest = source_digest(spec)
    if not force and fmu_digest(target) == digest:
        return target
    out_dir.mkdir(parents=True, exist_ok=True)
    what = f"building {name} (python, FMI 2.0)"
    if progress is not None:
        progress(0.0, f"{what}: compiling its kernels")
    try:
        libs = kernels.ensure_kernels(platforms, spec_kernels(spec))
    except kernels.KernelBuildError as exc:
        raise BuildError(f"building {name} failed: {exc}") from None
    with tempfile.TemporaryDirectory(prefix=f"flexpend_{name}_") as tmp:
        stage = Path(tmp) / "stage"
        for src in [*source_files(spec), *libs.values()]:
            dst = stage / src.relative_to(ROOT)
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
        (stage / f"{name}.py").write_text(_BUILD_MODULE.format(name=name, module=spec.module))
        built = Path(tmp) / f"{name}.fmu"
        args = json.dumps({"name": name, "module": spec.module, "stage": str(stage),
                           "packages": list(spec.packages), "dest": str(built),
                           "digest": digest})
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        env["PYTHONPATH"] = os.pathsep.join([str(stage), str(ROOT)])
        # pythonfmu's scratch folders inside ours: a packaging ended by Ctrl-C leaves none
        env["TMPDIR"] = tmp
        if progress is not None:
            progress(0.3, f"{what}: packaging with pythonfmu")
        proc = subprocess.run([sys.executable, "-c", _WORKER_CALL, args], cwd=tmp, env=env,
                              capture_output=True, text=True)
        if proc.returncode != 0 or not built.is_file():
            raise BuildError(f"building {name} failed:\n{proc.stdout}\n{proc.stderr}")
        # atomic: a concurrent reader sees the old or the new FMU, never half of one
        with atomic_path(target) as part:
            shutil.copyfile(built, part)
    if progress is not None:
        progress(1.0, f"{what}: written")
    return target


def build_fmus(out_dir: Path | None = None, names=None, force: bool = False,
               progress=None) -> dict:
    """Build (if stale) every FMU of :data:`SPECS` (or ``names``); return name -> path.
    ``progress(fraction, label)``: told each step of each FMU built."""
    names = list(SPECS) if names is None else list(names)
    unknown = sorted(set(names) - set(SPECS))
    if unknown:
        raise ValueError(f"unknown FMU(s) {', '.join(unknown)}; known: {', '.join(SPECS)}")
    stale = [n for n in names if force or is_stale(n, out_dir)]

    def share(i):                   # the i-th stale FMU's steps, as its share of the whole
        return None if progress is None else \
            (lambda f, label=None: progress((i + f) / len(stale), label))
    out = {n: build_fmu(n, out_dir, force, share(stale.index(n)) if n in stale else None)
           for n in names}
    if progress is not None:
        progress(1.0)
    return out


#: The slave module the pythonfmu builder imports (``<name>.py`` in the stage): the model's class.
_BUILD_MODULE = '''"""The slave module of {name} for the pythonfmu builder."""
from {module} import {name}  # noqa: F401
'''

#: The slave module inside the FMU (``resources/<name>.py``), which pythonfmu's binary imports by
#: its bare name and then executes a second time, at every fmi2Instantiate, with the module's dict
#: as globals and a fresh dict as locals. It
#:
#: * imports the FMU's own copy of its packages under a private name
#:   (``flexpend_loader.load_slave``), so that what is shipped is what runs, whatever the host
#:   process imported before (``flexpend run`` and the tests import the checkout's packages);
#: * binds nothing in that second execution and leaves the class as the module attribute ``""``:
#:   pythonfmu 0.7.0 looks for the class among the classes of the locals, and leaks the repr of
#:   every class of their MROs at every instantiation (about 1 KB); with no class there it takes
#:   the attribute named by an empty string;
#: * holds 2**20 references to its own dict: pythonfmu 0.7.0 releases, at every fmi2Instantiate,
#:   one reference to it that it never took (the borrowed result of PyModule_GetDict). The FMU's
#:   loader gives that reference back after each instantiation; the spare ones keep the count
#:   above zero in between.
_SLAVE_MODULE = '''"""The pythonfmu slave module of {name} (generated by orchestration/export/python_fmus.py)."""
if "_FLEXPEND_SLAVE" not in globals():
    def _load():
        import os
        here = os.path.dirname(os.path.abspath(__file__))
        path = os.path.join(here, "flexpend_loader.py")
        namespace = {{"__name__": "flexpend_loader", "__file__": path}}
        with open(path, encoding="utf-8") as f:
            exec(compile(f.read(), path, "exec"), namespace)
        return namespace["load_slave"](here, {module!r}, {name!r}, {packages!r})

    _FLEXPEND_SLAVE = _load()
    globals()[""] = _FLEXPEND_SLAVE
    _PYTHONFMU_DICT_REFS = [globals()] * (1 << 20)
'''

_WORKER_CALL = "import sys; from orchestration.export.python_fmus import _worker; _worker(sys.argv[1])"


def _worker(args_json: str):
    """Child process: run the pythonfmu builder, then replace its ``modelDescription.xml`` by the
    one written from the model's table of variables (with pythonfmu's GUID, capabilities and log
    categories), after checking that the slave registered exactly the table's variables."""
    import importlib
    import xml.etree.ElementTree as ET

    import pythonfmu
    from pythonfmu.builder import FmuBuilder

    from orchestration.export.loader_build import install_loader
    from orchestration.export.model_description import TABLES, fmi2_model_description

    a = json.loads(args_json)
    stage = Path(a["stage"])
    os.chdir(stage)
    raw = FmuBuilder.build_FMU(stage / f"{a['name']}.py", dest=Path(a["dest"]).parent / "raw.fmu",
                               project_files=[stage / p for p in a["packages"]],
                               canGetAndSetFMUstate=True, canSerializeFMUstate=True)
    cls = getattr(importlib.import_module(a["module"]), a["name"])
    slave = cls(instance_name="build", resources=str(stage))
    from fmu_common.variables import python_entries

    table = TABLES[a["name"]][1]
    registered = [(v.name, v.value_reference) for v in slave.vars.values()]
    expected = [(v.name, vr) for vr, v in python_entries(table)]   # co-simulation: no ME variables
    if registered != expected:
        raise SystemExit(f"{a['name']}: the slave registered {registered}, the table says "
                         f"{expected}")
    with zipfile.ZipFile(raw) as zf:
        entries = {i.filename: zf.read(i) for i in zf.infolist()}
    root = ET.fromstring(entries["modelDescription.xml"])
    cats = root.find("LogCategories")
    entries["modelDescription.xml"] = fmi2_model_description(
        a["name"], root.get("guid"),
        generation_tool=f"flexpend (pythonfmu {pythonfmu.__version__})",
        co_simulation=dict(root.find("CoSimulation").attrib),
        log_categories={c.get("name"): c.get("description") for c in cats} if cats else None)
    entries[f"resources/{a['name']}.py"] = _SLAVE_MODULE.format(
        name=a["name"], module=a["module"], packages=(*a["packages"], "pythonfmu")).encode()
    install_loader(entries, a["name"], table, [c.get("name") for c in cats] if cats else [])
    entries[STAMP] = json.dumps({"model": a["name"], "digest": a["digest"]}).encode()
    with zipfile.ZipFile(a["dest"], "w", zipfile.ZIP_DEFLATED) as zf:
        for fname, data in entries.items():
            zf.writestr(fname, data)
