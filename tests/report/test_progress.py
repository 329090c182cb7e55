"""Progress on every long command and function (:mod:`orchestration.report.progress`): the bar
and its lines, ``--quiet``, and the API's one ``progress=`` argument.

No test depends on timing: ``FLEXPEND_PROGRESS_DELAY=0`` shows every bar at once, and the
scenes are short (``stop_time = 0.2``)."""
import io
import json
import math
import re

import pytest

import orchestration as fp
from orchestration import api
from orchestration.cli import main
from orchestration.report import progress as pg
from orchestration.scene.schema import load_scene
from orchestration.studies.fidelity import available_ladder

SHORT = ["--set", "stop_time=0.2"]
AUTO = ["--set", "plant.fidelity=auto", *SHORT]
#: a progress line written to a stream that is not a terminal
LINE = re.compile(r"^(?P<label>.*): (?P<pct>\d+) % after \d+\.\d s$")


@pytest.fixture(autouse=True)
def no_delay(monkeypatch):
    monkeypatch.setenv(pg.DELAY_ENV, "0")


def progress_lines(err: str) -> list:
    """``[(label, percent)]`` of the progress lines in ``err``, in order."""
    return [(m["label"], int(m["pct"])) for m in map(LINE.match, err.splitlines()) if m]


def steady(out: str) -> str:
    """``out`` without what changes from run to run (times in seconds)."""
    return re.sub(r"\d[\d.e+-]* s\b", "# s", out)


class Recorder:
    """A ``progress(fraction, label)`` callable that keeps every call."""

    def __init__(self):
        self.calls = []

    def __call__(self, fraction, label):
        assert isinstance(fraction, float) and isinstance(label, str) and label
        self.calls.append((fraction, label))

    @property
    def fractions(self):
        return [f for f, _ in self.calls]

    def check_complete(self):
        f = self.fractions
        assert f, "no progress reported"
        assert all(0.0 <= x <= 1.0 for x in f), f
        assert all(a <= b for a, b in zip(f, f[1:])), f"decreasing: {f}"
        assert f[-1] == 1.0, f


def fake_compile(monkeypatch):
    """The native build without a compiler: each binary is a few bytes (the build's steps and
    progress are what is tested here, not the binaries)."""
    from orchestration.export import native_fmus

    monkeypatch.setattr(native_fmus, "_compile", lambda b, plat, gen, tmp: (
        native_fmus._binary(b.name, b.fmi_version, plat), b"not a binary", "fake-cc"))


# ---------------------------------------------------------------------- the bar
class Tty(io.StringIO):
    def isatty(self):
        return True


def test_a_bar_off_a_terminal_prints_quarters_and_each_new_label():
    out = io.StringIO()
    bar = pg.Progress("scene", out, delay=0.0)
    for f in (0.1, 0.3, 0.3):
        bar(f)
    bar(0.4, "scene: second rung")
    for f in (0.6, 0.9, 1.0):
        bar(f)
    assert progress_lines(out.getvalue()) == [
        ("scene", 10), ("scene", 25), ("scene: second rung", 40), ("scene: second rung", 50),
        ("scene: second rung", 75), ("scene: second rung", 100)]


def test_a_bar_says_nothing_after_100_percent():
    out = io.StringIO()
    bar = pg.Progress("scene", out, delay=0.0)
    bar(1.0, "scene: the reference")
    bar(1.0, "scene")
    assert progress_lines(out.getvalue()) == [("scene: the reference", 100)]


def test_a_bar_on_a_terminal_redraws_and_starts_a_new_line_for_a_new_label():
    out = Tty()
    bar = pg.Progress("scene", out, delay=0.0)
    bar(0.5)
    bar(0.6, "scene: next rung")
    bar(1.0)
    lines = out.getvalue().split("\n")
    assert len(lines) == 3 and lines[-1] == ""
    assert lines[0].startswith("\rscene [") and " 50.0 %" in lines[0]
    assert lines[1].startswith("\rscene: next rung [") and lines[1].count("\r") == 2
    assert " 100.0 %" in lines[1].split("\r")[-1]


def test_a_terminal_line_keeps_the_label_whole_within_the_width():
    bar = pg.Progress("flexible_pd: nonlinear rung (2 of 4)", Tty(), delay=0.0)
    for columns in (120, 80, 66):
        line = bar._line(0.5, 3.0, columns)
        assert line.startswith("flexible_pd: nonlinear rung (2 of 4) [") and len(line) <= columns
        assert " 50.0 % 3.0 s" in line
    assert "s left" in bar._line(0.5, 3.0, 120) and "s left" not in bar._line(0.5, 3.0, 66)
    bar.label = "flexible_pd: " + "x" * 200
    line = bar._line(0.5, 3.0, 80)
    assert len(line) <= 80 and line.startswith("flexible_pd: xxx") and "... [" in line


