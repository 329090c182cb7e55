"""Both C kernels built with the project's warning flags plus AddressSanitizer and
UndefinedBehaviorSanitizer, and driven through every entry point by tests/native/kernel_check.c
(on the invariants of real beams: n_modes 0, 1, 4 and 8, each nonlinear and linear, with and
without the preload). Any memory error, leak or undefined behaviour aborts the run; the driver's
own checks have known answers (see its header)."""
import shutil
import subprocess

import numpy as np
import pytest

from fmu_common import kernels
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _plant_data(path):
    """The invariants of real beams, in the driver's format (n first, then the data)."""
    rows = []
    for n in (0, 1, 4, 8):
        m = plant_model(PlantParams(n_modes=n, gravity_preload=True))
        data = [m.I0, m.I1, m.I2, m.g, *m.I3, *m.I5, *m.Kdiag, *m.Ddiag, *m.tip_slope,
                *m.tip_defl, *np.ravel(m.beam.Kg if n else [])]
        rows.append(f"{n} " + " ".join(repr(float(v)) for v in data))
    path.write_text("\n".join(rows) + "\n")


def test_kernels_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    plant = kernels.native_dir("flexpend_plant")
    filt = kernels.native_dir("flexpend_filter")
    driver = kernels.ROOT / "tests" / "native" / "kernel_check.c"
    exe = tmp_path / "kernel_check"
    cmd = ["gcc", *kernels.CFLAGS, "-O1", "-g", "-fno-omit-frame-pointer",
           "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
           f"-I{plant}", f"-I{filt}", "-o", str(exe), str(driver), str(plant / "fp_plant.c"),
           str(filt / "fp_filter.c"), "-lm"]
    cmd.remove("-fvisibility=hidden")
    build = subprocess.run(cmd, capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    data = tmp_path / "plant.txt"
    _plant_data(data)
    run = subprocess.run([str(exe), str(data)], capture_output=True, text=True, timeout=300,
                         env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0",
                              "UBSAN_OPTIONS": "print_stacktrace=1"})
    assert run.returncode == 0, run.stdout + run.stderr
    assert "runtime error" not in run.stderr and "Sanitizer" not in run.stderr, run.stderr
    assert run.stdout.startswith("ok ") and ", 0 failed" in run.stdout, run.stdout
    assert int(run.stdout.split()[1]) > 250            # every check ran
    print(run.stdout)
