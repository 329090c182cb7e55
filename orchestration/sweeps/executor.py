"""Many independent tasks, run in this process or on dask.distributed.

    with open_executor(workers=2) as ex:             # a LocalCluster of 2 worker processes
        for i, value in ex.map(fn, items): ...       # in the order the tasks finish
    with open_executor(scheduler="tcp://host:8786") as ex: ...   # an existing dask cluster
    with open_executor() as ex: ...                  # serial: this process, in order

The serial executor and the dask one call the same ``fn`` on the same items, so a study gives the
same numbers either way (only its wall times differ).

Why processes: the pythonfmu FMUs run their Python code in the interpreter of the process that
loads them, one interpreter per process, so two threads of one worker would share it (and its
GIL). Every dask worker is therefore a process with one thread
(``LocalCluster(processes=True, threads_per_worker=1)``), and every task, here or on a worker,
runs with numpy's BLAS on one thread (threadpoolctl).

Files the tasks need (the FMUs) are sent to every worker once, by a worker plugin, and a task
finds its copy with :func:`worker_file`: a cluster needs no shared file system. The workers must
run the same Python environment as the client (the project installed, the same version).

A task that raises in ``fn`` raises in :meth:`Executor.map` (a bug is not data); a task lost with
its worker (the process died, e.g. a crash inside an FMU, more times than dask retries it) comes
back as a :class:`TaskLost` value, so that the caller keeps every other result.
"""
from __future__ import annotations

import hashlib
import logging
import os
import sys
from pathlib import Path

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["Executor", "DaskExecutor", "TaskLost", "open_executor", "worker_file",
           "default_workers", "file_name", "scratch_dir"]


class TaskLost:
    """The result of a task whose worker died (or that dask cancelled): no value, a message."""

    def __init__(self, message: str):
        self.message = message

    def __repr__(self):
        return f"TaskLost({self.message!r})"


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:          # not on Linux
        return max(1, os.cpu_count() or 1)


def _run_batch(fn, items):
    """Run ``fn`` on each item with numpy's BLAS on one thread: a task has one core wherever it
    runs, and a BLAS routine's rounding can depend on its thread count (a matrix-pencil fit
    differed in the 13th digit between 2 threads and 1), so the serial path and the workers
    compute alike."""
    with _blas().limit(limits=1, user_api="blas"):
        return [fn(item) for item in items]


_BLAS: list = []


def _blas():
    """threadpoolctl's controller of this process's BLAS libraries, found once (finding them
    costs several milliseconds, most of a short run's own time): those loaded when the first task
    runs, numpy's and scipy's, which the tasks' modules import."""
    if not _BLAS:
        from threadpoolctl import ThreadpoolController
        _BLAS.append(ThreadpoolController())
    return _BLAS[0]


class Executor:
    """Serial: every task runs in this process, in order. The interface of every executor."""

    kind = "serial"
    workers = 1
    dashboard: str | None = None

    def map(self, fn, items, batch: int = 1):
        """``(index, fn(items[index]))`` for every item, as the tasks finish; ``batch`` items
        make one task (it only matters to a distributed executor)."""
        for i, item in enumerate(items):
            yield i, _run_batch(fn, [item])[0]

    def describe(self) -> str:
        return "serial (this process)"

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: name -> path of the files the worker plugin wrote into this worker process's folder
_WORKER_FILES: dict[str, str] = {}


def worker_file(name: str, default):
    """The path of file ``name`` sent to this worker by :class:`DaskExecutor` (``files=``), or
    ``default`` when the task runs elsewhere (the serial executor: the client's own path)."""
    return _WORKER_FILES.get(name, default)


def scratch_dir() -> str | None:
    """The local folder of the dask worker this runs on (dask removes it with the worker), or
    None outside a worker."""
    try:
        from distributed import get_worker
        return get_worker().local_directory
    except (ImportError, ValueError):
        return None


def file_name(path) -> str:
    """The name under which :class:`DaskExecutor` ships ``path``: content digest + file name, so
    two different files of one name never meet in a worker."""
    path = Path(path)
    return f"{hashlib.sha256(path.read_bytes()).hexdigest()[:16]}-{path.name}"


class _Setup(WorkerPlugin):
    """Worker plugin: put ``paths`` first on ``sys.path``, write ``files`` (name -> bytes) into
    the worker's local folder, and (a LocalCluster's workers) ignore Ctrl-C."""

    name = "flexpend-setup"

    def __init__(self, paths, files, ignore_sigint=False):
        self.paths, self.files = list(paths), dict(files)
        self.ignore_sigint = ignore_sigint

    def setup(self, worker):
        if self.ignore_sigint:
            # a LocalCluster's workers share the client's terminal: Ctrl-C is the client's to
            # handle (it keeps what finished and closes the cluster), not theirs to die of
            import signal
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            except ValueError:              # not the main thread: leave it
                pass
        for p in reversed(self.paths):
            if p not in sys.path:
                sys.path.insert(0, p)
        folder = Path(worker.local_directory) / "flexpend-files"
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in self.files.items():
            target = folder / name
            if not target.is_file():
                part = target.with_suffix(target.suffix + ".part")
                part.write_bytes(data)
                os.replace(part, target)
            _WORKER_FILES[name] = str(target)


