"""Log categories and event messages of the native FMUs (issue 37, 5), FMI 2.0 and 3.0.

* The categories (``native_fmus.LOG_CATEGORIES``) do what their descriptions say: a message of
  status Warning, Discard, Error, Fatal is in ``logStatus<Status>``, ``logAll`` lets every
  message through; ``fmi<v>SetDebugLogging`` enables or disables them (fpm_core.c, "Log
  categories"); an unknown category is refused with Error and a message naming it and the
  allowed ones, and nothing changes.
* Each event's message once: a run through the state event where the plant reaches
  ``phi_limit`` says "divergence" once, through fmpy's own ME master (``simulate_fmu``) and
  through a host that also calls ``completedIntegratorStep`` after every step (as FMI4j and
  flexpend's model-exchange master do) before it handles the event in event mode.

Warnings come from the plant's event update: started at ``phi0 = phi_limit`` its initial event
iteration says the bound is reached (and asks to terminate); errors from a get of a value
reference the FMU has not.
"""
from __future__ import annotations

import ctypes
import shutil

import numpy as np
import pytest

from conftest import fmi_status
from orchestration.export.native_fmus import LOG_CATEGORIES

PLANT = "FlexiblePendulum"
STATUS_CATEGORY = {1: "logStatusWarning", 2: "logStatusDiscard", 3: "logStatusError",
                   4: "logStatusFatal"}


@pytest.fixture(scope="module")
def plant_dirs(native, native3):
    from fmpy import extract
    out = {2: extract(native[PLANT]), 3: extract(native3[PLANT])}
    yield out
    for d in out.values():
        shutil.rmtree(d, ignore_errors=True)


class Me:
    """A Model-Exchange instance of the native plant through fmpy's classes with its own
    ``loggingOn``; ``logs``: (status, category, message)."""

    def __init__(self, unzipdir, version, logging_on=False, **start):
        from fmpy import read_model_description
        self.md = read_model_description(unzipdir)
        self.version, self.logs = version, []
        self.vrs = {v.name: v.valueReference for v in self.md.modelVariables}
        ident = self.md.modelExchange.modelIdentifier
        if version == 2:
            from fmpy.fmi2 import (FMU2Model, fmi2CallbackAllocateMemoryTYPE,
                                   fmi2CallbackFunctions, fmi2CallbackFreeMemoryTYPE,
                                   fmi2CallbackLoggerTYPE, calloc, free)
            self.fmu = FMU2Model(guid=self.md.guid, unzipDirectory=unzipdir,
                                 modelIdentifier=ident, instanceName="log")
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(
                lambda env, inst, status, cat, msg: self.logs.append(
                    (status, cat.decode(), msg.decode())))
            cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            self._cb = cb
            self.fmu.instantiate(callbacks=cb, loggingOn=logging_on)
            self.fmu.setupExperiment(startTime=0.0)
        else:
            from fmpy.fmi3 import FMU3Model
            self.fmu = FMU3Model(guid=self.md.guid, unzipDirectory=unzipdir,
                                 modelIdentifier=ident, instanceName="log")
            self.fmu.instantiate(loggingOn=logging_on, logMessage=lambda env, status, cat, msg:
                                 self.logs.append((status, cat.decode(), msg.decode())))
        for k, v in start.items():
            (self.fmu.setReal if version == 2 else self.fmu.setFloat64)([self.vrs[k]], [v])
        self.nx = len(self.md.derivatives)

    def init(self):
        if self.version == 2:
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=0.0)
        self.fmu.exitInitializationMode()

    def update(self):
        """The event update (newDiscreteStates / updateDiscreteStates): (status, terminate)."""
        from fmpy.fmi1 import FMICallException
        try:
            if self.version == 2:
                from fmpy.fmi2 import fmi2EventInfo
                info = fmi2EventInfo()
                rc = self.fmu.fmi2NewDiscreteStates(self.fmu.component, ctypes.byref(info))
                return rc, bool(info.terminateSimulation)
            flags = [ctypes.c_bool() for _ in range(5)]
            t_next = ctypes.c_double()
            rc = self.fmu.fmi3UpdateDiscreteStates(self.fmu.component,
                                                   *(ctypes.byref(f) for f in flags),
                                                   ctypes.byref(t_next))
            return rc, flags[1].value
        except FMICallException as exc:
            return exc.status, None

    def bad_get(self) -> int:
        get = self.fmu.getReal if self.version == 2 else self.fmu.getFloat64
        return fmi_status(get, [95])

    def debug(self, on, categories) -> int:
        return fmi_status(self.fmu.setDebugLogging, on, categories)

    def said(self, status):
        return [m for s, _, m in self.logs if s == status]

    def close(self):
        self.fmu.freeInstance()


@pytest.fixture
def me(plant_dirs):
    opened = []

    def _open(version, logging_on=False, **start):
        inst = Me(plant_dirs[version], version, logging_on, **start)
        opened.append(inst)
        return inst
    yield _open
    for inst in opened:
        inst.close()


def _warn_and_fail(m):
    """One warning (the initial event reaches phi_limit) and one error (a value reference the FMU
    has not): their statuses."""
    m.init()
    status, terminate = m.update()
    assert terminate
    return status, m.bad_get()


