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

__all__ = ["Executor", "ProcessExecutor", "DaskExecutor", "TaskLost", "SchedulerError",
           "open_executor", "probe_scheduler", "worker_file", "default_workers", "cluster_workers", "file_name",
           "scratch_dir", "PROBE_TIMEOUT", "WORKER_WAIT", "CLUSTER_START", "TASK_OVERHEAD",
           "PROCESS_START", "PROCESS_OVERHEAD", "local_workers", "process_limits"]

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
#: Seconds a :class:`ProcessExecutor` takes before its first result: a fork server that imports
#: the runs' modules once, then its worker processes (a sweep's first run came 0.3 s later than
#: serially on 2 cores; the rest a margin: docs/sweeps.md).
PROCESS_START = 1.0
#: What a task costs on a :class:`ProcessExecutor` beyond its own work: sending the task and its
#: row through a pipe, the journal, the client's share of the cores (s; 1000 runs of 24 ms took
#: 28 ms each on 2 workers beside the client, at load 2: docs/sweeps.md).
PROCESS_OVERHEAD = 0.004
#: Tasks sent ahead to each worker process of a :class:`ProcessExecutor` (what a crash or a
#: Ctrl-C leaves in flight).
PROCESS_AHEAD = 2


def cluster_workers(tasks: int, task_seconds: float, cores: int | None = None, *,
                    start: float = CLUSTER_START, overhead: float = TASK_OVERHEAD) -> int:
    """How many workers to start for ``tasks`` independent tasks of about ``task_seconds`` each,
    on ``cores`` cores (default :func:`default_workers`); 0 where they cannot win, and the
    tasks should run serially here. ``start`` and ``overhead``: what the executor costs before
    its first result and per task (by default a dask LocalCluster's; :func:`local_workers`
    gives the rule of a :class:`ProcessExecutor`).

    With ``W = min(cores, tasks)`` workers they win when they end before the serial runs::

        start + ceil(tasks / W) * (task_seconds + overhead)  <  tasks * task_seconds

    e.g. a LocalCluster on 2 cores, 4 runs of 0.6 s: 6.2 s against 2.4 s, serial (measured:
    8.2 s against 2.5 s); 64 runs of 0.69 s: 28 s against 44 s, 2 workers."""
    cores = default_workers() if cores is None else cores
    workers = min(cores, tasks)
    if workers < 2:
        return 0
    parallel = start + math.ceil(tasks / workers) * (task_seconds + overhead)
    return workers if parallel < tasks * task_seconds else 0


def local_workers(tasks: int, task_seconds: float, cores: int | None = None) -> int:
    """:func:`cluster_workers` for a :class:`ProcessExecutor` (:data:`PROCESS_START`,
    :data:`PROCESS_OVERHEAD`): the worker processes a sweep starts on this machine by
    default, 0 to run serially."""
    return cluster_workers(tasks, task_seconds, cores, start=PROCESS_START,
                           overhead=PROCESS_OVERHEAD)


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




#: A :class:`ProcessExecutor` worker's scratch folder (its client's, shared by its workers).
_SCRATCH: list = []


def _process_setup(paths, client: int, scratch: str | None = None):
    """A :class:`ProcessExecutor` worker starts: Ctrl-C is its client's to handle (it shares the
    terminal), ``paths`` go first on ``sys.path``, what it unpacks goes into ``scratch`` (the
    client removes it: a worker process runs no ``atexit`` handler), and a watchdog ends the
    worker when the client process ``client`` is gone (killed, or crashed: nothing else would
    end it, and it would keep the client's output pipes open), removing ``scratch`` first."""
    _SCRATCH[:] = [scratch] if scratch else []
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:                  # not the main thread: leave it
        pass
    for p in reversed(paths):
        if p not in sys.path:
            sys.path.insert(0, p)
    threading.Thread(target=_watch, args=(client,), daemon=True,
                     name="flexpend-client-watch").start()


#: Seconds between two looks of a worker's watchdog at its client.
WATCH_EVERY = 0.5


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True                     # no /proc: kill(0) is all we know


def _watch(client: int):
    while _alive(client):
        time.sleep(WATCH_EVERY)
    for folder in _SCRATCH:             # the client cannot remove it any more
        shutil.rmtree(folder, ignore_errors=True)
    os._exit(1)


def _ready():
    return os.getpid()


