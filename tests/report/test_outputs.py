"""The host side's outputs fail cleanly (issue 25): an ``--out`` in use by another run is refused,
a full disk is one line and exit 2 and destroys no earlier good file, the sweep journal never
ends on a torn row, and Ctrl-C is 130 at any moment with every temporary folder removed."""
import contextlib
import errno
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import flexpend, one_line_error
from orchestration.cli import main

ROOT = Path(__file__).resolve().parents[2]
RUN = ["run", "rigid_pd", "--set", "stop_time=1"]
SWEEP = ["sweep", "rigid_pd", "--values", "controller.kp=300,400", "--serial"]


def snapshot(folder: Path) -> dict:
    """name -> bytes of every file in ``folder``."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


# ---------------------------------------------------------------------- one run per --out
@contextlib.contextmanager
def held_lock(folder: Path):
    """Hold ``folder/.flexpend.lock`` as another flexpend process would (flock, exclusive)."""
    import fcntl

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / ".flexpend.lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        yield


@pytest.mark.skipif(sys.platform == "win32", reason="flock is POSIX")
@pytest.mark.parametrize("command", [RUN, SWEEP], ids=["run", "sweep"])
def test_an_out_in_use_by_another_run_is_refused_with_one_line(fmus, tmp_path, capsys,
                                                               command):
    out = tmp_path / "out"
    with held_lock(out):
        assert main([*command, "--set", "stop_time=1", "--out", str(out)]) == 2
        one_line_error(capsys.readouterr().err, str(out), "in use by another flexpend run")
        assert sorted(p.name for p in out.iterdir()) == [".flexpend.lock"]   # nothing written
    # released with the other run: the same command now runs, and releases it in turn
    assert main([*command, "--set", "stop_time=1", "--out", str(out)]) == 0
    with held_lock(out):
        pass


@pytest.mark.skipif(sys.platform == "win32", reason="flock is POSIX")
def test_the_lock_is_released_however_its_holder_ends(fmus, tmp_path, capsys):
    """A holder killed with SIGKILL (no clean-up of its own) leaves the folder free."""
    out = tmp_path / "out"
    out.mkdir()
    with subprocess.Popen(
            [sys.executable, "-c", "import sys; from orchestration.files import "
             "folder_lock\nwith folder_lock(sys.argv[1]):\n    print('held', flush=True); "
             "sys.stdin.read()", str(out)],
            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) as holder:
        try:
            assert holder.stdout.readline().strip() == "held"
            assert main([*RUN, "--out", str(out)]) == 2
            one_line_error(capsys.readouterr().err, f"(process {holder.pid})")
        finally:
            holder.kill()
    assert main([*RUN, "--out", str(out)]) == 0


# ---------------------------------------------------------------------- a full disk
@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB tmpfs (root on Linux; skipped elsewhere) and a function that fills it up."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if sys.platform != "linux" or os.geteuid() != 0 or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
            capture_output=True).returncode != 0:
        pytest.skip("needs to mount a small tmpfs (root on Linux)")

    def fill():
        fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        try:
            while True:
                os.write(fd, b"\0" * 65536)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
        finally:
            os.close(fd)
    try:
        yield mnt, fill
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_full_disk_is_one_line_exit_2_and_keeps_the_earlier_files(fmus, small_disk, capsys):
    mnt, fill = small_disk
    out = mnt / "out"
    assert main([*RUN, "--out", str(out)]) == 0
    before = snapshot(out)
    assert {"rigid_pd.csv", "summary.json"} <= set(before)
    capsys.readouterr()
    fill()
    assert main([*RUN, "--set", "controller.kp=400", "--out", str(out)]) == 2
    one_line_error(capsys.readouterr().err, "No space left on device")
    assert snapshot(out) == before            # every earlier file intact, no temporary left


def test_a_full_disk_in_a_sweep_keeps_the_table_and_a_whole_journal(fmus, small_disk, capsys):
    mnt, fill = small_disk
    out = mnt / "out"
    assert main([*SWEEP, "--set", "stop_time=1", "--out", str(out)]) == 0
    before = snapshot(out)
    assert {"sweep.json", "sweep.png", "runs.jsonl"} <= set(before)
    capsys.readouterr()
    fill()
    # the same sweep again (only the table, plot and record to write), then one with new runs
    for stop_time in (1, 2):
        assert main([*SWEEP, "--set", f"stop_time={stop_time}", "--out", str(out)]) == 2
        one_line_error(capsys.readouterr().err, "No space left on device")
        after = snapshot(out)
        journal = after.pop("runs.jsonl")
        assert after == {k: v for k, v in before.items() if k != "runs.jsonl"}
        # the journal keeps its rows and gains only whole ones (those the disk had room for)
        assert journal.startswith(before["runs.jsonl"]) and journal.endswith(b"\n")
        assert all(json.loads(line)["status"] == "ok" for line in journal.splitlines())


def test_a_journal_row_is_appended_whole_or_not_at_all(small_disk):
    """A row that the disk has room for only in part (it crosses into a page the full disk
    cannot give) is not left torn: the journal keeps its whole rows and says which file."""
    from orchestration.files import OutputError
    from orchestration.sweeps.engine import Journal

    mnt, fill = small_disk
    first = {"key": "a", "status": "ok", "pad": ""}
    first["pad"] = "x" * (4096 - 10 - len(json.dumps(first) + "\n"))   # ends 10 bytes short
    with Journal(mnt) as journal:
        journal.append(first)
    before = (mnt / "runs.jsonl").read_bytes()
    assert len(before) == 4086
    fill()
    with Journal(mnt) as journal, pytest.raises(OutputError, match="runs.jsonl"):
        journal.append({"key": "b", "status": "ok", "message": "y" * 100})
    assert (mnt / "runs.jsonl").read_bytes() == before
    assert Journal(mnt).read() == {"a": first}


def test_a_full_disk_keeps_the_reference_check_had_written(fmus, small_disk, capsys):
    """Rewriting a reference with more signals (a bigger file) on a full disk."""
    import shutil

    mnt, fill = small_disk
    ref = mnt / "ref"
    shutil.copytree(ROOT / "tests" / "reference" / "FlexiblePendulum", ref)
    before = snapshot(ref)
    fill()
    assert main(["check", fmus["FlexiblePendulum"], "--reference", str(ref), "--write-reference",
                 "--outputs", "x_o,x_dot,phi_o,omega_o,tip_deflection,eta_1,energy,phi"]) == 2
    one_line_error(capsys.readouterr().err, "FlexiblePendulum_ref.csv", "No space left on device")
    assert snapshot(ref) == before


def test_a_full_disk_keeps_the_earlier_ssp_export(fmus, small_disk, capsys):
    mnt, fill = small_disk
    archive = mnt / "rigid_pd.ssp"
    archive.write_bytes(b"an earlier archive")
    fill()
    assert main(["export", "rigid_pd", "--fmus", "python", "--out", str(archive)]) == 2
    one_line_error(capsys.readouterr().err, str(archive), "No space left on device")
    assert sorted(p.name for p in mnt.iterdir()) == ["filler", "rigid_pd.ssp"]
    assert archive.read_bytes() == b"an earlier archive"


# ---------------------------------------------------------------------- Ctrl-C
@pytest.fixture
def private_tmp(tmp_path):
    d = tmp_path / "tmp"
    d.mkdir()
    return d


def test_ctrl_c_after_the_command_while_it_cleans_up_is_130(fmus, private_tmp, tmp_path):
    """The Ctrl-C comes after the command's work, while the process's clean-ups at exit run
    (the moment a Ctrl-C after "100 %" exited with 0): the exit code is still 130."""
    driver = ("import atexit, os, signal\nreal = cli.main\n"
              "def main(argv=None):\n"
              "    code = real(argv)\n"
              "    atexit.register(os.kill, os.getpid(), signal.SIGINT)   # Ctrl-C at exit\n"
              "    return code\n"
              "cli.main = main")
    with flexpend([*RUN, "--out", tmp_path / "out"], private_tmp, driver=driver) as proc:
        out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and (tmp_path / "out" / "rigid_pd.csv").is_file()
    assert list(private_tmp.iterdir()) == []


def interrupt_when(proc, marker: str, *, group: bool = False) -> str:
    """Send SIGINT to ``proc`` (``group``: to its process group, as a terminal's Ctrl-C does) as
    soon as ``marker`` appears on its stderr; its whole stderr."""
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if marker in line and not any(marker in ln for ln in lines[:-1]):
            if group:
                os.killpg(proc.pid, signal.SIGINT)
            else:
                proc.send_signal(signal.SIGINT)
    proc.wait(timeout=300)
    return "".join(lines)


def whole_journal(out: Path) -> list:
    text = (out / "runs.jsonl").read_text() if (out / "runs.jsonl").exists() else ""
    assert text == "" or text.endswith("\n")
    return [json.loads(line) for line in text.splitlines()]


#: a driver: Ctrl-C while the third run of a sweep runs (in this process: a serial sweep)
CTRL_C_IN_THIRD_RUN = """
import os, signal
from orchestration.sweeps import engine
real, calls = engine.run_task, []
def run_task(task):
    calls.append(1)
    if len(calls) == 3:
        os.kill(os.getpid(), signal.SIGINT)
    return real(task)
engine.run_task = run_task
"""


def test_ctrl_c_on_a_serial_sweep_stops_it_and_removes_the_unpacked_fmus(fmus, private_tmp,
                                                                         tmp_path):
    out = tmp_path / "out"
    kps = ",".join(str(300 + 10 * i) for i in range(20))
    with flexpend(["sweep", "rigid_pd", "--values", f"controller.kp={kps}", "--serial",
                   "--out", out], private_tmp, driver=CTRL_C_IN_THIRD_RUN) as proc:
        _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "the same command continues the sweep" in err
    assert list(private_tmp.iterdir()) == []            # no flexpend_fmu_* folder
    assert [r["run"] for r in whole_journal(out)] == [0, 1, 2]  # the run under way finished


def test_ctrl_c_while_worker_processes_start_is_130_and_leaves_nothing(fmus, native,
                                                                       private_tmp, tmp_path):
    """A terminal's Ctrl-C (SIGINT to the whole process group: the client and the worker
    processes it is starting) as soon as the client has started a worker process (with a dask
    LocalCluster it crashed the start: a traceback, and dask's folders left in TMPDIR)."""
    psutil = pytest.importorskip("psutil")

    def a_worker_started(client):
        for child in client.children(recursive=True):
            with contextlib.suppress(psutil.Error):
                line = " ".join(child.cmdline())
                if "spawn_main" in line or "multiprocessing.forkserver" in line:
                    return True
        return False

    kps = ",".join(str(300 + 10 * i) for i in range(40))
    with flexpend(["sweep", "rigid_pd", "--values", f"controller.kp={kps}", "--workers", "2",
                   "--out", tmp_path / "out"], private_tmp, start_new_session=True) as proc:
        client = psutil.Process(proc.pid)
        while proc.poll() is None and not a_worker_started(client):
            psutil.wait_procs([client], timeout=0.005)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    for bad in ("Traceback", "leaked", "Error"):
        assert bad not in err, err
    assert list(private_tmp.iterdir()) == []            # no dask folder left
    whole_journal(tmp_path / "out")


def test_a_failed_check_leaves_no_unpacked_fmu(fmus, tmp_path, private_tmp, monkeypatch, capsys):
    """An FMU whose library does not load: fmpy's simulate_fmu raises and keeps the folder it
    unpacked the FMU into."""
    import tempfile
    import zipfile

    broken = tmp_path / "PDLowPass.fmu"
    with zipfile.ZipFile(fmus["PDLowPass"]) as src, zipfile.ZipFile(broken, "w") as dst:
        for info in src.infolist():
            dst.writestr(info, b"not a library" if info.filename.startswith("binaries/")
                         else src.read(info))
    monkeypatch.setenv("TMPDIR", str(private_tmp))
    monkeypatch.setattr(tempfile, "tempdir", str(private_tmp))
    assert main(["check", str(broken), "--reference", str(ROOT / "tests" / "reference")]) == 1
    assert "the FMU failed to simulate" in capsys.readouterr().out
    assert list(private_tmp.iterdir()) == []


@pytest.mark.parametrize("finished", [0, 1])
def test_an_interrupted_sweep_names_only_a_journal_that_holds_runs(finished, tmp_path,
                                                                   monkeypatch, capsys):
    """Issue 40, D6: interrupted before any run finished, the message named a runs.jsonl that
    did not exist; with a finished run it names the journal, which exists and holds it."""
    import orchestration.sweeps.job as job
    from orchestration.sweeps.engine import Journal

    def interrupted(*args, out=None, **kwargs):
        with Journal(out) as journal:           # opened, as a sweep opens it; a row if finished
            if finished:
                journal.append({"key": "a", "status": "ok"})
        raise KeyboardInterrupt

    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(job, "sweep", interrupted)
    assert main(["sweep", *SWEEP[1:], "--out", str(out)]) == 130
    err = capsys.readouterr().err
    named = [w for w in err.split() if "runs.jsonl" in w]
    assert bool(named) == bool(finished), err
    for name in named:
        assert Path(name.rstrip(";,")).read_text().strip(), err
