"""Build the native FMUs in C, FMI 2.0 and FMI 3.0: the plant, one FMU per rung family
(FlexiblePendulum, FlexiblePendulumStiffened, FlexiblePendulumExact:
:data:`plant_fmu.interface.PLANT_FMUS`), and the controller PDLowPass.

    build_native_fmus(out_dir=build/fmus/native, fmi_version=2, platforms=None)
        -> {"FlexiblePendulum": path, ..., "PDLowPass": path}

The plant families share one model source (``plant_model.c``); what tells them apart is
generated into their header: the rungs the FMU runs and what it offers (Model Exchange,
directional derivatives, the output derivatives' order), which its modelDescription declares
and which it honours at every parameter value it accepts (docs/fmus.md).

Each FMU is compiled from

* the instance core, version-neutral and written once for both models
  (``fmu_common/native/fpm_core.c`` on the guard ``fpm_guard.c``: modes, the table's checks,
  variable access, FMU states), under the thin adapter of its FMI version (``fmi2.c`` or
  ``fmi3.c``);
* the model (``plant_fmu/native/plant_model.c`` or ``controller_fmu/native/controller_model.c``:
  its parameter checks, its
  step, its outputs) on the compiled kernels the Python side calls too
  (``plant_fmu/native/fp_plant.c``, ``controller_fmu/native/fp_filter.c``);
* a header generated here into the build folder (never committed), ``fpm_vars.h``: the model's
  variables from the one Python table (:mod:`plant_fmu.interface`,
  :mod:`controller_fmu.interface`; value reference = position in the table, the input-derivative
  variables of the pythonfmu flavour left out), the model name and GUID, and for the plant the
  modal tables of the unit beam (:func:`plant_fmu.beam.unit_beam`) for ``n_elements`` 1 ..
  :data:`NE_MAX` and ``n_modes`` 0 .. :data:`N_MODES_MAX`, written as exact hexadecimal floats.

Binaries: ``linux64`` (host compiler) and ``win64`` (mingw-w64, when installed), with the flags of
the kernels (:data:`fmu_common.kernels.CFLAGS`: C99, ``-Wall -Wextra -Werror -pedantic``, no
floating-point contraction, hidden visibility: only the FMI functions are exported) and
link-time optimisation (:data:`FMU_CFLAGS`), linked
against libc and libm alone (``-static-libgcc`` on Windows). The FMI headers are fmpy's copy of
the standard's (``fmpy/c-code``). ``modelDescription.xml`` comes from
:mod:`.model_description`. An FMU is rebuilt only when the digest of its inputs (sources, table,
build scripts) changes, or when it lacks a binary asked for: a run asks for the host's alone
(:func:`orchestration.export.flavour_fmus`), ``flexpend build`` and ``flexpend export`` for
every platform this machine builds; the binaries an FMU has from the same sources are kept, the
missing ones compiled, all of them at once (one compiler process each, as many as there are
cores). A build says what it built on stderr: one line per binary compiled, and one line naming
the missing cross-compiler of a platform it skipped (win64 without mingw-w64).
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from controller_fmu.interface import CONTROLLER_FMUS
from fmu_common import kernels
from fmu_common.variables import (derivatives, event_indicators, native_variables,
                                  python_entries, states, value_references)
from plant_fmu.beam import _fe_modes_unit, unit_beam
from plant_fmu.interface import N_ETA_OUTPUTS, PLANT_FMUS, VARIABLES

from ..files import atomic_path
from ..notes import note
from . import places
from .model_description import (CLOCKS, NATIVE, fmi2_model_description,
                                fmi3_model_description)

__all__ = ["MODELS", "NE_MAX", "N_MODES_MAX", "MAX_SUBSTEPS", "PLATFORMS",
           "build_native_fmus", "build_native_fmu", "generate_header", "fmi_include_dir",
           "source_digest", "NativeBuildError", "GENERATION_TOOL"]

ROOT = kernels.ROOT
#: the FMI layers every native FMU is built from
SRC = ROOT / "fmu_common" / "native"
#: the core every native FMU links, under its FMI version's adapter (fmi<version>.c).
CORE_SOURCES = ("fpm_guard.c", "fpm_core.c")
#: room in fpm.h's table (FPM_MAX_VARS)
MAX_VARS = 96
#: The meshes and modes the native plant carries tables for (the pythonfmu plant computes any).
NE_MAX = 100
N_MODES_MAX = 8
#: substeps (or accepted adaptive steps) per doStep beyond which a step is discarded
MAX_SUBSTEPS = 1_000_000
#: Bump when the build changes in a way its inputs do not show.
BUILD_FORMAT = 2
STAMP = "resources/flexpend_build.json"
#: the modelDescription's generationTool of every native FMU (whose fmi2Reset/fmi3Reset restores
#: the state after instantiation: fpm_reset in fpm_core.c)
GENERATION_TOOL = "flexpend native FMU (C)"

#: model -> (its FMU glue in C, in the native folder of its first kernel; the kernels it links)
MODELS = {
    **{name: ("plant_model.c", ("flexpend_plant", "flexpend_filter"))
       for name in PLANT_FMUS},
    **{name: ("controller_model.c", ("flexpend_filter",)) for name in CONTROLLER_FMUS},
}


def model_source(name: str) -> Path:
    """The C file of model ``name``'s FMU glue (its parameter checks, step and outputs)."""
    model_c, kernel_names = MODELS[name]
    return kernels.native_dir(kernel_names[0]) / model_c
