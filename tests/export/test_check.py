"""flexpend check: one FMU against reference results in the FMI cross-check layout.

Every verdict is measured against the committed references (tests/reference/, made with the
physics as it is) or against those --write-reference writes: they pass; an FMU built from a plant
whose EI is 1 % higher fails; a reference with one signal shifted by twice its band fails on that
signal alone; a run that an FMU stops with a discard fails although fmpy.simulate_fmu returns
normally from it; a controller held at zero, a plant that ignores its input, one moved by 1 mm
and one fed its force 5 ms late fail; a reference that does not vary is refused. The rule itself
(fmpy.util.validate_signal) is tested on results edited: held at zero, delayed, moved, a NaN.
Every check runs the command line in a child process (an FMU's Python code, once loaded, stays in
a process), or check_fmu, which simulates in one.
"""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.util import read_csv, write_csv

from orchestration.export.check import (FMPY_RULE, REFERENCE_OUTPUTS, Rule, compare,
                                        reference_files)
from orchestration.export.python_fmus import ROOT

REFERENCES = ROOT / "tests" / "reference"
TIGHT = ["--tolerance", "0.01", "--window", "1", "--max-outliers", "0"]


def check(*args):
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", "check", *map(str, args)],
                          capture_output=True, text=True, timeout=600)
    return proc.returncode, proc.stdout, proc.stderr


def signal_lines(out):
    """signal -> its line (the lines that end with ': pass' or ': FAIL')."""
    return {line.split()[0]: line for line in out.splitlines()
            if line.startswith("  ") and not line.startswith("  run: ")
            and line.rstrip().endswith((": pass", ": FAIL"))}


def copy_reference(name, dest):
    shutil.copytree(REFERENCES / name, dest / name)
    return reference_files(name, dest)


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
@pytest.mark.parametrize("rule", [[], TIGHT, ["--tolerance", "1e-6", "--window", "1",
                                              "--max-outliers", "0"]],
                         ids=["fmpy-rule", "1%", "1e-6"])
def test_passes_on_the_committed_references(fmus, name, rule):
    code, out, err = check(fmus[name], "--reference", REFERENCES, *rule)
    assert code == 0, out + err
    lines = signal_lines(out)
    assert list(lines) == REFERENCE_OUTPUTS[name]            # one line per reference signal
    assert all(line.endswith(": pass") and "0/1001 outside" in line for line in lines.values())
    assert out.splitlines()[-1].startswith("PASSED")


