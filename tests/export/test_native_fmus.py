"""The native FMUs (C, FMI 2.0 and 3.0; orchestration/export/native_fmus.py): validity, what the
binaries need and export, the same outputs as the pythonfmu FMUs, every failure path, the FMU
state, the importers (fmpy's FMI 2.0 and 3.0 masters, a C host with no Python under ``env -i``,
libcosim), the sanitizers and win64 under wine.

Independent values: the pythonfmu FMUs (the same kernel under a Python stepper: the native
plant's stepper is a port, checked here bit for bit), the fmpy master (a second importer), and
the values of the states themselves (a restored state must continue bit-identically).
"""
from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import FmuInstance, opened_by

HOST_C = Path(__file__).parents[1] / "native" / "fmi2_host.c"
linux_gcc = pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                               reason="needs Linux and gcc")


@pytest.fixture(scope="session")
def native3() -> dict:
    from orchestration.export import build_fmus
    return {n: str(p) for n, p in build_fmus(flavour="native", fmi_version=3).items()}


@pytest.fixture
def open_native(native_dirs):
    yield from opened_by(lambda name, initialize=True, **start:
                         FmuInstance(native_dirs[name], start, name, initialize))


def pair(paths):
    return {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"]}


# ---------------------------------------------------------------------- the files
@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_fmpy_validate_finds_no_problem(native, native3, name, version):
    from fmpy.validation import validate_fmu
    path = (native if version == 2 else native3)[name]
    assert validate_fmu(path) == []


@linux_gcc
@pytest.mark.parametrize("version", [2, 3])
def test_linux_binaries_need_only_libc_and_libm(native, native3, tmp_path, version):
    paths = native if version == 2 else native3
    folder = "linux64" if version == 2 else "x86_64-linux"
    for name, path in paths.items():
        with zipfile.ZipFile(path) as zf:
            so = tmp_path / f"{name}.so"
            so.write_bytes(zf.read(f"binaries/{folder}/{name}.so"))
        out = subprocess.run(["readelf", "-d", str(so)], capture_output=True, text=True,
                             check=True).stdout
        needed = sorted(line.split("[")[1].rstrip("]") for line in out.splitlines()
                        if "(NEEDED)" in line)
        assert needed == ["libc.so.6", "libm.so.6"], (name, needed)
        syms = subprocess.run(["nm", "-D", "--defined-only", str(so)], capture_output=True,
                              text=True, check=True).stdout.split()
        exported = {s for s in syms if s.startswith(("fmi2", "fmi3", "fp_", "fpf_", "fpm_"))}
        assert exported == set(_fmi_functions(version)), name


def _fmi_functions(version: int) -> list[str]:
    """Every function the standard's header declares (fmpy's copy)."""
    from orchestration.export.native_fmus import fmi_include_dir
    import re
    text = (fmi_include_dir() / f"fmi{version}Functions.h").read_text()
    return sorted(set(re.findall(rf"FMI{version}_Export\s+fmi{version}\w+TYPE\s+(fmi{version}\w+)",
                                 text)))


@pytest.mark.parametrize("version", [2, 3])
def test_win64_binaries_export_every_fmi_function(native, native3, tmp_path, version):
    objdump = shutil.which("x86_64-w64-mingw32-objdump")
    paths = native if version == 2 else native3
    folder = "win64" if version == 2 else "x86_64-windows"
    with zipfile.ZipFile(paths["PDLowPass"]) as zf:
        if f"binaries/{folder}/PDLowPass.dll" not in zf.namelist():
            pytest.skip("built without the mingw-w64 cross-compiler")
    if objdump is None:
        pytest.skip("no x86_64-w64-mingw32-objdump")
    for name, path in paths.items():
        dll = tmp_path / f"{name}.dll"
        with zipfile.ZipFile(path) as zf:
            dll.write_bytes(zf.read(f"binaries/{folder}/{name}.dll"))
        out = subprocess.run([objdump, "-p", str(dll)], capture_output=True, text=True,
                             check=True).stdout
        table = out.split("[Ordinal/Name Pointer] Table")[1]
        exported = {line.split()[-1] for line in table.splitlines() if line.strip()
                    and line.split()[-1].startswith(("fmi", "fp"))}
        assert exported == set(_fmi_functions(version)), name
        dlls = {line.split()[-1].lower() for line in out.splitlines() if "DLL Name" in line}
        assert dlls <= {"kernel32.dll", "msvcrt.dll", "api-ms-win-crt-runtime-l1-1-0.dll",
                        "api-ms-win-crt-math-l1-1-0.dll", "api-ms-win-crt-stdio-l1-1-0.dll",
                        "api-ms-win-crt-heap-l1-1-0.dll", "api-ms-win-crt-string-l1-1-0.dll",
                        "api-ms-win-crt-private-l1-1-0.dll", "api-ms-win-crt-convert-l1-1-0.dll",
                        "api-ms-win-crt-environment-l1-1-0.dll",
                        "api-ms-win-crt-time-l1-1-0.dll"}, dlls


def test_variables_are_the_tables_less_the_derivative_inputs(native, native3):
    """One table writes both flavours' descriptions: the same names, value references, units and
    start values, without the input-derivative variables (fmi2SetRealInputDerivatives); FMI
    3.0's ``time`` at its reference in the table."""
    from fmpy import read_model_description

    from fmu_common.variables import independent_variable, native_variables
    from orchestration.export.model_description import TABLES, xml_value
    for name, path in native.items():
        _, table = TABLES[name]
        md2 = read_model_description(path)
        md3 = read_model_description(native3[name])
        expected = [(vr, v.name) for vr, v in native_variables(table)]
        assert [(v.valueReference, v.name) for v in md2.modelVariables] == expected
        assert [(v.valueReference, v.name) for v in md3.modelVariables
                if v.name != "time"] == expected
        assert [v.valueReference for v in md3.modelVariables if v.name == "time"] == \
            [independent_variable(table)[0]]
        assert md2.coSimulation.canInterpolateInputs
        for v, (_, t) in zip(md2.modelVariables, native_variables(table)):
            assert v.unit == (t.unit if t.type == "Real" else None)
            if t.start is not None:
                assert str(v.start).lower() == xml_value(t.start, native=True).lower() or \
                    float(v.start) == float(t.start)


def test_no_limit_is_the_largest_double_and_means_no_limit(native, native3, open_native):
    """Issue 23, 6: "no limit" is written as the largest double (the FMI 2.0 VDM checker's static
    distribution stops on INF), and inf is still accepted when set."""
    from fmpy import read_model_description

    from orchestration.export.model_description import NO_LIMIT
    for paths in (native, native3):
        md = read_model_description(paths["PDLowPass"])
        assert {v.name: v.start for v in md.modelVariables}["force_limit"] == NO_LIMIT
    assert float(NO_LIMIT) == sys.float_info.max
    a = open_native("PDLowPass", phi_o=0.3)                          # the start value
    b = open_native("PDLowPass", phi_o=0.3, force_limit=math.inf)
    for k in range(20):
        assert a.step(k * 1e-3, 1e-3) == 0 and b.step(k * 1e-3, 1e-3) == 0
    assert a.get("F_c") == b.get("F_c")


def test_the_build_says_what_it_built_and_what_it_skipped(tmp_path, monkeypatch, capsys):
    """Issue 23, 6: one line per platform built, one line naming the missing cross-compiler."""
    from fmu_common import kernels
    from orchestration.export import native_fmus
    monkeypatch.setitem(kernels.CROSS_COMPILERS, "win64", "no-such-x86_64-w64-mingw32-gcc")
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, force=True)
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("PDLowPass (FMI 2): built linux64 (binaries/linux64/PDLowPass.so)")
    assert err[1].startswith("PDLowPass (FMI 2): win64 skipped: the C cross-compiler "
                             "no-such-x86_64-w64-mingw32-gcc for win64 was not found")
    assert len(err) == 2
    with zipfile.ZipFile(tmp_path / "fmi2" / "PDLowPass.fmu") as zf:
        assert not any("win64" in n for n in zf.namelist())
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path)        # up to date: nothing said
    assert capsys.readouterr().err == ""