#: FMI platform folder names: (FMI 2.0, FMI 3.0)
PLATFORMS = {"linux64": ("linux64", "x86_64-linux"), "win64": ("win64", "x86_64-windows")}
LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with status fmi2Warning / fmi3Warning",
    "logStatusDiscard": "Log messages with status Discard",
    "logStatusError": "Log messages with status Error",
    "logStatusFatal": "Log messages with status Fatal",
    "logAll": "Every log message",
}


class NativeBuildError(RuntimeError):
    """A native FMU could not be built (the message holds the compiler's output)."""


def fmi_include_dir() -> Path:
    """The FMI 2.0 and 3.0 headers (fmpy ships the standard's)."""
    import fmpy

    d = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (d / "fmi2Functions.h").is_file() or not (d / "fmi3Functions.h").is_file():
        raise NativeBuildError(f"the FMI headers are missing from {d} (fmpy's c-code folder)")
    return d


# ---------------------------------------------------------------------- generated header
def _c_string(s: str) -> str:
    return json.dumps(s)            # a C string literal for the ASCII text of the tables


def _hex(x: float) -> str:
    """An exact C literal of ``x`` (hexadecimal float; HUGE_VAL for infinity)."""
    x = float(x)
    if x != x:
        raise NativeBuildError("a NaN in a table of the native FMUs")
    if x in (float("inf"), float("-inf")):
        return "HUGE_VAL" if x > 0 else "-HUGE_VAL"
    return x.hex()


