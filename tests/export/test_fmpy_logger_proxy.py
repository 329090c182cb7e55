"""The suite's guard against fmpy 0.3.32's logger proxy (tests/conftest.py): a test that hands
``simulate_fmu`` a logger of its own, then a later test in the same process whose FMI 2.0 FMU,
opened with fmpy's default callbacks, logs a message. Without the guard the second test jumps
into the first one's freed callback (a segfault, which under xdist took a whole worker down in
CI); with it, both pass."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_a_logger_handed_to_simulate_fmu_does_not_outlive_its_test():
    tests = ["tests/export/test_native_logging.py::test_fmpys_me_master_hears_the_state_event_once",
             "tests/export/test_me_state_restore.py::"
             "test_a_crafted_model_exchange_state_with_a_steps_input_is_refused"]
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
                          "-o", "addopts=", *tests], cwd=ROOT, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "3 passed" in run.stdout, run.stdout[-3000:]