class ProcessExecutor(Executor):
    """Tasks on ``workers`` processes of this machine (default: one per core), each keeping what
    its tasks leave it (the FMUs extracted and instantiated once, :func:`~orchestration.sweeps.
    engine.run_task`): the local executor, with no scheduler between the tasks and the client.

    The processes are forked from a fork server that has imported the sweep's modules
    (``forkserver``; ``spawn`` where there is none), never from this process, whatever threads
    or FMUs it holds. They ignore Ctrl-C: the client handles it, keeps what finished and ends
    them. A task that raises in ``fn`` raises in :meth:`map`; a worker process that dies (a crash
    inside an FMU) breaks the pool: the tasks that were in flight are run again one at a time,
    each in a process of its own, so that only the one that kills its process comes back as
    :class:`TaskLost`, and the pool starts again for the rest.

    ``paths``: folders put first on every worker's ``sys.path`` (for task functions defined in
    scripts, e.g. ``bench/``)."""

    kind = "processes"
    #: the modules the fork server imports once for every worker
    PRELOAD = ("orchestration.sweeps.engine",)

    def __init__(self, workers: int | None = None, *, paths=()):
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                    or workers < 1):
            raise ValueError(f"workers = {workers!r} is not allowed; allowed: an integer >= 1")
        self.workers = workers or default_workers()
        problem = process_limits(self.workers)
        if problem:
            raise ValueError(f"{problem}; raise the limit, or run serially")
        self.paths = [str(p) for p in paths]
        self._pool = None
        self.scratch = tempfile.mkdtemp(prefix="flexpend_workers_")
        try:
            self._pool = self._start(self.workers)
        except BaseException:
            self._remove_scratch()
            raise

    def _contexts(self):
        """The start methods to try, best first: a fork server that has imported the runs'
        modules, then ``spawn`` (where there is no fork server, or it cannot start: its socket
        lives in the temporary folder, and a long ``TMPDIR`` makes its path too long)."""
        import multiprocessing

        if "forkserver" in multiprocessing.get_all_start_methods():
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(list(self.PRELOAD))
            yield ctx
        yield multiprocessing.get_context("spawn")

    def _start(self, workers: int):
        """A pool of ``workers`` processes, started. Ctrl-C is held back meanwhile (no process
        is left half-started; the processes started inherit it held back, and a worker ignores
        it from its first moment), and a Ctrl-C then ends the pool before it is raised."""
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures.process import BrokenProcessPool

        pool = None
        try:
            with _sigint_blocked():
                for ctx in self._contexts():
                    pool = ProcessPoolExecutor(workers, mp_context=ctx,
                                               initializer=_process_setup,
                                               initargs=(self.paths, os.getpid(),
                                                         self.scratch))
                    try:
                        for f in [pool.submit(_ready) for _ in range(workers)]:
                            f.result()
                        break
                    except OSError:
                        self._end(pool)
                        pool = None
                        if ctx.get_start_method() == "spawn":
                            raise
                    except BrokenProcessPool:
                        raise RuntimeError(
                            "the worker processes did not start (each imports the main module "
                            "again: a script that starts them must run its code under "
                            "`if __name__ == \"__main__\":`)") from None
        except BaseException:
            if pool is not None:
                self._end(pool)
            raise
        return pool

    @staticmethod
    def _end(pool):
        """Stop ``pool`` now: what is queued is dropped, its processes are ended."""
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            with contextlib.suppress(Exception):
                proc.terminate()
        for proc in procs:
            with contextlib.suppress(Exception):
                proc.join(5)

    def describe(self) -> str:
        return f"{self.workers} worker process{'es' if self.workers != 1 else ''} on this machine"

    def map(self, fn, items, batch: int = 1):
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        items = list(items)
        batch = max(1, int(batch))
        chunks = [list(range(i, min(i + batch, len(items)))) for i in range(0, len(items), batch)]
        queue = list(range(len(chunks)))[::-1]           # popped from the end: in order
        flight: dict = {}
        if self._pool is None:                  # ended by an interrupted map
            self._pool = self._start(self.workers)
        try:
            while queue or flight:
                while queue and len(flight) < PROCESS_AHEAD * self.workers:
                    c = queue.pop()
                    try:
                        flight[self._pool.submit(_run_batch, fn,
                                                 [items[i] for i in chunks[c]])] = c
                    except BrokenProcessPool:
                        # a worker died since the last wait: this task was not sent, it goes
                        # first to the next pool; those in flight fail with the pool (below)
                        queue.append(c)
                        if not flight:
                            self._end(self._pool)
                            self._pool = None
                            self._pool = self._start(self.workers)
                        break
                if not flight:
                    continue
                done, _ = wait(flight, return_when=FIRST_COMPLETED)
                broken = []
                for fut in done:
                    c = flight.pop(fut)
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        broken.append(c)
                        continue
                    yield from zip(chunks[c], result)
                if broken:
                    # every task in flight went down with the pool: each is run again alone
                    suspects = sorted(broken + list(flight.values()))
                    flight.clear()
                    self._end(self._pool)
                    self._pool = None
                    for c in suspects:
                        yield from zip(chunks[c], self._alone(fn, [items[i] for i in chunks[c]]))
                    self._pool = self._start(self.workers)
        finally:                                 # interrupted or abandoned: end what is in flight
            if flight and self._pool is not None:
                self._end(self._pool)
                self._pool = None

    def _alone(self, fn, chunk):
        """``fn`` on ``chunk`` in a process of its own: the results, or a :class:`TaskLost` per
        item when that process dies too."""
        from concurrent.futures.process import BrokenProcessPool

        pool = self._start(1)
        try:
            return pool.submit(_run_batch, fn, chunk).result()
        except BrokenProcessPool:
            return [TaskLost("its worker process died (a crash inside an FMU?); the others' "
                             "runs went on")] * len(chunk)
        finally:
            self._end(pool)

    def close(self):
        pool, self._pool = getattr(self, "_pool", None), None
        try:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
        finally:
            self._remove_scratch()

    def _remove_scratch(self):
        """Remove the workers' scratch folder (the FMUs they unpacked), once."""
        scratch, self.scratch = getattr(self, "scratch", None), None
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def worker_file(name: str, default):
    """The path of file ``name`` sent to this worker by :class:`DaskExecutor` (``files=``), or
    ``default`` when the task runs elsewhere (serially or on a :class:`ProcessExecutor`: the
    client's own path)."""
    plugin = sys.modules.get("orchestration.sweeps.dask_setup")   # imported in dask workers
    return default if plugin is None else plugin.WORKER_FILES.get(name, default)