@pytest.fixture(scope="module")
def stiffer_plant(tmp_path_factory):
    """FlexiblePendulum built from a copy of the sources whose default EI is 1 % higher."""
    src = tmp_path_factory.mktemp("src_EI")
    for pkg in ("fmu_common", "plant_fmu", "controller_fmu", "orchestration"):
        shutil.copytree(ROOT / pkg, src / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    params = src / "plant_fmu" / "params.py"
    text = params.read_text()
    assert text.count("EI: float = real(8.75e2,") == 1
    params.write_text(text.replace("EI: float = real(8.75e2,", "EI: float = real(8.8375e2,"))
    env = {**os.environ, "PYTHONPATH": str(src)}
    code = ("import sys; from orchestration.export.python_fmus import build_fmus; "
            "print(build_fmus(sys.argv[1], ['FlexiblePendulum'])['FlexiblePendulum'])")
    proc = subprocess.run([sys.executable, "-c", code, str(src / "fmus")], cwd=src, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    fmu = src / "fmus" / "FlexiblePendulum.fmu"
    start = {v.name: v.start for v in read_model_description(str(fmu)).modelVariables}
    assert float(start["EI"]) == 883.75                   # built from the modified copy
    return fmu


def test_fails_on_a_plant_with_EI_one_percent_higher(stiffer_plant):
    code, out, err = check(stiffer_plant, "--reference", REFERENCES, *TIGHT)
    assert code == 1, out + err
    lines = signal_lines(out)
    failed = {n for n, line in lines.items() if line.endswith("FAIL")}
    # 1 % of the range at every sample: every signal but the cart position (0.95 %) leaves it
    assert failed >= {"x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1", "energy"}
    assert out.splitlines()[-1].startswith("FAILED: ")
    # FMPy's default band (10 % of the range, widened over 21 samples) is meant for comparing
    # tools: the tip angle (7 % off at most) stays inside it; the energy, which holds EI itself,
    # leaves it on more than 10 % of the samples
    code, out, err = check(stiffer_plant, "--reference", REFERENCES)
    assert code == 1
    lines = signal_lines(out)
    assert lines["energy"].endswith("FAIL") and lines["phi_o"].endswith("pass")


def test_fails_on_a_reference_signal_shifted_by_twice_the_band(fmus, tmp_path):
    files = copy_reference("FlexiblePendulum", tmp_path)
    ref = read_csv(str(files["ref"]))
    span = np.ptp(ref["phi_o"])
    ref["phi_o"] += 2 * FMPY_RULE.tolerance * span           # twice the band's half-width
    write_csv(str(files["ref"]), ref)
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path)
    assert code == 1, out + err
    lines = signal_lines(out)
    # the widened band still holds the result where the reference varies fast within 21
    # samples (the tip's ripple); about half of the samples are outside, far above 10 %
    outside = int(lines["phi_o"].split(" outside")[0].split()[-1].split("/")[0])
    assert lines["phi_o"].endswith("FAIL") and outside > 0.3 * 1001
    assert f"max |deviation| {2 * FMPY_RULE.tolerance * span:.3e}" in lines["phi_o"]
    assert all(line.endswith("pass") for n, line in lines.items() if n != "phi_o")
    assert out.splitlines()[-1] == "FAILED: 1 of 7 signals outside their band"


def diverging_reference(tmp_path):
    """The plant's reference with an input that topples the pendulum at about 0.1 s."""
    files = copy_reference("FlexiblePendulum", tmp_path)
    inputs = read_csv(str(files["in"]))
    inputs["F_c"] = 2000.0
    write_csv(str(files["in"]), inputs)
    return files


def test_fails_on_a_run_stopped_by_a_discard(fmus, tmp_path):
    files = diverging_reference(tmp_path)
    # the trap: fmpy.simulate_fmu returns normally, with a result that ends early
    result = simulate_fmu(fmus["FlexiblePendulum"], stop_time=1.0, step_size=1e-3,
                          output_interval=1e-3, input=read_csv(str(files["in"])),
                          output=REFERENCE_OUTPUTS["FlexiblePendulum"])
    assert 0.05 < result["time"][-1] < 0.2
    # and a reference that is that truncated run: every sample agrees, only the stop is wrong
    write_csv(str(files["ref"]), result)
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, "--plot",
                           tmp_path / "check.png")
    assert code == 1, out + err
    assert all(line.endswith(": pass") for line in signal_lines(out).values())
    (run_line,) = [line for line in out.splitlines() if line.startswith("  run: ")]
    assert "stopped early: doStep at t = 0.096 returned discard" in run_line
    assert "exceeds phi_limit" in run_line and run_line.endswith(": FAIL")
    (verdict,) = [line for line in out.splitlines() if line.startswith("FAILED")]
    assert verdict == "FAILED: the run did not complete"
    assert (tmp_path / "check.png").stat().st_size > 20_000


def test_fails_on_an_fmu_that_refuses_to_step(fmus):
    """A bad parameter: the plant refuses it at initialisation (fmi2Error from
    fmi2ExitInitializationMode, with the reason)."""
    from orchestration.export.check import check_fmu

    report = check_fmu(fmus["FlexiblePendulum"], REFERENCES, start_values={"n_modes": -1})
    assert not report.passed
    assert "fmi2ExitInitializationMode" in report.failure and "status 3 (error)" in report.failure
    assert "n_modes = -1 is out of range" in report.failure


