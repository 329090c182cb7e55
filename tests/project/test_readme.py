"""The README works verbatim: after its two set-up commands, every command of its code blocks that
has no placeholder runs as written, in the README's order, from the checkout, and exits 0 without
a traceback; its Python example runs too. The output a block shows under a command (its ``#``
lines) is that command's: every number printed there (with a decimal point or an exponent, as it
is printed) appears in what the command printed.

Blocks whose info string is ``text`` hold output. A line is a synopsis, not a command, when it
holds a placeholder: ``[...]``, ``...``, ``<...>``, ``/path/to/`` or one of the upper-case words
the synopses use (``SCENE``, ``KEY=VALUE``, ``DIR``...)."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLACEHOLDER = re.compile(r"\[|\]|\.\.\.|<[^>]*>|/path/to/|\b(SCENE|KEY|VALUE|DIR|FILE|FMU|N|S|T|"
                         r"ADDRESS|VENV|DIST|START|STOP|NUM|V1|V2|SAMPLES)\b")

pytestmark = pytest.mark.slow


def blocks():
    """``(info string, text)`` of every fenced code block of the README, in order."""
    text = (ROOT / "README.md").read_text()
    return re.findall(r"^```([^\n`]*)\n(.*?)^```", text, re.M | re.S)


#: A number as the README shows a command's output: with a decimal point or an exponent.
NUMBER = re.compile(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?|[-+]?\d+e[-+]?\d+")


def steps(shown: bool = False):
    """What the README asks to run: ``("shell", line)`` and ``("python", source)``; with
    ``shown``, triples whose third item is the output the README shows under a shell command:
    the ``#`` lines right after it, joined ("" for none)."""
    out = []
    for info, body in blocks():
        info = info.strip()
        if info == "text":
            continue
        if info == "python":
            out.append(["python", body, ""])
            continue
        under = None                      # the command whose output the next # lines show
        for line in body.splitlines():
            line = line.strip()
            if line.startswith("#") and under is not None:
                under[2] += " " + line[1:].strip()
                continue
            under = None
            if not line or line.startswith("#") or PLACEHOLDER.search(line.split("#")[0]):
                continue
            if "pip install" in line:           # the two set-up commands, done before the tests
                continue
            under = ["shell", line, ""]
            out.append(under)
    return [tuple(o) if shown else tuple(o[:2]) for o in out]


def test_the_readme_has_commands_and_a_python_example():
    kinds = [k for k, _ in steps()]
    assert kinds.count("python") == 1 and kinds.count("shell") >= 15
    assert {"flexpend run", "flexpend analyze", "flexpend design", "flexpend sweep",
            "flexpend export", "flexpend check", "flexpend build", "fmpy simulate"} <= {
        " ".join(line.split()[:2]) for k, line in steps() if k == "shell"}


def test_every_command_runs_as_written():
    if shutil.which("flexpend") is None:
        pytest.skip("the flexpend command is not installed (pip install -e .)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("FLEXPEND_HOME", None)
    for kind, what, shown in steps(shown=True):
        if kind == "python":
            proc = subprocess.run([sys.executable, "-"], input=what, cwd=ROOT, env=env,
                                  capture_output=True, text=True, timeout=900)
        else:
            proc = subprocess.run(["bash", "-c", what], cwd=ROOT, env=env, capture_output=True,
                                  text=True, timeout=900)
        assert proc.returncode == 0, (what, proc.stdout[-2000:], proc.stderr[-3000:])
        assert "Traceback" not in proc.stderr, (what, proc.stderr[-3000:])
        printed = proc.stdout + proc.stderr
        missing = [n for n in NUMBER.findall(shown) if n not in printed]
        assert not missing, (what, missing, shown, printed[-3000:])


def test_the_main_jobs_output_is_what_the_readme_shows(tmp_path):
    """The README's first ``text`` block is the main job's summary (``flexpend run``): every
    number in it appears in what a fresh run prints."""
    if shutil.which("flexpend") is None:
        pytest.skip("the flexpend command is not installed (pip install -e .)")
    shown = next(body for info, body in blocks() if info.strip() == "text")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("FLEXPEND_HOME", None)
    proc = subprocess.run(["flexpend", "run", "--out", str(tmp_path)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = proc.stdout + proc.stderr
    missing = [n for n in NUMBER.findall(shown) if n not in printed]
    assert not missing, (missing, printed[-3000:])
