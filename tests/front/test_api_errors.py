"""The front door speaks Python: an error names the key, what is allowed and (for a misspelt
key) the closest one, in one line of at most 200 characters without the command line's words;
a value of the wrong type is a TypeError; the limit a message quotes is the one enforced;
``Run.save`` takes a folder only; every result has a short ``repr``; every exported name is
documented."""
import difflib
import math
import re
import sys

import numpy as np
import pytest

import orchestration as fp
from orchestration.api import scene_keys
from orchestration.job import Run
from orchestration.scene.keys import ConfigError
from orchestration.scene.records import KEYS
from orchestration.studies.analysis import Analysis

CLI_WORDS = ("--set", "flexpend", "--grid", "--values", "--sample", "--out")
ALL_KEYS = list(KEYS)


def _closest(word, words):
    return difflib.get_close_matches(word, list(words), n=1)[0]


def _raised(call, kind):
    with pytest.raises(kind) as info:
        call()
    message = str(info.value)
    assert "\n" not in message and len(message) <= 200, message
    assert not any(w in message for w in CLI_WORDS), message
    return info.value


@pytest.mark.parametrize("call,key", [
    (lambda: fp.simulate("flexible_pd", {"plant.n_mode": 3}), "plant.n_mode"),
    (lambda: fp.load_scene("rigid_pd", {"controller.kpp": 1}), "controller.kpp"),
    (lambda: fp.load_scene({"master.stepp": 1e-3}), "master.stepp"),
    (lambda: fp.load_scene("rigid_pd", ["initial.ph=0.1"]), "initial.ph"),
    (lambda: fp.analyze(overrides={"fidelity.max_mode": 3}), "fidelity.max_mode"),
])
def test_a_misspelt_key_is_named_with_its_closest_match(call, key):
    exc = _raised(call, ConfigError)
    assert isinstance(exc, ValueError)
    assert repr(key) in str(exc) and repr(_closest(key, ALL_KEYS)) in str(exc)
    assert "orchestration.scene_keys()" in str(exc)          # where every key is listed


def test_a_misspelt_design_key_is_named_with_its_closest_match():
    from orchestration.studies.design import DESIGN_DEFAULTS

    exc = _raised(lambda: fp.design(design={"design.level": 3}), ConfigError)
    assert "'design.level'" in str(exc)
    assert repr(_closest("design.level", DESIGN_DEFAULTS)) in str(exc)


def test_a_misspelt_sweep_key_is_named_in_the_arguments_words(tmp_path):
    exc = _raised(lambda: fp.sweep("rigid_pd", values={"controller.kpp": [1, 2]}, serial=True,
                                   out=tmp_path, progress=False), ConfigError)
    assert str(exc).startswith("values: ") and "'controller.kp'" in str(exc)
    assert exc.cli.startswith("--values: ") and "flexpend keys" in exc.cli


def test_the_command_line_words_the_same_message_its_way():
    """One message, two readers: the CLI's form names --set and flexpend keys."""
    exc = _raised(lambda: fp.load_scene("rigid_pd", {"plant.n_mode": 3}), ConfigError)
    assert exc.cli == "--set: " + str(exc).replace("orchestration.scene_keys()", "flexpend keys")


@pytest.mark.parametrize("overrides,key", [
    ({"stop_time": "abc"}, "stop_time"),
    ({"controller.kp": "500"}, "controller.kp"),
    ({"plant.n_modes": "4"}, "plant.n_modes"),
    ({"controller.filter_order": "2"}, "controller.filter_order"),
    ({"master.adaptive": "yes"}, "master.adaptive"),
    ({"initial.phi": "0.1"}, "initial.phi"),
    ({"plant.m": [1.0]}, "plant.m"),
])
def test_a_value_of_the_wrong_type_is_a_type_error(overrides, key):
    exc = _raised(lambda: fp.load_scene({}, overrides), TypeError)
    assert isinstance(exc, ConfigError) and str(exc).startswith(key)


def test_a_wrong_type_in_a_scene_dict_and_in_simulate_is_a_type_error():
    _raised(lambda: fp.load_scene({"master.step": "1e-3"}), TypeError)
    _raised(lambda: fp.simulate("rigid_pd", {"stop_time": "2"}), TypeError)


def test_a_huge_value_is_cut_in_the_message():
    exc = _raised(lambda: fp.load_scene({}, {"master.algorithm": "x" * 10**6}), ConfigError)
    assert "master.algorithm" in str(exc) and "gauss-seidel" in str(exc)
    exc = _raised(lambda: fp.load_scene({}, {"y" * 10**5: 1}), ConfigError)
    assert "unknown key" in str(exc)


def _quoted_limit(message: str) -> float:
    m = re.search(r"allowed: \|initial\.phi\| <= ([0-9.e+-]+)", message)
    assert m, message
    return float(m[1])


