"""Shared fixtures: the FMUs, built once per session (only if their sources changed), and a small
harness that drives one FMU instance through fmpy's FMU2Slave and records its log messages."""
from __future__ import annotations

import os

# One BLAS thread per test process (before numpy is loaded), as the flexpend command sets it: the
# suite runs in two worker processes on two cores, and a Python host that made pythonfmu calls with
# scipy's threaded OpenBLAS loaded can abort at exit in libgfortran's destructor (docs/fmus.md,
# "The exit abort"; never with one BLAS thread).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import ctypes  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

# The tests live in one folder per package (tests/plant, tests/export, ...); a few import another
# folder's test module by its name (a shared derivation or host: ``from test_lagrange import
# _derive``), so every folder is on the path, as pytest puts the folder of each file it collects.
for _folder in sorted(Path(__file__).parent.iterdir()):
    if _folder.is_dir() and any(_folder.glob("test_*.py")) and str(_folder) not in sys.path:
        sys.path.append(str(_folder))

# The checkout's packages are imported in the test process on purpose: the FMUs must not run them
# (each FMU loads its own copy under a private name; tests/common/test_fmu_robustness.py checks it).
import controller_fmu.pd_lowpass  # noqa: E402,F401
import plant_fmu.dynamics  # noqa: E402,F401


_FMPY_PROXY_KEEP: list = []


@pytest.fixture(autouse=True)
def _fmpy_logger_proxy_put_back():
    """fmpy 0.3.32's native logger proxy keeps, in a global, the last logger that
    ``simulate_fmu(..., logger=f)`` handed it, and fmpy's default callbacks of every later FMI 2.0
    instance call that proxy: once ``f``'s ctypes callback is freed, the next message of any
    FMU 2.0 opened with fmpy's defaults jumps into freed memory (a segfault in whichever test of
    the same worker comes next). After each test the proxy is pointed back at a callback of
    fmpy's own printLogMessage that lives as long as the process. A fresh struct each time:
    addLoggerProxy puts itself into the struct it is given, so a struct handed to it twice would
    make the proxy call itself."""
    yield
    if "fmpy.logging" not in sys.modules:
        return
    from fmpy.fmi1 import printLogMessage
    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
    from fmpy.logging import addLoggerProxy
    if not _FMPY_PROXY_KEEP:
        _FMPY_PROXY_KEEP.append(fmi2CallbackLoggerTYPE(printLogMessage))
    cb = fmi2CallbackFunctions()
    cb.logger = _FMPY_PROXY_KEEP[0]
    _FMPY_PROXY_KEEP.append(cb)
    addLoggerProxy(ctypes.byref(cb))


def _built(**kw) -> dict:
    from orchestration.export import build_fmus

    return {name: str(path) for name, path in build_fmus(**kw).items()}


def _unpacked(paths: dict):
    """Each FMU of ``paths`` unpacked into a folder (name -> folder), removed afterwards."""
    from fmpy import extract

    dirs = {name: extract(path) for name, path in paths.items()}
    yield dirs
    for d in dirs.values():
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture(scope="session")
def fmus() -> dict:
    """``{"FlexiblePendulum": path, "PDLowPass": path}``, built into build/fmus/ if stale."""
    return _built()


@pytest.fixture(scope="session")
def fmu_dirs(fmus) -> dict:
    """The FMUs unpacked once per session: name -> folder."""
    yield from _unpacked(fmus)


@pytest.fixture(scope="session")
def native() -> dict:
    """The native FMI 2.0 pair, ``{"FlexiblePendulum": path, "PDLowPass": path}``, built if
    stale."""
    return _built(flavour="native")


@pytest.fixture(scope="session")
def native_dirs(native) -> dict:
    """The native FMI 2.0 pair unpacked once per session: name -> folder."""
    yield from _unpacked(native)


@pytest.fixture(scope="session")
def native3() -> dict:
    """The native FMI 3.0 pair, ``{"FlexiblePendulum": path, "PDLowPass": path}``, built if
    stale."""
    return _built(flavour="native", fmi_version=3)


def fmi_status(fn, *args) -> int:
    """0, or the status of the ``FMICallException`` that the fmpy call ``fn(*args)`` raised."""
    from fmpy.fmi1 import FMICallException

    try:
        fn(*args)
        return 0
    except FMICallException as exc:
        return exc.status


