"""flexpend installs as a wheel: ``pip wheel .`` makes one (tagged for this platform: it carries
compiled C libraries) and leaves nothing in the source tree; installed into a fresh virtual
environment, ``flexpend build``, ``flexpend run`` and the Python API work from any folder, with
every C source the builds need inside the wheel, and the FMUs built into the user's cache."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                                 reason="needs a git checkout (to copy the tracked tree)")]


def _tree(folder: Path) -> set:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")}


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The wheel, built from a copy of the checkout's tracked (and new, not ignored) files,
    installed into a virtual environment outside it; ``(venv, wheel, tree before, after)``."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                           cwd=ROOT, capture_output=True, text=True, check=True).stdout
    for rel in filter(None, files.split("\0")):
        if (ROOT / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / rel, src / rel)
    before = _tree(src)
    dist = tmp / "dist"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", str(dist),
                           "-q"], cwd=src, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    after = _tree(src)
    wheel, = dist.glob("*.whl")
    venv = tmp / "venv"
    # the dependencies are this interpreter's (no download in the test); flexpend is the wheel's
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)],
                   check=True)
    proc = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q",
                           "--no-deps", str(wheel)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv, wheel, before, after


def test_the_wheel_build_leaves_the_tree_as_it_was(installed):
    _, wheel, before, after = installed
    assert after == before
    assert wheel.name.startswith("flexpend-") and "-py3-none-" in wheel.name
    assert not wheel.name.endswith("-any.whl")            # it carries compiled libraries


def test_the_installed_command_and_api_work_from_any_folder(installed, tmp_path):
    venv = installed[0]
    site = subprocess.run([str(venv / "bin" / "python"), "-c",
                           "import orchestration, sysconfig; print(orchestration.__file__); "
                           "print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True, cwd=tmp_path).stdout.split()
    assert Path(site[0]).is_relative_to(venv)              # the wheel's code, not the checkout's
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    env.pop("FLEXPEND_HOME", None)
    env.pop("PYTHONPATH", None)
    flexpend = str(venv / "bin" / "flexpend")

    def run(*args):
        return subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, env=env,
                              timeout=900)

    version = run(flexpend, "--version")
    assert version.returncode == 0 and version.stdout.startswith("flexpend ")
    build = run(flexpend, "build", "--fmus", "native")
    assert build.returncode == 0, build.stderr[-3000:]
    assert str(tmp_path / "cache" / "flexpend") in build.stdout
    sim = run(flexpend, "run", "rigid_pd", "--set", "stop_time=1", "--out", "results")
    assert sim.returncode == 0, sim.stderr[-3000:]
    assert (tmp_path / "results" / "rigid_pd.csv").is_file()
    api = run(str(venv / "bin" / "python"), "-c",
              "import orchestration as fp; r = fp.simulate('rigid_pd', {'stop_time': 0.5}); "
              "print(r.completed, len(r.to_pandas()), r.scene.output.output_interval)")
    assert api.returncode == 0, api.stderr[-3000:]
    completed, rows, dt = api.stdout.split()
    assert completed == "True" and int(rows) == round(0.5 / float(dt)) + 1
    # nothing was written beside the installed packages
    purelib = Path(site[1])
    assert not (purelib / "build").exists()
