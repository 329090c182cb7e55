"""No code is loaded from outside the FMU being run (issue 40, D0 and D5).

fmpy loads ``binaries/<platform>/<modelIdentifier>.so`` of the unpacked FMU. The real native FMU
with only its ``modelIdentifier`` changed to ``../../..<a folder>/Evil`` would load a library
planted outside it and run its constructor. Here the planted library's constructor writes a file:
every command that takes an FMU (``run`` of a scene or an SSP, ``sweep``, ``check``, the Python
API) refuses the FMU in one line with exit 2 (a ValueError in Python), and the file never appears.
An SSP whose embedded FMU has a member outside the archive or a symbolic link member is refused
the same way (D5), and so is an unpacked FMU whose library is a symbolic link out of it.
"""
import os
import re
import shutil
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

PLANTED_C = r"""
#include <stdio.h>
__attribute__((constructor)) static void planted(void)
{
    FILE *f = fopen(MARK, "w");
    if (f) { fputs("the planted library ran\n", f); fclose(f); }
}
"""


@pytest.fixture
def planted(tmp_path):
    """``(identifier, mark)``: a library ``Evil.so`` compiled into ``tmp_path/planted`` whose
    constructor writes the file ``mark``, and a modelIdentifier that points fmpy at it from any
    folder an FMU is unpacked into (a run of ``../`` up to the root, then its folder)."""
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    folder, mark = tmp_path / "planted", tmp_path / "mark"
    folder.mkdir()
    (folder / "evil.c").write_text(PLANTED_C)
    subprocess.run([cc, "-shared", "-fPIC", f'-DMARK="{mark}"', "-o", str(folder / "Evil.so"),
                    str(folder / "evil.c")], check=True, capture_output=True)
    # the control: loading the library runs its constructor (in a child process, not ours)
    subprocess.run([sys.executable, "-c", "import ctypes, sys; ctypes.CDLL(sys.argv[1])",
                    str(folder / "Evil.so")], check=True)
    assert mark.is_file()
    mark.unlink()
    return "../" * 40 + str(folder).lstrip("/") + "/Evil", mark


def rewritten(src, dest, changes: dict, links: dict | None = None) -> Path:
    """The zip ``src`` copied to ``dest`` with ``changes`` ({member: function of its bytes,
    bytes for a new member, or None: left out}) applied, and ``links`` ({member: target}) added
    as symbolic link members."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zout:
        names = zin.namelist()
        for name in names:
            data = zin.read(name)
            change = changes.get(name, bytes)
            if change is not None:
                zout.writestr(name, change(data) if callable(change) else change)
        for name, data in changes.items():
            if name not in names:
                zout.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.create_system = 3
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            zout.writestr(info, target)
    return Path(dest)


def with_identifier(src, dest, identifier, elements=("ModelExchange", "CoSimulation")) -> Path:
    """The FMU ``src`` copied to ``dest`` with only the ``modelIdentifier`` of ``elements``
    changed."""
    def change(xml: bytes) -> bytes:
        for el in elements:
            xml, n = re.subn(rf'(<{el}\s+modelIdentifier=")[^"]*"'.encode(),
                             lambda m: m.group(1) + identifier.encode() + b'"', xml)
            assert n == 1, el
        return xml
    Path(dest).parent.mkdir(parents=True, exist_ok=True)
    return rewritten(src, dest, {"modelDescription.xml": change})


@pytest.fixture(scope="module")
def good_ssp(tmp_path_factory, native):
    """The rigid_pd scene exported as an SSP with the native FMUs."""
    from orchestration.export.system import export_scene
    from orchestration.scene.schema import load_scene

    path = tmp_path_factory.mktemp("ssp") / "rigid_pd.ssp"
    export_scene(load_scene("rigid_pd"), "native", path)
    return path


def ssp_with_plant(good_ssp, dest, plant_bytes) -> Path:
    """``good_ssp`` with its plant FMU's bytes replaced by ``plant_bytes``."""
    with zipfile.ZipFile(good_ssp) as zf:
        member, = [n for n in zf.namelist() if n.endswith("/FlexiblePendulum.fmu")]
    return rewritten(good_ssp, dest, {member: plant_bytes})


def flexpend(*args, env=None):
    """``flexpend -q ARGS`` (no progress chatter on stderr): exit code, stdout, stderr."""
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", "-q", *map(str, args)],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})
    return proc.returncode, proc.stdout, proc.stderr