def test_plot_draws_every_signal(fmus, tmp_path):
    from matplotlib.image import imread

    code, out, err = check(fmus["FlexiblePendulum"], "--reference", REFERENCES, "--plot",
                           tmp_path / "p.png")
    assert code == 0 and f"plot: {tmp_path / 'p.png'}" in out
    height, width = imread(tmp_path / "p.png").shape[:2]
    assert width > 900 and height > 7 * 180                 # one panel per signal


def test_write_reference_reproduces_the_committed_one(fmus, tmp_path):
    files = copy_reference("FlexiblePendulum", tmp_path)
    committed = read_csv(str(files["ref"]))
    files["ref"].unlink()
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path,
                           "--write-reference", "--outputs", ",".join(committed.dtype.names[1:]))
    assert code == 0, out + err
    new = read_csv(str(files["ref"]))
    assert new.dtype.names == committed.dtype.names
    tight = compare(new, committed, FMPY_RULE.__class__(1e-6, 1, 0.0))
    assert all(s.passed for s in tight.values())
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, *TIGHT)
    assert code == 0


def test_write_reference_from_the_default_experiment(fmus, tmp_path):
    """An input file and no options file: the FMU's default experiment writes one."""
    de = read_model_description(fmus["PDLowPass"]).defaultExperiment
    (tmp_path / "PDLowPass").mkdir()
    files = reference_files("PDLowPass", tmp_path)
    shutil.copy(REFERENCES / "PDLowPass" / "PDLowPass_in.csv", files["in"])
    code, out, err = check(fmus["PDLowPass"], "--reference", tmp_path, "--write-reference")
    assert code == 0, out + err
    assert files["opt"].read_text().splitlines()[:3] == [
        f"StartTime,{float(de.startTime or 0.0)!r}", f"StopTime,{float(de.stopTime)!r}",
        f"StepSize,{float(de.stepSize)!r}"]
    assert out.splitlines()[1:] == [f"  inputs {files['in']}", f"  options {files['opt']} "
                                    "(written)"]
    ref = read_csv(str(files["ref"]))
    n = round((float(de.stopTime) - float(de.startTime or 0.0)) / float(de.stepSize))
    assert ref.dtype.names == ("time", "F_c") and len(ref) == n + 1 and np.ptp(ref["F_c"]) > 0


# ---------------------------------------------------------------------- an informative reference
@pytest.fixture(scope="module")
def written(fmus, tmp_path_factory):
    """``flexpend check --write-reference`` of both FMUs into an empty folder: (folder, {name:
    the command's output})."""
    folder = tmp_path_factory.mktemp("written")
    outs = {}
    for name in ("FlexiblePendulum", "PDLowPass"):
        code, out, err = check(fmus[name], "--reference", folder, "--write-reference")
        assert code == 0, out + err
        outs[name] = out
    return folder, outs


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
def test_write_reference_drives_the_fmu_with_flexpends_excitation(fmus, written, name):
    """An empty folder: the excitation of the project's own reference is the input file, with
    its options; every output that varies is recorded, and agrees with the committed
    reference."""
    folder, outs = written
    files, committed = reference_files(name, folder), reference_files(name)
    assert files["in"].read_bytes() == committed["in"].read_bytes()
    assert files["opt"].read_bytes() == committed["opt"].read_bytes()
    ref = read_csv(str(files["ref"]))
    assert all(np.ptp(ref[n]) > 0 for n in ref.dtype.names[1:])
    md = read_model_description(fmus[name])
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    start = {v.name: v.start for v in md.modelVariables}
    # the modes beyond the model's (n_modes) stay at zero: left out, and said so
    idle = [n for n in outputs if n.startswith("eta_") and int(n[4:]) > int(start.get(
        "n_modes", 99))]
    assert list(ref.dtype.names[1:]) == [n for n in outputs if n not in idle]
    kind = "plant" if name == "FlexiblePendulum" else "controller"
    lines = outs[name].splitlines()
    assert lines[0] == (f"wrote {files['ref']}: {len(outputs) - len(idle)} signal"
                        f"{'s' * (len(outputs) - len(idle) != 1)}, 0 to 1 s in steps of 0.001 s")
    assert lines[1].startswith(f"  inputs {files['in']} (written): flexpend's excitation of "
                               f"the {kind}, ")
    assert lines[2] == f"  options {files['opt']} (written)"
    assert lines[3:] == ([f"  left out, constant in this run (no band): {', '.join(idle)}"]
                         if idle else [])
    tight = compare(ref, read_csv(str(committed["ref"])), Rule(1e-6, 1, 0.0))
    assert {n for n in REFERENCE_OUTPUTS[name]} <= set(ref.dtype.names)
    assert all(tight[n].passed for n in REFERENCE_OUTPUTS[name])


