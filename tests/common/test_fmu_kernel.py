"""The compiled kernels inside the pythonfmu FMUs: shipped per platform, built from the current C
sources, loaded from the unpacked FMU without compiling, and required (no silent fallback).

The FMUs are driven in child processes: an FMU loaded into this test process would use the
packages (and kernels) this process has already imported from the checkout. The children run
with no C compiler on their PATH, so a kernel that was not shipped could not be built either.
"""
import ctypes
import json
import os
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmu_common import kernels
from plant_fmu.dynamics import plant_model
from plant_fmu.integrators import make_stepper
from plant_fmu.params import PlantParams

#: A child process: unpack the FMU into a new folder, instantiate it, take one 1 ms step with
#: F_c = 3 from phi0 = 0.2 and print, as JSON, the outputs, where the project package and the
#: kernel were loaded from, and every log message. scipy is made unimportable in it: the FMUs
#: need numpy only (and their kernel).
_CHILD = textwrap.dedent('''
    import json, sys, tempfile
    from fmpy import extract, read_model_description
    for name in [m for m in sys.modules if m == "scipy" or m.startswith("scipy.")]:
        del sys.modules[name]
    sys.modules["scipy"] = None      # the FMUs start and step with numpy alone
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE,
                           fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, calloc, free)
    fmu, pkg, kernel_module, output = sys.argv[1:5]
    unpacked = extract(fmu, tempfile.mkdtemp(prefix="flexpend_unpack_"))
    md = read_model_description(unpacked)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    logs = []
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(
        lambda env, name, status, cat, msg: logs.append(msg.decode()))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    s = FMU2Slave(guid=md.guid, unzipDirectory=unpacked,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="child")
    result = {"unpacked": str(unpacked), "logs": logs}
    try:
        s.instantiate(callbacks=cb, loggingOn=True)
    except Exception as exc:
        result["instantiate"] = str(exc)
        print(json.dumps(result))
        sys.exit(0)
    plant = output != "F_c"
    if plant:
        s.setReal([vr["phi0"]], [0.2])
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    if plant:
        s.setReal([vr["F_c"]], [3.0])
    else:
        s.setReal([vr["phi_o"], vr["omega_o"]], [0.1, -0.5])
    s.doStep(0.0, 1e-3)
    result["output"] = s.getReal([vr[output]])[0]
    def shipped(name):   # the FMU's own copy, imported under a private name by its loader
        return next(m for k, m in sys.modules.items()
                    if k.startswith("_flexpend_") and k.endswith("." + name))
    result["package"] = shipped(pkg).__file__
    result["kernel"] = shipped(kernel_module)._lib._name
    result["hashlib"] = "_hashlib" in sys.modules
    s.terminate()
    s.freeInstance()
    print(json.dumps(result))
''')


def _run_child(fmu, pkg, kernel_module, output, tmp_path):
    nocc = tmp_path / "bin"                     # a PATH with python and no C compiler
    nocc.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("CC", "PYTHONPATH")}
    env["PATH"] = str(nocc)
    env["TMPDIR"] = str(tmp_path)
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(fmu), pkg, kernel_module, output],
                          capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_plant_fmu_unpacked_twice_instantiates_each_time_from_its_own_kernel(fmus, tmp_path):
    """Each fresh unpack (as fmpy and most importers do) instantiates at once, with the package
    and the compiled kernel of that folder, and steps as the plant model does in this process."""
    p = PlantParams()
    m = plant_model(p)
    st = make_stepper("rk4", m, 0.0, m.initial_state(phi=0.2), u=3.0, h=2.5e-4)
    assert st.advance(1e-3) == (True, None)
    expected = m.tip_angle(st.y)[0]
    seen = set()
    for _ in range(2):
        r = _run_child(fmus["FlexiblePendulum"], "plant_fmu", "plant_fmu.kernel", "phi_o",
                       tmp_path)
        resources = Path(r["unpacked"]) / "resources"
        assert Path(r["package"]).is_relative_to(resources), r
        assert Path(r["kernel"]) == resources / "plant_fmu" / "native" / "lib" / \
            kernels.host_platform() / kernels.library_name("flexpend_plant",
                                                           kernels.host_platform())
        assert r["output"] == pytest.approx(expected, rel=1e-12)
        assert not r["hashlib"]          # OpenSSL in an FMU breaks a C host's exit
        seen.add(r["unpacked"])
    assert len(seen) == 2


