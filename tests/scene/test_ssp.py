"""flexpend export / flexpend run FILE.ssp: the SSP 1.0 archive of a scene and back.

The archive is checked with readers that are not ours: fmpy's SSD reader (which validates against
the SSP 1.0 schema fmpy ships) and lxml's XPath on the raw XML; the values against the scene's own
TOML file, read with tomllib. The round trip must give, on our master, the very same numbers as
the scene run directly; a hand-written SSP of another tool must run like the equivalent scene.
"""
import math
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from lxml import etree

from orchestration.scene.ssp import NS, SSD_NAME, read_ssp, validate_ssd, write_ssp
from orchestration.studies.fidelity import select_model
from orchestration.job import run_scene
from orchestration.scene.schema import SCENE_DIR, load_scene, scene_from_config

FOREIGN = Path(__file__).parents[1] / "data" / "ssp_foreign"


def flexpend(*args, cwd=None):
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)
    return proc.returncode, proc.stdout, proc.stderr


def our_fmus(fmus):
    return {"plant": fmus["FlexiblePendulum"], "controller": fmus["PDLowPass"]}


def ssd_root(path):
    with zipfile.ZipFile(path) as zf:
        return etree.fromstring(zf.read(SSD_NAME))


def bound_values(root, component):
    """name -> (SSV type, value text) of the parameters bound on ``component``."""
    out = {}
    for p in root.xpath(f"//ssd:Component[@name='{component}']//ssv:Parameter", namespaces=NS):
        (typed,) = list(p)
        out[p.get("name")] = (etree.QName(typed).localname, typed.get("value"))
    return out


@pytest.fixture(scope="module")
def exported(fmus, tmp_path_factory):
    path = tmp_path_factory.mktemp("ssp") / "flexible_pd_lowpass.ssp"
    code, out, err = flexpend("export", "flexible_pd_lowpass", "--fmus", "python", "--out",
                              str(path))
    assert code == 0, err
    assert f"wrote {path}" in out
    return path


def test_exported_ssd_validates_and_names_the_fmus_connections_and_parameters(exported, fmus):
    from fmpy.ssp.ssd import read_ssd

    root = ssd_root(exported)
    assert validate_ssd(etree.tostring(root)) == []
    ssd = read_ssd(str(exported))                  # fmpy's reader validates against the schema
    assert ssd.version == "1.0"
    comps = {c.name: c for c in ssd.system.elements}
    assert set(comps) == {"plant", "controller"}
    with zipfile.ZipFile(exported) as zf:          # both FMUs, byte for byte the built ones
        for name, fmu in (("plant", "FlexiblePendulum"), ("controller", "PDLowPass")):
            assert comps[name].source == f"resources/{fmu}.fmu"
            assert zf.read(comps[name].source) == Path(fmus[fmu]).read_bytes()
    # every connection of the scene (the default loop: the scene file does not set it)
    conns = {f"{c.startElement}.{c.startConnector} -> {c.endElement}.{c.endConnector}"
             for c in ssd.system.connections}
    assert conns == {"plant.x_o -> controller.x_o", "plant.phi_o -> controller.phi_o",
                     "plant.omega_o -> controller.omega_o", "controller.F_c -> plant.F_c"}
    # every parameter the scene file sets, with its value
    toml = tomllib.loads((SCENE_DIR / "flexible_pd_lowpass.toml").read_text())
    plant, ctrl = bound_values(root, "plant"), bound_values(root, "controller")
    for key, value in toml["plant"].items():
        kind, text = plant[key]
        assert (int(text) if kind == "Integer" else float(text)) == value
    for key, value in toml["controller"].items():
        kind, text = ctrl[key]
        assert (int(text) if kind == "Integer" else float(text)) == value
    assert float(plant["phi0"][1]) == toml["initial"]["phi"]
    # the defaults it leaves to flexpend are written too (the archive does not depend on them)
    assert plant["integrator"] == ("String", "rk4") and plant["gravity_preload"] == ("Boolean",
                                                                                     "false")
    # no limit: the largest double, which libcosim reads (it cannot read INF)
    assert ctrl["force_limit"] == ("Real", "1.7976931348623157e+308")
    # the experiment: stop time, libcosim's step, our master settings
    exp = root.find(f"{{{NS['ssd']}}}DefaultExperiment")
    assert float(exp.get("startTime")) == 0.0 and float(exp.get("stopTime")) == toml["stop_time"]
    (step,) = root.xpath("//osp:FixedStepAlgorithm/@baseStepSize", namespaces=NS)
    assert float(step) == toml["master"]["step"]
    settings = {s.get("key"): tomllib.loads(f"v = {s.text}")["v"]
                for s in root.xpath("//fp:Setting", namespaces=NS)}
    assert settings["output_interval"] == toml["output_interval"]
    for key, value in toml["master"].items():
        assert settings[f"master.{key}"] == value


