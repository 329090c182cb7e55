"""A plant that diverges tells a simple master to stop: after the refused doStep it reports
``fmi2Terminated`` (FMI 2.0) or ``terminateSimulation`` (FMI 3.0), so that fmpy.simulate_fmu ends
with the samples up to the divergence instead of retrying the same step forever (it did, growing
without bound in memory). Each case runs in a child process with a time and memory limit.
(fmpy raises on an FMI 3.0 discard before it reads the flag, so the FMI 3.0 case reads it from the
raw fmi3DoStep.)"""
import subprocess
import sys

import pytest

SCRIPT = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
from fmpy import simulate_fmu
from fmpy.util import read_csv
inputs = read_csv(sys.argv[2])
inputs["F_c"] = 2000.0                    # topples the pendulum past phi_limit near 0.1 s
r = simulate_fmu(sys.argv[1], stop_time=1.0, step_size=1e-3, output_interval=1e-3,
                 input=inputs, output=["phi"])
print(r["time"][-1], abs(r["phi"][-1]))
"""


SCRIPT_FMI3 = """
import resource, sys
from ctypes import byref
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
from fmpy import extract, read_model_description
from fmpy.fmi3 import FMU3Slave, fmi3Boolean, fmi3Float64
md = read_model_description(sys.argv[1])
fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]),
                modelIdentifier=md.coSimulation.modelIdentifier)
fmu.instantiate()
vr = {v.name: v.valueReference for v in md.modelVariables}
fmu.enterInitializationMode()
fmu.exitInitializationMode()
flags = [fmi3Boolean(), fmi3Boolean(), fmi3Boolean()]
last = fmi3Float64()
for k in range(1000):
    fmu.setFloat64([vr["F_c"]], [2000.0])
    status = fmu._functions["fmi3DoStep"](fmu.component, k * 1e-3, 1e-3, False, byref(flags[0]),
                                         byref(flags[1]), byref(flags[2]), byref(last))
    if status != 0:
        break
phi = fmu.getFloat64([vr["phi"]])[0]
print(status, bool(flags[1].value), last.value, abs(phi))
"""


@pytest.fixture(scope="module")
def plants(fmus):
    from orchestration.export import build_fmus

    return {"python": fmus["FlexiblePendulum"],
            "native-fmi2": build_fmus(flavour="native", fmi_version=2)["FlexiblePendulum"],
            "native-fmi3": build_fmus(flavour="native", fmi_version=3)["FlexiblePendulum"]}


@pytest.mark.parametrize("flavour", ["python", "native-fmi2"])
def test_fmpy_simulate_stops_at_a_divergence(plants, flavour):
    from orchestration.export.check import reference_files

    files = reference_files("FlexiblePendulum")
    proc = subprocess.run([sys.executable, "-c", SCRIPT, str(plants[flavour]), str(files["in"])],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    t_end, phi_end = map(float, proc.stdout.splitlines()[-1].split())
    # the last sample is the last accepted state, just inside phi_limit = pi/2
    assert 0.05 < t_end < 0.2 and 1.4 < phi_end <= 1.5707963267948966


def test_fmi3_do_step_asks_to_terminate_at_a_divergence(plants):
    proc = subprocess.run([sys.executable, "-c", SCRIPT_FMI3, str(plants["native-fmi3"])],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    status, terminate, last, phi = proc.stdout.splitlines()[-1].split()
    assert status == "2" and terminate == "True"            # fmi3Discard, terminateSimulation
    assert 0.05 < float(last) < 0.2 and 1.4 < float(phi) <= 1.5707963267948966