def generate_header(name: str, token: str, table=None, mode_tables: bool = True) -> str:
    """``fpm_vars.h`` of model ``name``: its variables, value-reference macros, name, token, what
    it offers and (a plant) the rungs it runs, and for the plant the unit beam's modal tables.
    ``table``: a model's whole table, whose pythonfmu FMU's variables
    (:func:`fmu_common.variables.python_entries`) are written instead of the native FMU's (the
    pythonfmu loader checks its FMU's calls against them); ``mode_tables``: False leaves the
    modal tables out.

    A native FMU without Model Exchange declares no Model-Exchange local: its table
    (``fpm_vars``) leaves them out, while the value-reference macros and ``FPM_NX``/``FPM_NZ``
    still describe the whole table (the model's code, shared by the families, is compiled
    alike; the core refuses what the FMU does not offer before that code is reached)."""

    offers = None
    if table is None:
        _, table, offers = NATIVE[name]
        entries = native_variables(table, offers.model_exchange)
        every = native_variables(table)
    else:
        entries = every = python_entries(table)
    if len(table) > MAX_VARS:
        raise NativeBuildError(f"{name} has {len(table)} value references; fpm.h has room for "
                               f"{MAX_VARS}")
    types = {"Real": "FPM_REAL", "Integer": "FPM_INTEGER", "Boolean": "FPM_BOOLEAN",
             "String": "FPM_STRING"}
    caus = {"parameter": "FPM_PARAMETER", "input": "FPM_INPUT", "output": "FPM_OUTPUT",
            "local": "FPM_LOCAL"}
    listed = [v for _, v in entries]
    state_pos = {s: i + 1 for i, s in enumerate(states(listed))}
    der_pos = {d: i + 1 for i, d in enumerate(derivatives(listed))}
    ind_pos = {z: i + 1 for i, z in enumerate(event_indicators(listed))}
    whole = [v for _, v in every]
    lines = [f"/* Generated by orchestration/export/native_fmus.py from the table of {name}: do "
             f"not edit. */",
             f"const char fpm_model_name[] = {_c_string(name)};",
             f"const char fpm_token[] = {_c_string(token)};",
             f"const long fpm_time_vr = {_time_vr(table)};"]
    for vr, v in every:               # der(x) -> VR_der_x
        macro = v.name.replace("der(", "der_").replace(")", "")
        lines.append(f"#define VR_{macro} {vr}u")
    rows = []
    for vr, v in entries:
        start = v.start
        real = "0.0" if start is None or isinstance(start, str) else _hex(float(start))
        text = _c_string(start) if isinstance(start, str) else "NULL"
        rows.append(f"    [{vr}] = {{{_c_string(v.name)}, {types[v.type]}, {caus[v.causality]}, "
                    f"{real}, {text}, {state_pos.get(v.name, 0)}, {der_pos.get(v.name, 0)}, "
                    f"{ind_pos.get(v.name, 0)}}},")
    lines += [f"#define FPM_NX {len(states(whole))}",
              f"#define FPM_NZ {len(event_indicators(whole))}",
              "const fpm_var fpm_vars[FPM_MAX_VARS] = {", *rows, "};"]
    if offers is not None:
        lines += [f"#define FPM_OFFERS_ME {int(offers.model_exchange)}",
                  f"#define FPM_OFFERS_JACOBIAN {int(offers.directional_derivatives)}",
                  f"#define FPM_OUTPUT_DERIVATIVE_ORDER {offers.output_derivative_order}"]
    if offers is not None and name in CONTROLLER_FMUS:
        lines += [f"#define FPM_SAMPLED {int(CONTROLLER_FMUS[name].sampled)}"]
    if offers is not None:
        lines += _clock_lines(name)
    if offers is not None and name in PLANT_FMUS:
        rungs = PLANT_FMUS[name].fidelities
        lines += ["/* the rungs (fidelity values) this FMU runs, and every FMU's */",
                  f"#define FPM_N_RUNGS {len(rungs)}",
                  "static const char *const fpm_rungs[FPM_N_RUNGS] = {"
                  + ", ".join(map(_c_string, rungs)) + "};",
                  "#define FPM_RUNG_FMUS " + _c_string("; ".join(
                      f"{f.name}: {', '.join(f.fidelities)}" for f in PLANT_FMUS.values()))]
        if mode_tables:
            lines += _mode_tables()
    return "\n".join(lines) + "\n"


#: fpm.h's clock hooks as a model without clocks defines them (fpm_vars.h of every native FMU
#: without clocks: its model's source need not know of clocks)
_NO_CLOCK_HOOKS = """\
#include "fpm.h"
int fpm_model_n_clocks(void) { return 0; }
int fpm_model_clock_of(unsigned vr) { (void)vr; return -1; }
void fpm_model_use_clocks(fpm_model *m, int on) { (void)m; (void)on; }
int fpm_model_clock_timing(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                           double *interval, double *shift)
{
    (void)m; (void)clock; (void)interval; (void)shift;
    fpm_log(lg, FPM_ERROR, "%s: this FMU has no clocks", fn);
    return FPM_ERROR;
}
int fpm_model_set_clock(fpm_model *m, const fpm_logger *lg, const char *fn, int clock,
                        int active, int apply)
{
    (void)m; (void)clock; (void)active; (void)apply;
    fpm_log(lg, FPM_ERROR, "%s: this FMU has no clocks", fn);
    return FPM_ERROR;
}
int fpm_model_get_clock(const fpm_model *m, int clock) { (void)m; (void)clock; return 0; }
int fpm_model_clock_update(fpm_model *m, const fpm_logger *lg) { (void)m; (void)lg; return 0; }
int fpm_model_clocked_set(fpm_model *m, const fpm_logger *lg, const char *fn, int mode,
                          const unsigned vr[], size_t n)
{
    (void)m; (void)lg; (void)fn; (void)mode; (void)vr; (void)n;
    return 0;
}"""


