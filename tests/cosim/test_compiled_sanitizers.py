"""The master's compiled loops under AddressSanitizer and UndefinedBehaviorSanitizer: the
co-simulation's (orchestration/cosim/native/fm_master.c) and the model-exchange master's
(fm_me.c). Each library is rebuilt with the project's flags plus
``-fsanitize=address,undefined`` and the whole of its tests (``tests/cosim/test_compiled.py``:
every coupling, traced FMI calls, every injected failure, divergence, stop, a million steps;
``tests/cosim/test_compiled_me.py``: the paper scenes, events, failures, stops) runs against it in
a child Python that preloads the sanitizers' runtimes. Any report aborts the child
(``-fno-sanitize-recover=all``, ``halt_on_error``): the test then fails with the report.
Independent value: the agreement with the Python loop that those tests assert, now with every
memory access of the C loop checked. Skipped without gcc's sanitizer runtimes (Linux only).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from orchestration.cosim import compiled as compiled_master
from orchestration.cosim import compiled_me
from fmu_common import kernels

HERE = Path(__file__).parents[1]
SANITIZE = ["-fsanitize=address,undefined", "-fno-omit-frame-pointer",
            "-fno-sanitize-recover=all"]


def _runtime(name: str) -> str | None:
    if not shutil.which("gcc"):
        return None
    path = subprocess.run(["gcc", f"-print-file-name={name}"], capture_output=True,
                          text=True).stdout.strip()
    return path if os.path.isabs(path) and os.path.exists(path) else None


RUNTIMES = [_runtime("libasan.so"), _runtime("libubsan.so")]
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux") or not all(RUNTIMES),
                                 reason="needs Linux and gcc's libasan and libubsan")]

#: a pytest plugin for the child: the compiled loop (the binding ``module``) loads the sanitized
#: library
PLUGIN = '''
from pathlib import Path
from types import SimpleNamespace

from orchestration.cosim import {module} as compiled_master
from fmu_common import kernels

_NATIVE = Path({native!r})
compiled_master._lib = None
compiled_master.kernels = SimpleNamespace(
    load=lambda kernel, native: kernels.load(kernel, _NATIVE), native_dir=kernels.native_dir,
    KernelError=kernels.KernelError)


def pytest_sessionfinish(session, exitstatus):
    lib = compiled_master.load()
    assert Path(lib._name).resolve().parent.parent.parent == _NATIVE.resolve(), lib._name
    print("SANITIZED LIBRARY:", lib._name)
'''


@pytest.mark.parametrize("binding, tests", [(compiled_master, "test_compiled.py"),
                                            (compiled_me, "test_compiled_me.py")],
                         ids=["co-simulation", "model-exchange"])
def test_the_compiled_loop_tests_pass_under_the_sanitizers(tmp_path, binding, tests):
    native = tmp_path / "root" / "orchestration" / "native"
    native.mkdir(parents=True)
    for f in kernels.source_files(binding.KERNEL):
        shutil.copy(f, native / f.name)
    out = kernels.library_path(binding.KERNEL, None, native)
    out.parent.mkdir(parents=True)
    cmd = kernels.compile_command(binding.KERNEL, kernels.host_platform(), out, native, "gcc")
    cmd[1:1] = SANITIZE
    subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=native)
    module = binding.__name__.rsplit(".", 1)[1]
    (tmp_path / "sanitized_master.py").write_text(PLUGIN.format(native=str(native),
                                                                module=module))
    env = dict(os.environ, LD_PRELOAD=":".join(RUNTIMES),
               ASAN_OPTIONS="detect_leaks=0:halt_on_error=1:abort_on_error=0",
               UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1",
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(HERE.parent)]))
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "sanitized_master",
                           "-p", "no:cacheprovider", "-s",
                           str(Path(__file__).parent / tests)],
                          env=env, capture_output=True, text=True, timeout=1200, cwd=tmp_path)
    text = proc.stdout + proc.stderr
    assert proc.returncode == 0, text[-4000:]
    for report in ("ERROR: AddressSanitizer", "runtime error:", "SUMMARY: "):
        assert report not in text, text[-4000:]
    assert f"SANITIZED LIBRARY: {out}" in text
    assert " passed" in text and " failed" not in text
