"""Model Exchange, directional derivatives and output derivatives of the native FMUs (issue 24).

Independent values: the co-simulation FMU (the kernel under its own stepper, fine steps), the
numpy specification (PlantModel, its exact Jacobian ``jacobian_numpy`` and
``output_jacobian_numpy``) solved by scipy at tight tolerance, the controller's exact discrete
response (``PDLowPassModel.step``: matrix exponentials), central differences through the FMI API,
and the values of the FMU states themselves (a restored state must continue bit-identically).
"""
from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest

from conftest import NativeFmu, fmi_status, opened_by
from fmu_common.variables import derivatives, event_indicators, states


PLANT, CTRL = "FlexiblePendulum", "PDLowPass"
STIFFENED, EXACT = "FlexiblePendulumStiffened", "FlexiblePendulumExact"


@pytest.fixture(scope="session")
def paths(native, native3) -> dict:
    return {2: native, 3: native3}


@pytest.fixture(scope="session")
def dirs(paths):
    import shutil

    from fmpy import extract
    out = {(v, n): extract(p) for v, ps in paths.items() for n, p in ps.items()}
    yield out
    for d in out.values():
        shutil.rmtree(d, ignore_errors=True)


@pytest.fixture
def me(dirs):
    yield from opened_by(lambda version, name, cs=False, **start:
                         NativeFmu(dirs[(version, name)], version, cs, **start))


# ---------------------------------------------------------------------- the tables
def test_the_pythonfmu_tables_keep_every_variable_and_reference():
    """The Model-Exchange variables come after every other one: the pythonfmu FMUs (and every
    value reference of the native FMUs before issue 24) are unchanged."""
    from controller_fmu.interface import VARIABLES as CV
    from fmu_common.variables import python_variables
    from plant_fmu.interface import STATES, VARIABLES as PV
    py = python_variables(PV)
    assert [v.name for v in py[:4]] == ["F_c", "dF_c", "d2F_c", "x_o"]
    assert py[:40] == list(PV[:40]) and all(v.me_only for v in PV[40:71])
    assert PV[71].name == "time" and not any(v.me_only for v in py)
    assert python_variables(CV) == list(CV[:17]) + list(CV[22:]) and \
        all(v.me_only for v in CV[17:21])
    assert CV[21].name == "time" and \
        [v.name for v in CV[22:]] == ["sample_period", "delay", "discretization"]
    assert states(PV) == list(STATES) and len(STATES) == 20
    assert derivatives(PV) == [f"der({s})" for s in STATES]
    assert event_indicators(PV) == ["phi_limit_indicator", "energy_limit_indicator"]
    assert states(CV) == ["xc_1", "xc_2"]


@pytest.mark.parametrize("version", [2, 3])
def test_the_descriptions_declare_both_interfaces_and_the_states(paths, version):
    from fmpy import read_model_description
    for name, nx, nz in ((PLANT, 20, 2), (CTRL, 2, 0)):
        md = read_model_description(paths[version][name])
        assert md.modelExchange is not None and md.coSimulation is not None
        assert md.modelExchange.modelIdentifier == md.coSimulation.modelIdentifier == name
        root = _xml(paths[version][name])
        flag = "providesDirectionalDerivative" + ("s" if version == 3 else "")
        assert root.find("ModelExchange").get(flag) == "true"
        assert root.find("CoSimulation").get(flag) == "true"
        assert len(md.derivatives) == nx
        assert (md.numberOfEventIndicators if version == 2 else len(md.eventIndicators)) == nz
        for d in md.derivatives:
            assert d.variable.name == f"der({d.variable.derivative.name})"


def _xml(path):
    import xml.etree.ElementTree as ET
    import zipfile
    with zipfile.ZipFile(path) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def _kernel_names(n):
    """The names of the kernel's state [q, qd] of n modes, as the FMUs call the states."""
    eta = [f"eta_{j}" for j in range(1, n + 1)]
    return ["x_o", "phi", *eta, "x_dot", "phi_dot", *[f"eta_dot_{j}" for j in range(1, n + 1)]]


#: the kernel's output rows (PlantModel.output_jacobian_numpy) as the FMUs name them
_OUT_ROWS = ["x_o", "x_dot", "phi_o", "omega_o", "phi", "tip_deflection", "energy"]


def _numeric_pattern():
    """The nonzero pattern of the numpy Jacobians at random deformed, moving, tilted states, n =
    8, both fidelities, with and without the gravity preload: (derivative name -> states and
    inputs), (output name -> states)."""
    from plant_fmu.dynamics import LinearPlantModel, PlantModel
    from plant_fmu.params import PlantParams
    rng = np.random.default_rng(24)
    names = _kernel_names(8)
    der, out = {}, {}
    for preload in (False, True):
        for cls in (PlantModel, LinearPlantModel):
            m = cls(PlantParams(n_modes=8, gravity_preload=preload))
            for _ in range(4):
                x = rng.normal(size=m.nx) * 0.3
                J, b = m.jacobian_numpy(x, 0.7)
                C = m.output_jacobian_numpy(x)
                for i, s in enumerate(names):
                    deps = {names[k] for k in np.flatnonzero(J[i])}
                    if b[i] != 0.0:
                        deps.add("F_c")
                    der.setdefault(f"der({s})", set()).update(deps)
                rows = _OUT_ROWS + [f"eta_{j}" for j in range(1, 9)]
                for i, o in enumerate(rows):
                    out.setdefault(o, set()).update(names[k] for k in np.flatnonzero(C[i]))
    return der, out


@pytest.mark.parametrize("version", [2, 3])
def test_model_structure_is_the_numerical_jacobians_nonzero_pattern(paths, version):
    """Issue 24, 2: every dependency of the plant's derivatives and outputs on states and inputs,
    exactly the nonzero pattern of the numpy Jacobians (so the declared structure cannot
    drift)."""
    from fmpy import read_model_description
    md = read_model_description(paths[version][PLANT])
    der, out = _numeric_pattern()
    declared = {d.variable.name: {v.name for v in d.dependencies} for d in md.derivatives}
    assert declared == der
    outs = {o.variable.name: {v.name for v in o.dependencies} for o in md.outputs}
    assert outs == out


