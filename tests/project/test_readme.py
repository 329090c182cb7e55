"""The README and the manual work verbatim: after the README's two set-up commands, every command
of the code blocks of ``README.md`` and of every page of ``docs/`` (``docs/**/*.md``) that has no
placeholder runs as written, page by page (the README first, then the pages in the order of
``mkdocs.yml``'s nav, then any page the nav leaves out), each page's commands in its order, from
the checkout, and exits 0 without a traceback; the pages' Python blocks run too. The output a
block shows under a command (its ``#`` lines) is that command's: every number printed there (with
a decimal point or an exponent, as it is printed) appears in what the command printed. A command
that appears identically on an earlier page runs once: its output is kept for the session and
checked against what each later page shows under it. One test per page; the pages share one
process (``--dist loadfile``), so a page may use what an earlier page made (the FMUs, an SSP
archive in ``out/``).

Which blocks run, by their info string (the word after the opening fence):

- none, ``bash``, ``sh``, ``shell``: shell commands, one a line; ``python``: a Python program;
- ``text``: output, or anything else that is not a command (formulas, file lists);
- ``console``: commands shown but not run: those that need a cluster or a tool the tests do not
  install, benchmarks that take minutes (``bench/``), scripts that only illustrate. Write a
  command that takes long this way, never in a block that runs.

A line of a block that runs is a synopsis, not a command, when it holds a placeholder: ``[...]``,
``...``, ``<...>``, ``/path/to/`` or one of the upper-case words the synopses use (``SCENE``,
``KEY=VALUE``, ``DIR``...). ``pip install`` lines are the set-up, done before the tests."""
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
#: Info strings of blocks that are not run.
NOT_RUN = {"text", "console"}
#: Info strings of blocks of shell commands.
SHELL = {"", "bash", "sh", "shell"}

pytestmark = pytest.mark.slow


def pages() -> list[str]:
    """The pages whose commands run, relative to the checkout: the README, then ``docs/`` in the
    nav's order, then the pages the nav leaves out (sorted)."""
    nav = re.findall(r":\s*([\w/.-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M)
    found = sorted(p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md"))
    ordered = [p for p in nav if p in found] + [p for p in found if p not in nav]
    return ["README.md"] + ["docs/" + p for p in ordered]


def blocks(page: str = "README.md"):
    """``(info string, text)`` of every fenced code block of ``page``, in order."""
    text = (ROOT / page).read_text()
    return [(info.strip(), body) for info, body in
            re.findall(r"^```([^\n`]*)\n(.*?)^```", text, re.M | re.S)]


#: A number as a page shows a command's output: with a decimal point or an exponent.
NUMBER = re.compile(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?|[-+]?\d+e[-+]?\d+")


def steps(page: str = "README.md", shown: bool = False):
    """What ``page`` asks to run: ``("shell", line)`` and ``("python", source)``; with ``shown``,
    triples whose third item is the output the page shows under a shell command: the ``#`` lines
    right after it, joined ("" for none)."""
    out = []
    for info, body in blocks(page):
        if info in NOT_RUN:
            continue
        if info == "python":
            out.append(["python", body, ""])
            continue
        assert info in SHELL, (page, f"a code block with info string {info!r}: use one of "
                               f"{sorted(SHELL | NOT_RUN | {'python'})}")
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


def test_the_readme_has_the_setup_and_a_python_example():
    kinds = [k for k, _ in steps()]
    assert kinds.count("python") == 1
    setup = [line for info, body in blocks() if info in SHELL for line in body.splitlines()
             if "pip install" in line]
    assert len(setup) == 2, setup


def test_the_manual_has_commands_for_every_command_line_tool():
    every = [s for page in pages() for s in steps(page)]
    assert sum(k == "shell" for k, _ in every) >= 15
    assert {"flexpend run", "flexpend analyze", "flexpend design", "flexpend sweep",
            "flexpend export", "flexpend check", "flexpend build", "flexpend stability",
            "flexpend scenes", "fmpy simulate"} <= {
        " ".join(line.split()[:2]) for k, line in every if k == "shell"}
    assert {p for p in pages() if p.startswith("docs/guide/")} >= {
        f"docs/guide/{n}.md" for n in ("run", "analyze", "stability", "design", "sweep", "build",
                                       "export_and_check", "scenes", "tests")}


#: What each command printed in this session: ``(kind, text) -> (returncode, stdout, stderr)``.
_RAN: dict = {}


def _run(kind: str, what: str):
    if (kind, what) not in _RAN:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        env.pop("FLEXPEND_HOME", None)
        if kind == "python":
            proc = subprocess.run([sys.executable, "-"], input=what, cwd=ROOT, env=env,
                                  capture_output=True, text=True, timeout=900)
        else:
            proc = subprocess.run(["bash", "-c", what], cwd=ROOT, env=env, capture_output=True,
                                  text=True, timeout=900)
        _RAN[kind, what] = (proc.returncode, proc.stdout, proc.stderr)
    return _RAN[kind, what]


@pytest.mark.parametrize("page", pages())
def test_every_command_runs_as_written(page):
    if shutil.which("flexpend") is None:
        pytest.skip("the flexpend command is not installed (pip install -e .)")
    # the commands follow the README's main job, whose outputs folder they write into; on a
    # fresh clone no other test may have made it yet
    (ROOT / "out").mkdir(exist_ok=True)
    for kind, what, shown in steps(page, shown=True):
        returncode, stdout, stderr = _run(kind, what)
        assert returncode == 0, (page, what, stdout[-2000:], stderr[-3000:])
        assert "Traceback" not in stderr, (page, what, stderr[-3000:])
        printed = stdout + stderr
        missing = [n for n in NUMBER.findall(shown) if n not in printed]
        assert not missing, (page, what, missing, shown, printed[-3000:])


def test_the_main_jobs_output_is_what_the_readme_shows(tmp_path):
    """The README's first ``text`` block is the main job's summary (``flexpend run``): every
    number in it appears in what a fresh run prints."""
    if shutil.which("flexpend") is None:
        pytest.skip("the flexpend command is not installed (pip install -e .)")
    shown = next(body for info, body in blocks() if info == "text")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("FLEXPEND_HOME", None)
    proc = subprocess.run(["flexpend", "run", "--out", str(tmp_path)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = proc.stdout + proc.stderr
    missing = [n for n in NUMBER.findall(shown) if n not in printed]
    assert not missing, (missing, printed[-3000:])
