"""Extreme values of every numeric scene key and design key (subnormal, huge, infinite, NaN,
integers beyond a double), typed as after ``--set``: each is taken as it is or refused with one line
naming the key, never another exception; on the command line, one line and exit 2."""
import math

import pytest

from orchestration.cli import main
from orchestration.scene.keys import ConfigError
from orchestration.scene.schema import known_keys, load_scene


@pytest.mark.parametrize("overrides", [{"master.step": 1e-320}, {"output_interval": 1e-320},
                                       {"stop_time": 1e300}, {"master.step": 5e-324}])
def test_extreme_numbers_are_one_line_errors(overrides):
    """Subnormal or huge values are refused with a ConfigError naming a key, never an
    OverflowError or a ZeroDivisionError."""
    with pytest.raises(ConfigError) as info:
        load_scene("rigid_pd", overrides)
    assert "\n" not in str(info.value) and any(k in str(info.value) for k in overrides)


#: Every numeric scene key (its default an int or a float, not a bool).
NUMERIC_KEYS = [k for k, v in known_keys().items()
                if isinstance(v, (int, float)) and not isinstance(v, bool)]
#: Extreme values as they are typed after --set (read by the same parser as the command line).
EXTREMES = ["1e-320", "-1e-320", "5e-324", "1e308", "-1e308", "1.7976931348623157e308", "inf",
            "-inf", "nan", "-0", "-0.0", "9223372036854775808", "1" + "0" * 400,
            "-1" + "0" * 400]


def test_every_numeric_key_is_listed():
    assert len(NUMERIC_KEYS) >= 37 and {"master.step", "output_interval", "plant.n_modes",
                                        "controller.cutoff", "fidelity.max_modes"} <= set(NUMERIC_KEYS)


@pytest.mark.parametrize("base", ["rigid_pd", "flexible_pd_lowpass"])
@pytest.mark.parametrize("text", EXTREMES)
@pytest.mark.parametrize("key", NUMERIC_KEYS)
def test_extreme_values_of_every_numeric_key_are_taken_or_one_line(key, text, base):
    """Each extreme value of each numeric key is either taken as it is or refused with a
    ConfigError of one line naming the key; never another exception. Failed before for the
    integers beyond a double (OverflowError: int too large to convert to float)."""
    from orchestration.scene.keys import parse_value

    value = parse_value(text)
    try:
        scene = load_scene(base, [f"{key}={text}"])
    except ConfigError as exc:
        message = str(exc)
        assert "\n" not in message and len(message) <= 200, message
        assert "--set" not in message and key in message, message          # the API's words
        assert exc.cli.startswith("--set: ") and key in exc.cli, exc.cli  # the command line's
        return
    got = scene.get(key)
    assert not (isinstance(value, float) and math.isnan(value))      # nan is never a value
    assert got == value and type(got) in (int, float)


@pytest.mark.parametrize("text", EXTREMES)
def test_extreme_values_of_every_numeric_design_key_are_taken_or_one_line(text):
    """The design.* keys of flexpend design and --sample design, likewise."""
    from orchestration.scene.keys import parse_value
    from orchestration.studies.design import DESIGN_DEFAULTS, design_settings

    value = parse_value(text)
    for key, default in DESIGN_DEFAULTS.items():
        if isinstance(default, bool) or not isinstance(default, (int, float)):
            continue
        try:
            got = design_settings({key: value})[key]
        except ConfigError as exc:
            assert "\n" not in str(exc) and len(str(exc)) < 400 and key in str(exc), str(exc)
            continue
        assert got == value and not (isinstance(value, float) and math.isnan(value))


def test_extreme_values_on_the_command_line_are_one_line_exit_2(capsys):
    """run --set and sweep --values: one line, exit 2. Failed before for the integer beyond a
    double (an OverflowError traceback in sweep --values)."""
    huge = "1" + "0" * 400
    for args, fragment in (
            (["run", "rigid_pd", "--set", "master.step=1e-320"],
             "--set: master.step = 1e-320 is out of range: a subnormal number"),
            (["run", "rigid_pd", "--set", "output_interval=1e-320"],
             "--set: output_interval = 1e-320 is out of range: a subnormal number"),
            (["run", "rigid_pd", "--set", f"plant.m={huge}"],
             "plant.m = an integer of 401 digits is out of range"),
            (["run", "rigid_pd", "--set", "plant.n_modes=nan"], "plant.n_modes"),
            (["sweep", "rigid_pd", "--serial", "--values", "master.step=1e-320,0.002"],
             "master.step = 1e-320"),
            (["sweep", "rigid_pd", "--serial", "--values", "output_interval=0.01,1e-320"],
             "output_interval = 1e-320"),
            (["sweep", "rigid_pd", "--serial", "--values", f"plant.m=1,{huge}"],
             "plant.m = an integer of 401 digits is out of range")):
        assert main(args + ["--out", "/nonexistent-dir/never-written"]
                    if args[0] == "run" else args) == 2, args
        err = capsys.readouterr().err
        assert err.startswith("flexpend: error: ") and fragment in err, (args, err)
        assert len(err.strip().splitlines()) == 1, err