@pytest.mark.parametrize("version", [2, 3])
def test_controller_structure_is_the_filters(paths, version):
    """der(xc) = Af xc + Bf e over the filter orders 1 and 2: every derivative depends on both
    states (order 2: der(xc_1) = xc_2, der(xc_2) on both; order 1: der(xc_1) on xc_1) and on the
    sensors; F_c on xc_1 and (order 0) the sensors."""
    from fmpy import read_model_description

    from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
    md = read_model_description(paths[version][CTRL])
    want = {"der(xc_1)": set(), "der(xc_2)": set()}
    for order in (1, 2):
        c = PDLowPassModel(ControllerParams(filter_order=order, kx=1.0))
        for i in range(order):
            want[f"der(xc_{i + 1})"] |= {f"xc_{k + 1}" for k in np.flatnonzero(c.Af[i])}
            if np.any(c.B[i] != 0):
                want[f"der(xc_{i + 1})"] |= {"phi_o", "omega_o", "x_o"}
    declared = {d.variable.name: {v.name for v in d.dependencies} for d in md.derivatives}
    assert declared == want
    (o,) = md.outputs
    assert {v.name for v in o.dependencies} == {"xc_1", "phi_o", "omega_o", "x_o"}


# ---------------------------------------------------------------------- the mode machine


def _raw(m, fname, *args):
    """The status of a raw call of the binary's fname(instance, *args) (no fmpy checks)."""
    f = getattr(m.fmu.dll, fname)
    f.restype = ctypes.c_int
    conv = [ctypes.c_double(a) if isinstance(a, float) else a for a in args]
    return f(ctypes.c_void_p(m.fmu.component), *conv)


def _pre(version):
    return "fmi2" if version == 2 else "fmi3"


@pytest.mark.parametrize("version", [2, 3])
def test_model_exchange_calls_are_refused_in_co_simulation_and_back(me, version):
    """Issue 24, 1: every Model-Exchange call in a co-simulation instance, and doStep (and the
    input derivatives) in a Model-Exchange instance, are refused with a message naming the
    interface."""
    pre = _pre(version)
    x = (ctypes.c_double * 20)()
    f1, f2 = (ctypes.c_int(), ctypes.c_int()) if version == 2 else (ctypes.c_bool(),
                                                                     ctypes.c_bool())
    me_calls = [("SetTime", 0.1), ("SetContinuousStates", x, ctypes.c_size_t(20)),
                ("GetContinuousStates", x, ctypes.c_size_t(20)),
                ("GetNominalsOfContinuousStates", x, ctypes.c_size_t(20)),
                ("GetEventIndicators", x, ctypes.c_size_t(2)),
                ("EnterContinuousTimeMode",),
                ("CompletedIntegratorStep", ctypes.c_int(1), ctypes.byref(f1),
                 ctypes.byref(f2)),
                ("GetDerivatives" if version == 2 else "GetContinuousStateDerivatives", x,
                 ctypes.c_size_t(20))]
    cs = me(version, PLANT, cs=True)
    cs.initialize(event=False)
    for name, *args in me_calls:
        n = len(cs.logs)
        assert _raw(cs, pre + name, *args) == 3, name
        assert any("instantiated for co-simulation" in msg for _, msg in cs.logs[n:]), \
            (name, cs.logs[n:])
    m = me(version, PLANT)
    m.initialize()
    n = len(m.logs)
    if version == 2:
        assert _raw(m, "fmi2DoStep", 0.0, 1e-3, ctypes.c_int(1)) == 3
    else:
        b1, b2, b3, d = ctypes.c_bool(), ctypes.c_bool(), ctypes.c_bool(), ctypes.c_double()
        assert _raw(m, "fmi3DoStep", 0.0, 1e-3, ctypes.c_bool(True), ctypes.byref(b1),
                    ctypes.byref(b2), ctypes.byref(b3), ctypes.byref(d)) == 3
    assert any("instantiated for Model Exchange" in msg for _, msg in m.logs[n:]), m.logs[n:]
    if version == 2:
        n = len(m.logs)
        vr = (ctypes.c_uint * 1)(m.vr("F_c")[0])
        order = (ctypes.c_int * 1)(1)
        val = (ctypes.c_double * 1)(1.0)
        assert _raw(m, "fmi2SetRealInputDerivatives", vr, ctypes.c_size_t(1), order, val) == 3
        assert any("instantiated for Model Exchange" in msg for _, msg in m.logs[n:])
        n = len(m.logs)
        assert _raw(m, "fmi2GetRealOutputDerivatives", vr, ctypes.c_size_t(1), order, val) == 3
        assert any("instantiated for Model Exchange" in msg for _, msg in m.logs[n:])
    else:
        n = len(m.logs)
        assert _raw(m, "fmi3EnterStepMode") == 3
        assert any("instantiated for Model Exchange" in msg for _, msg in m.logs[n:])


@pytest.mark.parametrize("version", [2, 3])
def test_the_me_mode_machine_refuses_calls_out_of_order(me, version):
    """The standard's state machine of Model Exchange: states only in continuous-time mode,
    the sizes exact, values finite, the time not before the start; every refusal says why."""
    pre = _pre(version)
    x = (ctypes.c_double * 20)()
    m = me(version, PLANT)
    assert _raw(m, pre + "SetContinuousStates", x, ctypes.c_size_t(20)) == 3   # instantiated
    assert _raw(m, pre + "EnterContinuousTimeMode") == 3
    assert _raw(m, pre + "SetTime", 0.5) == 3
    m.initialize(event=False)                                  # event mode
    assert _raw(m, pre + "SetContinuousStates", x, ctypes.c_size_t(20)) == 3
    f1, f2 = (ctypes.c_int(), ctypes.c_int()) if version == 2 else (ctypes.c_bool(),
                                                                     ctypes.c_bool())
    assert _raw(m, pre + "CompletedIntegratorStep", ctypes.c_int(1), ctypes.byref(f1),
                ctypes.byref(f2)) == 3
    m.fmu.enterContinuousTimeMode()
    assert _raw(m, pre + "SetContinuousStates", x, ctypes.c_size_t(19)) == 3  # the wrong size
    assert _raw(m, pre + "GetEventIndicators", x, ctypes.c_size_t(3)) == 3
    x[3] = math.nan
    assert _raw(m, pre + "SetContinuousStates", x, ctypes.c_size_t(20)) == 3  # not finite
    assert _raw(m, pre + "SetContinuousStates", None, ctypes.c_size_t(20)) == 3
    assert _raw(m, pre + "SetTime", math.inf) == 3
    assert _raw(m, pre + "SetTime", -1.0) == 3                                 # before start
    x[3] = 0.0
    assert _raw(m, pre + "SetContinuousStates", x, ctypes.c_size_t(20)) == 0
    assert _raw(m, pre + "CompletedIntegratorStep", ctypes.c_int(1), ctypes.byref(f1),
                ctypes.byref(f2)) == 0
    assert m.logs and all(msg for s, msg in m.logs if s > 1)
    assert sum(1 for s, _ in m.logs if s == 3) >= 11
    m.set(F_c=math.nan)                         # an input that is not finite: an error, no NaN
    d = (ctypes.c_double * 20)()
    fn = "GetDerivatives" if version == 2 else "GetContinuousStateDerivatives"
    assert _raw(m, pre + fn, d, ctypes.c_size_t(20)) == 3
    assert "F_c" in m.logs[-1][1]