class DaskExecutor(Executor):
    """Tasks on dask.distributed: a new ``LocalCluster`` of ``workers`` processes (one thread
    each), or the cluster of the scheduler at ``scheduler``.

    ``paths``: folders put first on every worker's ``sys.path`` (for task functions defined in
    scripts, e.g. ``bench/``); ``files``: paths of files to send to every worker (see
    :func:`worker_file`, under :func:`file_name`)."""

    kind = "dask"

    def __init__(self, workers: int | None = None, scheduler: str | None = None, *,
                 paths=(), files=()):
        from distributed import Client, LocalCluster

        self.cluster = None
        if scheduler:
            try:
                self.client = Client(scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise ValueError(f"no dask scheduler at {scheduler!r}: {exc}") from None
        else:
            self.cluster = LocalCluster(n_workers=workers or default_workers(), processes=True,
                                        threads_per_worker=1, dashboard_address=":0",
                                        silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        self.scheduler = scheduler
        try:
            blobs = {file_name(f): Path(f).read_bytes() for f in files}
            self.client.register_plugin(_Setup([str(p) for p in paths], blobs,
                                               ignore_sigint=self.cluster is not None))
        except BaseException:
            self.close()
            raise
        self.workers = len(self.client.scheduler_info()["workers"])
        self.dashboard = (self.client.dashboard_link
                          if "dashboard" in self.client.scheduler_info().get("services", {})
                          else None)

    def describe(self) -> str:
        where = (f"the dask scheduler at {self.scheduler}" if self.scheduler
                 else "a dask LocalCluster")
        return f"{where}, {self.workers} worker process{'es' if self.workers != 1 else ''}"

    def dashboard_note(self) -> str | None:
        """``dask dashboard: <address>`` (with a hint when bokeh, which draws it, is missing
        here), or None when the scheduler serves none."""
        if not self.dashboard:
            return None
        note = f"dask dashboard: {self.dashboard}"
        if self.cluster is not None:
            try:
                import bokeh  # noqa: F401
            except ImportError:
                note += "  (install bokeh to see it: pip install 'flexpend[sweep]')"
        return note

    def map(self, fn, items, batch: int = 1):
        from distributed import KilledWorker, as_completed

        items = list(items)
        batch = max(1, int(batch))
        chunks = [list(range(i, min(i + batch, len(items)))) for i in range(0, len(items), batch)]
        futures = self.client.map(_run_batch, [fn] * len(chunks),
                                  [[items[i] for i in idx] for idx in chunks], pure=False)
        index = {fut.key: idx for fut, idx in zip(futures, chunks)}
        try:
            # results are gathered in the background as the tasks finish
            for fut, result in as_completed(futures, with_results=True, raise_errors=False):
                idx = index.pop(fut.key)
                if fut.status == "error":
                    exc = result[1]
                    if not isinstance(exc, KilledWorker):
                        raise exc.with_traceback(result[2])
                    text = " ".join(str(exc).split())
                    result = [TaskLost(f"KilledWorker: {text}")] * len(idx)
                elif fut.status == "cancelled":
                    result = [TaskLost("cancelled by dask")] * len(idx)
                fut.release()
                yield from zip(idx, result)
        finally:                        # interrupted or abandoned: stop what is still queued
            left = [f for f in futures if f.key in index]
            if left:
                self.client.cancel(left)

    def close(self):
        client, self.client = getattr(self, "client", None), None
        if client is not None:
            client.close()
        cluster, self.cluster = self.cluster, None
        if cluster is not None:
            cluster.close()


def open_executor(workers: int | None = None, scheduler: str | None = None, *, paths=(),
                  files=()) -> Executor:
    """The serial executor when neither ``workers`` nor ``scheduler`` is given, else a
    :class:`DaskExecutor` (a ``ValueError`` names a bad argument or an unreachable scheduler)."""
    if workers is not None and scheduler:
        raise ValueError("give a number of workers (a LocalCluster) or a scheduler address, "
                         "not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers = {workers!r} is not allowed; allowed: an integer >= 1")
    if workers is None and not scheduler:
        return Executor()
    return DaskExecutor(workers, scheduler, paths=paths, files=files)
