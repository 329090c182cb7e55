"""Build step of the project: compile the C kernels (plant_fmu/native, controller_fmu/native, and
the master's compiled loop in orchestration/cosim/native) into plain shared libraries for this platform, for regular and editable installs alike.

Everything else is declared in pyproject.toml. The compilation itself is fmu_common/kernels.py
(the same build the FMUs use). Without a C compiler the
install stops with one line naming the compiler it looked for.
"""
import atexit
import importlib.util
import shutil
import sys
import tempfile
from pathlib import Path

from setuptools import Distribution, setup
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


class BinaryDistribution(Distribution):
    """A distribution that carries binaries (the kernels) though it declares no Python extension:
    its packages install into ``platlib``, not ``purelib``, so the wheel's root is the platform
    library folder (``auditwheel repair``, which makes the wheel a ``manylinux`` one, refuses
    shared libraries under ``purelib``)."""

    def has_ext_modules(self):
        return True


def _bdist_wheel():
    """``bdist_wheel`` tagged for this platform and any CPython 3 (``py3-none-<platform>``): the
    wheel carries compiled C libraries, loaded by ctypes, not Python extensions."""
    try:
        from setuptools.command.bdist_wheel import bdist_wheel
    except ImportError:
        try:
            from wheel.bdist_wheel import bdist_wheel
        except ImportError:          # no wheel support here (an editable install needs none)
            return {}

    class bdist_wheel_platform(bdist_wheel):
        def finalize_options(self):
            super().finalize_options()
            self.root_is_pure = False

        def get_tag(self):
            return ("py3", "none", super().get_tag()[2])

    return {"bdist_wheel": bdist_wheel_platform}


# The build's scratch (build/lib, the egg-info) goes to a temporary folder, not into the source
# tree: `build/` is the project's own folder (the FMUs), and a wheel build leaves nothing behind.
SCRATCH = tempfile.mkdtemp(prefix="flexpend-setup-")
atexit.register(shutil.rmtree, SCRATCH, ignore_errors=True)

setup(distclass=BinaryDistribution,
      cmdclass={"build_py": build_py_with_kernels, **_bdist_wheel()},
      options={"build": {"build_base": str(Path(SCRATCH) / "build")},
               "egg_info": {"egg_base": SCRATCH}})