mingw = pytest.mark.skipif(shutil.which("x86_64-w64-mingw32-gcc") is None,
                           reason="needs the mingw-w64 cross-compiler")


def _zip(path) -> dict:
    with zipfile.ZipFile(path) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


@mingw
def test_a_run_builds_the_hosts_binary_and_a_build_adds_the_missing_ones(tmp_path, capsys):
    """Issue 25: the first run builds only what it runs (the host's binary); ``flexpend build``
    (every platform) then counts the FMU stale for what it misses, compiles that alone and keeps
    the host's binary; an FMU with both is up to date for a run and for a build."""
    from orchestration.export import native_fmus

    path = native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=["linux64"])
    assert capsys.readouterr().err.strip().splitlines() == [
        f"PDLowPass (FMI 2): built linux64 (binaries/linux64/PDLowPass.so) with "
        f"{shutil.which('cc') or shutil.which('gcc')}"]
    first = _zip(path)
    assert sorted(n for n in first if n.startswith("binaries/")) == [
        "binaries/linux64/PDLowPass.so"]
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=["linux64"])
    assert capsys.readouterr().err == ""                            # up to date for a run
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path)          # a build: every platform
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("PDLowPass (FMI 2): built win64 ")
    both = _zip(path)
    assert "binaries/win64/PDLowPass.dll" in both
    assert both["binaries/linux64/PDLowPass.so"] == first["binaries/linux64/PDLowPass.so"]
    guid = [re.search(rb'guid="([^"]+)"', z["modelDescription.xml"]).group(1)
            for z in (first, both)]
    assert guid[0] == guid[1]                                       # the same build, one GUID
    for platforms in (None, ["linux64"], ["win64"]):
        native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=platforms)
        assert capsys.readouterr().err == ""


@mingw
def test_an_fmu_missing_a_binary_its_stamp_names_is_stale_for_it(tmp_path, capsys):
    """Staleness counts the binaries an FMU holds, not those its stamp names."""
    from orchestration.export import native_fmus

    path = native_fmus.build_native_fmu("PDLowPass", 2, tmp_path)
    entries = _zip(path)
    del entries["binaries/win64/PDLowPass.dll"]                     # the stamp still names it
    with zipfile.ZipFile(path, "w") as zf:
        for n, data in entries.items():
            zf.writestr(n, data)
    capsys.readouterr()
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=["linux64"])
    assert capsys.readouterr().err == ""                            # a run has what it needs
    native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=["linux64", "win64"])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("PDLowPass (FMI 2): built win64 ")
    assert "binaries/win64/PDLowPass.dll" in _zip(path)


@mingw
def test_a_failed_compilation_leaves_the_fmu_as_it_was_and_no_partial_file(tmp_path,
                                                                          monkeypatch):
    from orchestration.export import BuildError, build_fmus, native_fmus

    path = native_fmus.build_native_fmu("PDLowPass", 2, tmp_path, platforms=["linux64"])
    before = path.read_bytes()
    real = native_fmus.compile_command

    def broken(name, fmi_version, platform, *args, **kwargs):
        cmd = real(name, fmi_version, platform, *args, **kwargs)
        return cmd + ["-fno-such-option"] if platform == "win64" else cmd
    monkeypatch.setattr(native_fmus, "compile_command", broken)
    with pytest.raises(BuildError, match="compiling PDLowPass .FMI 2. for win64 failed"):
        build_fmus(tmp_path, ["PDLowPass"], flavour="native")
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == ["PDLowPass.fmu"]


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: one compiler at a time")
def test_the_binaries_are_compiled_at_once(tmp_path, monkeypatch):
    """Issue 25: the two FMUs' compilers run together (each waits at a barrier for the other:
    compiled one after the other, the first would wait in vain), not one after the other."""
    import threading

    from orchestration.export import native_fmus

    barrier = threading.Barrier(2, timeout=120)
    real = subprocess.run

    def run(cmd, *args, **kwargs):
        barrier.wait()
        return real(cmd, *args, **kwargs)
    monkeypatch.setattr(native_fmus.subprocess, "run", run)
    paths = native_fmus.build_native_fmus(tmp_path, platforms=["linux64"])
    assert sorted(paths) == ["FlexiblePendulum", "PDLowPass"]
    assert all(p.is_file() for p in paths.values())