def _clock_lines(name: str) -> list[str]:
    """``fpm_vars.h``'s clocks (``model_description.CLOCKS``): their count and value-reference
    macros (``VR_<clock>``), or fpm.h's clock hooks of a model without clocks."""
    clocks = CLOCKS.get(name, ())
    lines = [f"#define FPM_N_CLOCKS {len(clocks)}"]
    lines += [f"#define VR_{c.name} {c.value_reference}u" for c in clocks]
    return lines if clocks else [*lines, _NO_CLOCK_HOOKS]


def _time_vr(table) -> int:
    """The value reference of the table's ``time`` (FMI 3.0's independent variable, which the
    FMI 3.0 adapter reads as the instance's time), -1 for a table without one."""
    found = [vr for vr, v in enumerate(table) if v.causality == "independent"]
    return found[0] if len(found) == 1 else -1


def _mode_tables() -> list[str]:

    n = N_MODES_MAX
    vrs = value_references(VARIABLES)
    out = [f"#define FPM_NE_MAX {NE_MAX}", f"#define FPM_N_MODES_MAX {n}",
           f"#define FPM_N_ETA {N_ETA_OUTPUTS}",
           "static const unsigned fpm_eta_vrs[FPM_N_ETA] = {"
           + ", ".join(f"{vrs[f'eta_{j}']}u" for j in range(1, N_ETA_OUTPUTS + 1)) + "};"]
    fields = {"lam": [], "I3": [], "I5": [], "tip_defl": [], "tip_slope": [], "Kg": []}
    for ne in range(1, NE_MAX + 1):
        k = min(ne, n)
        u = unit_beam(ne, k)
        for key, arr in (("lam", u.lam), ("I3", u.I3), ("I5", u.I5),
                         ("tip_defl", u.tip_deflection), ("tip_slope", u.tip_slope)):
            row = [_hex(x) for x in arr] + ["0.0"] * (n - k)
            fields[key].append("{" + ", ".join(row) + "}")
        kg = [[0.0] * n for _ in range(n)]
        for i in range(k):
            for j in range(k):
                kg[i][j] = float(u.Kg[i, j])
        fields["Kg"].append("{" + ", ".join(_hex(x) for r in kg for x in r) + "}")
    for key, rows in fields.items():
        width = "FPM_N_MODES_MAX * FPM_N_MODES_MAX" if key == "Kg" else "FPM_N_MODES_MAX"
        out.append(f"static const double fpm_unit_{key}[FPM_NE_MAX][{width}] = {{")
        out += [f"    {r}," for r in rows]
        out.append("};")
    return out + _mass_point_tables()


def _mass_point_tables() -> list[str]:
    """What the stiffened rung's mass points are made from (plant_fmu/beam.py, _unit_points):
    each mesh's unit modes at its free nodal dofs (the root's two are 0), ``2 ne`` rows of
    ``FPM_N_MODES_MAX`` (modes beyond ``ne`` 0), mesh after mesh from ``FPM_MODES_AT(ne)``; and
    numpy's Gauss-Legendre rules of ``4 max(n, 4)`` points (16 to 32) and of 3 points."""
    n = N_MODES_MAX
    out = ["#define FPM_MODES_AT(ne) ((long)FPM_N_MODES_MAX * (ne) * ((ne) - 1))",
           f"static const double fpm_unit_modes[{n * NE_MAX * (NE_MAX + 1)}] = {{"]
    for ne in range(1, NE_MAX + 1):
        phi = _fe_modes_unit(ne)[1][2:, :min(ne, n)]
        rows = [[_hex(x) for x in r] + ["0.0"] * (n - phi.shape[1]) for r in phi]
        out.append("    " + ", ".join(x for r in rows for x in r) + ",")
    out.append("};")
    sizes = range(16, 4 * n + 1, 4)
    for key, k in (("x", 0), ("w", 1)):
        out.append(f"static const double fpm_gauss_{key}[{len(sizes)}][{4 * n}] = {{")
        for P in sizes:
            v = list(np.polynomial.legendre.leggauss(P)[k]) + [0.0] * (4 * n - P)
            out.append("    {" + ", ".join(_hex(x) for x in v) + "},")
        out.append("};")
        out.append(f"static const double fpm_gauss3_{key}[3] = {{"
                   + ", ".join(_hex(x) for x in np.polynomial.legendre.leggauss(3)[k]) + "};")
    return out


