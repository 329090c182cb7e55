"""The local executor (:class:`~orchestration.sweeps.executor.ProcessExecutor`): every task once,
with its own result, however the tasks are batched; an exception in a task raises; a task that
kills its worker process comes back lost, alone, and the executor goes on; the workers leave
Ctrl-C to the client; the rule that starts them by default."""
import os
import signal
import time

import pytest

from orchestration.sweeps import executor
from orchestration.sweeps.executor import ProcessExecutor, TaskLost


def _square(i):
    return i * i


def _pid(_):
    time.sleep(0.001)                 # long enough that one worker does not take a whole map
    return os.getpid()


def _die_on_three(i):
    if i == 3:
        os._exit(1)                 # a crash inside an FMU takes its worker process with it
    return i * i


def _raise_on_two(i):
    if i == 2:
        raise ArithmeticError("task 2 is wrong")
    return i


@pytest.fixture(scope="module")
def two():
    with ProcessExecutor(2) as ex:
        yield ex


@pytest.mark.parametrize("batch", [1, 3, 50])
def test_every_task_once_with_its_result(two, batch):
    out = list(two.map(_square, range(20), batch=batch))
    assert sorted(i for i, _ in out) == list(range(20))
    assert dict(out) == {i: i * i for i in range(20)}


def test_the_tasks_run_in_the_worker_processes(two):
    pids = {pid for _, pid in two.map(_pid, range(40))}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    assert two.describe() == "2 worker processes on this machine"


def test_an_exception_in_a_task_raises_in_map(two):
    with pytest.raises(ArithmeticError, match="task 2 is wrong"):
        dict(two.map(_raise_on_two, range(5)))
    assert dict(two.map(_square, range(3))) == {0: 0, 1: 1, 2: 4}     # and it goes on


@pytest.mark.parametrize("batch", [1, 2])
def test_a_task_that_kills_its_process_is_lost_alone(two, batch):
    out = dict(two.map(_die_on_three, range(8), batch=batch))
    lost = {i for i, v in out.items() if isinstance(v, TaskLost)}
    # the task that crashed (with its batch), and nothing else, even what was in flight with it
    assert lost == ({3} if batch == 1 else {2, 3})
    assert "worker process died" in out[3].message
    assert {i: v for i, v in out.items() if i not in lost} == \
        {i: i * i for i in range(8) if i not in lost}
    assert dict(two.map(_square, range(4))) == {0: 0, 1: 1, 2: 4, 3: 9}


@pytest.mark.parametrize("nth", [1, 3])
def test_a_worker_that_dies_between_two_submissions_loses_nothing(two, nth):
    """A worker that dies after the map last waited (here: killed just before the ``nth``
    submission, which then finds the pool broken; seen under load, where the map raised
    BrokenProcessPool): the task not sent goes to the next pool, those in flight are run again
    alone, and every task comes back once with its result."""
    dict(two.map(_square, range(2)))           # the pool is up
    pool = two._pool
    real, calls = pool.submit, []

    def submit(*a, **k):
        calls.append(1)
        if len(calls) == nth:
            os.kill(next(iter(pool._processes.values())).pid, signal.SIGKILL)
            deadline = time.monotonic() + 60
            while not pool._broken and time.monotonic() < deadline:
                time.sleep(0.01)
            assert pool._broken
        return real(*a, **k)

    pool.submit = submit
    out = list(two.map(_square, range(8)))
    assert sorted(i for i, _ in out) == list(range(8))
    assert dict(out) == {i: i * i for i in range(8)}
    assert two._pool is not pool
    assert dict(two.map(_square, range(4))) == {0: 0, 1: 1, 2: 4, 3: 9}


def test_the_workers_leave_ctrl_c_to_the_client(two):
    pids = set()
    for _ in range(50):               # until both workers took a task (on a busy machine one
        pids |= {pid for _, pid in two.map(_pid, range(20))}     # can take a whole map)
        if len(pids) == 2:
            break
    assert len(pids) == 2
    for pid in pids:
        os.kill(pid, signal.SIGINT)
    assert dict(two.map(_square, range(6))) == {i: i * i for i in range(6)}
    assert {pid for _, pid in two.map(_pid, range(20))} <= pids        # the same processes


