"""The native FMUs (C, FMI 2.0 and 3.0; orchestration/export/native_fmus.py) as files:
validity (fmpy validate, the FMI 2.0 VDM checker), what the binaries need and export, the build,
and the same outputs as the pythonfmu FMUs. Their failure paths and states are in
test_native_failures.py, the importers in test_native_importers.py.

Independent values: the pythonfmu FMUs (the same kernel under a Python stepper: the native
plant's stepper is a port, checked here bit for bit) and the validators, which are not ours.
"""
from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

linux_gcc = pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                               reason="needs Linux and gcc")


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
    from orchestration.export.model_description import CLOCKS, NATIVE, xml_value
    for name, path in native.items():
        _, table, offers = NATIVE[name]
        md2 = read_model_description(path)
        md3 = read_model_description(native3[name])
        expected = [(vr, v.name) for vr, v in native_variables(table, offers.model_exchange)]
        assert [(v.valueReference, v.name) for v in md2.modelVariables] == expected
        assert [(v.valueReference, v.name) for v in md3.modelVariables
                if v.name != "time" and v.type != "Clock"] == expected
        # FMI 3.0 only: the clocks, after every value reference (model_description.CLOCKS)
        assert [(v.valueReference, v.name) for v in md3.modelVariables if v.type == "Clock"] \
            == [(c.value_reference, c.name) for c in CLOCKS.get(name, ())]
        assert [v.valueReference for v in md3.modelVariables if v.name == "time"] == \
            [independent_variable(table)[0]]
        assert bool(md2.coSimulation.canInterpolateInputs) == offers.interpolates_inputs
        for v, (_, t) in zip(md2.modelVariables, native_variables(table, offers.model_exchange)):
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
    """Issue 25: the FMUs' compilers run together, two at a time (each waits at a barrier for
    another: compiled one after the other, the first would wait in vain)."""
    import threading

    from orchestration.export import native_fmus

    barrier = threading.Barrier(2, timeout=120)
    real = subprocess.run
    calls = iter(range(10 ** 6))
    lock = threading.Lock()

    def run(cmd, *args, **kwargs):
        with lock:
            k = next(calls)
        if k < 2:                       # the first two meet (an odd count of FMUs: the last
            barrier.wait()              # would wait alone)
        return real(cmd, *args, **kwargs)
    monkeypatch.setattr(native_fmus.subprocess, "run", run)
    paths = native_fmus.build_native_fmus(tmp_path, platforms=["linux64"])
    assert sorted(paths) == sorted(native_fmus.MODELS)
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