# ---------------------------------------------------------------------- build
def _inputs(name: str) -> list[Path]:
    files = [SRC / f for f in ("fpm.h", *CORE_SOURCES, "fmi2.c", "fmi3.c")] + [model_source(name)]
    for k in MODELS[name][1]:
        files += kernels.source_files(k)
    files += [ROOT / "plant_fmu" / f for f in ("interface.py", "beam.py", "params.py",
                                                 "nominals.py")]
    files += [ROOT / "controller_fmu" / "interface.py", ROOT / "controller_fmu" / "pd_lowpass.py",
              ROOT / "controller_fmu" / "nominals.py",
              Path(__file__).resolve(), Path(kernels.__file__).resolve(),
              ROOT / "orchestration" / "export" / "model_description.py"]
    return files


def source_digest(name: str, fmi_version: int) -> str:
    """sha256 of everything an FMU is built from (the same for each of its platforms)."""
    h = hashlib.sha256(f"{BUILD_FORMAT} {name} fmi{fmi_version} "
                       f"{NE_MAX} {N_MODES_MAX} {MAX_SUBSTEPS} {kernels.CFLAGS} "
                       f"{FMU_CFLAGS}\n".encode())
    for path in _inputs(name):
        h.update(path.relative_to(ROOT).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def _token(name: str, digest: str) -> str:
    """The GUID / instantiation token: a UUID made from the build's digest."""
    return "{" + str(uuid.UUID(hex=hashlib.sha256(f"{name}{digest}".encode()).hexdigest()[:32])) \
        + "}"


def _built(path: Path, name: str, fmi_version: int) -> tuple[str | None, list]:
    """The digest of the sources the FMU at ``path`` was built from (its stamp; None when it has
    none) and the platforms its stamp names whose binary it holds."""
    try:
        with zipfile.ZipFile(path) as zf:
            stamp = json.loads(zf.read(STAMP))
            held = set(zf.namelist())
        platforms = [p for p in stamp["platforms"]
                     if p in PLATFORMS and _binary(name, fmi_version, p) in held]
        return str(stamp["digest"]), platforms
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile):
        return None, []


#: The FMU binaries' flags beside the kernels' (:data:`fmu_common.kernels.CFLAGS`): link-time
#: optimisation, so that the calls of every step inline across the FMI adapter, the instance
#: core, the model and its kernel (separate translation units): about 8 % of a macro step of
#: the filtered scene's co-simulation (T5's Hermite setting, 2026-11-29: 5.35 ms without, 4.95
#: ms with, medians of 15 runs). The arithmetic is the same (IEEE, no contraction, no
#: reassociation): the outputs are bit for bit those without it. The plant's steppers that run
#: with subnormals flushed are kept out of line (fp_plant.c, FP_NOINLINE), so that no caller's
#: arithmetic moves into their floating-point mode.
FMU_CFLAGS = ("-flto",)


def compile_command(name: str, fmi_version: int, platform: str, out: Path, gen: Path,
                    cc: str, extra=()) -> list[str]:
    """The compiler's command line for one binary."""
    sources = [SRC / f"fmi{fmi_version}.c", *(SRC / f for f in CORE_SOURCES), model_source(name)]
    includes = [gen, SRC, fmi_include_dir()]
    for k in MODELS[name][1]:
        native = kernels.native_dir(k)
        sources += [native / s for s in kernels.KERNELS[k][1]]
        includes.append(native)
    cmd = [cc, *kernels.CFLAGS, *FMU_CFLAGS, *extra, "-DFP_API=", "-DFPF_API=",
           f"-DFPM_MAX_SUBSTEPS={MAX_SUBSTEPS}L", *(f"-I{d}" for d in includes)]
    if platform.startswith("win"):
        cmd += ["-shared", "-static-libgcc", "-o", str(out), *map(str, sources)]
    else:
        cmd += ["-fPIC", "-shared", "-Wl,--no-undefined", "-o", str(out), *map(str, sources),
                "-lm"]
    return cmd


def _say(line: str) -> None:
    note(line)                              # silent within quiet() (flexpend --quiet)


def skipped_platforms() -> dict:
    """The cross platforms this machine cannot build: platform -> why (the compiler missing)."""
    out = {}
    for plat in kernels.CROSS_COMPILERS:
        if plat == kernels.host_platform():
            continue
        try:
            kernels.find_compiler(plat)
        except kernels.CompilerNotFound as exc:
            out[plat] = str(exc)
    return out