def scratch_dir() -> str | None:
    """The scratch folder of the :class:`ProcessExecutor` worker this runs on, or the local
    folder of the dask worker (dask removes it with the worker), or None outside a worker."""
    if _SCRATCH:
        return _SCRATCH[0]
    if "distributed" not in sys.modules:       # not imported: this is no dask worker
        return None
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


#: What a :class:`ProcessExecutor` of W worker processes needs: open files in the client (the
#: pipes to its workers and to the fork server), and address space in each process (numpy,
#: fmpy and the FMUs of a run).
PROCESS_FILES_BASE, PROCESS_FILES_PER_WORKER = 24, 4
PROCESS_ADDRESS_SPACE = 1 << 30


def process_limits(workers: int) -> str | None:
    """:func:`cluster_limits` for a :class:`ProcessExecutor` of ``workers`` processes: the soft
    limit of open files raised where the hard one allows, else, or where the address space
    (``ulimit -v``) is too small for a worker, the problem in words (None when it fits)."""
    import resource

    need = PROCESS_FILES_BASE + PROCESS_FILES_PER_WORKER * workers
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard == resource.RLIM_INFINITY or hard >= need:
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        else:
            return (f"too few file handles for {workers} worker processes: they need about "
                    f"{need}, this process may open {hard} (ulimit -n)")
    space = resource.getrlimit(resource.RLIMIT_AS)[0]
    if space != resource.RLIM_INFINITY and space < PROCESS_ADDRESS_SPACE:
        return (f"too little memory for worker processes: each needs about "
                f"{PROCESS_ADDRESS_SPACE >> 20} MiB of address space, this process may use "
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
            # them half-started (they ignore Ctrl-C anyway, see dask_setup.Setup); on this machine only
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
            from .dask_setup import Setup

            self.client.register_plugin(Setup([str(p) for p in paths], blobs,
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
                  files=(), notify=None, dask: bool = False) -> Executor:
    """The serial executor when neither ``workers`` nor ``scheduler`` is given; a
    :class:`ProcessExecutor` of ``workers`` processes on this machine; a :class:`DaskExecutor`
    on the cluster of ``scheduler``, or with ``dask=True`` on a new LocalCluster of ``workers``
    processes (a ``ValueError`` names a bad argument; a :class:`SchedulerError`, a
    ``ValueError`` too, a scheduler that does not answer as one or has no workers). ``notify``
    (default: print to stderr) gets the line saying that the executor waits for workers."""
    if workers is not None and scheduler:
        raise ValueError("give a number of workers (processes here) or a scheduler address, "
                         "not both")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers = {workers!r} is not allowed; allowed: an integer >= 1")
    if scheduler or dask:
        return DaskExecutor(workers, scheduler, paths=paths, files=files, notify=notify)
    if workers is None:
        return Executor()
    return ProcessExecutor(workers, paths=paths)