def test_export_then_run_gives_the_direct_run_bit_for_bit(exported, fmus):
    scene = load_scene("flexible_pd_lowpass")
    direct = run_scene(scene, our_fmus(fmus), progress=False)
    with read_ssp(exported) as system:
        assert system.scene.config == scene.config
        assert all(type(system.scene.config[k]) is type(v) for k, v in scene.config.items())
        via_ssp = run_scene(system.scene, system.fmus, progress=False)
    assert via_ssp.result.dtype == direct.result.dtype
    assert np.array_equal(via_ssp.result, direct.result)
    assert len(direct.result) == round(scene.output.stop_time / scene.output.output_interval) + 1
    assert direct.summary["stable"]


def test_run_cli_on_the_archive_writes_the_same_csv(exported, fmus, tmp_path):
    """The archive (exported with the pythonfmu FMUs) runs as the scene does with the same FMUs,
    byte for byte; the native FMUs' run agrees to round-off only (the pythonfmu controller
    discretises its filter in numpy and scipy, whose last bits move with their versions)."""
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    code, _, err = flexpend("run", "flexible_pd_lowpass", "--set", "stop_time=1", "--set",
                            "master.fmus=python", "--out", str(a))
    assert code == 0, err
    code, _, err = flexpend("run", str(exported), "--set", "stop_time=1", "--out", str(b))
    assert code == 0, err
    name = "flexible_pd_lowpass.csv"
    assert (a / name).read_bytes() == (b / name).read_bytes()
    code, _, err = flexpend("run", "flexible_pd_lowpass", "--set", "stop_time=1", "--out", str(c))
    assert code == 0, err
    native, python = (np.genfromtxt(d / name, delimiter=",", names=True) for d in (c, b))
    for col in native.dtype.names:
        scale = max(1.0, float(np.max(np.abs(native[col]))))
        assert np.max(np.abs(native[col] - python[col])) <= 1e-9 * scale, col


@pytest.mark.slow
def test_auto_model_is_chosen_and_written(fmus, tmp_path):
    path = tmp_path / "rigid.ssp"
    code, out, err = flexpend("export", "rigid_pd", "--set", "plant.n_modes=auto", "--set",
                              "stop_time=3", "--out", str(path))
    assert code == 0, err
    chosen, report = select_model(load_scene("rigid_pd", ["plant.n_modes=auto", "stop_time=3"]))
    assert chosen.plant.n_modes == report["n_modes"] == 0
    root = ssd_root(path)
    assert bound_values(root, "plant")["n_modes"] == ("Integer", "0")
    (choice,) = root.xpath("//fp:ModelChoice", namespaces=NS)
    assert choice.get("n_modes") == "0" and choice.text == report["reason"]
    assert "model: 0 modes" in out
    with read_ssp(path) as system:
        assert system.scene.config == chosen.config


def foreign_archive(fmus, dest, ssd_text=None, drop=(), extra=()):
    """The hand-written fixture zipped with the built FMUs (optionally edited)."""
    with zipfile.ZipFile(dest, "w") as zf:
        zf.writestr(SSD_NAME, ssd_text if ssd_text is not None
                    else (FOREIGN / SSD_NAME).read_text())
        members = {"resources/regulator.ssv": (FOREIGN / "resources" / "regulator.ssv").read_bytes(),
                   "resources/FlexiblePendulum.fmu": Path(fmus["FlexiblePendulum"]).read_bytes(),
                   "resources/PDLowPass.fmu": Path(fmus["PDLowPass"]).read_bytes(), **dict(extra)}
        for name, data in members.items():
            if name not in drop:
                zf.writestr(name, data)
    return dest