def test_an_interrupted_map_ends_what_is_in_flight_and_the_next_map_starts_again():
    with ProcessExecutor(2) as ex:
        it = ex.map(_square, range(100))
        next(it)
        it.close()                      # the consumer stops (a Ctrl-C in the sweep's loop)
        assert dict(ex.map(_square, range(5))) == {i: i * i for i in range(5)}


def test_a_bad_number_of_workers_is_refused():
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="allowed: an integer >= 1"):
            ProcessExecutor(bad)


def test_the_default_rule_for_worker_processes():
    """``local_workers`` is the break-even rule with the processes' start and per-task cost:
    start + ceil(runs / W) (t + overhead) < runs t."""
    t, start, over = 0.025, executor.PROCESS_START, executor.PROCESS_OVERHEAD
    even = start / (t / 2 - over / 2)                 # 2 cores: about 83 runs of 25 ms
    assert executor.local_workers(int(even) - 2, t, cores=2) == 0
    assert executor.local_workers(int(even) + 3, t, cores=2) == 2
    assert executor.local_workers(10_000, t, cores=1) == 0
    assert executor.local_workers(3, 1000.0, cores=8) == 3


def test_the_workers_end_when_their_client_dies(tmp_path):
    """A client killed (or crashed) must not leave its worker processes behind: they would run
    forever and keep its output pipes open."""
    import subprocess
    import sys
    import time

    code = ("import os, sys\n"
            "from orchestration.sweeps.executor import ProcessExecutor\n"
            "def pid(_): return os.getpid()\n"
            "if __name__ == '__main__':\n"
            "    ex = ProcessExecutor(2)\n"
            "    print(*sorted({p for _, p in ex.map(pid, range(20))}), flush=True)\n"
            "    os.kill(os.getpid(), 9)\n")
    script = tmp_path / "client.py"
    script.write_text(code)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "TMPDIR": str(tmp)})
    assert proc.returncode == -9, proc.stderr
    pids = [int(p) for p in proc.stdout.split()]
    assert pids
    deadline = time.monotonic() + 60
    while any(executor._alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(executor._alive(p) for p in pids)
    # and the first to see it gone removed their scratch folder
    assert not [p.name for p in tmp.iterdir() if p.name.startswith("flexpend_")]


def test_a_sweep_on_worker_processes_leaves_no_temporary_folder(tmp_path):
    """The workers unpack the FMUs into their executor's scratch folder, which the client
    removes: a worker process runs no atexit handler, and each sweep left its unpacked FMUs
    (two per worker) in the temporary folder."""
    import subprocess
    import sys

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", "-q", "sweep", "rigid_pd",
                           "--set", "stop_time=0.2", "--values", "controller.kp=300,400,500",
                           "--workers", "2", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "TMPDIR": str(tmp)})
    assert proc.returncode == 0, proc.stderr
    assert "2 worker processes" in (tmp_path / "out" / "sweep.json").read_text()
    assert sorted(p.name for p in tmp.iterdir()) == []


def test_a_long_temporary_folder_falls_back_to_spawn(tmp_path):
    """The fork server's socket lives in TMPDIR: under a long TMPDIR its path is longer than a
    Unix socket's 108 bytes ("AF_UNIX path too long", a traceback before). The workers then
    start by spawn, and run the same tasks."""
    import subprocess
    import sys

    tmp = tmp_path / ("t" * 120)
    tmp.mkdir()
    code = ("from orchestration.sweeps.executor import ProcessExecutor\n"
            "def sq(i): return i * i\n"
            "if __name__ == '__main__':\n"
            "    with ProcessExecutor(2) as ex:\n"
            "        print(sorted(dict(ex.map(sq, range(5))).items()))\n")
    script = tmp_path / "client.py"
    script.write_text(code)
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=300, env={**__import__("os").environ, "TMPDIR": str(tmp)})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[(0, 0), (1, 1), (2, 4), (3, 9), (4, 16)]"
    assert "Traceback" not in proc.stderr