@pytest.mark.parametrize("version", [2, 3])
def test_initialization_mode_gives_the_initial_states_and_derivatives(me, version):
    """The initial unknowns in initialization mode: the states from the start values and their
    derivatives (the numpy right-hand side there), before exitInitializationMode."""
    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    m = me(version, PLANT, n_modes=1, phi0=0.2, phi_dot0=-0.1, F_c=2.0)
    if version == 2:
        m.fmu.enterInitializationMode()
    else:
        m.fmu.enterInitializationMode(startTime=0.0)
    x, dx, z = m.states(), m.derivatives(), m.indicators()
    ref = PlantModel(PlantParams(n_modes=1))
    xk = np.zeros(ref.nx)
    xk[1], xk[ref.nq + 1] = 0.2, -0.1
    order = [_kernel_names(8).index(s) for s in _kernel_names(1)]
    assert np.array_equal(x[order], xk) and np.count_nonzero(x) == 2
    np.testing.assert_allclose(dx[order], ref.rhs_numpy(0.0, xk, 2.0), rtol=1e-12, atol=1e-14)
    assert z[0] == pytest.approx(1 - (0.2 / (math.pi / 2)) ** 2, rel=1e-15)
    m.fmu.exitInitializationMode()
    m2 = me(version, PLANT, n_modes=1, L=-1.0)          # a bad parameter: an error, said
    if version == 2:
        m2.fmu.enterInitializationMode()
    else:
        m2.fmu.enterInitializationMode(startTime=0.0)
    assert fmi_status(m2.derivatives) == 3
    assert any("L = -1" in msg for _, msg in m2.logs)


# ---------------------------------------------------------------------- states and derivatives
@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("fidelity", ["nonlinear", "linear"])
@pytest.mark.parametrize("n,damping", [(0, "modal"), (3, "modal"), (8, "modal"),
                                       (3, "kelvin-voigt"), (8, "kelvin-voigt")])
def test_derivatives_are_the_numpy_right_hand_side(me, version, fidelity, n, damping):
    """At random states and force, the FMU's derivatives are rhs_numpy (the kernel's right-hand
    side, to rounding) in the declared order, under either damping law (whose right-hand sides
    differ far beyond the tolerance); the states beyond n_modes stay 0 with derivative 0; the
    outputs follow the states set."""
    from plant_fmu.dynamics import LinearPlantModel, PlantModel
    from plant_fmu.params import PlantParams
    m = me(version, PLANT, n_modes=n, fidelity=fidelity, zeta=0.01, damping=damping)
    m.initialize()
    model = LinearPlantModel if fidelity == "linear" else PlantModel
    p = PlantParams(n_modes=n, zeta=0.01, damping=damping)
    ref = model(p)
    other = model(p.replace(damping="modal" if damping != "modal" else "kelvin-voigt"))
    rng = np.random.default_rng(n)
    order = [_kernel_names(8).index(s) for s in _kernel_names(n)]
    for _ in range(5):
        xk = rng.normal(size=2 * (n + 2)) * 0.3
        x = rng.normal(size=20)                # the states beyond n_modes: ignored
        x[order] = xk
        u = float(rng.normal() * 10)
        m.set(F_c=u)
        m.set_time(0.5)
        m.set_states(x)
        dx = m.derivatives()
        want = np.zeros(20)
        want[order] = ref.rhs_numpy(0.0, xk, u)
        np.testing.assert_allclose(dx, want, rtol=1e-11, atol=1e-11 * np.abs(want).max())
        if n:
            assert np.max(np.abs(ref.rhs_numpy(0.0, xk, u) - other.rhs_numpy(0.0, xk, u))) \
                > 1e5 * 1e-11 * np.abs(want).max()        # the laws apart, far beyond
        xs = m.states()
        assert np.all(xs[np.setdiff1d(np.arange(20), order)] == 0.0)
        assert np.array_equal(xs[order], xk)
        phi_o, _ = ref.tip_angle(xk)
        assert m.get("phi_o")[0] == pytest.approx(phi_o, rel=1e-13, abs=1e-15)
        assert m.get("phi_dot")[0] == xk[n + 3]
        assert m.get("der(x_dot)")[0] == dx[10]


@pytest.mark.parametrize("version", [2, 3])
def test_nominals_are_the_physical_scales(me, version):
    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    m = me(version, PLANT, n_modes=3, L=0.8)
    m.initialize()
    ref = PlantModel(PlantParams(n_modes=3, L=0.8))
    nom = m.nominals()
    g, L = ref.g, 0.8
    eta = 0.01 * L / np.abs(ref.tip_defl)
    want = np.ones(20)
    want[0], want[10], want[11] = L, math.sqrt(g * L), math.sqrt(g / L)
    want[2:5] = eta
    want[12:15] = np.sqrt(ref.Kdiag) * eta
    np.testing.assert_allclose(nom, want, rtol=1e-12)


# ---------------------------------------------------------------------- fmpy's CVode
def _input_signal():
    """The committed input file of the plant (the cross-check layout), F_c only."""
    from pathlib import Path
    data = np.genfromtxt(Path(__file__).parents[1] / "reference" / PLANT / f"{PLANT}_in.csv",
                         delimiter=",", names=True)
    sig = np.zeros(len(data), dtype=[("time", float), ("F_c", float)])
    sig["time"], sig["F_c"] = data["time"], data["F_c"]
    return sig