CI_RULE = ["--tolerance", "1e-3", "--window", "1", "--max-outliers", "0"]


@pytest.mark.parametrize("name", ["FlexiblePendulum", "PDLowPass"])
@pytest.mark.parametrize("rule", [[], CI_RULE], ids=["fmpy-rule", "ci"])
def test_the_genuine_fmu_passes_its_written_reference(fmus, written, name, rule):
    code, out, err = check(fmus[name], "--reference", written[0], *rule)
    assert code == 0 and out.splitlines()[-1].startswith("PASSED"), out + err


def test_an_fmu_held_at_zero_fails(fmus, written):
    """The controller with zero gains: its force is held at 0 (an FMU wrapped by start values
    that make it wrong)."""
    from orchestration.export.check import FMPY_RULE, check_fmu

    ref = read_csv(str(reference_files("PDLowPass", written[0])["ref"]))
    for rule in (FMPY_RULE, Rule(1e-3, 1, 0.0)):
        report = check_fmu(fmus["PDLowPass"], written[0], rule, start_values={"kp": 0.0,
                                                                              "kd": 0.0})
        assert report.failure is None and not report.passed
        assert np.all(report.run.result["F_c"] == 0.0)
        s = report.signals["F_c"]
        assert s.outliers > rule.max_outliers * s.samples
        if rule.window == 1:            # outside wherever the reference is beyond the band
            assert s.outliers == np.count_nonzero(np.abs(ref["F_c"]) > s.half_width) > 990


def test_a_plant_that_ignores_its_input_fails(fmus, written, tmp_path):
    """The plant fed no force stays at rest: its outputs are held at their initial values."""
    shutil.copytree(written[0] / "FlexiblePendulum", tmp_path / "FlexiblePendulum")
    files = reference_files("FlexiblePendulum", tmp_path)
    inputs = read_csv(str(files["in"]))
    inputs["F_c"] = 0.0
    write_csv(str(files["in"]), inputs)
    for rule in ([], CI_RULE):
        code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, *rule)
        assert code == 1, out + err
        failed = [n for n, line in signal_lines(out).items() if line.endswith("FAIL")]
        assert {"x_o", "energy"} <= set(failed)              # never near their initial values
        if rule:
            assert len(failed) == len(signal_lines(out)) == 11
        assert out.splitlines()[-1].startswith(f"FAILED: {len(failed)} of 11 signals outside")


def test_a_plant_moved_in_value_fails(fmus, written):
    """The cart started 1 mm off (x0 = 1e-3): the cart's position moves by 1 mm (3 % of its
    range), the rest is the same."""
    from orchestration.export.check import FMPY_RULE, check_fmu

    report = check_fmu(fmus["FlexiblePendulum"], written[0], Rule(1e-3, 1, 0.0),
                       start_values={"x0": 1e-3})
    assert not report.passed
    assert [n for n, s in report.signals.items() if not s.passed] == ["x_o"]
    assert abs(report.signals["x_o"].max_deviation - 1e-3) < 1e-12
    # within FMPy's band (10 % of the range)
    assert check_fmu(fmus["FlexiblePendulum"], written[0], FMPY_RULE,
                     start_values={"x0": 1e-3}).passed


