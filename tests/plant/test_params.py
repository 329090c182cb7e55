"""Parameter records: defaults of Table 1 and validation that names the field."""
import math

import pytest
from hypothesis import given, strategies as st

from controller_fmu.pd_lowpass import ControllerParams
from plant_fmu.params import MAX_ELEMENTS, PlantParams


def test_defaults_are_table_1():
    p = PlantParams()
    assert (p.m, p.L, p.rho, p.EA, p.EI, p.zeta) == (1, 1, 7.8e3, 4.2e8, 8.75e2, 0.001)
    assert p.rhoA == pytest.approx(15.6) and p.area == pytest.approx(2e-3)
    assert not p.gravity_preload
    assert p.damping == "modal"           # the paper's "zeta = 0.1 %" read as the modal law


@pytest.mark.parametrize("field,value,match", [
    ("m", 0.0, r"m = 0.0 is out of range; allowed: \[1e-15"),
    ("L", 5e-324, r"L = 5e-324 is out of range; allowed: \[1e-15"),
    ("L", -1.0, "L = -1.0"),
    ("rho", math.nan, "rho"),
    ("EI", math.inf, "EI"),
    ("EA", 0, "EA"),
    ("E", -2.0, "E = "),
    ("zeta", 1.0, r"zeta = 1.0 is out of range; allowed: \[0.0, 1.0\)"),
    ("zeta", -0.01, "zeta"),
    ("g", -9.81, "g = "),
    ("n_modes", -1, "n_modes = -1 is out of range; allowed: integers 0..24"),
    ("n_modes", 25, "n_modes = 25"),
    ("n_elements", 0, "n_elements = 0"),
    ("n_elements", MAX_ELEMENTS + 1, "n_elements"),
    ("damping", "kelvin", "damping = 'kelvin' is not allowed; allowed: modal, kelvin-voigt$"),
    ("damping", "Modal", "damping = 'Modal' is not allowed"),
    ("damping", None, "damping = None is not allowed; allowed: modal, kelvin-voigt"),
])
def test_bad_value_names_the_field(field, value, match):
    with pytest.raises(ValueError, match=match):
        PlantParams(**{field: value})


@pytest.mark.parametrize("field,value", [("n_modes", 2.5), ("n_modes", True), ("m", "1"),
                                         ("gravity_preload", "yes"), ("zeta", None)])
def test_bad_type_names_the_field(field, value):
    with pytest.raises(TypeError, match=field):
        PlantParams(**{field: value})


def test_n_modes_limited_by_mesh():
    assert PlantParams(n_modes=30, n_elements=30).n_modes == 30
    with pytest.raises(ValueError, match="integers 0..10"):
        PlantParams(n_modes=11, n_elements=10)


def test_unknown_field_rejected_by_replace():
    with pytest.raises(TypeError, match="n_mode"):
        PlantParams().replace(n_mode=3)
    with pytest.raises(TypeError, match="cutof"):
        ControllerParams().replace(cutof=3)


@given(st.floats(allow_nan=True, allow_infinity=True))
def test_zeta_accepted_iff_in_unit_interval(z):
    if 0 <= z < 1:
        assert PlantParams(zeta=z).zeta == z
    else:
        with pytest.raises(ValueError, match="zeta"):
            PlantParams(zeta=z)


@pytest.mark.parametrize("field,value", [("filter_order", 3), ("filter_order", -1),
                                         ("cutoff", 0.0), ("cutoff", math.nan),
                                         ("filter_damping", -0.1), ("force_limit", 0.0),
                                         ("kp", math.inf)])
def test_controller_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        ControllerParams(**{field: value})


def test_force_limit_may_be_infinite():
    assert ControllerParams(force_limit=math.inf).force_limit == math.inf