def _binary(name: str, fmi_version: int, platform: str) -> str:
    """The zip entry of ``name``'s binary for ``platform``."""
    suffix = ".dll" if platform.startswith("win") else ".so"
    return f"binaries/{PLATFORMS[platform][0 if fmi_version == 2 else 1]}/{name}{suffix}"


@dataclass
class _Build:
    """One FMU to (re)build: the platforms it will have, those to compile, the binaries kept."""
    name: str
    fmi_version: int
    target: Path
    digest: str
    platforms: list
    compile: list
    kept: dict = field(default_factory=dict)        # zip entry -> bytes, from the FMU replaced


def _plan(name: str, fmi_version: int, out_dir: Path, force: bool, platforms) -> _Build | None:
    """What building ``name`` needs, None when its FMU is up to date: built from the same sources
    (its stamp's digest) with a binary for every platform of ``platforms``. The binaries it
    already has from the same sources are kept, and only the missing ones compiled."""
    if name not in MODELS:
        raise ValueError(f"unknown FMU {name!r}; known: {', '.join(MODELS)}")
    for plat in platforms:
        if plat not in PLATFORMS:
            raise NativeBuildError(f"no native FMU build for platform {plat}")
    target = out_dir / f"fmi{fmi_version}" / f"{name}.fmu"
    digest = source_digest(name, fmi_version)
    built, have = (None, []) if force else _built(target, name, fmi_version)
    if built != digest:
        have = []
    if all(p in have for p in platforms):
        return None
    build = _Build(name, fmi_version, target, digest,
                   [*have, *(p for p in platforms if p not in have)],
                   [p for p in platforms if p not in have])
    try:
        with zipfile.ZipFile(target) as zf:
            build.kept = {e: zf.read(e) for e in (_binary(name, fmi_version, p) for p in have)}
    except (OSError, KeyError, zipfile.BadZipFile):     # changed since it was read: build all
        build.platforms, build.compile, build.kept = list(platforms), list(platforms), {}
    return build


class _Compilers:
    """The compilers running in the build's threads, so that an interrupted build (Ctrl-C in the
    main thread) ends them at once instead of waiting for each to finish (about 13 s)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.running: set = set()
        self.stopped = False

    def run(self, cmd, tmp: Path) -> subprocess.CompletedProcess:
        """``cmd`` run to its end, its temporary files in ``tmp`` (the build's own folder,
        removed however the build ends: a compiler ended by :meth:`stop` leaves its own)."""
        with self.lock:
            if self.stopped:
                raise NativeBuildError("the build was stopped")
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, env={**os.environ, "TMPDIR": str(tmp)})
            self.running.add(proc)
        try:
            out, err = proc.communicate()
        finally:
            with self.lock:
                self.running.discard(proc)
        return subprocess.CompletedProcess(cmd, proc.returncode, out, err)

    def stop(self):
        """End every running compiler, and start no other until :meth:`reset`."""
        with self.lock:
            self.stopped = True
            for proc in self.running:
                with contextlib.suppress(OSError):
                    proc.kill()

    def reset(self):
        with self.lock:
            self.stopped = False


_compilers = _Compilers()


def _compile(build: _Build, platform: str, gen: Path, tmp: Path) -> tuple[str, bytes, str]:
    """Compile ``build``'s binary for ``platform``: (zip entry, bytes, the compiler)."""
    cc = kernels.find_compiler(platform)
    entry = _binary(build.name, build.fmi_version, platform)
    lib = tmp / f"fmi{build.fmi_version}-{platform}-{Path(entry).name}"
    cmd = compile_command(build.name, build.fmi_version, platform, lib, gen, cc)
    proc = _compilers.run(cmd, tmp)
    if proc.returncode != 0:
        raise NativeBuildError(f"compiling {build.name} (FMI {build.fmi_version}) for "
                               f"{platform} failed:\n{' '.join(cmd)}\n{proc.stdout}{proc.stderr}")
    return entry, lib.read_bytes(), cc


