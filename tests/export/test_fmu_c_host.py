"""A host with no Python in it: ``tests/c_host/fmi2_host.c``, a minimal FMI 2.0 co-simulation
master in C compiled here, loads both FMUs' linux64 binaries with ``dlopen(RTLD_LOCAL)``, with no
``LD_PRELOAD``, no ``PYTHONPATH`` and ``PATH`` reduced to the system directories.

* The FMU's loader finds the interpreter recorded at build time (this test session's), loads its
  libpython and runs the closed loop; the outputs equal those of the fmpy master
  (``orchestration.cosim.master``) on the same scene to 1e-12 (they are in fact bit-identical: the
  same Python code and the same sequence of calls).
* Pointed (``FLEXPEND_PYTHON``) at a Python without numpy (a virtual environment made with
  ``--without-pip``), ``fmi2Instantiate`` returns NULL and logs why, with a category, and the host
  exits cleanly.
* The exit status is 0: before the loader, the controller aborted the host at exit ("free():
  corrupted unsorted chunks", status 134) every time.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from orchestration.job import controller_start_values, plant_start_values, run_scene
from orchestration.scene.schema import load_scene

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux") or not shutil.which("gcc"),
                                reason="needs Linux and gcc")

HOST_C = Path(__file__).parents[1] / "c_host" / "fmi2_host.c"
SYSTEM_PATH = "/usr/local/bin:/usr/bin:/bin"
#: The coupling the C host implements: the master's Gauss-Seidel with the inputs held
#: (zero-order hold), controller first, 1 ms.
ZOH = ["master.algorithm=gauss-seidel", "master.first=controller", "master.extrapolation=0",
       "master.input_derivatives=false", "master.adaptive=false", "master.step=0.001"]


def zoh_scene(*overrides):
    """The filtered scene with the coupling of the C host."""
    return load_scene("flexible_pd_lowpass", [*ZOH, *overrides])


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    exe = tmp_path_factory.mktemp("c_host") / "fmi2_host"
    subprocess.run(["gcc", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe), str(HOST_C),
                    "-ldl"], check=True, capture_output=True)
    return exe


def system_env(**extra) -> dict:
    """A bare environment: system PATH only, nothing that points at a Python. The ``OPENBLAS_*``
    variables stay: they choose OpenBLAS's kernels (this machine sets ``OPENBLAS_CORETYPE``), and
    another kernel changes the last bit of the filter's discretisation (scipy's expm), which the
    closed loop then carries to about 1e-11 in 2 s."""
    env = {"PATH": SYSTEM_PATH, "HOME": os.environ.get("HOME", "/"), "LANG": "C.UTF-8"}
    env.update({k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")})
    env.update(extra)
    return env


def host_command(host, fmu_dirs, scene, steps, every, binary="{model}.so"):
    """The host's command line for ``scene`` (start values typed from the model descriptions)."""
    from fmpy import read_model_description

    parts, vrs = [], {}
    for role, name in (("plant", "FlexiblePendulum"), ("controller", "PDLowPass")):
        d = Path(fmu_dirs[name])
        md = read_model_description(str(d / "modelDescription.xml"))
        vrs[role] = {v.name: v for v in md.modelVariables}
        parts += [str(d / "binaries" / "linux64" / binary.format(model=name)),
                  (d / "resources").as_uri(), md.guid]
    p, c = vrs["plant"], vrs["controller"]
    sensors = ("x_o", "phi_o", "omega_o")
    cmd = [str(host), repr(scene.config["master.step"]), str(steps), str(every), *parts,
           *(str(p[n].valueReference) for n in sensors), str(p["F_c"].valueReference),
           *(str(c[n].valueReference) for n in sensors), str(c["F_c"].valueReference)]
    for role, start in (("p", plant_start_values(scene)), ("c", controller_start_values(scene))):
        variables = p if role == "p" else c
        for name, value in start.items():
            v = variables[name]
            text = repr(float(value)) if v.type == "Real" else (
                str(int(value)) if v.type in ("Integer", "Boolean") else str(value))
            cmd.append(f"{role}:{v.type[0]}:{v.valueReference}={text}")
    return cmd