def _scipy_plant(start, sig, t_out, fidelity="nonlinear"):
    """The numpy specification with the input interpolated linearly (as fmpy's Input does), by
    scipy's DOP853 at rtol = atol = 1e-12, stepping sample to sample."""
    import scipy.integrate

    from plant_fmu.dynamics import LinearPlantModel, PlantModel
    from plant_fmu.params import PlantParams
    n = start.get("n_modes", 4)
    model = (LinearPlantModel if fidelity == "linear" else PlantModel)(PlantParams(n_modes=n))
    x0 = np.zeros(model.nx)
    x0[1] = start.get("phi0", 0.0)
    if sig is None:
        def u(t):
            return 0.0
        breaks = [t_out[0], t_out[-1]]
    else:
        def u(t):
            return float(np.interp(t, sig["time"], sig["F_c"]))
        breaks = sorted(set(sig["time"]) | {t_out[-1]})
    ts, xs = [], []
    x = x0
    for a, b in zip(breaks[:-1], breaks[1:]):
        if b <= a:
            continue
        sol = scipy.integrate.solve_ivp(lambda t, y: model.rhs_numpy(t, y, u(t)), (a, b), x,
                                        method="DOP853", rtol=1e-12, atol=1e-12,
                                        dense_output=True)
        mask = (t_out >= a) & (t_out <= b)
        if mask.any():
            ts.append(t_out[mask])
            xs.append(sol.sol(t_out[mask]).T)
        x = sol.y[:, -1]
    t = np.concatenate(ts)
    _, idx = np.unique(t, return_index=True)
    X = np.concatenate(xs)[idx]
    return {"phi": X[:, 1], "x_o": X[:, 0],
            "phi_o": np.array([model.tip_angle(r)[0] for r in X])}


@pytest.fixture
def fmpy_logger():
    """A logger for fmpy's simulate_fmu: the messages, decoded (fmpy's logger proxy is put back
    after each test by the autouse fixture in tests/conftest.py)."""
    logs = []
    yield logs, lambda *a: logs.append(a[-1].decode() if isinstance(a[-1], bytes)
                                       else str(a[-1]))


CASES = {
    # the committed input file (a smooth force), a flexible plant, until before it falls over
    "input_file": ({"n_modes": 4, "phi0": 0.0}, True, 0.6),
    # a free swing from a small tilt (no input), until before it falls past phi_limit
    "free_swing": ({"n_modes": 2, "phi0": 0.1}, False, 0.5),
}


@pytest.fixture
def fmpy_input_in_rhs(monkeypatch):
    """fmpy 0.3.32's CVode applies a continuous input in the root function (and after each output
    step) but not in the right-hand side: with event indicators, the derivative is evaluated with
    the input of the last root evaluation's time, an inconsistent right-hand side that stalls
    CVode (mxstep). Apply the input at the time of every right-hand side too, as an importer
    must."""
    from fmpy import sundials
    orig = sundials.CVodeSolver.f

    def f(self, t, y, ydot, user_data):
        self.input.apply(t)
        return orig(self, t, y, ydot, user_data)
    monkeypatch.setattr(sundials.CVodeSolver, "f", f)


def _cs_run(m, sig, stop, h, names):
    """The CS plant stepped by hand: FMI 2.0 with the input's slope as its derivative (exact for
    the linear interpolation), FMI 3.0 (held inputs) with the input at each step's midpoint."""
    t, out = 0.0, [(0.0, *m.get(*names))]
    nsteps = round(stop / h)
    for k in range(nsteps):
        t0, t1 = k * h, (k + 1) * h
        if sig is not None:
            if m.version == 2:
                m.set(F_c=np.interp(t0, sig["time"], sig["F_c"]))
                j = min(np.searchsorted(sig["time"], t0 + 1e-12, side="right") - 1,
                        len(sig) - 2)
                slope = (sig["F_c"][j + 1] - sig["F_c"][j]) / (sig["time"][j + 1]
                                                                 - sig["time"][j])
                m.fmu.setRealInputDerivatives(m.vr("F_c"), [1], [slope])
            else:
                m.set(F_c=np.interp(0.5 * (t0 + t1), sig["time"], sig["F_c"]))
        m.fmu.doStep(t0, h)
        t = t1
        out.append((t, *m.get(*names)))
    a = np.array(out)
    return {"time": a[:, 0], **{n: a[:, i + 1] for i, n in enumerate(names)}}


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("case", list(CASES))
def test_fmpy_cvode_in_model_exchange_matches_cs_and_the_monolithic_reference(
        paths, me, fmpy_input_in_rhs, version, case):
    """Issue 24, 5: fmpy's CVode on the ME plant (rtol 1e-10) against the CS plant (dopri5 at
    rtol = atol = 1e-12; 1 ms steps with the input's slope, FMI 2.0, or 0.025 ms steps with the
    input at the midpoint, FMI 3.0) and the numpy specification by scipy (DOP853 at 1e-12, the
    input interpolated linearly as fmpy does). Tolerances (rad, m): ME against the reference
    1e-8, CVode's global error at rtol 1e-10 over 0.6 s of an unstable plant with the kinks of
    the input at every millisecond (measured 1.3e-9, docs/fmus.md); CS against either 5e-8, for
    the midpoint input of FMI 3.0's CS, ~h^2 F' T / 12 = 1.9e-8 at 0.025 ms (FMI 2.0's CS, with
    the input's slope, is within 5e-12 of the reference)."""
    import fmpy
    start, with_input, stop = CASES[case]
    sig = _input_signal() if with_input else None
    out = ["phi", "x_o", "phi_o"]
    path = paths[version][PLANT]
    me_res = fmpy.simulate_fmu(path, fmi_type="ModelExchange", solver="CVode",
                               relative_tolerance=1e-10, stop_time=stop, start_values=start,
                               input=sig, output=out, output_interval=1e-3)
    t = me_res["time"]
    assert t[-1] == pytest.approx(stop)
    cs = me(version, PLANT, cs=True, **start, integrator="dopri5", rtol=1e-12, atol=1e-12)
    cs.initialize(event=False)
    cs_res = _cs_run(cs, sig, stop, 1e-3 if version == 2 else 2.5e-5, out)
    ref = _scipy_plant(start, sig, t)
    for name in out:
        cs_on = np.interp(t, cs_res["time"], cs_res[name])
        assert np.max(np.abs(me_res[name] - ref[name])) < 1e-8, name
        assert np.max(np.abs(me_res[name] - cs_on)) < 5e-8, name
        assert np.max(np.abs(cs_on - ref[name])) < 5e-8, name
    assert np.max(np.abs(me_res["phi"])) > 0.01          # it moved