def test_the_delay_is_set_by_the_environment(monkeypatch):
    for text, seconds in (("0", 0.0), ("2.5", 2.5), ("-1", 1.0), ("soon", 1.0), ("nan", 1.0)):
        monkeypatch.setenv(pg.DELAY_ENV, text)
        assert pg.delay_seconds() == seconds
    monkeypatch.delenv(pg.DELAY_ENV)
    assert pg.delay_seconds() == pg.DEFAULT_DELAY == 1.0
    monkeypatch.setenv(pg.DELAY_ENV, "1e9")              # not shown before the delay
    out = io.StringIO()
    bar = pg.Progress("scene", out)
    bar(0.5)
    bar(1.0)
    assert out.getvalue() == ""


def test_quiet_silences_bars_and_notes(capsys):
    with pg.quiet():
        bar = pg.Progress("scene", delay=0.0)
        bar(1.0)
        pg.note("chatter")
    assert capsys.readouterr().err == ""
    pg.note("chatter")
    assert capsys.readouterr().err == "chatter\n"


def test_a_sink_never_goes_back_and_steps_share_the_whole():
    rec = Recorder()
    sink = pg.sink_for(rec, "whole")
    steps = pg.Steps(sink, 4)
    first = steps.part(1, "first")
    first(0.5)
    first(0.25)                                  # less than before: not passed on as less
    first(math.nan)
    second = steps.part(3, "second")
    second(1 / 3, "second: detail")
    steps.finish()
    assert rec.calls == [(0.0, "first"), (0.125, "first"), (0.25, "second"),
                         (0.25 + 0.75 / 3, "second: detail"), (1.0, "second: detail")]
    assert pg.Steps(None, 3).part(1, "x") is None      # nothing to tell: no callback


@pytest.mark.parametrize("bad", ["yes", 1, 0.5, lambda: None, lambda fraction: None, len])
def test_a_bad_progress_is_a_type_error_naming_it(bad, tmp_path):
    calls = [lambda: api.simulate("rigid_pd", {"stop_time": 0.2}, progress=bad),
             lambda: api.stability("rigid_pd", progress=bad),
             lambda: api.design(progress=bad),
             lambda: api.sweep("rigid_pd", values={"controller.kp": [400]}, serial=True,
                               out=tmp_path, progress=bad),
             lambda: api.build_fmus("native", progress=bad)]
    for call in calls:
        with pytest.raises(TypeError, match=r"^progress must be True, False or a callable "
                                            r"progress\(fraction, label\), got "):
            call()


# ---------------------------------------------------------------------- the API
def test_simulate_names_each_rung_of_the_auto_ladder():
    rec = Recorder()
    run = fp.simulate("flexible_pd", {"plant.fidelity": "auto", "stop_time": 0.2}, progress=rec)
    rec.check_complete()
    ladder = available_ladder(load_scene("flexible_pd", {"plant.fidelity": "auto"}))
    ran = [why.split(":")[0] for why in run.summary["model"]["climb"]]
    assert ran and ran[-1] == run.scene.plant.fidelity
    rung_labels = [f"flexible_pd: {r} rung ({ladder.index(r) + 1} of {len(ladder)})" for r in ran]
    labels = [label for _, label in rec.calls]
    for want in rung_labels:
        assert want in labels, (want, sorted(set(labels)))
    # the rungs in the order they ran, each reached at a larger fraction than the one before
    firsts = [next(f for f, label in rec.calls if label == want) for want in rung_labels]
    assert firsts == sorted(firsts) and len(set(firsts)) == len(firsts)
    # each rung's share of the bar ends where the next one's starts: no rung fills the bar
    for want, nxt in zip(rung_labels, firsts[1:]):
        assert max(f for f, label in rec.calls if label.startswith(want)) <= nxt
    last = next(i for i, (_, label) in enumerate(rec.calls) if label == rung_labels[-1])
    assert max(f for f, _ in rec.calls[:last]) < 1.0
    # and no rung that did not run
    for r in set(ladder) - set(ran):
        assert not any(f"flexible_pd: {r} rung (" in label for label in labels)