class FmuInstance:
    """One FMU instance driven by fmpy's FMU2Slave, addressed by variable name.

    ``logs`` collects ``(status, category, message)`` of every log callback. :meth:`step` returns
    the status of ``fmi2DoStep`` (0 ok, 2 discard, 3 error...) instead of raising.
    """

    def __init__(self, unzipdir, start_values=None, instance_name="instance", initialize=True,
                 start_time=0.0):
        from fmpy import read_model_description
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFunctions,
                               fmi2CallbackFreeMemoryTYPE, fmi2CallbackLoggerTYPE, calloc, free)

        self.md = read_model_description(unzipdir)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.logs = []
        self.init_status = None

        def logger(env, name, status, category, message):
            self.logs.append((status, (category or b"").decode(), message.decode()))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb                      # keep the ctypes callbacks alive
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipdir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=instance_name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.fmu.setupExperiment(startTime=start_time)
        self.set(**(start_values or {}))
        if initialize:
            self.initialize()

    def initialize(self) -> int:
        """Enter and exit initialisation mode; the status of ``fmi2ExitInitializationMode`` (0,
        or 3 after a bad parameter, which the FMU logs and then refuses every step with)."""
        self.fmu.enterInitializationMode()
        self.init_status = fmi_status(self.fmu.exitInitializationMode)
        return self.init_status

    def vr(self, *names):
        return [self.vars[n].valueReference for n in names]

    def set(self, **values):
        for name, value in values.items():
            v = self.vars[name]
            if v.type == "Real":
                self.fmu.setReal([v.valueReference], [float(value)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(value)])
            elif v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            else:
                self.fmu.setString([v.valueReference], [str(value)])

    def get(self, *names) -> list:
        return self.fmu.getReal(self.vr(*names))

    def outputs(self) -> list:
        return self.get(*[v.name for v in self.md.modelVariables if v.causality == "output"])

    def step(self, t, h) -> int:
        return fmi_status(self.fmu.doStep, t, h)

    def messages(self, min_status=0) -> str:
        return "\n".join(m for s, _, m in self.logs if s >= min_status)

    def close(self):
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()


class NativeFmu:
    """One Model-Exchange (or, with cs=True, co-simulation) instance of a native FMU of either
    FMI version through fmpy's classes, addressed by name; ``logs`` collects (status, message)."""

    def __init__(self, unzipdir, version, cs=False, **start):
        from fmpy import read_model_description

        self.md = read_model_description(unzipdir)
        self.version = version
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.logs = []
        iface = self.md.coSimulation if cs else self.md.modelExchange
        if version == 2:
            from fmpy.fmi2 import FMU2Model, FMU2Slave
            cls = FMU2Slave if cs else FMU2Model
            self.fmu = cls(guid=self.md.guid, unzipDirectory=unzipdir,
                           modelIdentifier=iface.modelIdentifier, instanceName="i")

            from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFunctions,
                                   fmi2CallbackFreeMemoryTYPE, fmi2CallbackLoggerTYPE, calloc,
                                   free)

            def logger(env, name, status, category, message):
                self.logs.append((status, message.decode()))
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(logger)
            cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            self._cb = cb
            self.fmu.instantiate(callbacks=cb, loggingOn=True)
            self.fmu.setupExperiment(startTime=0.0)
        else:
            from fmpy.fmi3 import FMU3Model, FMU3Slave
            cls = FMU3Slave if cs else FMU3Model
            self.fmu = cls(guid=self.md.guid, unzipDirectory=unzipdir,
                           modelIdentifier=iface.modelIdentifier, instanceName="i")

            def logger(env, status, category, message):
                self.logs.append((status, message.decode()))
            self.fmu.instantiate(loggingOn=True, logMessage=logger)
        self.set(**start)
        self.nx = len(self.md.derivatives)
        self.nz = self.md.numberOfEventIndicators if version == 2 else \
            len(self.md.eventIndicators)

    def vr(self, *names):
        return [self.vars[n].valueReference for n in names]

    def set(self, **values):
        for name, value in values.items():
            v = self.vars[name]
            if v.type in ("Real", "Float64"):
                (self.fmu.setReal if self.version == 2 else self.fmu.setFloat64)(
                    [v.valueReference], [float(value)])
            elif v.type in ("Integer", "Int32"):
                (self.fmu.setInteger if self.version == 2 else self.fmu.setInt32)(
                    [v.valueReference], [int(value)])
            elif v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(value)])
            else:
                self.fmu.setString([v.valueReference], [value])

    def get(self, *names):
        get = self.fmu.getReal if self.version == 2 else self.fmu.getFloat64
        return get(self.vr(*names))

    def initialize(self, event=True):
        """Initialisation, the event iteration, continuous-time mode (ME)."""
        if self.version == 2:
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=0.0)
        self.fmu.exitInitializationMode()
        if event:
            if self.version == 2:
                info = self.fmu.newDiscreteStates()
                assert not info[1]
            else:
                assert not self.fmu.updateDiscreteStates()[1]
            self.fmu.enterContinuousTimeMode()

    def states(self):
        x = np.zeros(self.nx)
        self.fmu.getContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), self.nx)
        return x

    def set_states(self, x):
        x = np.ascontiguousarray(x, dtype=float)
        self.fmu.setContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), self.nx)

    def derivatives(self):
        dx = np.zeros(self.nx)
        p = dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        if self.version == 2:
            self.fmu.getDerivatives(p, self.nx)
        else:
            self.fmu.getContinuousStateDerivatives(p, self.nx)
        return dx

    def nominals(self):
        x = np.zeros(self.nx)
        self.fmu.getNominalsOfContinuousStates(
            x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), self.nx)
        return x

    def indicators(self):
        z = np.zeros(self.nz)
        self.fmu.getEventIndicators(z.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), self.nz)
        return z

    def set_time(self, t):
        self.fmu.setTime(t)

    def directional(self, unknowns, knowns, seed):
        if self.version == 2:
            return np.array(self.fmu.getDirectionalDerivative(self.vr(*unknowns),
                                                              self.vr(*knowns), list(seed)))
        return np.array(self.fmu.getDirectionalDerivative(self.vr(*unknowns), self.vr(*knowns),
                                                          list(seed)))

    def step(self, t, h) -> int:
        """The status of a co-simulation step (0 ok, 2 discard, 3 error...)."""
        return fmi_status(self.fmu.doStep, t, h)

    def messages(self, min_status=2) -> str:
        return "\n".join(m for s, m in self.logs if s >= min_status)

    def close(self):
        try:
            self.fmu.terminate()
        except Exception:  # noqa: BLE001 - an instance in error may refuse terminate
            pass
        self.fmu.freeInstance()