# ---------------------------------------------------------------------- categories
@pytest.mark.parametrize("version", [2, 3])
def test_every_message_carries_the_category_of_its_status(me, version):
    """A new instance (loggingOn = false) says its warnings and errors, each in its status's
    category, which the description declares."""
    m = me(version, phi0=0.6, phi_limit=0.6)
    assert _warn_and_fail(m) == (1, 3)
    assert [(s, c) for s, c, _ in m.logs] == [(1, "logStatusWarning"), (3, "logStatusError")]
    assert "reached phi_limit" in m.logs[0][2] and "value reference 95" in m.logs[1][2]


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("on, categories, said", [
    (True, ["logStatusError"], {3}),                 # only the named one
    (True, ["logStatusWarning"], {1}),
    (True, ["logStatusWarning", "logStatusError"], {1, 3}),
    (True, ["logAll"], {1, 3}),                      # every message
    (True, [], {1, 3}),                              # every category
    (False, ["logStatusError"], {1}),                # the named one off, the others as they were
    (False, ["logStatusWarning", "logStatusError"], set()),
    (False, [], {1, 3}),                             # debug messages off; refusals still said
])
def test_the_categories_filter_the_messages(me, version, on, categories, said):
    m = me(version, phi0=0.6, phi_limit=0.6)
    assert m.debug(on, categories) == 0
    assert _warn_and_fail(m) == (1, 3)                # the statuses whatever is logged
    assert {s for s, _, _ in m.logs} == said
    for s, c, _ in m.logs:
        assert c == STATUS_CATEGORY[s]


@pytest.mark.parametrize("version", [2, 3])
def test_an_unknown_category_is_refused_and_nothing_changes(me, version):
    m = me(version, phi0=0.6, phi_limit=0.6)
    assert m.debug(True, ["logStatusError"]) == 0     # warnings off
    assert m.debug(True, ["logStatusWarning", "logEvents"]) == 3
    msg = m.said(3)[-1]
    assert "unknown log category 'logEvents'" in msg and "categories[1]" in msg
    assert all(c in msg for c in LOG_CATEGORIES)
    assert "SetDebugLogging" in msg and "unchanged" in msg
    m.logs.clear()
    assert _warn_and_fail(m) == (1, 3)
    assert m.said(1) == [] and len(m.said(3)) == 1   # still: errors only (no warning enabled)
    # a NULL name
    if version == 2:
        f = m.fmu.dll.fmi2SetDebugLogging
        arr = (ctypes.c_char_p * 1)(None)
        assert f(m.fmu.component, 1, 1, arr) == 3
    else:
        f = m.fmu.dll.fmi3SetDebugLogging
        arr = (ctypes.c_char_p * 1)(None)
        assert f(m.fmu.component, True, 1, arr) == 3
    assert "unknown log category NULL" in m.said(3)[-1]


def test_the_description_declares_the_categories_the_fmus_take(native, native3):
    """The modelDescription's LogCategories are the ones the binaries accept (the refusal's
    list), in both versions."""
    from fmpy import read_model_description
    for paths in (native, native3):
        for path in paths.values():
            md = read_model_description(path)
            assert [c.name if hasattr(c, "name") else c for c in md.logCategories] == \
                list(LOG_CATEGORIES)


# ---------------------------------------------------------------------- each event once
def _divergence(logs):
    return [m for s, _, m in logs if "divergence" in m]


@pytest.mark.parametrize("version", [2, 3])
def test_fmpys_me_master_hears_the_state_event_once(plant_dirs, version):
    import fmpy
    logs = []

    def logger(*args):                 # FMI 2.0: (env, instance, status, category, message)
        logs.append((args[-3], args[-2].decode(), args[-1].decode()))
    fmpy.simulate_fmu(plant_dirs[version], fmi_type="ModelExchange", stop_time=1.0,
                      start_values={"phi0": 0.5, "phi_limit": 0.6}, logger=logger)
    said = _divergence(logs)
    assert len(said) == 1, logs
    assert "reached phi_limit" in said[0]


@pytest.mark.parametrize("version", [2, 3])
def test_a_host_that_also_completes_each_step_hears_each_event_once(me, version):
    """Explicit Euler through the state event, ``completedIntegratorStep`` after every step (it
    asks to terminate at the crossing), then event mode at the same point (the state event the
    host located): one message, both calls asking to terminate. A second run after a reset
    reaches the same event again and says it again (a new run's event)."""
    m = me(version, logging_on=True, phi0=0.5, phi_limit=0.6)
    for run in (1, 2):
        m.init()
        assert m.update() == (0, False)
        m.fmu.enterContinuousTimeMode()
        x, dx = np.zeros(m.nx), np.zeros(m.nx)
        px = x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        pdx = dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        m.fmu.getContinuousStates(px, m.nx)
        t, h, terminate = 0.0, 1e-3, False
        for _ in range(2000):
            (m.fmu.getDerivatives if version == 2 else
             m.fmu.getContinuousStateDerivatives)(pdx, m.nx)
            t += h
            x += h * dx
            m.fmu.setTime(t)
            m.fmu.setContinuousStates(px, m.nx)
            terminate = m.fmu.completedIntegratorStep()[1]
            if terminate:
                break
        assert terminate
        m.fmu.enterEventMode()
        assert m.update() == (0, True)            # the same event: said already
        assert m.update() == (0, True)
        said = _divergence(m.logs)
        assert len(said) == run and f"at t = {t!r}"[:12] in said[-1], m.logs
        m.fmu.terminate()
        m.fmu.reset()
        if version == 2:
            m.fmu.setupExperiment(startTime=0.0)
        for k, v in {"phi0": 0.5, "phi_limit": 0.6}.items():
            (m.fmu.setReal if version == 2 else m.fmu.setFloat64)([m.vrs[k]], [v])