def test_a_plain_ssp_of_another_tool_runs_like_the_equivalent_scene(fmus, tmp_path):
    path = foreign_archive(fmus, tmp_path / "foreign.ssp")
    # the same system typed in as a scene: the SSD's values, the scene defaults for the rest,
    # the step of libcosim's annotation (and the default output interval, a multiple of it)
    scene = scene_from_config("cart_and_regulator", {
        "plant.n_modes": 2, "plant.EI": 700.0, "plant.zeta": 0.002, "plant.gravity_preload": True,
        "plant.integrator": "dopri5", "initial.phi": 0.2, "initial.x_dot": -0.1,
        "controller.kp": 450.0, "controller.kd": 4.5, "controller.filter_order": 1,
        "controller.cutoff": 110.0, "stop_time": 2.0, "master.step": 0.002,
        "description": "A softer beam with two modes under a first-order filtered PD"})
    with read_ssp(path) as system:
        assert system.components == {"plant": "Pendulum", "controller": "Regulator"}
        assert system.scene.name == "cart_and_regulator"
        assert system.scene.config["initial.phi_dot"] == 0.0      # not in the file: default
        assert system.scene.config == {**scene.config,
                                       "connections": ["controller.F_c -> plant.F_c",
                                                       "plant.phi_o -> controller.phi_o",
                                                       "plant.omega_o -> controller.omega_o",
                                                       "plant.x_o -> controller.x_o"]}
        via_ssp = run_scene(system.scene, system.fmus, progress=False)
    direct = run_scene(scene, our_fmus(fmus), progress=False)
    assert np.array_equal(via_ssp.result, direct.result)
    assert len(direct.result) == round(2.0 / scene.output.output_interval) + 1
    assert np.ptp(direct.result["phi_o"]) > 0.1
    code, out, err = flexpend("run", str(path), "--out", str(tmp_path / "out"))
    assert code == 0, err
    assert (tmp_path / "out" / "cart_and_regulator.csv").is_file()


def _edit(text, old, new):
    assert old in text
    return text.replace(old, new, 1)


