"""A JVM host: FMI4j 0.38.0 (``info.laht.fmi4j:fmi-import`` from Maven Central, JNI) runs the
closed loop of ``tests/c_host/fmi2_host.c`` (``tests/jvm_host/Loop.java``) on both FMUs in a bare
environment (no ``LD_PRELOAD``, no ``PYTHONPATH``, system ``PATH``), and matches the fmpy master to
1e-12; pointed at a Python without numpy, the FMU logs the reason through FMI4j's logger and the
JVM lives (before the loader, FMI4j aborted the JVM). The native FMUs run the same loop in it, to
the same 1e-12. The native plant as a Model-Exchange FMU in FMI4j (``tests/jvm_host/MeLoop.java``,
FMI4j's Model-Exchange instance with a Runge-Kutta loop: FMI4j 0.38.0 has no solver of its own)
matches the numpy specification. Skipped without ``java``, ``javac`` and ``mvn``, or when Maven
cannot fetch FMI4j.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from orchestration.export import fmu_pair
from orchestration.job import run_scene
from test_fmu_c_host import host_command, system_env, zoh_scene

HERE = Path(__file__).parents[1] / "jvm_host"
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not all(shutil.which(t) for t in ("java", "javac", "mvn"))
                                 or not sys.platform.startswith("linux"),
                                 reason="needs Linux, java, javac and mvn")]


@pytest.fixture(scope="module")
def jvm_host(tmp_path_factory):
    d = tmp_path_factory.mktemp("jvm")
    proc = subprocess.run(["mvn", "-q", "-B", "-f", str(HERE / "pom.xml"),
                           "dependency:copy-dependencies", f"-DoutputDirectory={d / 'lib'}"],
                          capture_output=True, text=True, timeout=900)
    if proc.returncode != 0:
        pytest.skip(f"Maven could not fetch FMI4j: {proc.stdout[-500:]}{proc.stderr[-500:]}")
    cp = os.pathsep.join(str(j) for j in sorted((d / "lib").glob("*.jar")))
    subprocess.run(["javac", "-cp", cp, "-d", str(d / "classes"), str(HERE / "Loop.java"),
                    str(HERE / "MeLoop.java")], check=True, capture_output=True)
    return ["java", "-cp", os.pathsep.join([str(d / "classes"), cp]), "Loop"]


def jvm_command(jvm_host, fmus, fmu_dirs, scene, steps, every):
    cmd = host_command("host", fmu_dirs, scene, steps, every)
    return [*jvm_host, *cmd[1:4], fmus["FlexiblePendulum"], fmus["PDLowPass"], *cmd[10:]]


def java_env(**extra):
    env = system_env(**extra)
    if os.environ.get("JAVA_HOME"):
        env["JAVA_HOME"] = os.environ["JAVA_HOME"]
    env["PATH"] = os.pathsep.join([str(Path(shutil.which("java")).parent), env["PATH"]])
    return env


def assert_fmi4j_matches_the_fmpy_master(jvm_host, fmus, fmu_dirs):
    """2 s of the closed loop in FMI4j against the fmpy master's run of the same FMUs, to 1e-12."""
    scene = zoh_scene("stop_time=2.0", "output_interval=0.01")
    ref = run_scene(scene, fmu_pair(fmus), progress=False).result
    every = round(scene.config["output_interval"] / scene.config["master.step"])
    proc = subprocess.run(jvm_command(jvm_host, fmus, fmu_dirs, scene, every * (len(ref) - 1),
                                      every),
                          env=java_env(), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    got = np.array([[float(x) for x in line.split()] for line in proc.stdout.splitlines()
                    if line[:1].isdigit()])
    assert got.shape == (len(ref), 5)
    assert np.ptp(got[:, 2]) > 0.1                   # the pendulum moved
    for j, col in enumerate(("x", "phi_o", "omega_o", "F_c"), start=1):
        assert np.max(np.abs(got[:, j] - ref[col])) <= 1e-12, col


def test_closed_loop_in_fmi4j_matches_the_fmpy_master(jvm_host, fmus, fmu_dirs):
    assert_fmi4j_matches_the_fmpy_master(jvm_host, fmus, fmu_dirs)


def test_fmi4j_gets_the_reason_when_numpy_is_missing(jvm_host, fmus, fmu_dirs, tmp_path):
    venv = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   capture_output=True)
    proc = subprocess.run(jvm_command(jvm_host, fmus, fmu_dirs, zoh_scene(), 10, 10),
                          env=java_env(FLEXPEND_PYTHON=str(venv / "bin" / "python3")),
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 5, proc.stdout[-2000:] + proc.stderr[-2000:]   # the JVM lived
    text = proc.stdout + proc.stderr
    assert "category = logStatusError" in text and "numpy cannot be imported" in text


def test_closed_loop_of_the_native_fmus_in_fmi4j_matches_the_fmpy_master(jvm_host, native,
                                                                          native_dirs):
    """The native FMUs (no Python anywhere) in FMI4j: the same closed loop as the fmpy master's,
    to 1e-12."""
    assert_fmi4j_matches_the_fmpy_master(jvm_host, native, native_dirs)


def test_fmi4j_integrates_the_native_plant_in_model_exchange(jvm_host, native):
    """Issue 24: FMI4j 0.38.0 imports the native FMI 2.0 plant as a Model-Exchange FMU (its
    modelDescription with both interfaces, its states, derivatives and nominals through JNI);
    classical Runge-Kutta at 0.1 ms over a free swing of 0.5 s from 0.1 rad, n_modes = 2, matches
    the numpy specification solved by scipy (DOP853, 1e-12) to 1e-9 rad (RK4's error at this step
    is ~1e-11; the stiffest mode, 165 rad/s, gives h|lambda| = 0.017)."""
    import math

    import scipy.integrate
    from fmpy import read_model_description

    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    md = read_model_description(native["FlexiblePendulum"])
    vr = {v.name: v.valueReference for v in md.modelVariables}
    cmd = [*jvm_host[:-1], "MeLoop", native["FlexiblePendulum"], "1e-4", "5000", "500",
           str(vr["phi"]), f"R:{vr['phi0']}=0.1", f"I:{vr['n_modes']}=2"]
    proc = subprocess.run(cmd, env=java_env(), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    rows = [line.split() for line in proc.stdout.splitlines()]
    got = np.array([[float(x) for x in r] for r in rows if r[0] != "nominals"])
    nominals = np.array([float(x) for x in rows[-1][1:]])
    assert got.shape == (11, 2 + 20)
    m = PlantModel(PlantParams(n_modes=2))
    x0 = np.zeros(m.nx)
    x0[1] = 0.1
    sol = scipy.integrate.solve_ivp(lambda t, y: m.rhs_numpy(t, y, 0.0), (0, 0.5), x0,
                                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=got[:, 0])
    assert np.max(np.abs(got[:, 1] - sol.y[1])) < 1e-9                   # phi, read
    assert np.max(np.abs(got[:, 3] - sol.y[1])) < 1e-9                   # the state phi
    assert np.all(got[:, 2 + 4:2 + 10] == 0.0)                           # eta_3..eta_8
    assert nominals[1] == 1.0 and nominals[0] == 1.0                     # phi: 1 rad; L = 1 m
    assert nominals[11] == pytest.approx(math.sqrt(9.81))                # phi_dot: sqrt(g/L)