@pytest.mark.parametrize("version", [2, 3])
def test_the_phi_limit_event_terminates_where_cs_refuses_the_step(paths, fmpy_logger, version):
    """A fall from pi/6: CVode locates where |phi| reaches phi_limit (the event indicator), the
    FMU asks to terminate and says why; the time is where the numpy specification crosses it."""
    import fmpy
    import scipy.integrate

    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    logs, logger = fmpy_logger
    res = fmpy.simulate_fmu(paths[version][PLANT], fmi_type="ModelExchange", solver="CVode",
                            relative_tolerance=1e-10, stop_time=2.0,
                            start_values={"n_modes": 1, "phi0": math.pi / 6},
                            output=["phi"], output_interval=1e-3, logger=logger)
    m = PlantModel(PlantParams(n_modes=1))
    x0 = np.zeros(m.nx)
    x0[1] = math.pi / 6

    def hit(t, y):
        return abs(y[1]) - math.pi / 2
    hit.terminal = True
    sol = scipy.integrate.solve_ivp(lambda t, y: m.rhs_numpy(t, y, 0.0), (0, 2), x0,
                                    method="DOP853", rtol=1e-12, atol=1e-12, events=hit)
    assert res["time"][-1] == pytest.approx(sol.t_events[0][0], abs=1e-6)
    assert abs(res["phi"][-1]) == pytest.approx(math.pi / 2, abs=1e-6)
    assert any("phi_limit" in msg and "terminates" in msg for msg in logs), logs[-5:]


@pytest.mark.parametrize("version", [2, 3])
def test_the_energy_limit_event_terminates_at_the_bound(paths, fmpy_logger, version):
    """A constant push raises the energy: CVode stops where |energy| reaches energy_limit, the
    FMU names the bound; and an instance beyond the modes Model Exchange declares is refused at
    exitInitializationMode."""
    import fmpy
    from fmpy.fmi1 import FMICallException
    logs, logger = fmpy_logger
    with pytest.raises(FMICallException):       # (before any call with a logger of ours)
        fmpy.simulate_fmu(paths[version][PLANT], fmi_type="ModelExchange", stop_time=1e-3,
                          start_values={"n_modes": 9})
    e0 = fmpy.simulate_fmu(paths[version][PLANT], fmi_type="ModelExchange", stop_time=1e-3,
                           start_values={"n_modes": 1}, output=["energy"])["energy"][0]
    limit = abs(e0) + 0.5
    res = fmpy.simulate_fmu(paths[version][PLANT], fmi_type="ModelExchange", solver="CVode",
                            relative_tolerance=1e-10, stop_time=2.0,
                            start_values={"n_modes": 1, "F_c": 20.0, "energy_limit": limit},
                            output=["energy", "phi"], output_interval=1e-3, logger=logger)
    assert res["time"][-1] < 2.0
    assert abs(res["energy"][-1]) == pytest.approx(limit, rel=1e-6)
    assert np.all(np.abs(res["phi"]) < math.pi / 2)
    assert any("energy_limit" in msg and "terminates" in msg for msg in logs), logs[-3:]


# ---------------------------------------------------------------------- the controller
@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("order", [0, 1, 2])
def test_controller_me_is_the_exact_continuous_response(paths, version, order):
    """Piecewise-constant sensors (each value held 50 ms; the input's events make CVode restart
    at each jump): the ME controller's F_c against the exact discrete response of the filter
    (matrix exponentials, PDLowPassModel.step) on the same grid, saturation included."""
    import fmpy

    from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
    rng = np.random.default_rng(order)
    T = np.arange(0, 0.5 + 1e-12, 0.05)
    vals = rng.normal(size=(len(T), 3)) * [0.2, 1.0, 0.1]
    # a step signal for fmpy: each value repeated at the jump (an event)
    tt = np.repeat(T, 2)[1:]
    sig = np.zeros(len(tt), dtype=[("time", float), ("phi_o", float), ("omega_o", float),
                                   ("x_o", float)])
    sig["time"] = tt
    rows = np.repeat(vals, 2, axis=0)[:-1]
    sig["phi_o"], sig["omega_o"], sig["x_o"] = rows[:, 0], rows[:, 1], rows[:, 2]
    params = {"filter_order": order, "cutoff": 40.0, "filter_damping": 0.6, "kx": 3.0,
              "force_limit": 25.0}
    res = fmpy.simulate_fmu(paths[version][CTRL], fmi_type="ModelExchange", solver="CVode",
                            relative_tolerance=1e-11, stop_time=0.5, start_values=params,
                            input=sig, output=["F_c"], output_interval=0.01)
    ref = PDLowPassModel(ControllerParams(**params))
    xc = ref.initial_state()
    h = 0.01
    want = {}
    for k in range(51):
        t = k * h
        j = min(int(math.floor(t / 0.05 + 1e-9)), len(T) - 1)
        y = tuple(vals[j][[2, 0, 1]])              # (x_o, phi_o, omega_o)
        want[round(t, 6)] = ref.output(xc, y)
        xc = ref.step(xc, y, h)
    for t, f in zip(res["time"], res["F_c"]):
        key = round(float(t), 6)
        if key in want and abs(key / 0.05 - round(key / 0.05)) > 1e-6:   # not at a jump
            assert f == pytest.approx(want[key], abs=1e-6 * max(1.0, abs(want[key]))), t