def _build_all(builds: list, progress=None) -> None:
    """Compile every missing binary of ``builds`` at once (one compiler process per binary, as
    many at a time as there are cores), then write each FMU: complete, or not at all.
    ``progress(fraction, label)``: told as each binary is compiled and each FMU written."""
    def what(b):
        return f"building {b.name} (native, FMI {b.fmi_version}.0)"
    n_jobs = sum(len(b.compile) for b in builds)
    total = n_jobs + 0.1 * len(builds)                 # writing an FMU: a tenth of a compile
    done_work = 0.0

    def tell(label, work=0.0):
        nonlocal done_work
        done_work += work
        if progress is not None:
            progress(min(done_work / total, 1.0), label)
    with tempfile.TemporaryDirectory(prefix="flexpend_native_") as tmp:
        tmp = Path(tmp)
        jobs = {}
        from concurrent.futures import ThreadPoolExecutor, as_completed   # only when building

        _compilers.reset()
        with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as pool, \
                _stopped_on_error(pool):
            for b in builds:
                gen = tmp / f"gen-{b.name}-fmi{b.fmi_version}"
                gen.mkdir()
                (gen / "fpm_vars.h").write_text(generate_header(b.name, _token(b.name, b.digest)))
                for plat in b.compile:
                    jobs[b.name, b.fmi_version, plat] = pool.submit(_compile, b, plat, gen, tmp)
            compiling = [f"{b.name} {plat}" for b in builds for plat in b.compile]
            if builds:
                names = ", ".join(dict.fromkeys(b.name for b in builds))
                tell(f"building {names} (native, FMI {builds[0].fmi_version}.0): compiling "
                     f"{', '.join(compiling)}")
            keys = {job: key for key, job in jobs.items()}
            for job in as_completed(keys):
                name, version, plat = keys[job]
                job.result()                                            # the first error raises
                compiling.remove(f"{name} {plat}")
                tell(f"building {name} (native, FMI {version}.0): compiled {plat}"
                     + (f"; compiling {', '.join(compiling)}" if compiling else ""), 1.0)
            done = {key: job.result() for key, job in jobs.items()}
        for b in builds:
            binaries = dict(b.kept)
            for plat in b.compile:
                entry, data, cc = done[b.name, b.fmi_version, plat]
                binaries[entry] = data
                _say(f"{b.name} (FMI {b.fmi_version}): built {plat} ({entry}) with {cc}")
            tell(f"{what(b)}: writing {b.target.name}")
            _write_fmu(b, binaries, tmp)
            tell(f"{what(b)}: written", 0.1)


@contextlib.contextmanager
def _stopped_on_error(pool):
    """On any exception in the body (a failed compile, Ctrl-C): the compiles not started are
    dropped and those running are ended, so that leaving ``pool`` does not wait for them."""
    try:
        yield
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        _compilers.stop()
        raise


def _write_fmu(b: _Build, binaries: dict, tmp: Path) -> None:
    """Write ``b``'s FMU (``binaries``: zip entry -> bytes) to a temporary name beside its place,
    then rename it into place."""
    token = _token(b.name, b.digest)
    entries = {e: binaries[e] for e in (_binary(b.name, b.fmi_version, p) for p in b.platforms)}
    entries["modelDescription.xml"] = _model_description(b.name, b.fmi_version, token)
    entries[STAMP] = json.dumps({"model": b.name, "fmi_version": b.fmi_version,
                                 "digest": b.digest, "platforms": b.platforms}).encode()
    built = tmp / f"{b.name}-fmi{b.fmi_version}.fmu"
    with zipfile.ZipFile(built, "w", zipfile.ZIP_DEFLATED) as zf:
        for fname, data in entries.items():
            zf.writestr(fname, data)
    b.target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(b.target) as part:          # complete or absent, never through a link
        shutil.copyfile(built, part)


def build_native_fmu(name: str, fmi_version: int = 2, out_dir: Path | None = None,
                     force: bool = False, platforms=None) -> Path:
    """Build one native FMU into ``out_dir/fmi<version>/`` unless it is up to date
    (:func:`build_native_fmus`)."""
    return build_native_fmus(out_dir, [name], force, fmi_version, platforms)[name]


