"""Every scene key, listed once, from one source: ``flexpend keys``, ``docs/keys.md`` and
``orchestration.scene_keys()`` list each key the loader takes exactly once, and the limits they
quote are the ones validation enforces (probed at each bound and just beyond it)."""
import dataclasses
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.api import scene_keys
from orchestration.cli import main
from orchestration.report.keys import keys_lines, keys_markdown
from orchestration.scene.keys import ConfigError
from orchestration.scene.records import (FidelitySettings, InitialState, MasterSettings,
                                         OutputSettings, PlantSetup, Scene)
from orchestration.scene.schema import load_scene
from plant_fmu.params import PlantParams

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "keys.md"

#: The records and the prefix of their keys, as the records' module documents them.
RECORDS = {"plant.": (PlantParams, PlantSetup), "controller.": (ControllerParams,),
           "master.": (MasterSettings,), "initial.": (InitialState,),
           "fidelity.": (FidelitySettings,), "": (OutputSettings,)}


def accepted_keys() -> set:
    """The keys the loader takes, found without the listing: the records' fields by the naming
    rule of a scene file (``[plant] m`` is ``plant.m``), the scene's own ``description`` and
    ``connections``, each confirmed by the loader (it takes the key at its default) and a
    misspelling of it refused."""
    keys = {"description", "connections"}
    for prefix, classes in RECORDS.items():
        for cls in classes:
            keys |= {prefix + f.name for f in dataclasses.fields(cls)
                     if f.name not in ("beam", "n_modes_auto")}
    default = Scene(name="default")
    for key in keys:
        load_scene({key: default.get(key)})           # taken
        with pytest.raises(ConfigError, match="unknown key"):
            load_scene({key + "x": default.get(key)})
    return keys


def test_the_page_is_what_flexpend_keys_markdown_prints(capsys):
    assert main(["keys", "--markdown"]) == 0
    printed = capsys.readouterr().out
    assert printed == keys_markdown() + "\n"
    assert DOC.read_text() == printed, (
        "docs/keys.md is out of date: regenerate it with "
        "`PYTHONPATH=. python3 -m orchestration.cli keys --markdown > docs/keys.md`")


def test_every_accepted_key_is_listed_exactly_once():
    accepted = accepted_keys()
    listed = [k.key for k in scene_keys()]
    assert sorted(listed) == sorted(accepted) and len(set(listed)) == len(listed)
    page_rows = re.findall(r"^\| `([^`]+)` \|", DOC.read_text(), flags=re.M)
    assert sorted(page_rows) == sorted(accepted)
    text_keys = [line.split(" = ", 1)[0] for line in keys_lines()]
    assert sorted(text_keys) == sorted(accepted)


def test_every_key_has_a_type_a_default_and_a_meaning():
    default = Scene(name="default")
    for k in scene_keys():
        assert k.meaning and k.allowed and k.type, k
        assert k.default == default.get(k.key), k
        assert "\n" not in k.meaning + k.allowed