def test_a_plant_moved_in_time_fails_without_the_window(fmus, written, tmp_path):
    """The plant fed its force 5 ms late (an FMU that applies its input late): its outputs are
    the reference's, 5 ms later. FMPy's band, widened over 21 samples, holds them; the band of
    the CI recipe does not."""
    shutil.copytree(written[0] / "FlexiblePendulum", tmp_path / "FlexiblePendulum")
    files = reference_files("FlexiblePendulum", tmp_path)
    inputs = read_csv(str(files["in"]))
    late = inputs.copy()
    for n in inputs.dtype.names[1:]:
        late[n][5:], late[n][:5] = inputs[n][:-5], 0.0
    write_csv(str(files["in"]), late)
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path)
    assert code == 0, out + err
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, *CI_RULE)
    assert code == 1, out + err
    assert all(line.endswith("FAIL") for line in signal_lines(out).values())


def test_write_reference_refuses_a_signal_that_does_not_vary(fmus, tmp_path):
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path / "new" / "refs",
                           "--write-reference", "--outputs", "x_o,eta_5")
    assert code == 2 and len(err.strip().splitlines()) == 1, out + err
    assert ("no reference written: eta_5 does not vary in this run (a constant gives no band: "
            "an FMU held there would pass); flexpend's excitation of the plant does not move "
            "them, or leave them out (--outputs)") in err
    assert list(tmp_path.iterdir()) == []                   # nothing written, nothing left


def test_write_reference_refuses_an_old_reference_of_10_s(fmus, tmp_path):
    """A folder --write-reference wrote before: the options of the FMU's default experiment
    (10 s) and no input file. The excitation over 10 s topples the pendulum; nothing is written
    and the hint says why."""
    d = tmp_path / "FlexiblePendulum"
    d.mkdir()
    (d / "FlexiblePendulum_ref.opt").write_text("StartTime,0.0\nStopTime,10.0\n"
                                                "StepSize,0.001\n")
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, "--write-reference")
    assert code == 2 and "no reference written: stopped early: doStep at t = " in err, out + err
    assert err.rstrip().endswith("(flexpend's excitation of the plant is meant for 1 s, "
                                 "FlexiblePendulum_ref.opt asks 10 s: remove it to have the "
                                 "excitation's written)")
    assert sorted(p.name for p in d.iterdir()) == ["FlexiblePendulum_ref.opt"]
    (d / "FlexiblePendulum_ref.opt").unlink()
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, "--write-reference")
    assert code == 0, out + err


def test_write_reference_refuses_a_result_that_is_not_finite(fmus, tmp_path, monkeypatch):
    """A run whose output holds a NaN (here: the plant's run with one sample made NaN)."""
    from orchestration.export import check as module

    simulate = module.simulate_case

    def nan_at_t(*args, **kw):
        run = simulate(*args, **kw)
        run.result["phi_o"][500] = np.nan
        return run

    monkeypatch.setattr(module, "simulate_case", nan_at_t)
    with pytest.raises(module.ReferenceError, match=r"^FlexiblePendulum.fmu: no reference written: "
                       r"phi_o is not finite in this run \(NaN or inf\): a band needs finite "
                       r"values$"):
        module.write_reference(fmus["FlexiblePendulum"], tmp_path)
    assert list(tmp_path.iterdir()) == []


def renamed_input(fmu, dest):
    """A copy of ``fmu`` whose input F_c is named u in its modelDescription.xml."""
    import re
    import zipfile

    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "modelDescription.xml":
                data, n = re.subn(rb'name="F_c"', b'name="u"', data)
                assert n == 1
            out.writestr(info, data)
    return dest


def test_write_reference_refuses_inputs_it_has_no_excitation_for(fmus, tmp_path):
    fmu = renamed_input(fmus["FlexiblePendulum"], tmp_path / "Pendulum.fmu")
    code, out, err = check(fmu, "--reference", tmp_path / "refs", "--write-reference")
    assert code == 2 and len(err.strip().splitlines()) == 1, out + err
    assert (f"{tmp_path / 'refs' / 'Pendulum' / 'Pendulum_in.csv'}: missing, and flexpend has "
            "no excitation for the inputs of Pendulum.fmu (u, dF_c, d2F_c; it has the plant's: "
            "F_c; the controller's: phi_o, omega_o, x_o): write Pendulum_in.csv") in err
    assert not (tmp_path / "refs").exists()