# ---------------------------------------------------------------------- FMU states in ME
def _rk4(m, t, h, n):
    """n RK4 steps of the FMU's ODE by hand (setTime, setContinuousStates, getDerivatives):
    every output after each step."""
    out = []
    for _ in range(n):
        x = m.states()

        def f(tt, xx):
            m.set_time(tt)
            m.set_states(xx)
            return m.derivatives()
        k1 = f(t, x)
        k2 = f(t + h / 2, x + h / 2 * k1)
        k3 = f(t + h / 2, x + h / 2 * k2)
        k4 = f(t + h, x + h * k3)
        t += h
        m.set_time(t)
        m.set_states(x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4))
        m.fmu.completedIntegratorStep()
        out.append((t, m.states().tobytes(), m.get("phi_o", "omega_o", "energy")))
    return t, out


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("name", [PLANT, CTRL])
def test_me_state_get_set_and_serialisation_continue_bit_identically(me, version, name):
    start = {"n_modes": 3, "phi0": 0.2} if name == PLANT else {"filter_order": 2}
    a = me(version, name, **start)
    a.initialize()
    if name == CTRL:
        a.set(phi_o=0.1, omega_o=-0.3, x_o=0.02)
        a._outputs = ("F_c",)
    get_out = (lambda m: m.get("F_c")) if name == CTRL else None
    if get_out is not None:
        def run(m, t, n):
            out = []
            for _ in range(n):
                x = m.states()
                m.set_time(t)
                dx = m.derivatives()
                t += 1e-3
                m.set_time(t)
                m.set_states(x + 1e-3 * dx)
                out.append((t, m.states().tobytes(), get_out(m)))
            return t, out
    else:
        def run(m, t, n):
            return _rk4(m, t, 1e-3, n)
    t, _ = run(a, 0.0, 30)
    state = a.fmu.getFMUState() if version == 3 else a.fmu.getFMUstate()
    data = (a.fmu.serializeFMUState(state) if version == 3 else a.fmu.serializeFMUstate(state))
    _, first = run(a, t, 30)
    if version == 3:
        a.fmu.setFMUState(state)
    else:
        a.fmu.setFMUstate(state)
    _, again = run(a, t, 30)
    assert again == first
    b = me(version, name)                             # another instance, other parameters
    b.initialize()
    if version == 3:
        b.fmu.setFMUState(b.fmu.deserializeFMUState(data))
    else:
        b.fmu.setFMUstate(b.fmu.deSerializeFMUstate(data))
    _, third = run(b, t, 30)
    assert third == first
    # a co-simulation instance refuses a Model-Exchange state (its mode is not one of its own)
    c = me(version, name, cs=True)
    n = len(c.logs)
    with pytest.raises(Exception):                    # noqa: B017 - fmpy's FMICallException
        if version == 3:
            c.fmu.setFMUState(c.fmu.deserializeFMUState(data))
        else:
            c.fmu.setFMUstate(c.fmu.deSerializeFMUstate(data))
    assert any("not a state this instance can be in" in msg for _, msg in c.logs[n:])
    if version == 3:                    # even one in event mode (eventModeUsed), as ME's are
        from fmpy.fmi3 import FMU3Slave
        d = FMU3Slave(guid=c.md.guid, unzipDirectory=c.fmu.unzipDirectory,
                      modelIdentifier=c.md.coSimulation.modelIdentifier, instanceName="e")
        msgs = []
        d.instantiate(loggingOn=True, eventModeUsed=True,
                      logMessage=lambda env, status, cat, msg: msgs.append(msg.decode()))
        a.fmu.enterEventMode()                        # an ME state in event mode
        in_event = a.fmu.serializeFMUState(a.fmu.getFMUState())
        with pytest.raises(Exception):                # noqa: B017 - fmpy's FMICallException
            d.setFMUState(d.deserializeFMUState(in_event))
        assert any("a state of an instance of Model Exchange" in msg for msg in msgs), msgs
        d.freeInstance()


# ---------------------------------------------------------------------- directional derivatives
def _unknowns_knowns(md):
    ders = [d.variable.name for d in md.derivatives]
    states_ = [d.variable.derivative.name for d in md.derivatives]
    outs = [o.variable.name for o in md.outputs]
    ins = [v.name for v in md.modelVariables if v.causality == "input"]
    return ders, states_, outs, ins


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("n", [0, 2, 8])
def test_plant_directional_derivatives_are_the_numpy_jacobian_and_central_differences(
        me, version, n):
    """ME: d(der x, y)/d(x, F_c) through fmi*GetDirectionalDerivative against jacobian_numpy /
    output_jacobian_numpy at random states, and against central differences of getDerivatives
    through the FMI API."""
    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    m = me(version, PLANT, n_modes=n)
    m.initialize()
    ders, sts, outs, ins = _unknowns_knowns(m.md)
    ref = PlantModel(PlantParams(n_modes=n))
    order = [_kernel_names(8).index(s) for s in _kernel_names(n)]
    rng = np.random.default_rng(100 + n)
    xk = rng.normal(size=2 * (n + 2)) * 0.3
    x = np.zeros(20)
    x[order] = xk
    u = 3.0
    m.set(F_c=u)
    m.set_states(x)
    J, b = ref.jacobian_numpy(xk, u)
    for j, s in enumerate(_kernel_names(n)):
        col = m.directional(ders, [s], [1.0])
        want = np.zeros(20)
        want[order] = J[:, j]
        np.testing.assert_allclose(col, want, rtol=1e-9, atol=1e-9 * np.abs(J).max())
        # central differences through the FMI API
        hstep = 1e-6
        xp, xm = x.copy(), x.copy()
        xp[order[j]] += hstep
        xm[order[j]] -= hstep
        m.set_states(xp)
        dp = m.derivatives()
        m.set_states(xm)
        dm = m.derivatives()
        m.set_states(x)
        np.testing.assert_allclose(col, (dp - dm) / (2 * hstep), rtol=1e-5,
                                   atol=1e-5 * np.abs(J).max())
    col = m.directional(ders, ["F_c"], [1.0])
    want = np.zeros(20)
    want[order] = b
    np.testing.assert_allclose(col, want, rtol=1e-9, atol=1e-12)
    # outputs on states (energy, phi_o, omega_o ...)
    C = ref.output_jacobian_numpy(xk)
    rows = _OUT_ROWS + [f"eta_{j}" for j in range(1, n + 1)]
    for j, s in enumerate(_kernel_names(n)):
        col = m.directional(rows, [s], [1.0])
        np.testing.assert_allclose(col, C[:, j], rtol=1e-9, atol=1e-9 * np.abs(C).max())