@pytest.mark.parametrize("phi_limit", [None, 0.5, 2.5, math.inf])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e7])
def test_the_limit_quoted_for_initial_phi_is_the_enforced_one(phi_limit, bad):
    """The limit a bad initial.phi quotes is where the loader draws the line: just inside it is
    taken, just outside refused (NaN quoted +-1e6 before, though pi/2 was the limit)."""
    base = {} if phi_limit is None else {"plant.phi_limit": phi_limit}
    exc = _raised(lambda: fp.load_scene(base, {"initial.phi": bad}), ValueError)
    assert "initial.phi" in str(exc)
    limit = _quoted_limit(str(exc))
    expected = min(math.pi / 2 if phi_limit is None else phi_limit, 1e6)
    assert limit == pytest.approx(expected, rel=1e-5)
    for sign in (1, -1):
        fp.load_scene(base, {"initial.phi": sign * limit * (1 - 1e-4),
                             "plant.energy_limit": math.inf})
        with pytest.raises(ConfigError):
            fp.load_scene(base, {"initial.phi": sign * limit * (1 + 1e-4),
                                 "plant.energy_limit": math.inf})


@pytest.mark.parametrize("key,bad", [("master.step", -1.0), ("controller.cutoff", 0.0),
                                     ("plant.zeta", 1.0), ("master.rtol", 1.0),
                                     ("plant.n_elements", 401), ("fidelity.tolerance", 2.0)])
def test_the_range_quoted_for_a_bad_value_is_enforced(key, bad):
    """The quoted range's bounds: the side nearer the bad value is where the loader refuses."""
    exc = _raised(lambda: fp.load_scene({}, {key: bad}), ValueError)
    m = re.search(r"allowed: (?:integers (\S+)\.\.(\S+)|([\[(])(\S+), (\S+)([\])]))", str(exc))
    assert m and str(exc).startswith(key), str(exc)
    extra = {"plant.n_modes": 0, "fidelity.max_modes": 1} if key == "plant.n_elements" else {}
    if m[1]:
        lo, hi = int(m[1]), int(m[2])
        for ok in (lo, hi):
            fp.load_scene({}, {key: ok, **extra})
        for no in (lo - 1, hi + 1):
            with pytest.raises(ConfigError):
                fp.load_scene({}, {key: no, **extra})
        return
    lo, hi = float(m[4]), float(m[5])
    near, closed = (lo, m[3] == "[") if bad <= lo else (hi, m[6] == "]")
    outward = -math.inf if bad <= lo else math.inf
    with pytest.raises(ConfigError):
        fp.load_scene({}, {key: math.nextafter(near, outward)})
    inside = math.nextafter(near, -outward)
    if near == 0 and not closed:           # a range open at 0 takes normal numbers only
        with pytest.raises(ConfigError, match="subnormal"):
            fp.load_scene({}, {key: inside})
        inside = sys.float_info.min
    if key != "master.step":                           # a step must also divide the grid
        fp.load_scene({}, {key: inside})
    if closed and key != "master.step":
        fp.load_scene({}, {key: near})


# ------------------------------------------------------------------ Run.save takes a folder
def _run(scene_name="rigid_pd"):
    sc = fp.load_scene(scene_name, {"stop_time": 0.01})
    n = 6
    result = np.zeros(n, dtype=[("time", float), ("x", float), ("phi_o", float)])
    result["time"] = np.linspace(0, 0.01, n)
    return Run(sc, result, {"stopped": None, "verdict": "stable"})


@pytest.mark.parametrize("name", ["x.csv", "out/summary.json", "plot.PNG", "a.parquet"])
def test_save_refuses_a_path_with_a_files_suffix(tmp_path, name):
    target = tmp_path / name
    with pytest.raises(ValueError) as info:
        _run().save(target)
    message = str(info.value)
    assert str(target) in message and "folder" in message and "\n" not in message
    assert not target.exists()


def test_save_refuses_an_existing_file(tmp_path):
    target = tmp_path / "results"
    target.write_text("kept")
    with pytest.raises(ValueError, match="is a file; allowed: a folder"):
        _run().save(target)
    assert target.read_text() == "kept"


def test_save_refuses_a_path_that_is_not_one():
    with pytest.raises(TypeError, match="folder must be a path"):
        _run().save(3)


def test_sweep_refuses_an_out_that_names_a_file(tmp_path):
    """sweep(out=...) is a folder as Run.save's is: refused before any run, nothing made."""
    target = tmp_path / "table.csv"
    with pytest.raises(ValueError) as info:
        fp.sweep("rigid_pd", values={"controller.kp": [400, 500]}, serial=True, out=target)
    assert str(target) in str(info.value) and "folder" in str(info.value)
    assert not target.exists()