def assert_one_line(code, err, *words):
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("flexpend: error: ")
    for w in words:
        assert w in lines[0], lines[0]


@pytest.fixture
def home(tmp_path, native, planted):
    """A ``FLEXPEND_HOME`` whose built native FMUs are up to date, the plant's modelIdentifier
    pointing at the planted library: what ``run`` of a scene and ``sweep`` run on."""
    identifier, _ = planted
    folder = tmp_path / "home" / "fmus" / "native" / "fmi2"
    folder.mkdir(parents=True)
    for path in Path(native["FlexiblePendulum"]).parent.glob("*.fmu"):
        shutil.copy(path, folder / path.name)
    with_identifier(Path(native["FlexiblePendulum"]), folder / "FlexiblePendulum.fmu", identifier)
    return tmp_path / "home"


def test_run_of_a_scene_on_a_hostile_fmu_is_refused(tmp_path, home, planted):
    code, _, err = flexpend("run", "rigid_pd", "--set", "stop_time=0.05", "--figures", "none",
                            "--out", tmp_path / "out", env={"FLEXPEND_HOME": str(home)})
    assert_one_line(code, err, "FlexiblePendulum.fmu", "modelIdentifier", "not a C identifier")
    assert not planted[1].exists()


def test_sweep_on_a_hostile_fmu_is_refused(tmp_path, home, planted):
    code, _, err = flexpend("sweep", "rigid_pd", "--values", "controller.kp=500,600", "--set",
                            "stop_time=0.05", "--serial", "--out", tmp_path / "out",
                            env={"FLEXPEND_HOME": str(home)})
    assert_one_line(code, err, "modelIdentifier", "not a C identifier")
    assert not planted[1].exists()


def test_run_of_an_ssp_with_a_hostile_fmu_is_refused(tmp_path, native, good_ssp, planted):
    identifier, mark = planted
    plant = with_identifier(native["FlexiblePendulum"], tmp_path / "p" / "FlexiblePendulum.fmu",
                            identifier)
    ssp = ssp_with_plant(good_ssp, tmp_path / "evil.ssp", plant.read_bytes())
    code, _, err = flexpend("run", ssp, "--figures", "none", "--out", tmp_path / "out")
    assert_one_line(code, err, "evil.ssp", "modelIdentifier", "not a C identifier")
    assert not mark.exists()


def test_check_of_a_hostile_fmu_is_refused(tmp_path, native, planted):
    from orchestration.export.check import REFERENCE_DIR

    identifier, mark = planted
    plant = with_identifier(native["FlexiblePendulum"], tmp_path / "p" / "FlexiblePendulum.fmu",
                            identifier)
    code, _, err = flexpend("check", plant, "--reference", REFERENCE_DIR)
    assert_one_line(code, err, "modelIdentifier", "not a C identifier")
    assert not mark.exists()


def test_the_python_api_refuses_a_hostile_fmu(tmp_path, native, good_ssp, planted):
    import orchestration
    from orchestration.job import run_scene
    from orchestration.sweeps.engine import run_sweep
    from orchestration.sweeps.plan import plan_sweep

    identifier, mark = planted
    plant = with_identifier(native["FlexiblePendulum"], tmp_path / "p" / "FlexiblePendulum.fmu",
                            identifier)
    scene = orchestration.load_scene("rigid_pd", {"stop_time": 0.05})
    with pytest.raises(ValueError, match="modelIdentifier .* is not a C identifier"):
        run_scene(scene, {"plant": str(plant), "controller": native["PDLowPass"]},
                  progress=False, check_step=False)
    ssp = ssp_with_plant(good_ssp, tmp_path / "evil.ssp", plant.read_bytes())
    with pytest.raises(ValueError, match="modelIdentifier .* is not a C identifier"):
        orchestration.simulate(ssp)
    plan = plan_sweep("rigid_pd", values=["controller.kp=500,600"], overrides=["stop_time=0.05"])
    with pytest.raises(ValueError, match="modelIdentifier .* is not a C identifier"):
        run_sweep(plan, {"plant": str(plant), "controller": native["PDLowPass"]},
                  tmp_path / "sweep", progress=False, plot=False)
    assert not mark.exists()


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("element", ["CoSimulation", "ModelExchange"])
def test_every_interface_identifier_is_checked(tmp_path, native, native3, planted, version,
                                               element):
    """FMI 2.0 and 3.0, Co-Simulation and Model Exchange: one changed identifier is enough;
    neither interface's unit loads the FMU."""
    from orchestration.cosim.model_exchange import ModelExchangeUnit
    from orchestration.cosim.slave import Slave

    identifier, mark = planted
    src = (native if version == 2 else native3)["FlexiblePendulum"]
    fmu = with_identifier(src, tmp_path / "p" / "FlexiblePendulum.fmu", identifier, (element,))
    for unit in (Slave, ModelExchangeUnit):
        with pytest.raises(ValueError, match=rf"^{re.escape(str(fmu))}: modelIdentifier "
                                             r"'(\.\./)+.*Evil' is not a C identifier"):
            unit(fmu, "plant")
    assert not mark.exists()