def test_flexpend_keys_prints_one_line_per_key():
    out = subprocess.run([sys.executable, "-m", "orchestration.cli", "keys"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == keys_lines()
    assert "plant.m = 1.0 kg (float): cart mass; allowed: [1e-15, 1e+15]" in out.splitlines()


@pytest.mark.parametrize("command", ["run", "analyze", "stability", "design", "sweep", "export"])
def test_the_help_of_every_command_with_set_points_to_flexpend_keys(command):
    out = subprocess.run([sys.executable, "-m", "orchestration.cli", command, "--help"],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert "flexpend keys" in " ".join(out.split())


# ------------------------------------------------------------------ the limits are the real ones
#: A partner field that a bound ties a key to, moved out of the way of the probe value ``v``.
PARTNERS = {
    "master.min_step": lambda v: {"max_step": 1e6},
    "plant.n_elements": lambda v: {"n_modes": 0},     # (and fidelity.max_modes: the scene's)
    "master.max_step": lambda v: {"min_step": min(v, 1e-6)} if v > 0 else {},
    "stop_time": lambda v: {"output_interval": v} if 0 < v <= 1e6 else {},
    "output_interval": lambda v: {"stop_time": v} if 0 < v <= 1e6 else {},
    # the tustin filter also needs cutoff * sample_period < pi (the listing's note); the delay
    # is at most the sample period (its note)
    "controller.sample_period": lambda v: {"discretization": "zoh"},
    "controller.delay": lambda v: {"sample_period": 1e3, "discretization": "zoh"},
}


def _record(key: str, value):
    """The record of ``key`` made with ``value`` (the other fields at their defaults)."""
    for prefix, classes in RECORDS.items():
        name = key[len(prefix):]
        if key.startswith(prefix) and "." not in name:
            cls = next(c for c in classes if name in {f.name for f in dataclasses.fields(c)})
            extra = PARTNERS[key](value) if key in PARTNERS else {}
            return cls(**{name: value, **extra})
    raise KeyError(key)


def _accepts(key, value) -> bool:
    try:
        _record(key, value)
    except (TypeError, ValueError):
        return False
    return True


def _bounds(allowed: str):
    """The rule a listing quotes, before any ``;``: ``("real", lo, hi, lo_open, hi_open)`` or
    ``("int", lo, hi)``, or None."""
    rule = allowed.split(";")[0]
    m = re.fullmatch(r"([\[(])(\S+), (\S+)([\])])(?: \(inf: none\))?", rule)
    if m:
        return "real", float(m[2]), float(m[3]), m[1] == "(", m[4] == ")"
    m = re.fullmatch(r"integers (-?\d+)\.\.([\w.]+)(?:, or .*)?", rule)
    if m:
        hi = int(m[2]) if m[2].isdigit() else getattr(PlantParams(), m[2].split(".")[-1])
        return "int", int(m[1]), hi
    return None


NUMERIC = [k for k in scene_keys() if _bounds(k.allowed)]


def test_every_number_key_has_its_rule_listed():
    assert {k.key for k in NUMERIC} >= {"plant.m", "plant.zeta", "master.step", "stop_time",
                                        "controller.cutoff", "plant.n_modes", "fidelity.max_modes",
                                        "master.rtol", "plant.phi_limit"}
    assert len(NUMERIC) >= 37


@pytest.mark.parametrize("spec", NUMERIC, ids=lambda k: k.key)
def test_each_quoted_bound_is_where_validation_draws_the_line(spec):
    """At each quoted bound and one floating-point step beyond it, the record agrees with the
    listing: a closed bound is taken and its neighbour outside refused; an open bound refused
    and its neighbour inside taken."""
    b = _bounds(spec.allowed)
    if b[0] == "int":
        _, lo, hi = b
        assert _accepts(spec.key, lo) and _accepts(spec.key, hi)
        assert not _accepts(spec.key, lo - 1) and not _accepts(spec.key, hi + 1)
        return
    _, lo, hi, lo_open, hi_open = b
    for bound, is_open, outward in ((lo, lo_open, -math.inf), (hi, hi_open, math.inf)):
        if math.isinf(bound):
            assert _accepts(spec.key, bound) != is_open, (spec.key, bound)
            continue
        inside = math.nextafter(bound, -outward)
        outside = math.nextafter(bound, outward)
        if bound == 0 and is_open and outward < 0:
            # a range open at 0 takes normal numbers (docs/keys.md): a subnormal is 0
            assert not _accepts(spec.key, inside), (spec.key, inside)
            inside = sys.float_info.min
        assert _accepts(spec.key, bound) == (not is_open), (spec.key, bound)
        assert _accepts(spec.key, inside), (spec.key, inside)
        assert not _accepts(spec.key, outside), (spec.key, outside)


@pytest.mark.parametrize("spec", NUMERIC, ids=lambda k: k.key)
def test_an_out_of_range_value_quotes_the_listed_rule(spec):
    """The error of a value beyond the bound quotes the same rule as the listing."""
    b = _bounds(spec.allowed)
    value = (b[2] + 1) if b[0] == "int" else (math.nan)
    with pytest.raises(ValueError) as info:
        _record(spec.key, value)
    rule = re.sub(r" \(inf: none\)|, or .*", "", spec.allowed.split(";")[0])
    if b[0] == "int" and not rule.split("..")[1].isdigit():
        rule = f"{rule.split('..')[0]}..{b[2]}"          # the bound's value, in the message
    assert rule in str(info.value), (rule, str(info.value))
