"""A sweep's worker reuses its FMU instances between runs (orchestration/cosim/pool.py): the
native FMUs are reset with fmi2Reset and given the next run's parameters, and the rows are those
of fresh instances, value for value."""
import sys

import pytest

from orchestration.cosim.pool import SlavePool
from orchestration.cosim.slave import Slave
from orchestration.sweeps import engine
from orchestration.sweeps.engine import run_sweep
from orchestration.sweeps.plan import plan_sweep

TIMES = ("wall_time", "cosim_time")


@pytest.fixture(scope="module")
def pair(native):
    return {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]}


def untimed(rows):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in rows]


def sweep(plan, pair, folder, monkeypatch, pool):
    """The rows of ``plan`` run serially with ``pool`` as the worker's pool (None: every run
    makes and frees its own instances, as ``flexpend run`` does)."""
    monkeypatch.setattr(engine, "_pool", lambda: pool)
    res = run_sweep(plan, pair, folder, progress=False, plot=False)
    return res.rows


# the plant's size (modes), its parameters and the controller change from run to run; kp = 1e5
# drives the beam past phi_limit (the FMU refuses a step: the next run resets an instance in
# error), and the model-exchange runs reuse their instances too
PLAN = dict(values=["controller.kp=1e5,500,650", "plant.n_modes=3,2"],
            samples=["plant.EI=uniform:800:950"], n_samples=1, seed=3,
            overrides=["stop_time=1", "initial.phi=0.05"])


def test_reused_instances_give_the_rows_of_fresh_ones(pair, tmp_path, monkeypatch):
    plan = plan_sweep("flexible_pd_lowpass", **PLAN)
    assert len(plan.points) == 6
    fresh = sweep(plan, pair, tmp_path / "fresh", monkeypatch, None)
    pool = SlavePool(engine._resets_fully)
    reused = sweep(plan, pair, tmp_path / "reused", monkeypatch, pool)
    assert [r["status"] for r in fresh] == ["failed", "failed", "ok", "ok", "ok", "ok"]
    assert "phi_limit" in fresh[0]["message"]
    # every run after the first took both instances from the pool, reset
    assert (pool.created, pool.reused) == (2, 2 * (len(plan.points) - 1))
    assert untimed(reused) == untimed(fresh)
    pool.close()


def test_model_exchange_instances_are_reused_too(pair, tmp_path, monkeypatch):
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=500,650"],
                      overrides=["stop_time=0.1", "initial.phi=0.05",
                                 "master.interface=model-exchange"])
    fresh = sweep(plan, pair, tmp_path / "fresh", monkeypatch, None)
    pool = SlavePool(engine._resets_fully)
    reused = sweep(plan, pair, tmp_path / "reused", monkeypatch, pool)
    assert (pool.created, pool.reused) == (2, 2)
    assert [r["status"] for r in fresh] == ["ok", "ok"]
    assert untimed(reused) == untimed(fresh)
    pool.close()


def test_a_reuse_without_reset_would_be_caught(pair, tmp_path, monkeypatch):
    """The comparison above can fail: instances handed on without fmi2Reset (only new start
    values) do not give the fresh rows."""
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=500,650"],
                      overrides=["stop_time=0.5", "initial.phi=0.05"])
    fresh = sweep(plan, pair, tmp_path / "fresh", monkeypatch, None)

    def no_reset(self, start_values=None):
        self.messages.clear()
        self._start_values = dict(start_values or {})
    monkeypatch.setattr(Slave, "reset", no_reset)
    wrong = sweep(plan, pair, tmp_path / "wrong", monkeypatch, SlavePool(engine._resets_fully))
    assert untimed(wrong)[0] == untimed(fresh)[0]
    assert untimed(wrong)[1] != untimed(fresh)[1]


def test_pythonfmu_instances_are_not_reused(fmus, tmp_path, monkeypatch):
    """pythonfmu's fmi2Reset is not known to restore the state after instantiation: its
    instances are freed after each run."""
    pair = {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}
    plan = plan_sweep("flexible_pd_lowpass", values=["controller.kp=500,650"],
                      overrides=["stop_time=0.05"])
    pool = SlavePool(engine._resets_fully)
    rows = sweep(plan, pair, tmp_path, monkeypatch, pool)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert (pool.created, pool.reused, pool._idle) == (4, 0, {})


def test_journal_is_flushed_per_row_and_synced_at_the_end(tmp_path, monkeypatch):
    """A row is in the file (flushed) as soon as it is appended, for a killed process; the
    fsync, which cost a third of a short run, comes at most every SYNC_EVERY seconds and at the
    end."""
    import os

    from orchestration.sweeps.engine import Journal
    synced = []
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd))
    monkeypatch.setattr(Journal, "SYNC_EVERY", 3600.0)
    with Journal(tmp_path) as j:
        for k in range(5):
            j.append({"key": str(k), "status": "ok"})
            assert len(Journal(tmp_path).read()) == k + 1
        assert synced == []
    assert len(synced) == 1 and sorted(Journal(tmp_path).read()) == list("01234")