def opened_by(make):
    """A factory fixture's body (``yield from``): the test gets a function that opens instances
    by ``make(...)``; every one opened is closed after the test, even one an error left unable
    to terminate cleanly."""
    opened = []

    def _open(*args, **kwargs):
        inst = make(*args, **kwargs)
        opened.append(inst)
        return inst

    yield _open
    for inst in opened:
        try:
            inst.close()
        except Exception:  # noqa: BLE001 - an instance in error may refuse terminate
            pass


@pytest.fixture
def open_native(native_dirs):
    """Factory: ``open_native("FlexiblePendulum", **start)`` -> an initialised
    :class:`FmuInstance` of the native FMI 2.0 FMU (``initialize=False`` stops before
    initialisation); closed after the test."""
    yield from opened_by(lambda name, initialize=True, **start:
                         FmuInstance(native_dirs[name], start, name, initialize))


@pytest.fixture
def open_fmu(fmu_dirs):
    """Factory: ``open_fmu("FlexiblePendulum", n_modes=2)`` -> an initialised :class:`FmuInstance`
    (pass ``initialize=False`` to stop before initialisation, ``start_time`` for
    fmi2SetupExperiment); closed after the test."""
    opened = []

    def _open(name, initialize=True, instance_name=None, start_time=0.0, **start_values):
        inst = FmuInstance(fmu_dirs[name], start_values, instance_name or name, initialize,
                           start_time)
        opened.append(inst)
        return inst

    yield _open
    for inst in opened:
        inst.close()


def all_finite(values) -> bool:
    return all(math.isfinite(v) for v in values)


def hand_stepped(scene, n_rows):
    """The samples ``(phi_o, omega_o, x_o, F_c)`` of the scene's transition matrices
    (``scene_transition_matrix``: explicit or implicit, start-up steps included) stepped by hand
    from the master's consistent initial outputs (with output derivatives: the initial ones, the
    input derivatives 0), as ``transition_matrix`` lays out ``z``. The tests compare the master's
    co-simulation of the linear plant with it."""

    from controller_fmu.pd_lowpass import PDLowPassModel
    from orchestration.studies.stability import linear_plant, scene_transition_matrix
    from plant_fmu.dynamics import linear_plant_model

    m = scene.master
    plant = linear_plant(scene.plant.params, drift_free=False)
    ctrl = PDLowPassModel(scene.controller)
    Ac, Bc, Cc, Dc = ctrl.state_space()
    x0 = linear_plant_model(scene.plant.params).initial_state(phi=scene.initial.phi)
    nx, nc, P = len(x0), ctrl.nx, m.extrapolation + 1
    y0 = plant.C @ x0
    F0 = (Dc @ y0)[0]                         # F_c(0): -e(0) without filter, else 0
    if m.coupling == "hermite":               # its registers: y and two rates, F and four
        z, iF = _hermite_start(m, plant, (Ac, Bc, Cc, Dc), x0), nx + nc + 9
    else:
        z, iF = _polynomial_start(m, plant, (Ac, Bc, Cc, Dc), x0, y0, F0), nx + nc + 3 * P
    rows = []
    for k in range(n_rows):
        x_o, phi_o, omega_o = plant.C @ z[:nx]
        rows.append((phi_o, omega_o, x_o, z[iF]))
        z = scene_transition_matrix(scene, drift_free=False, step_index=k) @ z
    return np.array(rows)