def test_write_reference_refuses_a_run_that_stops_early(fmus, tmp_path):
    files = diverging_reference(tmp_path)
    before = files["ref"].read_bytes()
    code, out, err = check(fmus["FlexiblePendulum"], "--reference", tmp_path, "--write-reference")
    assert code == 2 and "no reference written: stopped early" in err
    assert files["ref"].read_bytes() == before


def test_refuses_a_reference_of_the_plant_at_rest(fmus, tmp_path):
    """What --write-reference recorded before (the plant at rest, no input: all 15 signals
    constant), and a check of it at --tolerance 1e-6 said PASSED, whatever the FMU's outputs."""
    fmu = fmus["FlexiblePendulum"]
    outputs = [v.name for v in read_model_description(fmu).modelVariables
               if v.causality == "output"]
    rest = simulate_fmu(fmu, stop_time=1.0, step_size=1e-3, output_interval=1e-3,
                        output=outputs)
    assert all(np.ptp(rest[n]) == 0 for n in outputs)
    (tmp_path / "FlexiblePendulum").mkdir()
    files = reference_files("FlexiblePendulum", tmp_path)
    write_csv(str(files["ref"]), rest)
    files["opt"].write_text("StartTime,0.0\nStopTime,1.0\nStepSize,0.001\n")
    code, out, err = check(fmu, "--reference", tmp_path, "--tolerance", "1e-6")
    assert code == 2 and out == "", out + err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"flexpend: error: {files['ref']}: {', '.join(outputs)} do not vary "
                          "(a constant gives no band")
    assert "--write-reference" in err and "leave them out of FlexiblePendulum_ref.csv" in err
    # one constant signal among varying ones: refused too, naming it alone
    ref = read_csv(str(REFERENCES / "FlexiblePendulum" / "FlexiblePendulum_ref.csv"))
    ref["eta_1"] = 0.0
    shutil.copy(REFERENCES / "FlexiblePendulum" / "FlexiblePendulum_in.csv", files["in"])
    write_csv(str(files["ref"]), ref)
    code, out, err = check(fmu, "--reference", tmp_path)
    assert code == 2 and f"{files['ref']}: eta_1 does not vary (" in err, out + err
    # and a reference that is not finite
    ref["eta_1"][3] = np.nan
    write_csv(str(files["ref"]), ref)
    code, out, err = check(fmu, "--reference", tmp_path)
    assert code == 2 and f"{files['ref']}: eta_1 is not finite" in err, out + err


@pytest.mark.parametrize("args, fragment", [
    (["{fmu}", "--reference", "{tmp}/nowhere"], "no reference of FlexiblePendulum.fmu"),
    (["{tmp}/missing.fmu", "--reference", "{ref}"], "missing.fmu: no such FMU"),
    (["{fmu}", "--reference", "{ref}", "--tolerance", "0"], "--tolerance = 0.0 is out of range; allowed"),
    (["{fmu}", "--reference", "{ref}", "--max-outliers", "1.5"], "--max-outliers = 1.5"),
    (["{fmu}"], "the following arguments are required: --reference"),
])
def test_bad_input_one_line_exit_2(fmus, tmp_path, args, fragment):
    args = [a.format(fmu=fmus["FlexiblePendulum"], tmp=tmp_path, ref=REFERENCES) for a in args]
    code, out, err = check(*args)
    assert code == 2 and fragment in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


# ---------------------------------------------------------------------- the host side's faults
def renamed_model(fmu, dest, model_name):
    """A copy of ``fmu`` whose modelDescription.xml gives ``model_name`` as its modelName."""
    import re
    import zipfile

    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "modelDescription.xml":
                data, n = re.subn(rb'modelName="[^"]*"', f'modelName="{model_name}"'.encode(), data)
                assert n == 1
            out.writestr(info, data)
    return dest


