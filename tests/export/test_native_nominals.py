"""The declared nominals of the native FMUs' continuous states (issue 37, 4), FMI 2.0 and 3.0.

The modelDescription declares ``nominal`` on every continuous state (FMI 2.0: its ``<Real>``,
FMI 3.0: its ``<Float64>``), computed in Python (``plant_fmu/nominals.py``,
``controller_fmu/nominals.py``) from the formulas the binaries use. Checked here: the declared
values are what ``fmi*GetNominalsOfContinuousStates`` returns after initialisation at the start
values; at other parameter values the binaries' run-time values follow the parameters and equal
the Python formulas there (so that a drift of either side fails); and no derivative declares one
(the reason: ``model_description.state_nominals``).
"""
from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest

from conftest import NativeFmu, opened_by

NAMES = ("FlexiblePendulum", "PDLowPass")


@pytest.fixture(scope="module")
def paths(native, native3) -> dict:
    return {2: native, 3: native3}


@pytest.fixture(scope="module")
def dirs(paths):
    from fmpy import extract
    out = {(v, n): extract(p) for v, ps in paths.items() for n, p in ps.items()}
    yield out
    for d in out.values():
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def me(dirs):
    yield from opened_by(lambda version, name, **start:
                         NativeFmu(dirs[(version, name)], version, **start))


def _declared(path, version) -> tuple[list, dict]:
    """(the states in the order of their derivatives, {variable name: declared nominal}) read
    from the FMU's modelDescription.xml itself."""
    with zipfile.ZipFile(path) as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    nominal, by_index, by_vr, ders = {}, {}, {}, []
    if version == 2:
        for i, sv in enumerate(root.find("ModelVariables"), 1):
            real = sv.find("Real")
            by_index[i] = sv.get("name")
            if real is not None and real.get("nominal") is not None:
                nominal[sv.get("name")] = float(real.get("nominal"))
            if real is not None and real.get("derivative") is not None:
                ders.append(int(real.get("derivative")))
        order = [by_index[i] for i in ders]
    else:
        for v in root.find("ModelVariables"):
            by_vr[int(v.get("valueReference"))] = v.get("name")
            if v.get("nominal") is not None:
                nominal[v.get("name")] = float(v.get("nominal"))
            if v.get("derivative") is not None:
                ders.append(int(v.get("derivative")))
        order = [by_vr[r] for r in ders]
    return order, nominal


def _python(name, **values) -> dict:
    if name == "FlexiblePendulum":
        from plant_fmu.nominals import state_nominals
    else:
        from controller_fmu.nominals import state_nominals
    return state_nominals(values)


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("name", NAMES)
def test_the_declared_nominals_are_what_the_fmu_returns(me, paths, name, version):
    order, declared = _declared(paths[version][name], version)
    assert order and set(declared) == set(order)          # every state, nothing else
    m = me(version, name)
    m.initialize()
    got = m.nominals()
    want = np.array([declared[s] for s in order])
    np.testing.assert_array_equal(got, want)
    assert np.all(want > 0) and np.any(want != 1.0)         # physical scales, not all 1
    if name == "FlexiblePendulum":
        # a closed form: a uniform cantilever's mass-normalised modes have |N_j(L)| =
        # 2 / sqrt(rhoA L), so eta_j's nominal 0.01 L / |N_j(L)| is 0.01 L sqrt(rhoA L) / 2 (the
        # FE modes of the default mesh within 1e-3)
        from plant_fmu.params import PlantParams
        p = PlantParams()
        n = p.n_modes
        etas = [declared[f"eta_{j}"] for j in range(1, n + 1)]
        np.testing.assert_allclose(etas, 0.01 * p.L * np.sqrt(p.rhoA * p.L) / 2, rtol=1e-3)
        assert declared["x_o"] == p.L and declared["phi_dot"] == pytest.approx(np.sqrt(p.g / p.L))
    else:
        from controller_fmu.pd_lowpass import ControllerParams
        p = ControllerParams()
        assert declared["xc_1"] == min(abs(p.kp), p.force_limit)
        assert declared["xc_2"] == pytest.approx(declared["xc_1"] * p.cutoff, rel=1e-15)


#: non-default parameters (the C values must follow them, and equal the Python formulas there)
OTHER = {
    "FlexiblePendulum": [dict(L=0.8, g=3.7, EI=500.0, rho=5e3, n_modes=3, n_elements=10),
                         dict(L=2.5, g=0.0, n_modes=8, n_elements=12, EA=1e8),
                         dict(n_modes=0)],
    "PDLowPass": [dict(kp=-120.0, force_limit=80.0, cutoff=50.0),
                  dict(kp=300.0, cutoff=20.0, filter_order=1),
                  dict(kp=0.0, filter_order=2, cutoff=5.0),
                  dict(filter_order=0)],
}


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("name", NAMES)
def test_the_run_time_nominals_follow_the_parameters_as_the_formulas_say(me, paths, name,
                                                                        version):
    order, declared = _declared(paths[version][name], version)
    for values in OTHER[name]:
        m = me(version, name, **values)
        m.initialize()
        got = m.nominals()
        py = _python(name, **values)
        np.testing.assert_allclose(got, [py[s] for s in order], rtol=1e-15, atol=0)
        assert not np.array_equal(got, [declared[s] for s in order]), values


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("name", NAMES)
def test_only_the_states_declare_a_nominal(paths, name, version):
    """The derivatives (and every other variable) declare none: no importer we test reads
    them (model_description.state_nominals says why)."""
    order, declared = _declared(paths[version][name], version)
    assert sorted(declared) == sorted(order)
    assert not [n for n in declared if n.startswith("der(")]