def test_a_run_asks_for_the_hosts_binaries_and_an_export_for_every_platform(monkeypatch):
    import orchestration.export as export
    from fmu_common.kernels import host_platform

    asked = []
    monkeypatch.setattr(export, "build_fmus", lambda **kw: asked.append(kw) or {
        "FlexiblePendulum": "p", "PDLowPass": "c"})
    export.flavour_fmus("native")
    export.flavour_fmus("native", portable=True)
    export.flavour_fmus("python")
    assert asked == [{"flavour": "native", "platforms": [host_platform()]},
                     {"flavour": "native", "platforms": None},
                     {"flavour": "python", "platforms": None}]


VDM_ARTIFACT = "org.into-cps.vdmcheck.fmi2:vdmcheck2:1.1.3:zip:distribution-{}"


@pytest.fixture(scope="session")
def vdmcheck(tmp_path_factory) -> dict:
    """The FMI 2.0 VDM checker 1.1.3, both distributions, from Maven Central (into a temporary
    folder: nothing is cached in the repository)."""
    if shutil.which("mvn") is None or shutil.which("java") is None:
        pytest.skip("needs maven and java (.ci/run installs them)")
    root = tmp_path_factory.mktemp("vdmcheck")
    out = {}
    for dist in ("static", "rules"):
        proc = subprocess.run(["mvn", "-q", "-B", "dependency:copy",
                               f"-Dartifact={VDM_ARTIFACT.format(dist)}",
                               f"-DoutputDirectory={root}"], capture_output=True, text=True,
                              timeout=600)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        with zipfile.ZipFile(root / f"vdmcheck2-1.1.3-distribution-{dist}.zip") as zf:
            zf.extractall(root / dist)
        (script,) = (root / dist).glob("*/VDMCheck2.sh")
        script.chmod(0o755)                  # the script finds its folder with `which $0`
        out[dist] = script
    return out


