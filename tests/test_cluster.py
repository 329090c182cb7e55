"""flexpend sweep --scheduler: a peer that is not a dask scheduler (silent, HTTP, garbage, a huge
frame) or a scheduler without workers is one line and exit 2, within a bounded time
(orchestration/sweeps/executor.py). Everything listens on 127.0.0.1 only."""
import contextlib
import http.server
import socket
import struct
import threading

import pytest

from orchestration.cli import main
from orchestration.sweeps import executor

SWEEP = ["sweep", "flexible_pd_lowpass", "--values", "controller.kp=500,600",
         "--set", "stop_time=1"]


@contextlib.contextmanager
def fake_service(kind):
    """A service on 127.0.0.1 that is not a dask scheduler: its address."""
    if kind == "http":
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0),
                                                 http.server.BaseHTTPRequestHandler)
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"tcp://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()
            server.server_close()
        return
    listener = socket.create_server(("127.0.0.1", 0))
    held, stop = [], threading.Event()

    def serve():
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            held.append(conn)               # kept open: a silent peer holds the socket
            if kind == "garbage":
                conn.sendall(bytes(range(7, 250)) * 4)
            elif kind == "huge":            # a frame header announcing 2**62 bytes
                conn.sendall(struct.pack("Q", 2 ** 62) + b"\0" * 64)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        stop.set()
        listener.close()
        for conn in held:
            conn.close()


def closed_port() -> str:
    with socket.create_server(("127.0.0.1", 0)) as s:
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and "allocate" not in err, err
    lines = [l for l in err.splitlines() if l.startswith("flexpend: error:")]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("kind,fragment", [
    ("silent", "did not answer within 1 s"),
    ("http", "did not answer within 1 s"),
    ("garbage", "not a dask scheduler"),
    ("huge", "not a dask scheduler"),
])
def test_scheduler_that_is_not_dask_is_one_line_exit_2(kind, fragment, fmus, monkeypatch,
                                                       capsys, tmp_path):
    monkeypatch.setattr(executor, "PROBE_TIMEOUT", 1.0)
    with fake_service(kind) as address:
        code = main([*SWEEP, "--scheduler", address, "--out", str(tmp_path)])
    line = one_line_error(capsys)
    assert code == 2
    assert f"--scheduler {address}: " in line and fragment in line, line


def test_scheduler_nobody_listens_is_one_line_exit_2(fmus, capsys, tmp_path):
    address = closed_port()
    assert main([*SWEEP, "--scheduler", address, "--out", str(tmp_path)]) == 2
    assert "connection refused" in one_line_error(capsys)


def test_scheduler_without_workers_waits_with_a_message_then_one_line(fmus, monkeypatch,
                                                                      capsys, tmp_path):
    from distributed import LocalCluster

    monkeypatch.setattr(executor, "WORKER_WAIT", 1.0)
    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        code = main([*SWEEP, "--scheduler", address, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert f"the dask scheduler at {address} has no workers; waiting up to 1 s" in err, err
    assert "Traceback" not in err
    assert code == 2
    assert err.strip().splitlines()[-1] == (
        f"flexpend: error: --scheduler {address}: no worker joined within 1 s (start "
        f"workers with: dask worker {address} --nthreads 1)")