@pytest.mark.parametrize("version", [2, 3])
def test_cs_directional_derivatives_of_the_outputs_are_central_differences(me, version):
    """CS: the outputs after a step with respect to the states the importer may hold, against
    output_jacobian_numpy at the state reached."""
    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    m = me(version, PLANT, cs=True, n_modes=3, phi0=0.3)
    m.initialize(event=False)
    for k in range(20):
        m.fmu.doStep(k * 1e-3, 1e-3)
    sts = _kernel_names(3)
    xk = np.array(m.get(*sts))
    C = PlantModel(PlantParams(n_modes=3)).output_jacobian_numpy(xk)
    rows = _OUT_ROWS + ["eta_1", "eta_2", "eta_3"]
    for j, s in enumerate(sts):
        np.testing.assert_allclose(m.directional(rows, [s], [1.0]), C[:, j], rtol=1e-9,
                                   atol=1e-9 * np.abs(C).max())
    assert np.all(m.directional(rows, ["F_c"], [1.0]) == 0.0)      # no direct feedthrough


@pytest.mark.parametrize("version", [2, 3])
@pytest.mark.parametrize("order", [0, 1, 2])
def test_controller_directional_derivatives_are_its_state_space(me, version, order):
    """ME: d(der xc)/d(xc, sensors) = [Af, Bf gains] of PDLowPassModel (zero beyond the filter
    order), dF_c/dxc_1 = -1 unsaturated (order 0: dF_c/d(sensors) = -gains), and central
    differences of getDerivatives through the FMI API."""
    from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
    params = {"filter_order": order, "kx": 2.0, "cutoff": 50.0, "filter_damping": 0.5}
    m = me(version, CTRL, **params)
    m.initialize()
    ref = PDLowPassModel(ControllerParams(**params))
    m.set(phi_o=0.01, omega_o=-0.02, x_o=0.003)
    x = np.array([0.2, -1.0])[:max(order, 0)]
    xs = np.zeros(2)
    xs[:order] = x
    m.set_states(xs)
    ders = ["der(xc_1)", "der(xc_2)"]
    ins = ["x_o", "phi_o", "omega_o"]            # PDLowPassModel's sensor order
    for j in range(2):
        col = m.directional(ders, [f"xc_{j + 1}"], [1.0])
        want = np.zeros(2)
        if j < order:
            want[:order] = ref.Af[:, j]
        np.testing.assert_allclose(col, want, rtol=1e-14, atol=1e-14)
        h = 1e-6
        xp, xm = xs.copy(), xs.copy()
        xp[j] += h
        xm[j] -= h
        m.set_states(xp)
        dp = m.derivatives()
        m.set_states(xm)
        dm = m.derivatives()
        m.set_states(xs)
        np.testing.assert_allclose(col, (dp - dm) / (2 * h), rtol=1e-6, atol=1e-6)
    for j, name in enumerate(ins):
        col = m.directional(ders, [name], [1.0])
        want = np.zeros(2)
        want[:order] = ref.B[:, j] if order else []
        np.testing.assert_allclose(col, want, rtol=1e-14, atol=1e-14)
    dF = m.directional(["F_c"], ["xc_1", *ins], [1.0, 0.0, 0.0, 0.0])
    assert dF[0] == pytest.approx(-1.0 if order else 0.0, abs=1e-14)
    if order == 0:
        gains = [m.directional(["F_c"], [name], [1.0])[0] for name in ins]
        np.testing.assert_allclose(gains, -ref.gains[0], rtol=1e-14)


@pytest.mark.parametrize("version", [2, 3])
def test_directional_derivative_refuses_the_wrong_kinds_with_a_message(me, version):
    m = me(version, PLANT)
    m.initialize()
    for unknowns, knowns in ((["phi_dot"], ["phi"]), (["der(phi)"], ["m"]),
                             (["der(phi)"], ["der(x_o)"]), (["F_c"], ["phi"])):
        n = len(m.logs)
        assert fmi_status(m.directional, unknowns, knowns, [1.0]) == 3
        assert any("GetDirectionalDerivative" in msg for _, msg in m.logs[n:]), m.logs[n:]
    c = me(version, PLANT, cs=True)
    c.initialize(event=False)
    n = len(c.logs)
    assert fmi_status(c.directional, ["der(phi)"], ["phi"], [1.0]) == 3    # no derivatives in CS
    assert any("an output" in msg for _, msg in c.logs[n:])


# ---------------------------------------------------------------------- output derivatives
def _output_derivative(m, names, order):
    if m.version == 2:
        return np.array(m.fmu.getRealOutputDerivatives(m.vr(*names), [order] * len(names)))
    return np.array(m.fmu.getOutputDerivatives(m.vr(*names), [order] * len(names)))


@pytest.mark.parametrize("version", [2, 3])
def test_output_derivatives_are_the_numpy_specifications_and_the_fmus_steps(me, version):
    """The first and second time derivatives of every output at the end of a step (held input):
    against the numpy specification, y' = C(x) f(x, u) (output_jacobian_numpy, rhs_numpy) and
    y'' = d/dt [C f] by central differences of C f along f (eps = 1e-6); and y' against forward
    differences of the FMU's own steps from the same state (h = 1e-5, error (omega h)^2)."""
    from plant_fmu.dynamics import PlantModel
    from plant_fmu.params import PlantParams
    n = 2
    rows = _OUT_ROWS + ["eta_1", "eta_2"]
    m = me(version, PLANT, cs=True, n_modes=n, phi0=0.3, integrator="dopri5", rtol=1e-12,
           atol=1e-12)
    m.initialize(event=False)
    u = 1.5
    m.set(F_c=u)
    for k in range(50):
        m.fmu.doStep(k * 1e-3, 1e-3)
    t = 0.05
    d1 = _output_derivative(m, rows, 1)
    d2 = _output_derivative(m, rows, 2)
    ref = PlantModel(PlantParams(n_modes=n))
    x = np.array(m.get(*_kernel_names(n)))

    def g(z):
        return ref.output_jacobian_numpy(z) @ ref.rhs_numpy(0.0, z, u)
    f = ref.rhs_numpy(0.0, x, u)
    eps = 1e-6
    want1 = g(x)
    want2 = (g(x + eps * f) - g(x - eps * f)) / (2 * eps)
    np.testing.assert_allclose(d1, want1, rtol=1e-9, atol=1e-9 * np.abs(want1).max())
    np.testing.assert_allclose(d2, want2, rtol=1e-6, atol=1e-6 * np.abs(want2).max())
    restore = m.fmu.setFMUstate if version == 2 else m.fmu.setFMUState
    state = m.fmu.getFMUstate() if version == 2 else m.fmu.getFMUState()
    y0 = np.array(m.get(*rows))
    h, ys = 1e-5, []
    for k in (1, 2):
        restore(state)
        m.fmu.doStep(t, k * h)
        ys.append(np.array(m.get(*rows)))
    fd1 = (-3 * y0 + 4 * ys[0] - ys[1]) / (2 * h)
    np.testing.assert_allclose(d1, fd1, rtol=1e-4, atol=1e-4 * np.abs(fd1).max())