def test_controller_fmu_loads_its_own_filter_kernel(fmus, tmp_path):
    r = _run_child(fmus["PDLowPass"], "controller_fmu", "controller_fmu.kernel", "F_c", tmp_path)
    resources = Path(r["unpacked"]) / "resources"
    assert Path(r["kernel"]).is_relative_to(resources / "controller_fmu" / "native" / "lib")
    assert r["output"] != 0.0                    # the filter moved


kernel_of = {"plant_fmu": "flexpend_plant", "controller_fmu": "flexpend_filter"}


def _without(fmu: str, drop: str, dest: Path) -> Path:
    """A copy of ``fmu`` without the entries whose names contain ``drop``."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            if drop not in info.filename:
                out.writestr(info, src.read(info))
    return dest


@pytest.mark.parametrize("name,pkg,module,output", [
    ("FlexiblePendulum", "plant_fmu", "plant_fmu.kernel", "phi_o"),
    ("PDLowPass", "controller_fmu", "controller_fmu.kernel", "F_c")])
def test_fmu_without_the_host_kernel_refuses_to_instantiate(fmus, tmp_path, name, pkg, module,
                                                            output):
    """No silent fallback: without the host platform's kernel fmi2Instantiate fails, and the log
    names the missing file and the platform."""
    plat = kernels.host_platform()
    broken = _without(fmus[name], f"native/lib/{plat}/", tmp_path / f"{name}.fmu")
    r = _run_child(broken, pkg, module, output, tmp_path)
    assert "instantiate" in r, r
    msg = " ".join(r["logs"])
    assert "KernelError" in msg and "is missing" in msg and f"({plat})" in msg, msg
    assert f"native/lib/{plat}/{kernels.library_name(kernel_of[pkg], plat)}" in msg, msg


def _shipped(fmu: str) -> dict:
    """``{(kernel, platform): bytes}`` of the kernels inside an FMU."""
    out = {}
    with zipfile.ZipFile(fmu) as zf:
        names = zf.namelist()
        for kernel, (pkg, *_) in kernels.KERNELS.items():
            for plat in ("linux64", "win64", "darwin64"):
                entry = (f"resources/{pkg}/native/lib/{plat}/"
                         f"{kernels.library_name(kernel, plat)}")
                if entry in names:
                    out[(kernel, plat)] = zf.read(entry)
    return out


def test_kernels_in_the_fmus_are_built_from_the_current_sources(fmus, tmp_path):
    """Every kernel an FMU ships, for every platform this machine can build, embeds the digest
    of the C sources in this checkout, and the linux64 one is byte for byte what compiling them
    now gives (the build is deterministic) and reports that digest when loaded."""
    platforms = kernels.available_platforms()
    expect = {"FlexiblePendulum": {"flexpend_plant"},
              "PDLowPass": {"flexpend_filter"}}
    for name, fmu in fmus.items():
        shipped = _shipped(fmu)
        assert {(k, p) for k in expect[name] for p in platforms} == set(shipped), name
        for (kernel, plat), data in shipped.items():
            digest = kernels.source_digest(kernel, kernels.native_dir(kernel))
            assert digest.encode() in data, (name, kernel, plat)
            if plat.startswith("win"):
                assert data[:2] == b"MZ"               # a PE image (a DLL)
            if plat != kernels.host_platform():
                continue
            fresh = kernels.build_kernel(kernel, plat, tmp_path / f"{kernel}_{plat}")
            assert fresh.read_bytes() == data, (name, kernel, plat)
            copy = tmp_path / f"{name}_{kernels.library_name(kernel, plat)}"
            copy.write_bytes(data)
            lib = ctypes.CDLL(str(copy))
            getter = getattr(lib, kernels.KERNELS[kernel][4])
            getter.restype = ctypes.c_char_p
            assert getter().decode() == digest


@pytest.mark.skipif("win64" not in kernels.available_platforms(),
                    reason="the mingw-w64 cross-compiler (x86_64-w64-mingw32-gcc) is not installed")
def test_win64_kernels_export_the_interface(fmus, tmp_path):
    """The win64 DLLs export every function of the headers (read from the PE export table)."""
    objdump = kernels.find_compiler("win64").replace("-gcc", "-objdump")
    headers = {"flexpend_plant": "fp_plant.h", "flexpend_filter": "fp_filter.h"}
    shipped = {k: v for fmu in fmus.values() for k, v in _shipped(fmu).items()}
    assert {k for k, p in shipped if p == "win64"} == set(headers)
    for (kernel, plat), data in shipped.items():
        if plat != "win64":
            continue
        dll = tmp_path / kernels.library_name(kernel, plat)
        dll.write_bytes(data)
        table = subprocess.run([objdump, "-p", str(dll)], capture_output=True, text=True).stdout
        header = (kernels.native_dir(kernel) / headers[kernel]).read_text()
        declared = set(re.findall(r"^FPF?_API [^(;]*?(\w+)\(", header, re.M))
        assert len(declared) >= 7 and all(f in table for f in declared), (kernel, declared)


def _package_copy(root: Path) -> Path:
    native = root / "plant_fmu" / "native"
    native.mkdir(parents=True)
    for f in kernels.source_files("flexpend_plant", kernels.native_dir("flexpend_plant")):
        (native / f.name).write_bytes(f.read_bytes())
    return native


def test_a_stale_kernel_is_rebuilt_in_its_checkout_and_loaded_as_shipped_elsewhere(
        tmp_path, monkeypatch):
    """Outside a checkout (a package without the kernel build beside it, as in an unpacked FMU)
    a missing kernel is an error and a present one is loaded as shipped, without hashing the
    sources. In a checkout, a library whose sources changed is rebuilt when loaded, by the
    checkout's own kernel build only."""
    native = _package_copy(tmp_path / "fmu")
    with pytest.raises(kernels.KernelError, match=r"is missing.*reinstall"):
        kernels._load("flexpend_plant", native)
    kernels.build_kernel("flexpend_plant", out=kernels.library_path(
        "flexpend_plant", native=native), native=native)
    with open(native / "fp_plant.c", "a") as f:
        f.write("/* an edit */\n")
    assert kernels._load("flexpend_plant", native) is not None

    root = tmp_path / "checkout"
    native = _package_copy(root)
    lib = kernels.library_path("flexpend_plant", native=native)
    kernels.build_kernel("flexpend_plant", out=lib, native=native)
    with open(native / "fp_plant.c", "a") as f:
        f.write("/* an edit */\n")
    (root / kernels.CHECKOUT_MARK).parent.mkdir(parents=True)
    (root / kernels.CHECKOUT_MARK).write_text("")
    assert kernels.in_checkout(native)
    with pytest.raises(kernels.KernelError, match="out of date"):   # another checkout's build
        kernels._load("flexpend_plant", native)
    monkeypatch.setattr(kernels, "ROOT", root)
    assert kernels._load("flexpend_plant", native) is not None
    assert kernels.embedded_digest(lib, kernels.source_digest("flexpend_plant", native))


def test_install_without_a_compiler_names_it(tmp_path):
    """``pip install`` runs this lookup first: without a compiler it stops with one line that
    names what it looked for."""
    with pytest.raises(kernels.CompilerNotFound) as exc:
        kernels.find_compiler(env={"PATH": str(tmp_path)})
    assert "no C compiler found (looked for $CC, cc, gcc, clang)" in str(exc.value)
    assert "\n" not in str(exc.value)
    with pytest.raises(kernels.CompilerNotFound, match="CC=/nonexistent/cc was not found"):
        kernels.find_compiler(env={"PATH": str(tmp_path), "CC": "/nonexistent/cc"})
