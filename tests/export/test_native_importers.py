"""The native FMUs in importers: fmpy's FMI 2.0 and 3.0 masters (the FMI 3.0 pair against the
FMI 2.0 pair, input derivatives, the adaptive master's rollback), a C host with no Python under
``env -i``, the FMUs and that host under the sanitizers, win64 under wine, and libcosim.

Independent values: the fmpy master (a second importer) against the C host and libcosim.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

HOST_C = Path(__file__).parents[1] / "native" / "fmi2_host.c"
linux_gcc = pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                               reason="needs Linux and gcc")


def pair(paths):
    return {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"]}


# ---------------------------------------------------------------------- importers
def _master(paths, *, algorithm="jacobi", extrapolation=0, step=1e-3, stop=2.0, start=None,
            input_derivatives=False, plant="FlexiblePendulum"):
    from orchestration.cosim.master import Master
    from orchestration.cosim.slave import Slave
    from orchestration.scene.wiring import parse_connection
    from orchestration.scene.records import DEFAULT_CONNECTIONS
    slaves = {"plant": Slave(paths[plant], "plant", start or {"phi0": 0.3}),
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
    for name in ("FlexiblePendulum", "PDLowPass"):        # the pair (not the other families)
        path = paths[name]
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
                           "`python -m pytest tests/export/test_native_importers.py -k wine` after "
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
extra = dict(a.split("=") for a in sys.argv[6:])     # more start values of the plant
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
for name, value in extra.items():
    assert (ex.integer_initial_value(plant, pv[name], int(value)) if name == "n_elements"
            else ex.string_initial_value(plant, pv[name], value))
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
    inputs, to 1e-12; in an isolated interpreter (python -I) as a user's tool would run it. Not
    bit for bit: libcosim's clock counts nanoseconds (its step is the difference of two points
    ``ns / 1e9``, an ulp off 1e-3 at some steps), the master's ``k h``; on libcosim's clock the
    loop agrees to the bit (:func:`test_libcosim_runs_every_plant_family`)."""
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


def _jacobi_on_libcosims_clock(native, plant, start, steps, step_ns):
    """The Jacobi loop libcosim runs (outputs of step k feed the inputs of step k + 1), driven
    through fmpy with libcosim's time arithmetic: integer nanoseconds, the communication point
    ``ns / 1e9`` and the step the difference of two such points (which differs from 1e-3 by an
    ulp at some steps: the controller's step then rounds differently)."""
    from fmpy import extract

    from conftest import NativeFmu
    sensors = ["x_o", "phi_o", "omega_o"]
    p = NativeFmu(extract(native[plant]), 2, cs=True, phi0=0.3, **start)
    c = NativeFmu(extract(native["PDLowPass"]), 2, cs=True)
    rows = []
    try:
        p.initialize(event=False)
        c.initialize(event=False)
        for k in range(steps):
            t, t_next = (k * step_ns) / 1e9, ((k + 1) * step_ns) / 1e9
            c.set(**dict(zip(sensors, p.get(*sensors))))
            p.set(F_c=c.get("F_c")[0])
            assert p.step(t, t_next - t) == 0 and c.step(t, t_next - t) == 0
            rows.append(p.get(*sensors) + c.get("F_c"))
    finally:
        p.close()
        c.close()
    return np.array(rows)


@pytest.mark.parametrize("plant, start", [
    ("FlexiblePendulum", {}),
    ("FlexiblePendulumStiffened", {"fidelity": "stiffened"}),
    ("FlexiblePendulumExact", {"fidelity": "exact", "n_elements": 4}),
])
def test_libcosim_runs_every_plant_family(native, tmp_path, plant, start):
    """Issue 37, F2: libcosim reads every variable an FMU declares after each step, and aborted on
    the single plant FMU's exact rung (its Model-Exchange locals refused). Each rung family's own
    FMU declares only what it gives: libcosim runs it with the controller, bit for bit like the
    same Jacobi loop driven through fmpy on libcosim's clock."""
    import libcosimpy  # noqa: F401  (a declared test dependency)
    out = tmp_path / "libcosim.npy"
    steps, step_ns = 200, 1_000_000
    args = [f"{k}={v}" for k, v in start.items()]
    proc = subprocess.run([sys.executable, "-I", "-c", LIBCOSIM_RUN, native[plant],
                           native["PDLowPass"], str(out), str(steps), str(step_ns), *args],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = np.load(out)
    assert np.array_equal(rows, _jacobi_on_libcosims_clock(native, plant, start, steps, step_ns))
    assert np.ptp(rows[:, 1]) > 1e-3
