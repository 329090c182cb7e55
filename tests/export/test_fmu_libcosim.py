"""An independent importer: libcosim (the Open Simulation Platform's engine, through libcosimpy)
loads both FMUs and runs the closed loop with its fixed-step algorithm; an fmpy-driven loop doing
the same exchange (outputs of step k feed the inputs of step k + 1, both FMUs step together)
agrees to 1e-9.

libcosim runs in a fresh, isolated interpreter (``python -I``, another working directory): the
FMUs must then bring everything they import, as in a user's tool. It also keeps libcosim out of
the test process: with libcosim and fmpy both holding pythonfmu FMUs, a process occasionally
aborts at exit ("corrupted double-linked list"), which neither does alone.
"""
import subprocess
import sys

import numpy as np
import pytest

import libcosimpy  # noqa: E402,F401  (a declared test dependency: fail, do not skip)

H = 1e-3
STEPS = 500
PLANT_START = {"phi0": 0.3, "x_dot0": 0.2}
PLANT_OUT = ["x_o", "x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1", "energy"]
SENSORS = ["x_o", "phi_o", "omega_o"]

LIBCOSIM_RUN = """
import sys
import numpy as np
from libcosimpy.CosimEnums import CosimExecutionState
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

plant_fmu, ctrl_fmu, out, steps, step_ns = sys.argv[1:6]
PLANT_START, PLANT_OUT, SENSORS = {start!r}, {outputs!r}, {sensors!r}
log_output_level(CosimLogLevel.WARNING)
ex = CosimExecution.from_step_size(step_size=int(step_ns))
slaves = [CosimLocalSlave(fmu_path=plant_fmu, instance_name="plant"),
          CosimLocalSlave(fmu_path=ctrl_fmu, instance_name="controller")]
plant, ctrl = (ex.add_local_slave(s) for s in slaves)
pv = {{v.name.decode(): v.reference for v in ex.slave_variables(plant)}}
cv = {{v.name.decode(): v.reference for v in ex.slave_variables(ctrl)}}
for name in SENSORS:                                        # wired by name
    ex.connect_real_variables(plant, pv[name], ctrl, cv[name])
ex.connect_real_variables(ctrl, cv["F_c"], plant, pv["F_c"])
for name, value in PLANT_START.items():
    assert ex.real_initial_value(plant, pv[name], value)
obs = CosimObserver.create_last_value()
ex.add_observer(obs)
rows = []
for _ in range(int(steps)):
    assert ex.step()
    rows.append(obs.last_real_values(plant, [pv[n] for n in PLANT_OUT])
                + obs.last_real_values(ctrl, [cv["F_c"]]))
assert CosimExecutionState(ex.status().state) != CosimExecutionState.ERROR
np.save(out, np.array(rows))
"""


def run_libcosim(fmus, tmp_path):
    out = tmp_path / "libcosim.npy"
    code = LIBCOSIM_RUN.format(start=PLANT_START, outputs=PLANT_OUT, sensors=SENSORS)
    proc = subprocess.run([sys.executable, "-I", "-c", code, fmus["FlexiblePendulum"],
                           fmus["PDLowPass"], str(out), str(STEPS), str(round(H * 1e9))],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return np.load(out)


def run_fmpy(open_fmu):
    plant = open_fmu("FlexiblePendulum", **PLANT_START)
    ctrl = open_fmu("PDLowPass")
    rows = []
    for k in range(STEPS):
        y = plant.get(*SENSORS)
        ctrl.set(**dict(zip(SENSORS, y)))
        plant.set(F_c=ctrl.get("F_c")[0])
        assert plant.step(k * H, H) == 0 and ctrl.step(k * H, H) == 0
        rows.append(plant.get(*PLANT_OUT) + ctrl.get("F_c"))
    return np.array(rows)


def test_libcosim_agrees_with_an_fmpy_jacobi_loop(fmus, open_fmu, tmp_path):
    cosim = run_libcosim(fmus, tmp_path)
    ref = run_fmpy(open_fmu)
    assert cosim.shape == ref.shape == (STEPS, len(PLANT_OUT) + 1)
    assert np.all(np.isfinite(cosim))
    assert np.max(np.abs(cosim - ref)) <= 1e-9
    assert np.ptp(ref[:, 2]) > 0.1 and abs(ref[-1, 2]) < 0.05      # a real, stabilised motion