def test_a_task_runs_with_blas_on_one_thread():
    """Every task runs with numpy's and scipy's BLAS on one thread (the executor's limit), and
    the limit ends with the task."""
    import scipy.linalg  # noqa: F401 - scipy's BLAS loaded, as in a sweep
    from threadpoolctl import threadpool_info, threadpool_limits

    from orchestration.sweeps.executor import Executor

    def blas_threads(_):
        return sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")
    with threadpool_limits(limits=2, user_api="blas"):
        inside = [v for _, v in Executor().map(blas_threads, [0, 1])]
        after = blas_threads(None)
    assert len(inside[0]) >= 1 and inside == [[1] * len(inside[0])] * 2
    assert after == [2] * len(after)


def test_linear_window_is_the_first_longest_stretch():
    """The summary's linear window (numpy, for the cost of a sweep run) against a plain scan."""
    import itertools

    import numpy as np

    from orchestration.studies.summary import LINEAR_PHI, linear_window

    def scan(ok):
        best, i = (0, 0), 0
        for v, run in itertools.groupby(ok):
            n = len(list(run))
            if v and n > best[1] - best[0]:
                best = (i, i + n)
            i += n
        return slice(*best)
    rng = np.random.default_rng(5)
    cases = [np.zeros(0, bool), np.zeros(7, bool), np.ones(7, bool),
             np.array([1, 1, 0, 1, 1, 0, 1], bool), np.array([0, 1, 1, 0, 1, 1], bool)]
    cases += [rng.random(n) < q for n in (1, 2, 50, 5000) for q in (0.2, 0.5, 0.9)]
    for ok in cases:
        res = np.zeros(len(ok), dtype=[("time", "f8"), ("phi_o", "f8")])
        res["phi_o"] = np.where(ok, 0.5, 2.0) * LINEAR_PHI
        assert linear_window(res, None) == scan(ok.tolist()), ok


def test_a_rebuilt_fmu_is_extracted_again(native, tmp_path):
    """A worker's extraction (and so its pooled instances) is keyed by the FMU's file and its
    content's stamp: an FMU rebuilt at the same path (a changed model, in a long-lived Python
    session) is extracted again, not run from the old folder."""
    import os
    import shutil
    from pathlib import Path

    fmu = tmp_path / "Model.fmu"
    shutil.copy(native["PDLowPass"], fmu)
    first = engine._extracted(str(fmu))
    assert engine._extracted(str(fmu)) == first
    shutil.copy(native["FlexiblePendulum"], fmu)               # rebuilt: other content
    st = os.stat(fmu)
    os.utime(fmu, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    second = engine._extracted(str(fmu))
    assert second != first
    assert (Path(second) / "binaries").is_dir() and \
        "FlexiblePendulum" in (Path(second) / "modelDescription.xml").read_text()


def loaded(library) -> bool:
    """Whether this process has ``library`` (a shared library's file) mapped."""
    from pathlib import Path
    return str(Path(library).resolve()) in Path("/proc/self/maps").read_text()


@pytest.mark.skipif(sys.platform != "linux", reason="reads the process's memory map (Linux)")
@pytest.mark.parametrize("role", ["controller", "plant"])
def test_closing_an_instance_leaves_the_library_of_another_one(pair, tmp_path, role):
    """Instances of one unpacked folder share one loaded library, counted by the dynamic loader
    (one dlopen each): closing one must unload it once. A second unload (fmpy's freeInstance
    already calls freeLibrary) unloaded the library under a pooled instance, whose next fmi2Reset
    jumped into unmapped code: a sweep's worker segfaulted after a run without the pool (or a
    closed instance) of the folder its pool's instances came from."""
    from fmpy import extract, platform, sharedLibraryExtension

    from orchestration.cosim.model_exchange import ModelExchangeUnit
    from orchestration.cosim.slave import describe

    folder = extract(pair[role], unzipdir=tmp_path / "fmu")
    library = tmp_path / "fmu" / "binaries" / platform / \
        (describe(pair[role]).coSimulation.modelIdentifier + sharedLibraryExtension)
    assert library.is_file()
    for unit in (Slave, ModelExchangeUnit):
        kept = unit(pair[role], role, {}, unzipdir=folder)
        other = unit(pair[role], role, {}, unzipdir=folder)
        other.close()
        assert loaded(library)                  # before kept.reset(), which would segfault
        kept.reset({})
        kept.initialize(0.0, 1.0)
        kept.close()
        assert not loaded(library)              # and every load undone
