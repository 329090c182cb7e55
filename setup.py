"""Build step of the project: compile the C kernels (plant_fmu/native, controller_fmu/native, and
the master's compiled loop in orchestration/cosim/native) into plain shared libraries for this platform, for regular and editable installs alike.

Everything else is declared in pyproject.toml. The compilation itself is fmu_common/kernels.py
(the same build the FMUs use). Without a C compiler the
install stops with one line naming the compiler it looked for.
"""
import importlib.util
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


def _kernel_build():
    """fmu_common/kernels.py, loaded by its path (standard library only; nothing is installed
    yet)."""
    spec = importlib.util.spec_from_file_location("_flexpend_kernels",
                                                  HERE / "fmu_common" / "kernels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class build_py_with_kernels(build_py):
    """``build_py``, then the kernels: into the build folder, or into the checkout itself for an
    editable install (whose packages are read from there)."""

    def run(self):
        super().run()
        kb = _kernel_build()
        target = HERE if self.editable_mode else Path(self.build_lib)
        try:
            kb.build_host_kernels(HERE, target)
        except kb.CompilerNotFound as exc:
            sys.exit(f"error: {exc}")
        except kb.KernelBuildError as exc:
            sys.exit(f"error: {exc}")


setup(cmdclass={"build_py": build_py_with_kernels})