@pytest.mark.parametrize("identifier", ["", "1abc", "a-b", "a.b", "a b", "Flexible\u00e9"])
def test_an_identifier_that_is_not_a_c_identifier_is_refused(tmp_path, native, identifier):
    from orchestration.scene.fmu import FmuError, model_description

    fmu = with_identifier(native["PDLowPass"], tmp_path / "PDLowPass.fmu", identifier)
    with pytest.raises(FmuError, match="is not a C identifier"):
        model_description(fmu)
    ok = with_identifier(native["PDLowPass"], tmp_path / "ok" / "PDLowPass.fmu", "_PD_2")
    assert model_description(ok).coSimulation.modelIdentifier == "_PD_2"


def test_a_library_that_is_a_symbolic_link_out_of_the_fmu_is_refused(tmp_path, native,
                                                                      planted):
    """An unpacked FMU (a folder: symbolic links are real there) whose library is a link to the
    planted one: its identifier is fine, its library resolves outside."""
    from orchestration.cosim.slave import Slave
    from orchestration import load_scene
    from orchestration.job import run_scene
    from orchestration.scene.fmu import unpack

    _, mark = planted
    folder = Path(unpack(native["FlexiblePendulum"], tmp_path / "unpacked"))
    lib, = (folder / "binaries").glob("linux64/FlexiblePendulum.so")
    lib.unlink()
    lib.symlink_to(tmp_path / "planted" / "Evil.so")
    with pytest.raises(ValueError, match=r"binaries/linux64/FlexiblePendulum.so resolves to "
                                         r".*Evil.so, outside the FMU"):
        Slave(native["FlexiblePendulum"], "plant", unzipdir=str(folder))
    scene = load_scene("rigid_pd", {"stop_time": 0.05})
    with pytest.raises(ValueError, match="outside the FMU"):
        run_scene(scene, {"plant": native["FlexiblePendulum"], "controller": native["PDLowPass"]},
                  unzipdirs={"plant": str(folder), "controller": str(unpack(
                      native["PDLowPass"], tmp_path / "c"))}, progress=False, check_step=False)
    assert not mark.exists()


@pytest.mark.parametrize("member", ["/abs/evil.txt", "../evil.txt", "a/../../evil.txt", "link"])
def test_an_ssp_whose_fmu_has_a_hostile_member_is_one_line(tmp_path, native, good_ssp, member,
                                                           planted):
    """D5: an absolute or ``../`` member name in an SSP's embedded FMU, or a symbolic link
    member (to the planted library, named as the FMU's library): exit 2, one line naming the
    member, the same member check as ``flexpend check`` (before: a traceback of fmpy.extract)."""
    _, mark = planted
    lib = "binaries/linux64/FlexiblePendulum.so"
    if member == "link":
        plant = rewritten(native["FlexiblePendulum"], tmp_path / "p.fmu", {lib: None},
                          {lib: str(tmp_path / "planted" / "Evil.so")})
        words = (f"{lib!r} is a symbolic link",)
    else:
        plant = rewritten(native["FlexiblePendulum"], tmp_path / "p.fmu", {member: b"evil"})
        words = (repr(member), "is not a relative path inside the archive")
    ssp = ssp_with_plant(good_ssp, tmp_path / "evil.ssp", plant.read_bytes())
    code, _, err = flexpend("run", ssp, "--figures", "none", "--out", tmp_path / "out")
    assert_one_line(code, err, "evil.ssp", *words)
    code, _, err = flexpend("check", plant, "--reference", tmp_path)
    assert_one_line(code, err, *words)
    assert not mark.exists() and not list(tmp_path.rglob("evil.txt"))
