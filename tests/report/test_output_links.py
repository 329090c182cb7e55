"""No output is written through a link (issue 40, D1): a symbolic link planted at any name that
``run``, ``sweep``, ``design``, ``export``, ``check`` and ``build`` write, the lock and the sweep's
journal included, leaves its target as it was, and the command says what it refused (one line,
exit 2). The names are those each command writes into an empty folder, found by running it once:
a name added later is covered without touching this file."""
import os
import shutil
from pathlib import Path

import pytest

from conftest import one_line_error
from orchestration.cli import main
from orchestration.files import LOCK_FILE, OutputError, open_in_place

ROOT = Path(__file__).resolve().parents[2]
QUICK_DESIGN = ["--set", "design.levels=2", "--set", "design.check_levels=2",
                "--set", "design.n_cutoffs=9", "--set", "design.n_dampings=4"]


def _commands(fmus):
    """``name -> (argv for an output folder, whether it holds the folder's lock, a setup of
    the folder)``."""
    def reference(folder: Path):
        shutil.copytree(ROOT / "tests" / "reference" / "FlexiblePendulum", folder,
                        dirs_exist_ok=True)

    return {
        "run": (lambda o: ["run", "rigid_pd", "--set", "stop_time=0.2", "--out", str(o)], True,
                None),
        "sweep": (lambda o: ["sweep", "rigid_pd", "--set", "stop_time=0.2", "--values",
                             "controller.kp=300,400", "--serial", "--out", str(o)], True, None),
        "design": (lambda o: ["design", *QUICK_DESIGN, "--out", str(o)], True, None),
        "export": (lambda o: ["export", "rigid_pd", "--out", str(o / "scene.ssp")], False, None),
        "check": (lambda o: ["check", fmus["FlexiblePendulum"], "--reference", str(o),
                             "--write-reference", "--plot", str(o / "check.png")], False,
                  reference),
    }


def _written(argv, setup, folder: Path) -> list:
    """The files ``argv`` writes into the empty ``folder`` (relative names)."""
    folder.mkdir()
    if setup:
        setup(folder)
    before = {p for p in folder.rglob("*")}
    assert main(["-q", *argv(folder)]) == 0
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")
                  if p.is_file() and p not in before or p.name.endswith("_ref.csv"))


@pytest.mark.parametrize("command", ["run", "sweep", "design", "export", "check"])
def test_a_link_at_any_output_name_is_refused_and_its_target_untouched(command, fmus, tmp_path,
                                                                        capsys):
    argv, locks, setup = _commands(fmus)[command]
    names = _written(argv, setup, tmp_path / "first")
    assert names, "the command wrote nothing"
    if locks:
        names.append(LOCK_FILE)
    capsys.readouterr()
    for i, name in enumerate(names):
        folder = tmp_path / f"out{i}"
        folder.mkdir()
        if setup:
            setup(folder)
        link = folder / name
        link.parent.mkdir(parents=True, exist_ok=True)
        # a name the command also reads (check's reference) links to a file it can read
        data = link.read_bytes() if link.exists() else b"precious data\n"
        victim = tmp_path / f"victim{i}.txt"
        victim.write_bytes(data)
        link.unlink(missing_ok=True)
        link.symlink_to(victim)
        assert main(["-q", *argv(folder)]) == 2, name
        one_line_error(capsys.readouterr().err, str(link), "is a link")
        assert victim.read_bytes() == data, name
        assert link.is_symlink() and Path(os.readlink(link)) == victim, name


def test_a_lock_or_journal_that_is_a_hard_link_is_refused(tmp_path, capsys):
    """A second name of a file elsewhere would be truncated (the lock) or appended to (the
    journal) through it: refused, the file as it was."""
    victim = tmp_path / "victim.txt"
    victim.write_bytes(b"precious data\n")
    for i, name in enumerate((LOCK_FILE, "runs.jsonl")):
        out = tmp_path / f"out{i}"
        out.mkdir()
        os.link(victim, out / name)
        assert main(["-q", "sweep", "rigid_pd", "--set", "stop_time=0.2", "--values",
                     "controller.kp=300,400", "--serial", "--out", str(out)]) == 2
        one_line_error(capsys.readouterr().err, name, "hard link")
        assert victim.read_bytes() == b"precious data\n"


def test_open_in_place_refuses_what_is_not_a_file_of_its_own(tmp_path):
    """The primitive itself: a symbolic link (to a file, dangling), a hard link, a FIFO are
    refused; a new file and an existing one of one name are opened."""
    target = tmp_path / "target"
    target.write_text("x")
    (tmp_path / "sym").symlink_to(target)
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    os.link(target, tmp_path / "hard")
    os.mkfifo(tmp_path / "fifo")
    for name in ("sym", "dangling", "hard", "fifo"):
        with pytest.raises(OutputError, match=name):
            open_in_place(tmp_path / name, os.O_RDWR | os.O_CREAT)
    assert not (tmp_path / "nowhere").exists() and target.read_text() == "x"
    for name in ("new", "target2"):
        if name == "target2":
            (tmp_path / name).write_text("y")
        os.close(open_in_place(tmp_path / name, os.O_RDWR | os.O_CREAT))


def test_the_exported_archive_has_the_mode_of_the_other_outputs(tmp_path):
    """An SSP gets the mode every other output gets (0644), whatever mkstemp made (0600)."""
    assert main(["-q", "export", "rigid_pd", "--out", str(tmp_path / "a.ssp")]) == 0
    assert main(["-q", "run", "rigid_pd", "--set", "stop_time=0.1", "--out", str(tmp_path)]) == 0
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir() if p.is_file()}
    assert modes["a.ssp"] == modes["summary.json"] == 0o644, modes


@pytest.mark.slow
def test_a_link_at_a_built_fmus_name_is_refused(native, native3, tmp_path, capsys):
    """``flexpend build --out``: a copy of the session's up-to-date native FMUs, with a link in
    place of one of them: that one is rebuilt (about 4 s), and refused; its target is untouched.
    The first FMU of each FMI version."""
    built = Path(native["FlexiblePendulum"]).parents[1]            # <out>/native
    names = [str(p.relative_to(built.parent)) for p in
             (sorted(built.glob(f"fmi{v}/*.fmu"))[0] for v in (2, 3))]
    for i, name in enumerate(names):
        out = tmp_path / f"out{i}"
        shutil.copytree(built, out / "native")
        victim = tmp_path / f"victim{i}"
        victim.write_bytes(b"precious data\n")
        (out / name).unlink()
        (out / name).symlink_to(victim)
        assert main(["-q", "build", "--fmus", "native", "--out", str(out)]) == 2, name
        one_line_error(capsys.readouterr().err, str(out / name), "is a link")
        assert victim.read_bytes() == b"precious data\n"
