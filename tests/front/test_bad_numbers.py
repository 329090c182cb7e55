"""Every bad number ends in one line and exit 2 (issue 40, D4): the scene keys that are steps,
intervals, tolerances and times at a subnormal (1e-320, 5e-324), a huge (1e308), an infinite, a
NaN or a negative value, through every command that takes them; ``flexpend check``'s band and
``flexpend stability``'s ``--max-step`` too. Before, ``plant.step = 1e-320`` passed the range
``(0.0, 1e+06]`` and ``flexpend run`` died in the stability preflight (OverflowError).

The commands run in this process (:func:`orchestration.cli.main`): an exception that the command
line does not turn into its one line propagates and fails the test; one case of each kind also
runs as the ``flexpend`` command, for its stderr and exit code."""
import subprocess
import sys

import pytest

from orchestration.cli import main

#: the scene keys that are steps, intervals, tolerances or times (flexpend keys)
STEP_KEYS = ("plant.step", "plant.rtol", "plant.atol", "plant.exact_step",
             "controller.sample_period", "controller.delay", "stop_time", "output_interval",
             "master.step", "master.tolerance", "master.min_step", "master.max_step",
             "master.rtol", "master.atol", "master.implicit_tolerance", "fidelity.tolerance")
BAD = ("1e-320", "5e-324", "1e308", "inf", "nan", "-0.001")


def commands(tmp_path, key, value):
    """``{command: argv}``: every command that takes ``--set KEY=VALUE``, each kept cheap (a
    short run), and a sweep that takes the value as an axis."""
    kv = f"{key}={value}"
    short = ["--set", "stop_time=0.02"]
    return {
        "run": ["run", "rigid_pd", *short, "--figures", "none", "--out", tmp_path / "run",
                "--set", kv],
        "sweep": ["sweep", "rigid_pd", "--values", "controller.kp=500,600", *short, "--serial",
                  "--out", tmp_path / "sweep", "--set", kv],
        "sweep axis": ["sweep", "rigid_pd", *short, "--serial", "--out", tmp_path / "axis",
                       "--values", f"{kv},{value}"],
        "design": ["design", "--out", tmp_path / "design", "--set", kv],
        "stability": ["stability", "rigid_pd", "--set", kv],
        "analyze": ["analyze", "--set", kv],
        "export": ["export", "rigid_pd", "--out", tmp_path / "x.ssp", "--set", kv],
    }


def one_line(capsys, argv) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, (argv, err)
    assert len(err) == 1 and err[0].startswith("flexpend: error: "), err
    return err[0]


@pytest.mark.parametrize("value", BAD)
@pytest.mark.parametrize("key", STEP_KEYS)
def test_a_bad_step_like_value_is_one_line_in_every_command(tmp_path, capsys, key, value):
    for name, argv in commands(tmp_path, key, value).items():
        line = one_line(capsys, ["-q", *argv])
        assert key in line, (name, line)
    assert not (tmp_path / "x.ssp").exists()


@pytest.mark.parametrize("value", ["1e-320", "5e-324"])
def test_a_subnormal_value_is_refused_as_zero(capsys, tmp_path, value):
    """The rule named in the line: a range open at 0 takes normal numbers only."""
    line = one_line(capsys, ["-q", "analyze", "--set", f"plant.step={value}"])
    assert "subnormal" in line and "allowed: (0.0, 1e+06]" in line
    assert main(["-q", "analyze", "--set", "plant.step=2.2250738585072014e-308"]) == 0


@pytest.mark.parametrize("option, value", [("--tolerance", v) for v in BAD]
                         + [("--max-outliers", v) for v in ("1e308", "inf", "nan", "-0.001")]
                         + [("--window", "0")])
def test_a_bad_band_of_check_is_one_line(capsys, native, option, value):
    from orchestration.export.check import REFERENCE_DIR

    line = one_line(capsys, ["check", native["PDLowPass"], "--reference", REFERENCE_DIR,
                             option, value])
    assert option in line


@pytest.mark.parametrize("value", BAD)
def test_a_bad_max_step_of_stability_is_one_line(capsys, value):
    assert "--max-step" in one_line(capsys, ["stability", "rigid_pd", "--max-step", value])


@pytest.mark.parametrize("key, argv", [
    ("plant.step", ["run", "rigid_pd", "--set", "plant.step=1e-320", "--set", "stop_time=0.02",
                    "--out", "OUT"]),
    ("plant.step", ["sweep", "rigid_pd", "--values", "plant.step=1e-320,2e-4", "--set",
                    "stop_time=0.02", "--out", "OUT"]),
    ("master.min_step", ["stability", "rigid_pd", "--set", "master.min_step=5e-324"]),
], ids=["run", "sweep", "stability"])
def test_the_command_prints_one_line_and_exits_2(tmp_path, key, argv):
    """The command itself (the D4 case first): stderr one line naming the key, no traceback."""
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", "-q", *argv],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and key in lines[0], proc.stderr


@pytest.mark.parametrize("argv", [
    ["run", "rigid_pd", "--set", "plant.step=2.3e-308", "--set", "master.step=100", "--set",
     "output_interval=100", "--set", "stop_time=100", "--figures", "none", "--out", "OUT"],
    ["stability", "rigid_pd", "--max-step", "10", "--set", "plant.step=2.3e-308"],
], ids=["run", "stability"])
def test_a_normal_plant_step_whose_substeps_overflow_is_one_line(tmp_path, capsys, argv):
    """A normal but tiny plant.step against a long communication step: the substep count is
    beyond a double (an OverflowError in the stability preflight before)."""
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    assert "plant.step = 2.3e-308 s is out of range" in one_line(capsys, ["-q", *argv])