def _model_description(name: str, fmi_version: int, token: str) -> bytes:
    """The modelDescription of native FMU ``name``: its flags are what it offers
    (:data:`.model_description.NATIVE`), at every parameter value it accepts."""
    model, table, offers = NATIVE[name]
    derivative = "true" if offers.directional_derivatives else "false"
    common = {"modelIdentifier": name, "needsExecutionTool": "false",
              "canHandleVariableCommunicationStepSize": "true",
              "canBeInstantiatedOnlyOncePerProcess": "false",
              "canGetAndSetFMUstate" if fmi_version == 2 else "canGetAndSetFMUState": "true",
              "canSerializeFMUstate" if fmi_version == 2 else "canSerializeFMUState": "true",
              "providesDirectionalDerivative" if fmi_version == 2 else
              "providesDirectionalDerivatives": derivative}
    tool = GENERATION_TOOL
    order = str(offers.output_derivative_order)
    me = dict(common)
    del me["canHandleVariableCommunicationStepSize"]
    if fmi_version == 2:
        me = {**me, "completedIntegratorStepNotNeeded": "true",
              "canNotUseMemoryManagementFunctions": "false"}
        cs = {**common, "canInterpolateInputs": "true" if offers.interpolates_inputs else "false",
              "maxOutputDerivativeOrder": order,
              "canRunAsynchronuously": "false", "canNotUseMemoryManagementFunctions": "false"}
        return fmi2_model_description(name, token, generation_tool=tool, co_simulation=cs,
                                      log_categories=LOG_CATEGORIES, native=True,
                                      model_exchange=me if offers.model_exchange else None,
                                      table=table, model=model)
    me = {**me, "needsCompletedIntegratorStep": "false",
          "providesEvaluateDiscreteStates": "false"}
    # an FMU with clocks runs them in event mode (docs/fmus.md, PDLowPassSampled)
    cs = {**common, "maxOutputDerivativeOrder": order,
          "hasEventMode": "true" if CLOCKS.get(name) else "false",
          "providesIntermediateUpdate": "false", "mightReturnEarlyFromDoStep": "false",
          "canReturnEarlyAfterIntermediateUpdate": "false"}
    return fmi3_model_description(name, token, generation_tool=tool, co_simulation=cs,
                                  log_categories=LOG_CATEGORIES, table=table, model=model,
                                  model_exchange=me if offers.model_exchange else None)


def max_output_derivative_order(name: str) -> int:
    """maxOutputDerivativeOrder of native FMU ``name``: what its interface offers (a test compares
    it with what the binary gives)."""
    return NATIVE[name][2].output_derivative_order


def build_native_fmus(out_dir: Path | None = None, names=None, force: bool = False,
                      fmi_version: int = 2, platforms=None, progress=None) -> dict:
    """Build the native FMUs of one FMI version that are missing or stale; ``{name: path}``.

    ``platforms``: the binaries each FMU must have (default: every platform this machine can
    build, the host's and those whose cross-compiler is installed; a missing cross-compiler is
    said on stderr). An FMU built from the same sources that has them is up to date, whatever
    other binaries it has; one that misses some gets them compiled and keeps those it has; one
    built from other sources is built anew for ``platforms``. Every binary to compile is
    compiled at once (:func:`_build_all`); each FMU is written complete or not at all. Says on
    stderr one line per binary compiled (not within :func:`orchestration.notes.quiet`).
    ``progress(fraction, label)``: told as each binary is compiled and each FMU written."""
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version = {fmi_version!r}; allowed: 2, 3")
    names = list(MODELS) if names is None else list(names)
    unknown = sorted(set(names) - set(MODELS))
    if unknown:
        raise ValueError(f"unknown FMU(s) {', '.join(unknown)}; known: {', '.join(MODELS)}")
    out_dir = Path(out_dir or places.native_fmu_dir())
    try:
        skipped = skipped_platforms() if platforms is None else {}
        platforms = kernels.available_platforms() if platforms is None else list(platforms)
        builds = [b for b in (_plan(n, fmi_version, out_dir, force, platforms) for n in names)
                  if b is not None]
        if builds:
            _build_all(builds, progress)
            for b in builds:
                for plat, why in skipped.items():
                    print(f"{b.name} (FMI {fmi_version}): {plat} skipped: {why} (Debian: "
                          f"apt-get install gcc-mingw-w64-x86-64); the FMU has no {plat} binary",
                          file=sys.stderr, flush=True)     # a warning: not silenced by quiet
    except kernels.CompilerNotFound as exc:
        raise NativeBuildError(str(exc)) from None
    return {n: out_dir / f"fmi{fmi_version}" / f"{n}.fmu" for n in names}