def run_host(cmd, **env):
    return subprocess.run(cmd, env=system_env(**env), capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_closed_loop_in_a_c_host_matches_the_fmpy_master(host, fmus, fmu_dirs):
    scene = zoh_scene("stop_time=2.0", "output_interval=0.01")
    ref = run_scene(scene, {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]},
                    progress=False).result
    every = round(scene.config["output_interval"] / scene.config["master.step"])
    steps = every * (len(ref) - 1)
    proc = run_host(host_command(host, fmu_dirs, scene, steps, every))
    assert proc.returncode == 0, proc.stderr[-3000:]      # no abort at exit (was 134)
    got = np.array([[float(x) for x in line.split()] for line in proc.stdout.splitlines()])
    assert got.shape == (len(ref), 5)
    np.testing.assert_array_equal(got[:, 0], ref["time"])
    for j, col in enumerate(("x", "phi_o", "omega_o", "F_c"), start=1):
        assert np.max(np.abs(got[:, j] - ref[col])) <= 1e-12, col
    assert abs(ref["phi_o"]).max() > 0.1                   # a real run, not a resting pendulum


def test_the_c_host_exits_cleanly_every_time(host, fmu_dirs):
    scene = zoh_scene()
    for _ in range(3):
        proc = run_host(host_command(host, fmu_dirs, scene, 20, 10))
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert len(proc.stdout.splitlines()) == 3


def test_a_python_without_numpy_gives_null_and_the_reason(host, fmu_dirs, tmp_path):
    venv = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   capture_output=True)
    bare = venv / "bin" / "python3"
    scene = zoh_scene()
    proc = run_host(host_command(host, fmu_dirs, scene, 10, 10), FLEXPEND_PYTHON=str(bare))
    assert proc.returncode == 5, proc.stderr[-3000:]     # NULL, then a clean exit
    assert "fmi2Instantiate returned NULL" in proc.stderr
    assert "(NULL category)" not in proc.stderr
    log = [line for line in proc.stderr.splitlines() if line.startswith("log [3] plant")]
    assert log and "logStatusError" in log[0]
    assert f"{bare} (named by FLEXPEND_PYTHON" in proc.stderr
    assert "numpy cannot be imported" in proc.stderr
    assert "FLEXPEND_PYTHON=/path/to/python3" in proc.stderr


def test_pythonfmus_own_library_alone_does_not_load(host, fmu_dirs):
    """Why the loader exists: pythonfmu's library (shipped beside it) needs libpython in the
    process, which a dlopen(RTLD_LOCAL) host does not have."""
    scene = zoh_scene()
    proc = run_host(host_command(host, fmu_dirs, scene, 10, 10, binary="{model}_pythonfmu.so"))
    assert proc.returncode == 4
    assert "undefined symbol: _Py_NoneStruct" in proc.stderr


def test_threads_in_a_c_host_each_with_an_instance(fmu_dirs, tmp_path):
    """8 host threads at once, 30 rounds (240 threads, each ending after its run): every thread
    gets the main thread's output bit for bit, and the thread states the loader gave the ended
    threads are deleted (RSS grows by less than 2 MiB over the rounds)."""
    from fmpy import read_model_description

    exe = tmp_path / "fmi2_threads"
    subprocess.run(["gcc", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
                    str(HOST_C.parent / "fmi2_threads.c"), "-ldl", "-lpthread"], check=True,
                   capture_output=True)
    d = Path(fmu_dirs["PDLowPass"])
    md = read_model_description(str(d / "modelDescription.xml"))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    proc = subprocess.run([str(exe), str(d / "binaries" / "linux64" / "PDLowPass.so"),
                           (d / "resources").as_uri(), md.guid, "30", str(vr["phi_o"]),
                           str(vr["F_c"])], env=system_env(), capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.split("\n")
    assert float(lines[0]) != 0.0
    before, after = (int(line.split()[1]) for line in lines[1:3])
    assert after - before < 2048, (before, after)