BAD = {
    "missing FMU": (dict(drop=("resources/PDLowPass.fmu",)),
                    "component 'Regulator' names the FMU 'resources/PDLowPass.fmu', which the "
                    "archive does not contain"),
    "unknown connection": (dict(edit=('startConnector="omega_o"', 'startConnector="omega"')),
                           "connection Pendulum.omega -> Regulator.omega_o: Pendulum has no "
                           "output 'omega'"),
    "unknown component": (dict(edit=('endElement="Pendulum"', 'endElement="Cart"')),
                          "no component named 'Cart'"),
    "malformed XML": (dict(edit=("</ssd:Connections>", "</ssd:Connection>")),
                      "SystemStructure.ssd is not well-formed XML"),
    "not the schema": (dict(edit=('name="F_c" kind="output"', 'name="F_c" kind="sideways"')),
                       "does not follow the SSP 1.0 schema"),
    "SSP 2.0": (dict(edit=('version="1.0"\n', 'version="2.0"\n')),
                "SSD version '2.0': flexpend reads SSP 1.x"),
    "missing .ssv": (dict(drop=("resources/regulator.ssv",)),
                     "the parameter file 'resources/regulator.ssv' is not in the archive"),
    "unknown parameter": (dict(edit=('name="zeta"', 'name="viscosity"')),
                          "Pendulum has no parameter 'viscosity'"),
    "bad value": (dict(edit=('<ssv:Integer value="2"/>', '<ssv:Integer value="-2"/>')),
                  "plant.n_modes = -2 is out of range"),
    "start time": (dict(edit=('startTime="0"', 'startTime="1"')),
                   "startTime = 1: flexpend runs from 0"),
    # libcosim's step (an annotation: no schema checks it); tracebacks before (ValueError,
    # ZeroDivisionError, OverflowError)
    **{f"step {v}": (dict(edit=('baseStepSize="0.002"', f'baseStepSize="{v}"')),
                     f"osp:FixedStepAlgorithm baseStepSize = {v!r}: allowed: a positive number")
       for v in ("abc", "0", "-0.002", "NaN", "INF")},
    "step 1e-320": (dict(edit=('baseStepSize="0.002"', 'baseStepSize="1e-320"')),
                    "output_interval = 1e-320 is out of range: a subnormal number"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_ssp_gives_one_line_and_exit_2(fmus, tmp_path, case):
    how, fragment = BAD[case]
    text = (FOREIGN / SSD_NAME).read_text()
    if "edit" in how:
        text = _edit(text, *how["edit"])
    path = foreign_archive(fmus, tmp_path / "bad.ssp", text, drop=how.get("drop", ()))
    code, out, err = flexpend("run", str(path), "--out", str(tmp_path / "out"))
    assert code == 2, (out, err)
    assert fragment in err and err.startswith("flexpend: error: bad.ssp: ")
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out" / "cart_and_regulator.csv").exists()


def test_not_an_archive_and_no_file_give_one_line(tmp_path):
    import os

    (tmp_path / "x.ssp").write_text("hello")
    os.mkfifo(tmp_path / "fifo.ssp")                  # was "no such file"
    (tmp_path / "zero.ssp").symlink_to("/dev/zero")
    for path, fragment in ((tmp_path / "x.ssp", "not an SSP archive"),
                           (tmp_path / "none.ssp", "no such file"),
                           (tmp_path / "fifo.ssp", "fifo.ssp: not a regular file"),
                           (tmp_path / "zero.ssp", "zero.ssp: not a regular file")):
        code, _, err = flexpend("run", str(path))
        assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1


def test_export_native_ships_the_native_fmus(tmp_path):
    import zipfile

    from fmpy import read_model_description
    code, out, err = flexpend("export", "rigid_pd", "--fmus", "native", "--out",
                              str(tmp_path / "x.ssp"))
    assert code == 0, err
    with zipfile.ZipFile(tmp_path / "x.ssp") as zf:
        fmus = [n for n in zf.namelist() if n.endswith(".fmu")]
        # the pair, and the companion run's plant riding along (no component names it)
        assert sorted(fmus) == sorted(f"resources/{n}.fmu" for n in
                                      ("FlexiblePendulum", "PDLowPass",
                                       "FlexiblePendulumStiffened"))
        assert "FlexiblePendulumStiffened" not in zf.read("SystemStructure.ssd").decode()
        for n in fmus:
            (tmp_path / n.replace("/", "_")).write_bytes(zf.read(n))
    for n in fmus:
        md = read_model_description(str(tmp_path / n.replace("/", "_")))
        assert md.coSimulation.canInterpolateInputs          # the native FMI 2.0 FMUs
        assert not any(v.name.startswith("d2") for v in md.modelVariables)


def test_an_exact_scene_ships_and_runs_the_exact_rungs_fmu(tmp_path):
    """One native plant FMU per rung family: the archive of an exact-rung scene carries
    FlexiblePendulumExact (and no companion: the exact rung states its numerical error), and
    flexpend runs the archive on it."""
    import zipfile
    code, out, err = flexpend("export", "rigid_pd", "--set", "plant.fidelity=exact",
                              "--out", str(tmp_path / "x.ssp"))
    assert code == 0, err
    with zipfile.ZipFile(tmp_path / "x.ssp") as zf:
        assert sorted(n for n in zf.namelist() if n.endswith(".fmu")) == \
            ["resources/FlexiblePendulumExact.fmu", "resources/PDLowPass.fmu"]
    code, out, err = flexpend("run", str(tmp_path / "x.ssp"), "--set", "stop_time=0.05",
                              "--out", str(tmp_path / "o"), "-q")
    assert code == 0, err
    assert "numerical error" in out


def test_the_fidelity_keys_round_trip(tmp_path):
    """The fidelity.* keys are no FMU parameter: the scene annotation carries them, so that the
    archive of a scene on a short mesh (fidelity.max_modes <= plant.n_elements) reads back, and
    a run of it keeps fidelity.companion and the tolerance."""
    keys = {"plant.n_elements": 4, "plant.n_modes": 2, "fidelity.max_modes": 4,
            "fidelity.companion": False, "fidelity.tolerance": 0.02,
            "fidelity.outputs": ["phi_o", "F_c"]}
    code, out, err = flexpend("export", "flexible_pd_lowpass",
                              *(a for k, v in keys.items() for a in
                                ("--set", f"{k}={v!r}".replace("'", '"') if isinstance(v, list)
                                 else f"{k}={str(v).lower() if isinstance(v, bool) else v}")),
                              "--out", str(tmp_path / "x.ssp"))
    assert code == 0, err
    from orchestration.scene.ssp import read_ssp
    system = read_ssp(tmp_path / "x.ssp")
    try:
        for k, v in keys.items():
            assert system.scene.get(k) == v, k
    finally:
        system.close()


def test_export_bad_input_one_line(tmp_path):
    for args, fragment in ((["no_such_scene"], "no scene 'no_such_scene'"),
                           (["rigid_pd", "--out", str(tmp_path / "x.zip")], "must end in .ssp"),
                           (["rigid_pd", "--set", "master.step=-1"], "master.step")):
        code, _, err = flexpend("export", *args)
        assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1


def test_write_ssp_refuses_an_unchosen_model(fmus, tmp_path):
    scene = load_scene("rigid_pd", ["plant.n_modes=auto"])
    with pytest.raises(ValueError, match="choose the model"):
        write_ssp(scene, our_fmus(fmus), tmp_path / "x.ssp")


def test_an_infinite_value_the_fmu_does_not_have_is_written_as_INF(fmus, tmp_path):
    scene = load_scene("rigid_pd", ["plant.phi_limit=inf"])
    path = write_ssp(scene, our_fmus(fmus), tmp_path / "x.ssp")
    assert bound_values(ssd_root(path), "plant")["phi_limit"] == ("Real", "INF")
    with read_ssp(path) as system:
        assert math.isinf(system.scene.config["plant.phi_limit"])


# ---------------------------------------------------------------------- archives within limits
def deflated(members: dict) -> bytes:
    """A zip (deflated) of ``{name: bytes}``, in memory."""
    import io

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def declaring(data: bytes, member: str, size: int) -> bytes:
    """The zip ``data`` with the inflated size of ``member`` in its table of contents (the
    central directory) set to ``size``: a header that lies, as a crafted archive's may."""
    import struct

    name = member.encode()
    at = data.index(b"PK\x01\x02")
    while True:
        n = struct.unpack_from("<H", data, at + 28)[0]
        if data[at + 46:at + 46 + n] == name:
            break
        at = data.index(b"PK\x01\x02", at + 4)
    return data[:at + 24] + struct.pack("<I", size) + data[at + 28:]


ZEROS = bytes(8 << 20)            # 8 MiB of zeros deflate to 8 kB: a ratio of about 1000


def test_an_ssp_zip_bomb_is_refused_before_it_is_inflated(fmus, tmp_path):
    """Failed before the archive limits: the 8 MiB member was inflated whole, then refused as
    'not a readable FMU' (a 2.4 MB bomb of 2 x 1.2 GB took 19 s and 2.1 GB of memory)."""
    path = tmp_path / "bomb.ssp"
    path.write_bytes(deflated({SSD_NAME: (FOREIGN / SSD_NAME).read_bytes(),
                               "resources/regulator.ssv":
                                   (FOREIGN / "resources" / "regulator.ssv").read_bytes(),
                               "resources/FlexiblePendulum.fmu":
                                   Path(fmus["FlexiblePendulum"]).read_bytes(),
                               "resources/PDLowPass.fmu": ZEROS}))
    code, out, err = flexpend("run", str(path), "--out", str(tmp_path / "out"))
    assert code == 2, (out, err)
    assert err.startswith("flexpend: error: bomb.ssp: member 'resources/PDLowPass.fmu' inflates ")
    assert "the limit is 100 times for a member over 1 MiB" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_an_fmu_inside_an_ssp_is_bounded_too(fmus, tmp_path):
    """The FMU (itself a zip) stored in the SSP is checked before fmpy reads its model
    description. Failed before: the 8 MiB modelDescription.xml was inflated and parsed."""
    path = foreign_archive(fmus, tmp_path / "nested.ssp",
                           extra={"resources/PDLowPass.fmu":
                                  deflated({"modelDescription.xml": ZEROS})}.items())
    with pytest.raises(ValueError, match=r"^nested.ssp: component 'Regulator': "
                                         r"resources/PDLowPass.fmu: member 'modelDescription.xml' "
                                         r"inflates 10\d\d times"):
        read_ssp(path)


def test_a_declared_size_beyond_the_limit_is_refused_unread(fmus, tmp_path):
    """A table of contents that declares 300 MiB for a small member: refused on the declared
    size, before reading. Failed before: the member was read (its real 8 kB)."""
    from orchestration.scene import archive

    data = deflated({SSD_NAME: (FOREIGN / SSD_NAME).read_bytes(),
                     "resources/regulator.ssv":
                         (FOREIGN / "resources" / "regulator.ssv").read_bytes(),
                     "resources/FlexiblePendulum.fmu": Path(fmus["FlexiblePendulum"]).read_bytes(),
                     "resources/PDLowPass.fmu": bytes(8000)})
    path = tmp_path / "liar.ssp"
    path.write_bytes(declaring(data, "resources/PDLowPass.fmu", 300 << 20))
    with zipfile.ZipFile(path) as zf:
        assert zf.getinfo("resources/PDLowPass.fmu").file_size == 300 << 20
    assert archive.MAX_MEMBER_BYTES == 256 << 20
    with pytest.raises(ValueError, match=r"^liar.ssp: member 'resources/PDLowPass.fmu' inflates "
                                         r"to 300 MiB; the limit is 256 MiB per member"):
        read_ssp(path)


def test_too_many_members_or_too_much_in_total_is_refused(fmus, tmp_path, monkeypatch):
    """Failed before: any number of members and any total were read."""
    from orchestration.scene import archive

    path = foreign_archive(fmus, tmp_path / "many.ssp",
                           extra=[(f"resources/doc/{i}.txt", b"") for i in range(10_000)])
    with pytest.raises(ValueError, match=r"^many.ssp: 10004 members; the limit is 10000$"):
        read_ssp(path)
    path = foreign_archive(fmus, tmp_path / "large.ssp")
    with zipfile.ZipFile(path) as zf:
        total = sum(i.file_size for i in zf.infolist())
    monkeypatch.setattr(archive, "MAX_TOTAL_BYTES", total - 1)
    with pytest.raises(ValueError, match=r"^large.ssp: the members inflate to more than "
                                         r"[0-9.]+ (MiB|bytes) together; that is the limit$"):
        read_ssp(path)


def test_fmpy_parameter_set_reads_within_the_limits(fmus, tmp_path):
    from orchestration.scene.ssp import fmpy_parameter_set

    path = foreign_archive(fmus, tmp_path / "nested.ssp",
                           extra={"resources/PDLowPass.fmu":
                                  deflated({"modelDescription.xml": ZEROS})}.items())
    with pytest.raises(ValueError, match="member 'modelDescription.xml' inflates 10\\d\\d times"):
        fmpy_parameter_set(path)


def test_the_damping_law_goes_into_the_archive_and_back(fmus, native, tmp_path):
    """plant.damping is a String parameter of the plant FMU (value reference 72): an exported
    scene binds it, the archive read back has the same law, and a run of it is the scene's run
    (the native pair: the law reaches the FMU)."""
    scene = load_scene("flexible_pd_lowpass", {"plant.damping": "kelvin-voigt", "stop_time": 0.5})
    path = write_ssp(scene, our_fmus(native), tmp_path / "kv.ssp")
    assert bound_values(ssd_root(path), "plant")["damping"] == ("String", "kelvin-voigt")
    with read_ssp(path) as system:
        assert system.scene.plant.beam.damping == "kelvin-voigt"
        assert system.scene.config == scene.config
        via = run_scene(system.scene, system.fmus, progress=False)
    direct = run_scene(scene, our_fmus(native), progress=False)
    modal = run_scene(load_scene(scene, {"plant.damping": "modal"}), our_fmus(native),
                      progress=False)
    assert np.array_equal(via.result, direct.result)
    # the laws apart: 1.1e-3 of 3.1e-2 in eta_1 over 0.5 s
    assert np.max(np.abs(direct.result["eta_1"] - modal.result["eta_1"])) > \
        0.01 * np.max(np.abs(modal.result["eta_1"]))