@pytest.mark.parametrize("where", ["absolute", "dotdot"])
def test_references_are_looked_up_only_inside_the_reference_folder(fmus, tmp_path, where):
    """An FMU whose modelName is a path names the reference it is compared against: with an
    empty --reference it was compared with a reference outside and PASSED. Failed before the
    names were sanitised (exit 0)."""
    shutil.copytree(REFERENCES / "FlexiblePendulum", tmp_path / "outside")
    (tmp_path / "empty").mkdir()
    name = (str(tmp_path / "outside" / "FlexiblePendulum") if where == "absolute"
            else "../outside/FlexiblePendulum")
    fmu = renamed_model(fmus["FlexiblePendulum"], tmp_path / "Evil.fmu", name)
    assert read_model_description(str(fmu)).modelName == name
    code, out, err = check(fmu, "--reference", tmp_path / "empty")
    assert code == 2, out + err
    assert "PASSED" not in out and err.startswith(f"flexpend: error: {tmp_path / 'empty'}: no "
                                                  "reference of Evil.fmu (Evil_ref.csv or "
                                                  "FlexiblePendulum_ref.csv, ")
    assert len(err.strip().splitlines()) == 1
    # the same reference inside the folder, under a plain name, is found and passes
    shutil.copytree(REFERENCES / "FlexiblePendulum", tmp_path / "empty" / "FlexiblePendulum")
    code, out, err = check(fmu, "--reference", tmp_path / "empty")
    assert code == 0 and "empty/FlexiblePendulum/FlexiblePendulum_ref.csv" in out, out + err