def _polynomial_start(m, plant, ss, x0, y0, F0):
    """The polynomial couplings' registers at t0 (``transition_matrix``'s layout): the initial
    samples (with output derivatives: the initial ones, the input derivatives 0), the older
    ones 0."""
    Ac, Bc, Cc, Dc = ss
    nx, nc, P = len(x0), Ac.shape[0], m.extrapolation + 1
    z = np.zeros(nx + nc + 3 * P + P)
    z[:nx] = x0
    iy, iF = nx + nc, nx + nc + 3 * P
    z[iy:iy + 3] = y0
    z[iF] = F0
    if m.output_derivatives:                  # the FMUs' initial output derivatives
        d1 = plant.A @ x0 + plant.B[:, 0] * F0
        dc = Bc @ y0                          # xc(0) = 0, the sensors' derivatives 0
        ders = [(plant.C @ d1, (Cc @ dc)[0]), (plant.C @ plant.A @ d1, (Cc @ Ac @ dc)[0])]
        for j in range(1, P):
            z[iy + 3 * j:iy + 3 * j + 3], z[iF + j] = ders[j - 1]
    return z


def _hermite_start(m, plant, ss, x0):
    """The Hermite coupling's registers at t0 (``transition_matrix``'s layout: x, xc = 0, the
    plant's outputs and two derivatives, F_c and four derivatives), as the master's consistent
    initial outputs make them: each FMU's outputs at its start inputs, then, twice in the
    coupling order, its inputs and input derivatives set from its source's sample and its sample
    read again."""
    Ac, Bc, Cc, Dc = ss
    A, b, C = plant.A, plant.B[:, 0], plant.C
    nc = Ac.shape[0]

    def plant_sample(u, du):
        d1 = A @ x0 + b * u
        return [C @ x0, C @ d1, C @ (A @ d1 + b * du)]

    def ctrl_sample(ys):                      # xc(0) = 0; sensors' derivatives beyond 2: 0
        v, out = np.zeros(nc), []
        for j in range(5):
            yj = ys[j] if j < 3 else np.zeros(3)
            out.append(float((Cc @ v)[0] + (Dc @ yj)[0]))
            v = Ac @ v + Bc @ yj
        return out

    ys, Fs = plant_sample(0.0, 0.0), ctrl_sample([np.zeros(3)] * 3)
    order = [m.first, "controller" if m.first == "plant" else "plant"]
    for _ in range(2):
        for n in order:
            if n == "plant":
                ys = plant_sample(Fs[0], Fs[1])
            else:
                Fs = ctrl_sample(ys)
    return np.concatenate([x0, np.zeros(nc), *ys, Fs])


def one_line_error(err: str, *fragments) -> None:
    """``err`` (stderr) ends on the one line of an error, which names each of ``fragments``."""
    lines = err.strip().splitlines()
    assert lines[-1].startswith("flexpend: error: "), err
    assert sum(ln.startswith("flexpend") for ln in lines) == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in lines[-1], (f, err)


def flexpend(args, tmpdir: Path, *, driver: str = "", **popen):
    """``flexpend ARGS`` in a subprocess whose temporary folder is ``tmpdir`` (so that whatever
    it leaves there is seen); ``driver``: Python run first in the process, before
    :func:`orchestration.cli.entry` (``cli`` is the module)."""
    code = ("import sys\nfrom orchestration import cli\n" + driver
            + "\nsys.argv = ['flexpend', *sys.argv[1:]]\ncli.entry()\n")
    env = dict(os.environ, TMPDIR=str(tmpdir))
    return subprocess.Popen([sys.executable, "-c", code, *map(str, args)],
                            cwd=Path(__file__).resolve().parents[1], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **popen)