def test_simulate_with_the_reference_and_a_chosen_n_modes():
    rec = Recorder()
    run = fp.simulate("rigid_pd", {"stop_time": 0.2}, reference=True, progress=rec)
    rec.check_complete()
    assert run.reference is not None
    assert any(label == "rigid_pd: the monolithic reference" for _, label in rec.calls)
    rec = Recorder()
    run = fp.simulate("flexible_pd", {"plant.n_modes": "auto", "stop_time": 0.2},
                      progress=rec)
    rec.check_complete()
    n = run.scene.plant.params.n_modes
    assert any(label == f"flexible_pd: choosing the model: solving {n} mode"
               f"{'' if n == 1 else 's'}, nonlinear" for _, label in rec.calls)


def test_stability_design_sweep_and_build_report_to_one_callable(tmp_path, monkeypatch):
    rec = Recorder()
    api.stability("rigid_pd", max_step=0.005, progress=rec)
    rec.check_complete()
    assert {label for _, label in rec.calls} == {"rigid_pd: stability"}

    rec = Recorder()
    small = {"design.levels": 2, "design.check_levels": 2, "design.n_cutoffs": 5,
             "design.n_dampings": 2}
    api.design(design=small, progress=rec)
    rec.check_complete()
    assert any("design: searching the filters" in label for _, label in rec.calls)
    n_cands = 5 + 5 * 2                          # first order per cutoff, second per pair
    searching = [f for f, label in rec.calls if label.endswith("searching the filters")]
    assert len(searching) >= n_cands

    rec = Recorder()
    s = api.sweep("rigid_pd", values={"controller.kp": [400, 500, 600]},
                  overrides={"stop_time": 0.2}, serial=True, out=tmp_path / "sweep",
                  progress=rec)
    rec.check_complete()
    assert len(s.rows) == 3
    assert rec.calls[-1] == (1.0, "sweep of rigid_pd: 3 of 3 runs finished, 0 failed")
    assert [f for f, label in rec.calls if "runs finished" in label] == [1 / 3, 2 / 3, 1.0]

    fake_compile(monkeypatch)
    rec = Recorder()
    paths = api.build_fmus("native", out=tmp_path / "fmus", force=True, progress=rec)
    rec.check_complete()
    from orchestration.export.native_fmus import MODELS
    assert sorted(paths) == sorted(MODELS)
    labels = [label for _, label in rec.calls]
    for name in paths:
        assert any(label.startswith(f"building {name} (native, FMI 2.0): compiled ")
                   for label in labels), labels
        assert f"building {name} (native, FMI 2.0): writing {name}.fmu" in labels
    rec = Recorder()                            # up to date: nothing to do, done at once
    api.build_fmus("native", out=tmp_path / "fmus", progress=rec)
    assert rec.fractions == [1.0]
    rec = Recorder()
    paths = api.build_fmus("python", out=tmp_path / "python", force=True, progress=rec)
    rec.check_complete()
    labels = [label for _, label in rec.calls]
    for name in paths:
        assert f"building {name} (python, FMI 2.0): packaging with pythonfmu" in labels, labels


def test_true_draws_a_bar_and_false_is_silent(capsys):
    fp.simulate("rigid_pd", {"stop_time": 0.2}, progress=False)
    assert capsys.readouterr().err == ""
    fp.simulate("rigid_pd", {"stop_time": 0.2}, progress=True)
    lines = progress_lines(capsys.readouterr().err)
    assert lines and lines[-1][1] == 100 and lines[0][0] == "rigid_pd: the native FMUs"
    assert all(label.startswith("rigid_pd") for label, _ in lines) and \
        [p for _, p in lines] == sorted(p for _, p in lines)


# ---------------------------------------------------------------------- the commands
def run_cli(capsys, args):
    code = main(args)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_run_names_the_rungs_never_restarts_and_quiet_prints_nothing(capsys, tmp_path):
    out = ["--out", str(tmp_path)]
    code, stdout, err = run_cli(capsys, ["run", "flexible_pd", *AUTO, *out, "--json"])
    assert code == 0
    climb = json.loads(stdout)["flexible_pd"]["model"]["climb"]
    ran = [why.split(":")[0] for why in climb]
    ladder = available_ladder(load_scene("flexible_pd", {"plant.fidelity": "auto"}))
    lines = [(label, pct) for label, pct in progress_lines(err) if label.startswith("flexible_pd")]
    labels = [label for label, _ in lines]
    for i, r in enumerate(ran):
        assert f"flexible_pd: {r} rung ({ladder.index(r) + 1} of {len(ladder)})" in labels, err
    pcts = [pct for _, pct in lines]
    assert pcts == sorted(pcts) and pcts[-1] == 100, err          # one bar: no restart

    code, stdout, err = run_cli(capsys, ["run", "flexible_pd", *AUTO, *out])
    assert code == 0 and progress_lines(err) and "flexible_pd: running 0.2 s" in err
    for quiet in (["run", "--quiet"], ["--quiet", "run"], ["run", "-q"]):
        code, quiet_out, quiet_err = run_cli(capsys, [*quiet, "flexible_pd", *AUTO, *out])
        assert code == 0 and quiet_err == ""
        assert steady(quiet_out) == steady(stdout)