@pytest.mark.parametrize("command", [["run", "rigid_pd"], ["design"],
                                     ["sweep", "rigid_pd", "--serial", "--values",
                                      "controller.kp=400,500"]])
def test_the_commands_refuse_an_out_that_names_a_file(tmp_path, capsys, command):
    """The command line says the same in one line, exit 2 (usage), before anything runs or is
    made (a traceback before: run.save's ValueError reached the top)."""
    from orchestration.cli import main

    target = tmp_path / "figure.png"
    assert main([*command, "--out", str(target)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"flexpend: error: --out {target}: names a .png file")
    assert len(err.splitlines()) == 1 and not target.exists()


# ------------------------------------------------------------------ short reprs
def _short(obj, *fragments):
    text = repr(obj)
    assert "\n" not in text and len(text) <= 200, text
    for f in fragments:
        assert f in text, (f, text)
    return text


def test_a_scene_and_a_run_have_a_short_repr():
    sc = fp.load_scene("flexible_pd_lowpass")
    _short(sc, "flexible_pd_lowpass", f"stop_time {sc.output.stop_time:g} s",
           f"{sc.plant.n_modes} modes {sc.plant.fidelity}", "gauss-seidel")
    _short(_run("flexible_pd"), "flexible_pd", "completed", "verdict stable", "6 points",
           "of 0.01 s")


def test_an_analysis_has_a_short_repr():
    a = fp.analyze(overrides={"plant.n_modes": 3, "controller.filter_order": 0})
    _short(a, "unstable" if not a.stable else "stable", f"{a.max_real_part:.4g}",
           f"{len(a.eigenvalues)} closed-loop roots")
    a = Analysis([], np.zeros(0), np.array([-1 + 0j]), -1.0, True, {})
    _short(a, "stable", "1 closed-loop roots")


def test_a_design_report_and_a_sweep_have_a_short_repr():
    from types import SimpleNamespace

    from orchestration.report.design import DesignReport
    from orchestration.sweeps.job import Sweep

    ch = fp.load_scene("flexible_pd_lowpass").controller.replace(cutoff=97.3)
    worst = SimpleNamespace(decay=1.5, damping=0.02, n_plants=125)
    d = DesignReport(SimpleNamespace(chosen=ch, worst=worst, criterion="decay"), None, ch, {},
                     None)
    _short(d, "97.3 rad/s", "decay rate 1.5", "125 plants", "criterion decay")
    plan = SimpleNamespace(keys=["controller.kp"] * 40, scene=fp.load_scene("rigid_pd"))
    s = Sweep(plan, SimpleNamespace(rows=[{}] * 7), {"lost": 1}, {}, "serial")
    _short(s, "rigid_pd", "7 runs", "1 lost", "serial")


def test_a_key_spec_has_a_short_repr():
    for k in scene_keys():
        _short(k, k.key)


# ------------------------------------------------------------------ the exported names
def test_every_exported_name_imports_and_is_documented():
    import orchestration.api as api

    for module in (fp, api):
        for name in module.__all__:
            obj = getattr(module, name)
            if name == "__version__":
                assert isinstance(obj, str) and obj
                continue
            assert obj.__doc__ and obj.__doc__.strip(), f"{module.__name__}.{name}"
            assert obj.__doc__ is not type(obj).__doc__ or isinstance(obj, type), name
    assert {"ConfigError", "CoSimulationError", "scene_keys"} <= set(fp.__all__)
    assert set(api.__all__) <= set(fp.__all__)
    assert sorted(dir(fp)) == sorted(fp.__all__)


def test_the_results_inside_the_results_have_a_short_repr():
    """What a result holds (the job's, the design's, the sweep's plan and runs) is short too."""
    from types import SimpleNamespace

    from orchestration.job import JobResult
    from orchestration.studies.design import DesignResult
    from orchestration.sweeps.engine import SweepResult
    from orchestration.sweeps.plan import SweepPlan

    runs = [_run("rigid_pd"), _run("flexible_pd"), _run("flexible_pd_lowpass")]
    _short(JobResult(runs, 0, ["a"] * 9), "3 runs", "rigid_pd", "code 0", "9 files")
    ch = fp.load_scene("flexible_pd_lowpass").controller
    worst = SimpleNamespace(decay=1.5, damping=0.02)
    _short(DesignResult("decay", None, ch, worst, {}, {}), f"cutoff {ch.cutoff:g} rad/s",
           "decay rate 1.5", "criterion decay")
    _short(SweepResult([{}] * 1000, 990, 10, 12.0), "1000 rows", "990 ran", "10 found")
    plan = SweepPlan(fp.load_scene("rigid_pd"), [SimpleNamespace(key="controller.kp")] * 30, [],
                     0, None, False, [None] * 500)
    _short(plan, "rigid_pd", "controller.kp", "500 runs")