def test_a_bomb_fmu_is_refused_before_fmpy_reads_it(tmp_path):
    """Failed before: fmpy inflated the 8 MiB modelDescription.xml to read the model's name."""
    import zipfile

    with zipfile.ZipFile(tmp_path / "Bomb.fmu", "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("modelDescription.xml", bytes(8 << 20))
    code, out, err = check(tmp_path / "Bomb.fmu", "--reference", REFERENCES)
    assert code == 2, out + err
    assert "Bomb.fmu: member 'modelDescription.xml' inflates " in err and "the limit is 100 times" \
        in err and len(err.strip().splitlines()) == 1


def test_a_window_beyond_the_samples_is_the_whole_signal():
    """--window 99999999999999999999: an OverflowError traceback in scipy before; a window wider
    than the signal is the whole signal, as a window of 2n + 1 samples is."""
    from orchestration.export.check import Rule, band

    t = np.linspace(0.0, 1.0, 101)
    y = np.sin(7.0 * t)
    wide = band(t, y, Rule(0.1, 10 ** 20, 0.1))
    assert np.array_equal(wide[1], band(t, y, Rule(0.1, 2 * y.size + 1, 0.1))[1])
    assert np.allclose(wide[1], y.min() - 0.1 * np.ptp(y), rtol=0, atol=1e-15)
    assert np.allclose(wide[2], y.max() + 0.1 * np.ptp(y), rtol=0, atol=1e-15)


# ---------------------------------------------------------------------- the rule on edited results
@pytest.fixture(scope="module")
def genuine():
    """The plant's committed reference: the result of the genuine FMU (a fresh run agrees with it
    to 3.4e-9 of the range, tests/export/test_fmu_reference.py)."""
    return read_csv(str(REFERENCES / "FlexiblePendulum" / "FlexiblePendulum_ref.csv"))


def edited(result, how, k=0, offset=0.0):
    """A copy of ``result`` whose signals are held at zero, delayed by ``k`` samples (the first
    value held before) or moved by ``offset`` times each signal's range."""
    out = result.copy()
    for n in result.dtype.names[1:]:
        if how == "zero":
            out[n] = 0.0
        elif how == "delayed":
            out[n][k:] = result[n][:-k]
            out[n][:k] = result[n][0]
        elif how == "offset":
            out[n] += offset * np.ptp(result[n])
    return out


RULES = {"fmpy": FMPY_RULE, "1e-6": Rule(1e-6), "ci": Rule(1e-3, 1, 0.0),
         "reference": Rule(1e-6, 1, 0.0)}


@pytest.mark.parametrize("rule", RULES, ids=list(RULES))
def test_the_rule_passes_the_genuine_result_and_fails_one_held_at_zero(genuine, rule):
    assert all(s.passed and s.outliers == 0 for s in compare(genuine, genuine, RULES[rule])
               .values())
    zero = compare(edited(genuine, "zero"), genuine, RULES[rule])
    # the cart's position and the energy never come near zero: every rule fails them
    assert not zero["x_o"].passed and not zero["energy"].passed
    if rule in ("ci", "reference"):
        assert not any(s.passed for s in zero.values())
    else:
        # widened over 21 samples (21 ms), the band of a signal that rings about zero at 24 Hz
        # holds zero: the rates and the bending modes held at zero pass FMPy's rule
        assert zero["omega_o"].passed and zero["eta_1"].passed


@pytest.mark.parametrize("k", [1, 5, 10])
def test_a_result_delayed_by_k_samples_fails_without_the_window(genuine, k):
    delayed = edited(genuine, "delayed", k)
    assert all(s.passed for s in compare(delayed, genuine, FMPY_RULE).values())  # the window
    assert all(s.passed for s in compare(delayed, genuine, RULES["1e-6"]).values())
    ci = compare(delayed, genuine, RULES["ci"])
    assert not any(s.passed for s in ci.values())


def test_a_result_moved_by_twice_the_band_fails(genuine):
    for name in ("fmpy", "ci", "reference"):
        rule = RULES[name]
        moved = compare(edited(genuine, "offset", offset=2 * rule.tolerance), genuine, rule)
        assert not any(s.passed for s in moved.values()), name
        if rule.window == 1:                       # widened, the band holds it where y is steep
            assert all(s.outliers == s.samples for s in moved.values())
    # --tolerance 1e-6 alone: the band widened over 21 samples is as wide as the signal moves in
    # 21 ms, which a move of 2e-6 of the range stays within on most samples
    moved = compare(edited(genuine, "offset", offset=2e-6), genuine, RULES["1e-6"])
    assert all(s.passed and 0 < s.outliers < 0.1 * s.samples for s in moved.values())


@pytest.mark.parametrize("where", [0, 500, -1])
def test_one_bad_sample_anywhere_fails_the_strict_rule(genuine, where):
    """fmpy.util.validate_signal leaves the first and the last sample out of its count, and
    finds no NaN outside: here every sample counts, and a NaN is outside."""
    for value in (np.nan, 1e3):
        bad = genuine.copy()
        bad["phi_o"][where] = value
        checks = compare(bad, genuine, RULES["reference"])
        assert not checks["phi_o"].passed and checks["phi_o"].outliers == 1
        assert all(s.passed for n, s in checks.items() if n != "phi_o")


def test_repeated_times_late_in_a_run_do_not_hang():
    """fmpy.util.validate_signal moves a repeated time by 1e-13 s in a loop, which never ends
    beyond 2**10 s (1e-13 is below the spacing of the floats there): an event at t = 1500 s hung
    the check."""
    import signal

    def hung(signum, frame):
        raise TimeoutError("compare() hung")

    t = np.concatenate([np.linspace(1000.0, 1500.0, 501), np.linspace(1500.0, 2000.0, 501)])
    ref = np.zeros(t.size, dtype=[("time", "f8"), ("y", "f8")])
    ref["time"], ref["y"] = t, np.where(np.arange(t.size) > 500, 1.0, 0.0) + 1e-3 * t
    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(30)
    try:
        checks = compare(ref, ref, FMPY_RULE)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    assert checks["y"].passed and checks["y"].samples == t.size


def test_a_reference_signal_that_does_not_vary_fails_whatever_the_result(genuine):
    ref = genuine.copy()
    ref["x_o"] = 0.0
    checks = compare(ref, ref, FMPY_RULE)
    assert checks["x_o"].problem == "constant in the reference: no band"
    assert not checks["x_o"].passed
    assert all(s.passed for n, s in checks.items() if n != "x_o")