def test_run_reference_shows_the_reference(capsys, tmp_path):
    code, _, err = run_cli(capsys, ["run", "rigid_pd", *SHORT, "--reference",
                                    "--out", str(tmp_path)])
    assert code == 0
    lines = progress_lines(err)
    assert ("rigid_pd: the monolithic reference", 100) in lines, err


def test_stability_and_design(capsys, tmp_path):
    args = ["stability", "rigid_pd", "--max-step", "0.005"]
    code, stdout, err = run_cli(capsys, args)
    assert code == 0 and ("flexpend stability", 100) in progress_lines(err)
    code, quiet_out, quiet_err = run_cli(capsys, [*args, "--quiet"])
    assert code == 0 and quiet_err == "" and quiet_out == stdout

    args = ["design", "--set", "design.levels=2", "--set", "design.check_levels=2",
            "--set", "design.n_cutoffs=5", "--set", "design.n_dampings=2",
            "--out", str(tmp_path)]
    code, stdout, err = run_cli(capsys, args)
    lines = progress_lines(err)
    assert code == 0 and lines[-1][1] == 100
    assert any(label.endswith("design: searching the filters") for label, _ in lines)
    pcts = [p for _, p in lines]
    assert pcts == sorted(pcts)
    code, quiet_out, quiet_err = run_cli(capsys, [*args, "-q"])
    assert code == 0 and quiet_err == "" and steady(quiet_out) == steady(stdout)


def test_build_names_each_step(capsys, tmp_path, monkeypatch):
    fake_compile(monkeypatch)
    args = ["build", "--fmus", "native", "--force", "--out", str(tmp_path)]
    code, stdout, err = run_cli(capsys, args)
    assert code == 0
    lines = progress_lines(err)
    labels = [label for label, _ in lines]
    for version in (2, 3):
        for name in ("FlexiblePendulum", "PDLowPass"):
            what = f"building {name} (native, FMI {version}.0)"
            assert any(label.startswith(f"{what}: compiled ") for label in labels), err
            assert f"{what}: writing {name}.fmu" in labels, err
    pcts = [p for _, p in lines]
    assert pcts == sorted(pcts) and pcts[-1] == 100
    code, quiet_out, quiet_err = run_cli(capsys, [*args, "--quiet"])
    # quiet keeps the warnings: a platform skipped for want of its cross-compiler (win64 on a
    # machine without mingw-w64), as the run without it says them
    warnings = "".join(f"{line}\n" for line in err.splitlines() if " skipped: " in line)
    assert code == 0 and quiet_err == warnings and quiet_out == stdout


def test_sweep_and_export(capsys, tmp_path):
    args = ["sweep", "rigid_pd", "--values", "controller.kp=400,500", *SHORT, "--serial",
            "--out", str(tmp_path / "sweep")]
    code, stdout, err = run_cli(capsys, args)
    assert code == 0
    assert "sweep of rigid_pd: 2 runs" in err and "2/2 finished, 0 failed" in err
    args[-1] = str(tmp_path / "again")
    code, quiet_out, quiet_err = run_cli(capsys, [*args, "--quiet"])
    assert code == 0 and quiet_err == ""
    assert steady(quiet_out) == steady(stdout.replace(str(tmp_path / "sweep"), args[-1]))

    args = ["export", "flexible_pd", *AUTO, "--out", str(tmp_path / "x.ssp")]
    code, stdout, err = run_cli(capsys, args)
    assert code == 0
    labels = [label for label, _ in progress_lines(err)]
    assert "flexible_pd: choosing the model: solving 4 modes, linear" in labels, err
    assert progress_lines(err)[-1][1] == 100
    code, quiet_out, quiet_err = run_cli(capsys, [*args, "--quiet"])
    assert code == 0 and quiet_err == "" and quiet_out == stdout


def test_every_long_command_takes_quiet(capsys):
    for command in ("run", "stability", "design", "build", "sweep", "export", "check",
                    "analyze"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--quiet" in capsys.readouterr().out, command