@pytest.mark.parametrize("version", [2, 3])
def test_max_output_derivative_order_is_what_the_binary_gives(me, version):
    """The modelDescription's maxOutputDerivativeOrder (the Python-side constant) is the highest
    order the binary gives: that order works, the next is refused with a message."""
    from orchestration.export.native_fmus import max_output_derivative_order
    for name, out in ((PLANT, "phi_o"), (CTRL, "F_c")):
        m = me(version, name, cs=True)
        top = max_output_derivative_order(name)
        assert m.md.coSimulation.maxOutputDerivativeOrder == top
        m.initialize(event=False)
        m.fmu.doStep(0.0, 1e-3)
        assert np.isfinite(_output_derivative(m, [out], top)).all()
        n = len(m.logs)
        assert fmi_status(_output_derivative, m, [out], top + 1) == 3
        assert any("maxOutputDerivativeOrder" in msg for _, msg in m.logs[n:])


def test_controller_output_derivatives_after_a_step_follow_the_input_derivatives_set_then(me):
    """FMI 2.0 co-simulation: after a doStep, F_c's derivatives are those of the step's input
    polynomial at its end, until input derivatives are set: then, orders 1 to 4, those of the
    inputs and input derivatives set now (the Hermite coupling reads them so), equal to the
    kernel's fpf_output_derivatives at the filter state read through F_c and its rate."""
    from controller_fmu.kernel import FilterKernel
    from controller_fmu.pd_lowpass import ControllerParams, PDLowPassModel
    params = {"kx": 2.0, "cutoff": 50.0, "filter_damping": 0.5}
    p = ControllerParams(**params)
    model, kern = PDLowPassModel(p), FilterKernel(p)
    m = me(2, CTRL, cs=True, **params)
    m.initialize(event=False)
    ins = ["x_o", "phi_o", "omega_o"]           # PDLowPassModel's sensor order
    y0, y1, y2 = [0.01, 0.2, -1.5], [0.3, 2.0, 40.0], [-2.0, 50.0, 900.0]
    m.set(**dict(zip(ins, y0)))
    vrs = m.vr(*ins)
    m.fmu.setRealInputDerivatives(vrs, [1] * 3, y1)
    m.fmu.setRealInputDerivatives(vrs, [2] * 3, y2)
    h = 2e-3
    m.fmu.doStep(0.0, h)
    F, dF = m.get("F_c")[0], _output_derivative(m, ["F_c"], 1)[0]
    xc = np.array([-F, -dF])                    # F_c = -xc_1, its rate -xc_2 (unsaturated)
    end = [[a + h * b + 0.5 * h * h * c for a, b, c in zip(y0, y1, y2)],
           [b + h * c for b, c in zip(y1, y2)], y2]        # the step's polynomial at its end
    e_end = [model.error_signal(v) for v in end]
    assert _output_derivative(m, ["F_c"], 2)[0] == pytest.approx(
        kern.output_derivatives(xc, *e_end)[1], rel=1e-12)
    z0, z1, z2 = [0.02, 0.1, 3.0], [-0.4, 7.0, -80.0], [5.0, -300.0, 2e4]
    m.set(**dict(zip(ins, z0)))
    m.fmu.setRealInputDerivatives(vrs, [1] * 3, z1)
    m.fmu.setRealInputDerivatives(vrs, [2] * 3, z2)
    want = kern.output_derivatives(xc, *(model.error_signal(v) for v in (z0, z1, z2)), orders=4)
    got = [_output_derivative(m, ["F_c"], k)[0] for k in (1, 2, 3, 4)]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got[2] != 0.0 and got[3] != 0.0

# ---------------------------------------------------------------------- the stiffened rung
@pytest.mark.parametrize("version", [2, 3])
def test_stiffened_derivatives_are_its_numpy_rhs_and_its_jacobians_are_refused(me, version):
    """``fidelity = "stiffened"`` in Model Exchange: the derivatives are
    StiffenedPlantModel.rhs_numpy (whose mass points beam.py makes, the FMU its own from the
    modes' nodal tables) and the energy its energy_numpy; the directional and output
    derivatives, which its FMU (FlexiblePendulumStiffened) does not declare, are refused with a
    message."""
    from plant_fmu.dynamics import stiffened_plant_model
    from plant_fmu.params import PlantParams
    for n, ne, L in ((3, 12, 1.0), (5, 7, 0.8)):            # 16 and 20 mass points
        m = me(version, STIFFENED, n_modes=n, n_elements=ne, L=L, fidelity="stiffened")
        m.initialize()
        ref = stiffened_plant_model(PlantParams(n_modes=n, n_elements=ne, L=L))
        rng = np.random.default_rng(4)
        order = [_kernel_names(8).index(s) for s in _kernel_names(n)]
        for _ in range(3):
            xk = rng.normal(size=2 * (n + 2)) * 0.3
            x = np.zeros(20)
            x[order] = xk
            u = float(rng.normal() * 10)
            m.set(F_c=u)
            m.set_states(x)
            want = ref.rhs_numpy(0.0, xk, u)
            np.testing.assert_allclose(m.derivatives()[order], want, rtol=1e-11,
                                       atol=1e-11 * np.abs(want).max())
            assert m.get("energy")[0] == pytest.approx(ref.energy_numpy(xk), rel=1e-12)
    k = len(m.logs)
    assert fmi_status(m.directional, ["der(phi_dot)"], ["phi"], [1.0]) == 3
    assert any("provides no directional derivatives" in msg for _, msg in m.logs[k:]), m.logs[k:]
    c = me(version, STIFFENED, cs=True, n_modes=3, fidelity="stiffened")
    c.initialize(event=False)
    k = len(c.logs)
    assert fmi_status(_output_derivative, c, ["phi_o"], 1) == 3
    assert any("gives no output derivatives" in msg for _, msg in c.logs[k:]), c.logs[k:]