@pytest.mark.slow
@pytest.mark.parametrize("dist", ["static", "rules"])
@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_the_fmi2_vdm_checker_finds_no_error(native, vdmcheck, name, dist):
    """Issue 23, 6: both distributions of the VDM checker accept every native FMI 2.0 FMU
    (the static one stopped on PDLowPass's start="INF"; the checker has no FMI 3.0 version:
    fmpy validate checks those, above)."""
    proc = subprocess.run(["bash", str(vdmcheck[dist]), native[name]], capture_output=True,
                          text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert "No errors found." in out, out[-3000:]
    assert not any(line.startswith("Error") for line in out.splitlines()), out[-3000:]


# ---------------------------------------------------------------------- same as pythonfmu
SCENES = [
    ("rigid_pd", ["stop_time=2"]),
    ("flexible_pd", ["stop_time=1"]),
    ("flexible_pd_lowpass", ["stop_time=2"]),
    ("flexible_pd_lowpass", ["stop_time=1", "plant.integrator='euler'", "plant.step=5e-6"]),
    ("flexible_pd_lowpass", ["stop_time=1", "plant.integrator='symplectic_euler'",
                             "plant.step=5e-5"]),
    ("flexible_pd_lowpass", ["stop_time=2", "plant.integrator='dopri5'"]),
    ("flexible_pd_lowpass", ["stop_time=2", "plant.fidelity='linear'",
                             "plant.integrator='exponential'", "plant.step=5e-4"]),
    ("flexible_pd_lowpass", ["stop_time=1.5", "master.algorithm='jacobi'",
                             "master.extrapolation=1", "master.step=1.5e-3",
                             "output_interval=3e-3"]),
]


def assert_same(a, b, rel_exponential=False):
    """Native and pythonfmu outputs within 1e-10. The exponential integrator's matrices are
    computed by scipy (pythonfmu) and by the C kernel (native): there the bound is 1e-10
    relative to the signal's size (F_c reaches 457 N)."""
    for c in a.dtype.names:
        scale = max(1.0, float(np.max(np.abs(b[c])))) if rel_exponential else 1.0
        assert np.max(np.abs(a[c] - b[c])) <= 1e-10 * scale, c


@pytest.mark.slow
@pytest.mark.parametrize("scene, sets", SCENES, ids=[f"{s}-{'-'.join(x)}" for s, x in SCENES])
def test_native_and_pythonfmu_give_the_same_outputs(native, fmus, scene, sets):
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    sc = load_scene(scene, sets)
    a = run_scene(sc, pair(native), progress=False)
    b = run_scene(sc, pair(fmus), progress=False)
    assert a.summary["stopped"] is None and b.summary["stopped"] is None
    assert len(a.result) == len(b.result) == round(sc.output.stop_time / sc.output.output_interval) + 1
    assert_same(a.result, b.result, rel_exponential="plant.integrator='exponential'" in sets)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_native_and_pythonfmu_agree_at_random_parameters(native, fmus, seed):
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    rng = np.random.default_rng(seed)
    f = lambda: float(np.exp(rng.uniform(-0.5, 0.5)))  # noqa: E731
    ne = int(rng.integers(8, 40))
    sets = [f"plant.n_modes={int(rng.integers(0, 9))}", f"plant.n_elements={ne}",
            f"plant.m={f()}", f"plant.L={f()}", f"plant.EI={875 * f()}", f"plant.rho={7.8e3 * f()}",
            f"plant.g={9.81 * f()}", f"plant.zeta={0.001 * f()}",
            f"plant.gravity_preload={'true' if seed % 2 else 'false'}",
            f"plant.damping='{'modal' if seed == 1 else 'kelvin-voigt'}'",
            f"controller.cutoff={97.3 * f()}", f"initial.phi={0.3 * f()}", "stop_time=0.5",
            f"plant.fidelity='{'linear' if seed == 2 else 'nonlinear'}'"]
    sc = load_scene("flexible_pd_lowpass", sets)
    a = run_scene(sc, pair(native), progress=False)
    b = run_scene(sc, pair(fmus), progress=False)
    assert a.summary["stopped"] == b.summary["stopped"]
    assert_same(a.result, b.result)


# ---------------------------------------------------------------------- failure paths
def test_bad_parameter_is_an_error_at_exit_initialization(open_native):
    from fmpy.fmi1 import FMICallException
    for start, word in (({"n_modes": 9}, "n_modes"), ({"EI": -1.0}, "EI"),
                        ({"integrator": "radau"}, "supported: dopri5, euler, exponential, rk4"),
                        ({"n_elements": 101}, "n_elements"),
                        ({"integrator": "exponential"}, "fidelity = 'linear'"),
                        ({"damping": "viscous"}, "bad parameter: damping = 'viscous' is not "
                                                 "allowed; allowed: modal, kelvin-voigt"),
                        ({"damping": "Kelvin-Voigt"}, "damping = 'Kelvin-Voigt' is not")):
        inst = open_native("FlexiblePendulum", initialize=False, **start)
        inst.fmu.enterInitializationMode()
        with pytest.raises(FMICallException) as exc:
            inst.fmu.exitInitializationMode()
        assert exc.value.status == 3
        assert word in inst.messages(3)
        assert inst.step(0.0, 1e-3) == 3              # the instance is in its error state
    ctrl = open_native("PDLowPass", initialize=False, filter_damping=0.0)
    ctrl.fmu.enterInitializationMode()
    with pytest.raises(FMICallException):
        ctrl.fmu.exitInitializationMode()
    assert "filter_damping = 0 is out of range" in ctrl.messages(3)


def test_nan_input_is_discarded_with_the_state_unchanged(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.2)
    inst.set(F_c=1.0)
    assert inst.step(0.0, 1e-3) == 0
    before = inst.outputs()
    inst.set(F_c=math.nan)
    assert inst.step(1e-3, 1e-3) == 2
    assert "non-finite input F_c" in inst.messages(2)
    assert inst.outputs() == before
    inst.set(F_c=1.0)
    assert inst.step(1e-3, 1e-3) == 0                   # a retry may follow
    ctrl = open_native("PDLowPass")
    ctrl.set(phi_o=math.inf)
    assert ctrl.step(0.0, 1e-3) == 2 and "phi_o = inf" in ctrl.messages(2)


def test_bad_step_size_is_discarded(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.2)
    for h in (-1e-3, 0.0, math.nan, math.inf):
        assert inst.step(0.0, h) == 2
    assert "must be positive and finite" in inst.messages(2)
    assert inst.step(0.0, 1e-3) == 0


def test_divergence_is_discarded_and_refuses_until_a_state_is_restored(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.3, phi_limit=0.31)
    state = inst.fmu.getFMUstate()
    codes = [inst.step(k * 1e-3, 1e-3) for k in range(200)]
    k = codes.index(2)
    assert all(c == 0 for c in codes[:k])
    assert "|phi| =" in inst.messages(2) and "phi_limit = 0.31" in inst.messages(2)
    assert all(math.isfinite(v) for v in inst.outputs())
    assert abs(inst.get("phi")[0]) <= 0.31                # the last accepted state
    assert inst.step(k * 1e-3, 1e-3) == 2                 # refused
    assert "restore a saved FMU state" in inst.messages(2)
    inst.fmu.setFMUstate(state)
    assert inst.step(0.0, 1e-3) == 0


def test_blow_up_is_discarded(open_native):
    """Explicit Euler on the stiff modes at a large substep blows up: Discard, never NaN."""
    inst = open_native("FlexiblePendulum", integrator="euler", step=2e-3, n_modes=8,
                       phi_limit=math.inf, energy_limit=math.inf, phi0=0.1)
    codes = [inst.step(k * 2e-3, 2e-3) for k in range(2000)]
    assert 2 in codes
    assert "non-finite state" in inst.messages(2) or "exceeds 1e100" in inst.messages(2)
    assert all(math.isfinite(v) for v in inst.outputs())


def test_invalid_value_reference_and_calls_out_of_order_are_errors(open_native):
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", initialize=False)
    assert inst.step(0.0, 1e-3) == 3                      # doStep before initialisation
    assert "fmi2DoStep is not allowed in state Instantiated" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.getReal([1])                             # dF_c: not in the native FMU
    assert "no variable with value reference 1" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.getReal([999])
    with pytest.raises(FMICallException):
        inst.fmu.getInteger([inst.vr("phi0")[0]])          # a Real read as Integer
    inst.initialize()
    with pytest.raises(FMICallException):
        inst.set(n_modes=2)                               # a fixed parameter after init
    assert "parameter n_modes is fixed" in inst.messages(3)
    with pytest.raises(FMICallException):
        inst.fmu.setReal(inst.vr("phi_o"), [1.0])         # an output
    with pytest.raises(FMICallException):
        inst.fmu.exitInitializationMode()                 # twice
    assert inst.step(0.5, 1e-3) == 3                      # not the FMU's time
    assert "but the FMU is at t = 0" in inst.messages(3)


def test_substep_cap_discards_the_step_and_says_so(open_native):
    from orchestration.export.native_fmus import MAX_SUBSTEPS
    inst = open_native("FlexiblePendulum", phi0=0.2, step=1e-9)
    before = inst.outputs()
    assert inst.step(0.0, 2.0) == 2                       # 2e9 substeps
    msg = inst.messages(2)
    assert f"more than the cap of {MAX_SUBSTEPS} per doStep" in msg and "2000000000" in msg
    assert inst.outputs() == before
    assert inst.step(0.0, 1e-4) == 0                      # 1e5 substeps: within the cap


def test_corrupt_serialised_state_is_an_error(open_native):
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", phi0=0.2)
    data = bytearray(inst.fmu.serializeFMUstate(inst.fmu.getFMUstate()))
    for where in (0, 5, 100, len(data) // 2, len(data) - 1):
        bad = bytearray(data)
        bad[where] ^= 0x40
        with pytest.raises(FMICallException):
            inst.fmu.deSerializeFMUstate(bytes(bad))
    with pytest.raises(FMICallException):
        inst.fmu.deSerializeFMUstate(bytes(data[:-8]))
    log = inst.messages(3)
    assert "corrupt" in log and "format version" in log and "bytes" in log
    other = open_native("PDLowPass")
    with pytest.raises(FMICallException):
        other.fmu.deSerializeFMUstate(bytes(data))
    assert "belongs to another model" in other.messages(3)


def test_every_non_ok_status_comes_with_a_message(open_native):
    inst = open_native("FlexiblePendulum", phi0=0.3, phi_limit=0.31)
    inst.set(F_c=math.nan)
    inst.step(0.0, 1e-3)
    inst.set(F_c=0.0)
    for k in range(200):
        if inst.step(k * 1e-3, 1e-3):
            break
    statuses = [s for s, _, _ in inst.logs]
    assert 2 in statuses and all(m for s, _, m in inst.logs if s > 0)
    assert all(cat for _, cat, _ in inst.logs)            # never a NULL category


# ---------------------------------------------------------------------- FMU state
@pytest.mark.parametrize("integrator", ["rk4", "dopri5", "symplectic_euler"])
def test_state_get_set_and_serialisation_are_bit_identical(open_native, integrator):
    def run(inst, k0, n):
        out = []
        for k in range(k0, k0 + n):
            inst.set(F_c=10 * math.sin(0.05 * k))
            inst.fmu.setRealInputDerivatives(inst.vr("F_c"), [1], [0.5 * math.cos(0.05 * k)])
            assert inst.step(k * 1e-3, 1e-3) == 0
            out.append(inst.outputs())
        return out

    a = open_native("FlexiblePendulum", phi0=0.4, integrator=integrator)
    run(a, 0, 50)
    state = a.fmu.getFMUstate()
    data = a.fmu.serializeFMUstate(state)
    first = run(a, 50, 50)
    a.fmu.setFMUstate(state)
    assert run(a, 50, 50) == first
    b = open_native("FlexiblePendulum")                    # another instance, other parameters
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    assert run(b, 50, 50) == first
    a.fmu.freeFMUstate(state)


def test_a_state_carries_the_damping_law(open_native):
    """The damping law is a parameter of the state: one saved under the Kelvin-Voigt law and
    restored into an instance opened with the modal law continues as the Kelvin-Voigt run to
    the last bit, and the modal run is another."""
    def run(inst, k0, n):
        out = []
        for k in range(k0, k0 + n):
            inst.set(F_c=10 * math.sin(0.05 * k))
            assert inst.step(k * 1e-3, 1e-3) == 0
            out.append(inst.outputs())
        return np.array(out)

    start = dict(phi0=0.4, zeta=0.02, n_modes=4)
    a = open_native("FlexiblePendulum", damping="kelvin-voigt", **start)
    run(a, 0, 50)
    state = a.fmu.getFMUstate()
    data = a.fmu.serializeFMUstate(state)
    first = run(a, 50, 50)
    b = open_native("FlexiblePendulum", **start)
    modal = run(b, 0, 100)[50:]
    b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    assert np.array_equal(run(b, 50, 50), first)
    assert np.max(np.abs(modal - first)) > 1e-6
    a.fmu.freeFMUstate(state)


# ---------------------------------------------------------------------- importers
def _master(paths, *, algorithm="jacobi", extrapolation=0, step=1e-3, stop=2.0, start=None,
            input_derivatives=False):
    from orchestration.cosim.master import Master
    from orchestration.cosim.slave import Slave
    from orchestration.scene.wiring import parse_connection
    from orchestration.scene.records import DEFAULT_CONNECTIONS
    slaves = {"plant": Slave(paths["FlexiblePendulum"], "plant", start or {"phi0": 0.3}),
              "controller": Slave(paths["PDLowPass"], "controller")}
    rec = {"x_o": ("plant", "x_o"), "phi_o": ("plant", "phi_o"),
           "omega_o": ("plant", "omega_o"), "F_c": ("controller", "F_c")}
    m = Master(slaves, [parse_connection(c) for c in DEFAULT_CONNECTIONS], rec,
               algorithm=algorithm, first="controller", step=step, extrapolation=extrapolation,
               input_derivatives=input_derivatives)
    try:
        res, stats = m.run(0.0, stop, step)
    finally:
        m.close()
    return res


def test_fmi3_pair_agrees_with_the_fmi2_pair(native, native3):
    """fmpy's FMI 3.0 master on the FMI 3.0 pair against the FMI 2.0 pair (held inputs: FMI 3.0
    offers no input derivatives, docs/fmus.md), Gauss-Seidel with quadratic extrapolation."""
    kw = dict(algorithm="gauss-seidel", extrapolation=2, step=2e-3, stop=2.0)
    a = _master(native, **kw)
    b = _master(native3, **kw)
    for c in a.dtype.names:
        assert np.max(np.abs(a[c] - b[c])) <= 1e-12
    assert np.ptp(a["phi_o"]) > 0.3


def test_input_derivatives_go_through_fmi2SetRealInputDerivatives(native, fmus):
    """The master gives the native FMUs their input derivatives by fmi2SetRealInputDerivatives
    and the pythonfmu FMUs by variables: the same third-order coupling, the same numbers."""
    kw = dict(algorithm="gauss-seidel", extrapolation=2, step=2e-3, stop=1.0,
              input_derivatives=True)
    a = _master(native, **kw)
    b = _master(fmus, **kw)
    held = _master(native, **{**kw, "input_derivatives": False})
    for c in a.dtype.names:
        assert np.max(np.abs(a[c] - b[c])) <= 1e-12
    assert np.max(np.abs(a["phi_o"] - held["phi_o"])) > 1e-8     # they are used


def test_adaptive_master_rolls_back_the_native_fmus(native, fmus):
    from orchestration.job import run_scene
    from orchestration.scene.schema import load_scene
    from orchestration.studies.reference import simulate_reference
    sc = load_scene("flexible_pd_lowpass", ["stop_time=1", "master.adaptive=true",
                                            "master.step=2e-2"])
    a = run_scene(sc, pair(native), progress=False)
    b = run_scene(sc, pair(fmus), progress=False)
    assert a.stats.rejected > 0 and b.stats.rejected > 0
    ref = simulate_reference(sc)
    err_a = np.max(np.abs(a.result["phi_o"] - ref["phi_o"]))
    err_b = np.max(np.abs(b.result["phi_o"] - ref["phi_o"]))
    # the steps the two flavours choose differ only where an off-grid plant substep rounds
    # differently (numpy's step against the C kernel's), far inside the tolerance
    assert err_a <= 2 * err_b + 1e-6 and err_a < 1e-3


def _host(tmp_path, cc="gcc", flags=(), suffix=""):
    from orchestration.export.native_fmus import fmi_include_dir
    exe = tmp_path / f"fmi2_host{suffix}"
    cmd = [cc, "-O1", "-std=gnu11", "-Wall", "-Werror", *flags, f"-I{fmi_include_dir()}",
           "-o", str(exe), str(HOST_C)]
    if not cc.startswith("x86_64-w64"):
        cmd.append("-ldl")
    subprocess.run(cmd, check=True, capture_output=True)
    return exe


def _host_args(paths, unpacked, plat, suffix, steps=2000, h=1e-3, phi0=0.3):
    from fmpy import read_model_description
    args = []
    vrs = {}
    for name, path in paths.items():
        d = unpacked / name
        with zipfile.ZipFile(path) as zf:
            zf.extractall(d)
        md = read_model_description(str(d / "modelDescription.xml"))
        vrs[name] = {v.name: v.valueReference for v in md.modelVariables}
        args += [str(d / "binaries" / plat / f"{name}{suffix}"), md.guid]
    args = args[:2] + args[2:4] + [str(steps), repr(h)]
    args += [str(vrs["FlexiblePendulum"][n]) for n in ("F_c", "x_o", "phi_o", "omega_o")]
    args += [str(vrs["PDLowPass"][n]) for n in ("x_o", "phi_o", "omega_o", "F_c")]
    args.append(f"{vrs['FlexiblePendulum']['phi0']}={phi0!r}")
    return args


def _parse(out):
    rows = np.array([[float(x) for x in line.split()] for line in out.splitlines()])
    return rows


@linux_gcc
def test_c_host_without_python_matches_the_fmpy_master(native, tmp_path):
    """A C host (dlopen RTLD_LOCAL) under ``env -i``: no PATH, no PYTHONHOME, no Python in the
    process; 2 s of closed loop, against the fmpy master's Jacobi run to 1e-12."""
    exe = _host(tmp_path)
    args = _host_args(native, tmp_path / "unpacked", "linux64", ".so")
    proc = subprocess.run(["env", "-i", str(exe), *args], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = _parse(proc.stdout)
    ref = _master(native, stop=2.0)
    assert rows.shape == (2000, 5)
    for j, c in enumerate(("time", "x_o", "phi_o", "omega_o", "F_c")):
        assert np.max(np.abs(rows[:, j] - ref[c][1:])) <= 1e-12, c
    assert np.ptp(rows[:, 2]) > 0.3 and abs(rows[-1, 2]) < 0.05


@linux_gcc
@pytest.mark.slow
def test_fmus_and_host_under_the_sanitizers(tmp_path):
    """The native FMUs compiled with -fsanitize=address,undefined (and -Wall -Wextra -Werror),
    driven by the C host through the closed loop and through the FMU's failure paths in the
    fmpy tests' shape (a NaN input, a bad step): no report, the same numbers."""
    from fmu_common import kernels
    from orchestration.export import native_fmus
    san = ["-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-fno-sanitize-recover=all"]
    exe = _host(tmp_path, flags=san)
    paths = {}
    for name in native_fmus.MODELS:
        gen = tmp_path / f"gen_{name}"
        gen.mkdir()
        from fmpy import read_model_description
        from orchestration.export import build_fmus
        built = build_fmus(flavour="native")[name]
        guid = read_model_description(str(built)).guid
        (gen / "fpm_vars.h").write_text(native_fmus.generate_header(name, guid))
        lib = tmp_path / f"{name}.so"
        cmd = native_fmus.compile_command(name, 2, "linux64", lib, gen,
                                          kernels.find_compiler(), extra=san)
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        paths[name] = (lib, guid)
    from orchestration.export import build_fmus
    built = build_fmus(flavour="native")
    args = _host_args(built, tmp_path / "unpacked", "linux64", ".so", steps=500)
    args[0], args[2] = str(paths["FlexiblePendulum"][0]), str(paths["PDLowPass"][0])
    env = {"ASAN_OPTIONS": "detect_leaks=1", "UBSAN_OPTIONS": "print_stacktrace=1"}
    proc = subprocess.run(["env", "-i", *(f"{k}={v}" for k, v in env.items()), str(exe), *args],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr
    plain = subprocess.run([str(_host(tmp_path, suffix="_plain")),
                            *_host_args(built, tmp_path / "u2", "linux64", ".so", steps=500)],
                           capture_output=True, text=True, timeout=300)
    assert _parse(proc.stdout).tolist() == _parse(plain.stdout).tolist()


@pytest.mark.skipif(shutil.which("wine64") is None and shutil.which("wine") is None,
                    reason="needs wine (Debian's wine64): the separate command "
                           "`python -m pytest tests/export/test_native_fmus.py -k wine` after "
                           "apt-get install wine64")
def test_win64_host_under_wine_agrees_with_linux64(native, tmp_path):
    if shutil.which("x86_64-w64-mingw32-gcc") is None:
        pytest.skip("no mingw-w64 cross-compiler")
    exe = _host(tmp_path, cc="x86_64-w64-mingw32-gcc", flags=["-static"], suffix=".exe")
    args = _host_args(native, tmp_path / "unpacked", "win64", ".dll", steps=2000)
    wine = shutil.which("wine64") or shutil.which("wine")
    env = {**os.environ, "WINEDEBUG": "-all", "WINEPREFIX": str(tmp_path / "wineprefix")}
    proc = subprocess.run([wine, str(exe), *args], capture_output=True, text=True, timeout=900,
                          env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = _parse(proc.stdout.replace("\r", ""))
    ref = _master(native, stop=2.0)
    assert rows.shape == (2000, 5)
    for j, c in enumerate(("time", "x_o", "phi_o", "omega_o", "F_c")):
        assert np.max(np.abs(rows[:, j] - ref[c][1:])) <= 1e-12, c


LIBCOSIM_RUN = """
import sys
import numpy as np
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

plant_fmu, ctrl_fmu, out, steps, step_ns = sys.argv[1:6]
log_output_level(CosimLogLevel.WARNING)
ex = CosimExecution.from_step_size(step_size=int(step_ns))
plant = ex.add_local_slave(CosimLocalSlave(fmu_path=plant_fmu, instance_name="plant"))
ctrl = ex.add_local_slave(CosimLocalSlave(fmu_path=ctrl_fmu, instance_name="controller"))
pv = {v.name.decode(): v.reference for v in ex.slave_variables(plant)}
cv = {v.name.decode(): v.reference for v in ex.slave_variables(ctrl)}
for name in ("x_o", "phi_o", "omega_o"):
    ex.connect_real_variables(plant, pv[name], ctrl, cv[name])
ex.connect_real_variables(ctrl, cv["F_c"], plant, pv["F_c"])
assert ex.real_initial_value(plant, pv["phi0"], 0.3)
obs = CosimObserver.create_last_value()
ex.add_observer(obs)
rows = []
for _ in range(int(steps)):
    assert ex.step()
    rows.append(obs.last_real_values(plant, [pv[n] for n in ("x_o", "phi_o", "omega_o")])
                + obs.last_real_values(ctrl, [cv["F_c"]]))
np.save(out, np.array(rows))
"""


@pytest.mark.slow
def test_libcosim_runs_the_native_pair_like_the_fmpy_master(native, tmp_path):
    """libcosim (Jacobi, its fixed-step algorithm) against the fmpy master's Jacobi run with held
    inputs, to 1e-12; in an isolated interpreter (python -I) as a user's tool would run it."""
    import libcosimpy  # noqa: F401  (a declared test dependency)
    out = tmp_path / "libcosim.npy"
    proc = subprocess.run([sys.executable, "-I", "-c", LIBCOSIM_RUN, native["FlexiblePendulum"],
                           native["PDLowPass"], str(out), "1000", str(1_000_000)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = np.load(out)
    ref = _master(native, stop=1.0)
    for j, c in enumerate(("x_o", "phi_o", "omega_o", "F_c")):
        assert np.max(np.abs(rows[:, j] - ref[c][1:])) <= 1e-12, c


# ---------------------------------------------------------------------- issue 23: the core
def _fnv(data: bytes) -> int:
    h = 14695981039346656037
    for b in data:
        h = ((h ^ b) * 1099511628211) & 0xFFFFFFFFFFFFFFFF
    return h


def _refix(blob: bytearray) -> bytes:
    """Recompute a state's trailer, as anyone can (an FNV-1a, no key)."""
    import struct
    blob[-8:] = struct.pack("<Q", _fnv(bytes(blob[:-8])))
    return bytes(blob)


def _state_offsets(name: str) -> dict:
    sys.path.insert(0, str(Path(__file__).parents[1] / "fuzz"))
    from make_corpus import layout
    return layout(name, {})


@pytest.mark.parametrize("name, item, kind, value, words", [
    ("FlexiblePendulum", "n_modes", "d", 4194304.0, "n_modes = 4194304 is out of range"),
    ("FlexiblePendulum", "n_elements", "d", 2.5, "n_elements = 2.5 is not an Integer value"),
    ("FlexiblePendulum", "initialized", "i", 0, "not initialised in a state that needs"),
    ("FlexiblePendulum", "k", "d", 2.0 ** 63, "is not a substep count"),
    ("FlexiblePendulum", "y", "d", math.nan, "the state y = nan is not finite"),
    ("FlexiblePendulum", "mode", "i", 0x7FFFFFFF, "the mode 2147483647 is not a state"),
    ("FlexiblePendulum", "phi_limit", "d", -1.0, "phi_limit = -1 is out of range"),
    ("PDLowPass", "filter_order", "d", 1048576.0, "filter_order = 1048576 is out of range"),
    ("PDLowPass", "xc0", "d", math.inf, "xc[0] = inf is not finite"),
    ("PDLowPass", "F", "d", -math.inf, "F_c = -inf is not finite"),
    ("PDLowPass", "force_limit", "d", 0.0, "force_limit = 0 is out of range"),
], ids=lambda x: x if isinstance(x, str) and " " not in x else None)
def test_23_1_a_crafted_state_with_its_checksum_recomputed_is_refused(open_native, name, item,
                                                                      kind, value, words):
    """Issue 23, 1: a state edited field by field with the trailer recomputed passes the
    checksum and is refused by the checks of the values, naming the item; the instance is
    unchanged (the old layer accepted next = 1048576 or nx = 4194304 and crashed at doStep)."""
    import struct
    from fmpy.fmi1 import FMICallException
    start = {"phi0": 0.3} if name == "FlexiblePendulum" else {"phi_o": 0.1}
    out = "phi_o" if name == "FlexiblePendulum" else "F_c"
    inst = open_native(name, **start)
    assert inst.step(0.0, 1e-3) == 0
    state = inst.fmu.getFMUstate()
    blob = bytearray(inst.fmu.serializeFMUstate(state))
    at = _state_offsets(name)[item]
    blob[at:at + (8 if kind == "d" else 4)] = struct.pack("<d" if kind == "d" else "<i", value)
    with pytest.raises(FMICallException) as exc:
        inst.fmu.deSerializeFMUstate(_refix(blob))
    assert exc.value.status == 3
    log = inst.messages(3)
    assert "corrupt" not in log and words in log and "the instance is unchanged" in log
    assert inst.step(1e-3, 1e-3) == 0
    twin = open_native(name, **start)
    assert twin.step(0.0, 1e-3) == 0 and twin.step(1e-3, 1e-3) == 0
    assert inst.get(out) == twin.get(out)
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_23_1_every_double_of_a_state_crafted_restores_to_a_legal_state_or_is_refused(
        open_native, name):
    """Each 8 bytes of the payload overwritten with a hostile double (checksum recomputed):
    the restore is refused, or what it restores steps with finite outputs or refuses the step
    with a message."""
    import struct
    from fmpy.fmi1 import FMICallException
    inst = open_native(name, **({"phi0": 0.3} if name == "FlexiblePendulum" else {"phi_o": 0.1}))
    assert inst.step(0.0, 1e-3) == 0
    state = inst.fmu.getFMUstate()
    good = bytes(inst.fmu.serializeFMUstate(state))
    outputs = [v for v in inst.vars.values() if v.causality == "output"]
    restored = 0
    for at in range(24, len(good) - 8 - 7):
        for value in (math.nan, 1e300, -1.0, 2.0 ** 62):
            blob = bytearray(good)
            blob[at:at + 8] = struct.pack("<d", value)
            try:
                back = inst.fmu.deSerializeFMUstate(_refix(blob))
            except FMICallException as exc:
                assert exc.status == 3 and inst.logs[-1][2]
                continue
            restored += 1
            inst.fmu.setFMUstate(back)
            inst.fmu.freeFMUstate(back)
            t = inst.fmu.getRealStatus(2)                    # fmi2LastSuccessfulTime
            status = inst.step(t, 1e-3)
            assert status == 0 or inst.logs[-1][0] == status
            for v in outputs:
                try:
                    assert math.isfinite(inst.fmu.getReal([v.valueReference])[0])
                except FMICallException as exc:
                    assert exc.status == 3
            inst.fmu.setFMUstate(state)
    assert restored > 0                                      # inputs may be anything
    inst.fmu.freeFMUstate(state)


@pytest.mark.parametrize("start, h", [({}, 1e19), ({}, 1e300), ({"step": 1e-300}, 1e-3),
                                      ({"step": 5e-324}, 1e-3)])
def test_23_2_a_step_too_long_for_the_cap_is_refused_not_skipped(open_native, start, h):
    """Issue 23, 2: the substep count is computed in floating point and checked before any
    conversion: a step of 1e19 or 1e300 (2^63 substeps or more), or a plant step of 1e-300 or
    5e-324 (which hung the second doStep), is discarded with the count, the state unchanged."""
    inst = open_native("FlexiblePendulum", phi0=0.2, **start)
    before = inst.outputs()
    for _ in range(2):
        assert inst.step(0.0, h) == 2
        assert "more than the cap of" in inst.messages(2)
        assert inst.outputs() == before
    assert inst.fmu.getRealStatus(2) == 0.0                  # the time did not move


def test_23_2_a_step_below_the_time_resolution_is_refused(open_native):
    inst = open_native("PDLowPass", phi_o=0.1)
    assert inst.step(0.0, 1.0) == 0
    assert inst.step(1.0, 1e-20) == 2                        # 1 + 1e-20 == 1
    assert "below the resolution of the time" in inst.messages(2)
    assert inst.step(1.0, 1e-3) == 0


@pytest.mark.parametrize("phi_dot0", [1e160, 1.7976931348623157e308])
def test_23_3_an_initial_state_with_non_finite_outputs_is_a_bad_parameter(open_native,
                                                                         phi_dot0):
    """Issue 23, 3: exitInitializationMode refused (it returned OK and energy read inf or NaN
    with status OK); no output is ever read non-finite with OK."""
    from fmpy.fmi1 import FMICallException
    inst = open_native("FlexiblePendulum", initialize=False, phi_dot0=phi_dot0)
    assert inst.initialize() == 3
    assert "the initial state" in inst.messages(3) and "too large" in inst.messages(3)
    for v in [v for v in inst.vars.values() if v.causality == "output"]:
        with pytest.raises(FMICallException):
            inst.fmu.getReal([v.valueReference])


@pytest.mark.parametrize("param, value", [("L", 1e-200), ("rho", 5e-324), ("EI", 1e16)])
def test_23_3_a_parameter_outside_the_range_of_finite_invariants_is_named(open_native, param,
                                                                          value):
    """The positive parameters lie in [1e-15, 1e15] as in plant_fmu/params.py: a subnormal one
    gave a float division by zero (UBSan) in the modal scaling."""
    inst = open_native("FlexiblePendulum", initialize=False, **{param: value})
    assert inst.initialize() == 3
    assert f"bad parameter: {param} = " in inst.messages(3)


FMI3_NULL = r"""
import sys
from fmpy import read_model_description, extract
from fmpy.fmi3 import FMU3Slave
from fmpy.fmi1 import FMICallException
path = sys.argv[1]
md = read_model_description(path)
d = extract(path)
messages = []
fmu = FMU3Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier)
fmu.instantiate(loggingOn=True, logMessage=lambda *a: messages.append(a))
fmu.enterInitializationMode()
fmu.exitInitializationMode()
for fn in (fmu.fmi3GetFloat64, fmu.fmi3SetFloat64, fmu.fmi3GetInt32, fmu.fmi3GetFloat32):
    try:
        fn(fmu.component, None, 2, None, 2)
        print("OK", fn.__name__)
    except FMICallException as exc:
        print("status", exc.status)
print("messages", len(messages))
fmu.terminate()
fmu.freeInstance()
"""


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_23_4_null_arrays_with_a_count_are_an_error_in_fmi3(native3, name):
    """Issue 23, 4: fmi3GetFloat64(inst, NULL, 2, NULL, 2) was SIGSEGV (in a child process)."""
    proc = subprocess.run([sys.executable, "-c", FMI3_NULL, native3[name]], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.split("\n")
    assert lines[:4] == ["status 3"] * 4
    assert "messages 4" in proc.stdout
