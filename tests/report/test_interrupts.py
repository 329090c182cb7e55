"""Ctrl-C stops every command within moments (issue 40, D2: ``design`` and ``stability`` finished
their whole computation first, 72 to 180 s; ``build`` waited for its compilers, about a minute):
SIGINT at seeded random moments into each command, which exits 130 (or 0 when it had already
finished) well within the bound below, with no temporary left and every output complete or
absent.

The bound is wide on purpose: the machines are shared and busy, so the delays are printed and
the test fails only on delays like the defect's (tens of seconds), not on a loaded machine's."""
import random
import signal
import time
from pathlib import Path

import pytest

from conftest import flexpend

#: Seconds from the SIGINT to the exit that fail the test (the defect: 72 to 180 s; the goal:
#: 2 s on an idle machine; a busy one can slow a process's exit several times).
BOUND = 20.0
#: The moments of the SIGINTs, seconds after the start (after the interpreter's start-up).
MOMENTS, EARLY = (0.8, 4.0), {"check --reference": (0.8, 1.6)}
ROOT = Path(__file__).resolve().parents[2]


def _commands(fmus, out: Path) -> dict:
    """``name -> argv``: each command at a size that keeps it busy for seconds (``check``: about
    two, so its SIGINT comes early: :data:`EARLY`)."""
    ref = ROOT / "tests" / "reference" / "FlexiblePendulum"
    return {
        "design": ["design", "--out", out],
        "stability": ["stability", "flexible_pd", "--max-step", "0.05"],
        "analyze": ["analyze"],
        "auto ladder": ["run", "flexible_pd_lowpass", "--set", "plant.fidelity=auto",
                        "--set", "stop_time=60", "--out", out],
        "run --reference": ["run", "flexible_pd_lowpass", "--reference", "--set",
                            "stop_time=60", "--out", out],
        "check --reference": ["check", fmus["FlexiblePendulum"], "--reference", ref],
        "build": ["build", "--force", "--out", out],           # python, then native
    }


@pytest.mark.slow
@pytest.mark.parametrize("name", ["design", "stability", "analyze", "auto ladder",
                                  "run --reference", "check --reference", "build"])
def test_ctrl_c_ends_every_command_at_once(name, fmus, tmp_path):
    rng = random.Random(f"issue 40, D2: {name}")
    for attempt, delay in enumerate(rng.uniform(*EARLY.get(name, MOMENTS)) for _ in range(2)):
        tmp, out = tmp_path / f"tmp{attempt}", tmp_path / f"out{attempt}"
        tmp.mkdir()
        proc = flexpend(_commands(fmus, out)[name], tmp)
        time.sleep(delay)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=600)
        took = time.monotonic() - sent
        print(f"{name}: SIGINT at {delay:.2f} s, exit {proc.returncode} {took:.2f} s later")
        assert proc.returncode in (130, 0), err
        assert "Traceback" not in err, err
        if proc.returncode == 130:
            assert took < BOUND, (name, delay, took)
        assert sorted(p.name for p in tmp.iterdir()) == [], name       # no temporary left
        if out.exists():                                               # complete or absent
            left = [p.name for p in out.rglob("*") if ".part" in p.name
                    or p.name == ".flexpend.lock"]
            assert left == [], left


def test_a_ctrl_c_a_library_turned_into_another_error_is_still_a_ctrl_c():
    """A SIGINT inside a C extension's module initialisation (matplotlib's, imported late by
    analyze) surfaces as ImportError("initialization failed") raised from the KeyboardInterrupt:
    the CLI sees the interrupt in the chain (exit 130, one line), and only there."""
    from orchestration.cli import _interrupted

    def chained():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            try:
                raise ImportError("initialization failed") from inner
            except ImportError as outer:
                return outer

    assert _interrupted(chained())
    assert _interrupted(KeyboardInterrupt())
    assert not _interrupted(ImportError("no module"))
    try:
        try:
            raise ValueError("a")
        except ValueError:
            raise OSError("b")
    except OSError as exc:
        assert not _interrupted(exc)
