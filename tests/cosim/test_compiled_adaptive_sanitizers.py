"""The master's compiled adaptive and implicit loops (orchestration/cosim/native/fm_adaptive.c)
under AddressSanitizer and UndefinedBehaviorSanitizer, as test_compiled_sanitizers.py does for the
fixed-step loop: the library rebuilt with ``-fsanitize=address,undefined`` and the whole of
``tests/cosim/test_compiled_adaptive.py`` (paper scenes, couplings, both estimators, rollback,
injected failures, implicit Newton and IQN-ILS, stop) run against it in a child Python that
preloads the sanitizers' runtimes; any report fails the test.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fmu_common import kernels
from orchestration.cosim import compiled_adaptive
from test_compiled_sanitizers import HERE, RUNTIMES, SANITIZE

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux") or not all(RUNTIMES),
                                 reason="needs Linux and gcc's libasan and libubsan")]

#: a pytest plugin for the child: the compiled adaptive loop loads the sanitized library
PLUGIN = '''
from pathlib import Path
from types import SimpleNamespace

from orchestration.cosim import compiled_adaptive
from fmu_common import kernels

_NATIVE = Path({native!r})
compiled_adaptive._lib = None
compiled_adaptive.kernels = SimpleNamespace(
    load=lambda kernel, native: kernels.load(kernel, _NATIVE), native_dir=kernels.native_dir,
    KernelError=kernels.KernelError)


def pytest_sessionfinish(session, exitstatus):
    lib = compiled_adaptive.load()
    assert Path(lib._name).resolve().parent.parent.parent == _NATIVE.resolve(), lib._name
    print("SANITIZED LIBRARY:", lib._name)
'''


def test_the_compiled_adaptive_tests_pass_under_the_sanitizers(tmp_path):
    native = tmp_path / "root" / "orchestration" / "native"
    native.mkdir(parents=True)
    for f in kernels.source_files(compiled_adaptive.KERNEL):
        shutil.copy(f, native / f.name)
    out = kernels.library_path(compiled_adaptive.KERNEL, None, native)
    out.parent.mkdir(parents=True)
    cmd = kernels.compile_command(compiled_adaptive.KERNEL, kernels.host_platform(), out,
                                  native, "gcc")
    cmd[1:1] = SANITIZE
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=native)
    (tmp_path / "sanitized_adaptive.py").write_text(PLUGIN.format(native=str(native)))
    env = dict(os.environ, LD_PRELOAD=":".join(RUNTIMES),
               ASAN_OPTIONS="detect_leaks=0:halt_on_error=1:abort_on_error=0",
               UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1",
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(HERE.parent),
                                           str(Path(__file__).parent)]))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "sanitized_adaptive",
                           "-p", "no:cacheprovider", "-s", "-n", "0",
                           str(Path(__file__).parent / "test_compiled_adaptive.py")],
                          env=env, capture_output=True, text=True, timeout=1200, cwd=tmp_path)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-4000:]
    for report in ("ERROR: AddressSanitizer", "runtime error:", "SUMMARY: "):
        assert report not in text, text[-4000:]
    assert f"SANITIZED LIBRARY: {out}" in text
    assert " passed" in text and " failed" not in text
