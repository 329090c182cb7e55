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

An existing scheduler (``scheduler=``) is checked before dask is handed the address
(:func:`probe_scheduler`): within :data:`PROBE_TIMEOUT` seconds it must answer dask's handshake
with one, read with a bounded size (a silent service, an HTTP server or one that sends garbage or
announces a huge message is a :class:`SchedulerError`, not a hang or a huge allocation); then,
if it has no worker, the executor waits :data:`WORKER_WAIT` seconds for one, saying so.
"""
from __future__ import annotations

import contextlib
import hashlib
import logging
import math
import os
import shutil
import signal
import socket
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["Executor", "DaskExecutor", "TaskLost", "SchedulerError", "open_executor",
           "probe_scheduler", "worker_file", "default_workers", "cluster_workers", "file_name",
           "scratch_dir", "PROBE_TIMEOUT", "WORKER_WAIT", "CLUSTER_START", "TASK_OVERHEAD"]

#: Seconds within which a scheduler given by address must answer dask's handshake.
PROBE_TIMEOUT = 5.0
#: Seconds to wait for a first worker when that scheduler has none.
WORKER_WAIT = 30.0
#: The largest first message read from a scheduler (its handshake is about 100 bytes).
HANDSHAKE_LIMIT = 64 * 1024


class SchedulerError(ValueError):
    """The scheduler at ``address`` cannot run the tasks: ``reason`` says why (no answer, not a
    dask scheduler, no workers)."""

    def __init__(self, address: str, reason: str):
        super().__init__(f"scheduler {address}: {reason}")
        self.address, self.reason = address, reason


@contextlib.contextmanager
def _sigint_blocked():
    """SIGINT held back in this thread (the main one) while the block runs, and delivered (to
    Python's handler) after it; threads and processes started meanwhile keep it blocked."""
    if threading.current_thread() is not threading.main_thread() or \
            not hasattr(signal, "pthread_sigmask"):
        yield
        return
    # multiprocessing's resource tracker, started from a thread, unblocks SIGINT in that thread
    # (dask's IO loop, which starts the workers): start it here first
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


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


#: What a LocalCluster costs before its first result: starting its processes, their imports and
#: the first FMU load (s; 5.1 s measured for 2 workers on 2 cores, docs/sweeps.md).
CLUSTER_START = 5.0
#: What a task costs on dask beyond its own work: scheduling it, sending its row back, the
#: journal (s; 21 ms measured per run, docs/sweeps.md).
TASK_OVERHEAD = 0.02


def cluster_workers(tasks: int, task_seconds: float, cores: int | None = None) -> int:
    """How many LocalCluster workers to start for ``tasks`` independent tasks of about
    ``task_seconds`` each, on ``cores`` cores (default :func:`default_workers`); 0 where a
    cluster cannot win, and the tasks should run serially here.

    With ``W = min(cores, tasks)`` workers the cluster wins when it ends before the serial
    runs::

        CLUSTER_START + ceil(tasks / W) * (task_seconds + TASK_OVERHEAD)  <  tasks * task_seconds

    e.g. on 2 cores, 4 runs of 0.6 s: 6.2 s against 2.4 s, serial (measured: 8.2 s against
    2.5 s); 64 runs of 0.69 s: 28 s against 44 s, 2 workers."""
    cores = default_workers() if cores is None else cores
    workers = min(cores, tasks)
    if workers < 2:
        return 0
    cluster = CLUSTER_START + math.ceil(tasks / workers) * (task_seconds + TASK_OVERHEAD)
    return workers if cluster < tasks * task_seconds else 0


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


def _handshake() -> bytes:
    """What a dask client sends first on a TCP connection: its handshake, framed as dask frames
    every message (the length of the rest, the frame count, the frame lengths, the frames)."""
    import pickle

    from distributed.protocol import dumps
    from distributed.protocol.utils import pack_frames

    body = pack_frames(dumps({"compression": None, "python": tuple(sys.version_info)[:3],
                              "pickle-protocol": pickle.HIGHEST_PROTOCOL}))
    return struct.pack("Q", len(body)) + body


class _NotDask(Exception):
    pass


def _receive(sock, n: int, deadline: float) -> bytes:
    """Exactly ``n`` bytes, by ``deadline`` (``socket.timeout`` after it)."""
    data = bytearray()
    while len(data) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise socket.timeout
        sock.settimeout(left)
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise _NotDask("it closed the connection without a dask handshake")
        data += chunk
    return bytes(data)


def _handshake_of(data: bytes) -> dict:
    """The peer's handshake from the bytes of its first message, or :class:`_NotDask`. The first
    frame is decoded as plain msgpack: distributed's ``loads`` would unpickle what the peer put
    in it (code of the peer's choosing, run here) and log a traceback of what does not decode."""
    import msgpack
    from distributed.protocol.utils import unpack_frames

    (frames,) = struct.unpack_from("Q", data)
    if not 1 <= frames <= (len(data) - 8) // 8:
        raise _NotDask(f"its first message announces {frames} frames")
    try:
        msg = msgpack.unpackb(unpack_frames(data)[0], use_list=False, raw=False,
                              strict_map_key=False)
    except Exception as exc:  # noqa: BLE001 - any decoding failure means "not dask"
        raise _NotDask(f"its first message does not decode ({type(exc).__name__})") from None
    if not isinstance(msg, dict) or "python" not in msg:
        raise _NotDask("its first message is not a dask handshake")
    return msg


#: What a LocalCluster of W worker processes needs (measured with 2 and 4 workers: its nannies
#: fail to start below about 48 and 96 open files; its client crashes with 1 GiB of address
#: space per process and runs with 2 GiB).
CLUSTER_FILES_BASE, CLUSTER_FILES_PER_WORKER = 64, 16
CLUSTER_ADDRESS_SPACE = 2 << 30


def cluster_limits(workers: int) -> str | None:
    """Whether a LocalCluster of ``workers`` processes fits this process's limits: the soft
    limit of open files is raised to what it needs where the hard limit allows (never lowered);
    else, or where the address space (``ulimit -v``) is too small for dask's processes, the
    problem in words (None when it fits). Every LocalCluster is checked (:class:`DaskExecutor`),
    and the default rule of a sweep runs serially where one would not fit."""
    import resource

    need = CLUSTER_FILES_BASE + CLUSTER_FILES_PER_WORKER * workers
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard == resource.RLIM_INFINITY or hard >= need:
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        else:
            return (f"too few file handles for a LocalCluster of {workers} workers: it needs "
                    f"about {need}, this process may open {hard} (ulimit -n)")
    space = resource.getrlimit(resource.RLIMIT_AS)[0]
    if space != resource.RLIM_INFINITY and space < CLUSTER_ADDRESS_SPACE:
        return (f"too little memory for a LocalCluster: each of its processes needs about "
                f"{CLUSTER_ADDRESS_SPACE >> 20} MiB of address space, this process may use "
                f"{space >> 20} MiB (ulimit -v)")
    return None


def probe_scheduler(address: str, timeout: float | None = None) -> None:
    """Check that a dask scheduler answers at ``address`` within ``timeout`` seconds (default
    :data:`PROBE_TIMEOUT`): connect, send dask's handshake and read the peer's, at most
    :data:`HANDSHAKE_LIMIT` bytes, before anything else talks to it. A :class:`SchedulerError`
    says what answered instead. Addresses of other transports than ``tcp://`` (``tls://``...)
    are left to dask."""
    from distributed.comm.addressing import parse_address, parse_host_port

    timeout = PROBE_TIMEOUT if timeout is None else timeout
    try:
        scheme, loc = parse_address(address)
        host, port = parse_host_port(loc, 8786)
    except (ValueError, TypeError) as exc:
        raise SchedulerError(address, f"not an address ({exc}); expected e.g. "
                                      "tcp://HOST:8786") from None
    if scheme != "tcp":
        return
    deadline = time.monotonic() + timeout
    not_dask = "not a dask scheduler: "
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            sock.sendall(_handshake())
            (size,) = struct.unpack("Q", _receive(sock, 8, deadline))
            if not 16 <= size <= HANDSHAKE_LIMIT:
                raise _NotDask(f"its first message announces {size} bytes (a dask handshake "
                               f"has about 100)")
            _handshake_of(_receive(sock, size, deadline))
    except _NotDask as exc:
        raise SchedulerError(address, not_dask + str(exc)) from None
    except socket.timeout:
        raise SchedulerError(address, f"did not answer within {timeout:g} s (not a dask "
                                      "scheduler, or one too busy to answer)") from None
    except ConnectionRefusedError:
        raise SchedulerError(address, "connection refused (nothing listens there)") from None
    except OSError as exc:
        raise SchedulerError(address, f"cannot connect ({exc.strerror or exc})") from None


def _dashboard_works(link: str, timeout: float = 2.0) -> bool:
    """Whether ``link`` serves the dask dashboard from here: it answers within ``timeout`` and
    is not the page dask serves when bokeh, which draws the dashboard, is missing."""
    import urllib.request

    try:
        with urllib.request.urlopen(link, timeout=timeout) as page:
            return page.status == 200 and b"needs bokeh" not in page.read(4096)
    except (OSError, ValueError):
        return False


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
                 paths=(), files=(), notify=None):
        from distributed import Client, LocalCluster

        notify = notify or (lambda text: print(text, file=sys.stderr, flush=True))
        self.cluster = self.client = None
        self.scratch = None
        if scheduler:
            probe_scheduler(scheduler)
            try:
                self.client = Client(scheduler, timeout=f"{PROBE_TIMEOUT}s")
            except (OSError, TimeoutError) as exc:
                raise SchedulerError(scheduler, " ".join(str(exc).split())) from None
        else:
            # the workers' folders in one of ours, removed by close(); a Ctrl-C while the
            # cluster starts waits until it has started (and then stops the sweep): the
            # processes it starts inherit the blocked SIGINT, a terminal's Ctrl-C cannot kill
            # them half-started (they ignore Ctrl-C anyway, see _Setup); on this machine only
            # (the scheduler's HTTP server too: a free port on 127.0.0.1). Its processes log
            # only what is critical: a worker whose heartbeat meets the scheduler closing (a
            # Ctrl-C, or any close under load) logs an ERROR with a traceback, and what does go
            # wrong reaches the sweep anyway (a task's exception, or a lost run in the table)
            problem = cluster_limits(workers or default_workers())
            if problem:
                raise ValueError(f"{problem}; raise the limit, or run the sweep serially")
            self.scratch = tempfile.mkdtemp(prefix="flexpend_dask_")
            try:
                with _sigint_blocked():
                    self.cluster = LocalCluster(
                        n_workers=workers or default_workers(), processes=True,
                        threads_per_worker=1, host="127.0.0.1",
                        dashboard_address="127.0.0.1:0",
                        silence_logs=logging.CRITICAL, local_directory=self.scratch,
                        scheduler_kwargs={"local_directory": self.scratch})
                    self.client = Client(self.cluster)
            except BaseException:
                self.close()
                raise
        self.scheduler = scheduler
        try:
            if scheduler:
                self._wait_for_workers(notify)
            blobs = {file_name(f): Path(f).read_bytes() for f in files}
            self.client.register_plugin(_Setup([str(p) for p in paths], blobs,
                                               ignore_sigint=self.cluster is not None))
            info = self.client.scheduler_info()
        except BaseException:
            self.close()
            raise
        self.workers = len(info["workers"])
        link = self.client.dashboard_link if "dashboard" in info.get("services", {}) else None
        self.dashboard = link if link and _dashboard_works(link) else None

    def _wait_for_workers(self, notify):
        """A scheduler without workers: wait :data:`WORKER_WAIT` seconds for one, saying so."""
        if self.client.scheduler_info()["workers"]:
            return
        notify(f"the dask scheduler at {self.scheduler} has no workers; waiting up to "
               f"{WORKER_WAIT:g} s for one")
        try:
            self.client.wait_for_workers(1, timeout=WORKER_WAIT)
        except TimeoutError:
            raise SchedulerError(self.scheduler, f"no worker joined within {WORKER_WAIT:g} s "
                                                 f"(start workers with: dask worker "
                                                 f"{self.scheduler} --nthreads 1)") from None

    def describe(self) -> str:
        where = (f"the dask scheduler at {self.scheduler}" if self.scheduler
                 else "a dask LocalCluster")
        return f"{where}, {self.workers} worker process{'es' if self.workers != 1 else ''}"

    def dashboard_note(self) -> str | None:
        """``dask dashboard: <address>``, or None where it would not work: the scheduler serves
        none, bokeh is missing where it runs, or the address does not answer from here."""
        return f"dask dashboard: {self.dashboard}" if self.dashboard else None

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
        scratch, self.scratch = self.scratch, None
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def open_executor(workers: int | None = None, scheduler: str | None = None, *, paths=(),
                  files=(), notify=None) -> Executor:
    """The serial executor when neither ``workers`` nor ``scheduler`` is given, else a
    :class:`DaskExecutor` (a ``ValueError`` names a bad argument; a :class:`SchedulerError`, a
    ``ValueError`` too, a scheduler that does not answer as one or has no workers). ``notify``
    (default: print to stderr) gets the line saying that the executor waits for workers."""
    if workers is not None and scheduler:
        raise ValueError("give a number of workers (a LocalCluster) or a scheduler address, "
                         "not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers = {workers!r} is not allowed; allowed: an integer >= 1")
    if workers is None and not scheduler:
        return Executor()
    return DaskExecutor(workers, scheduler, paths=paths, files=files, notify=notify)
