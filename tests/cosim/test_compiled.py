"""The master's compiled fixed-step loop (orchestration/cosim/native/fm_master.c, bound in
orchestration/cosim/compiled.py) against its Python loop.

Independent value: the Python loop of orchestration/cosim/master.py, which the compiled loop must
reproduce bit for bit: the same output rows on the paper's scenes and every coupling option, the
same FMI calls with the same arguments in the same order (traced through wrappers of the FMUs'
own functions), the same failure for a failed call of every kind (message, status, time, partial
rows), the same divergence and the same interruption.
"""
from __future__ import annotations

import ctypes
import itertools

import numpy as np
import pytest

from orchestration.cosim import compiled as compiled_master
from orchestration.scene.keys import ConfigError
from orchestration.cosim.slave import CoSimulationError, RunInterrupted, Slave
from orchestration.cosim.master import Master
from orchestration.scene.wiring import parse_connection
from orchestration.job import RECORD, controller_start_values, plant_start_values, run_scene
from orchestration.scene.schema import PAPER_SCENES, load_scene


@pytest.fixture(scope="module")
def pair(native) -> dict:
    """The native FMI 2.0 pair by the master's names (``plant``, ``controller``)."""
    from orchestration.export import fmu_pair
    return fmu_pair(native)


@pytest.fixture(scope="module")
def unzipped(native_dirs) -> dict:
    from orchestration.export import fmu_pair
    return fmu_pair(native_dirs)


def both(scene_name, sets, pair, unzipped, **kw):
    """The scene run by the Python loop and by the compiled loop."""
    out = {}
    for compiled in (False, True):
        scene = load_scene(scene_name, [f"master.compiled={str(compiled).lower()}", *sets])
        out[compiled] = run_scene(scene, pair, progress=False, unzipdirs=unzipped, **kw)
    assert out[False].summary["master_loop"] == "python"
    assert out[True].summary["master_loop"] == "compiled"
    return out[False], out[True]


def assert_same_rows(a, b):
    assert a.dtype == b.dtype and len(a) == len(b)
    for c in a.dtype.names:
        np.testing.assert_array_equal(a[c], b[c], err_msg=c)
        # bit for bit, the signs of zeros too
        assert a[c].tobytes() == b[c].tobytes(), c


# ---------------------------------------------------------------------- the same numbers
SHORT = {"rigid_pd": "stop_time=1", "flexible_pd": "stop_time=0.25",
         "flexible_pd_lowpass": "stop_time=1"}


@pytest.mark.parametrize("name", PAPER_SCENES)
def test_paper_scenes_are_bit_identical(pair, unzipped, name):
    """Each paper scene with its own coupling (Gauss-Seidel, quadratic extrapolation, input
    derivatives; flexible_pd's controller has no filter: a feedthrough FMU), shortened."""
    py, c = both(name, [SHORT[name]], pair, unzipped)
    assert py.summary["completed"] and c.summary["completed"]
    assert_same_rows(py.result, c.result)
    assert np.ptp(c.result["phi_o"]) > 0.01          # the loop did move


COUPLINGS = list(itertools.product(["gauss-seidel", "jacobi"], ["controller", "plant"], [0, 1, 2],
                                   [True, False], [2, 0]))


@pytest.mark.parametrize("algorithm,first,p,derivatives,filter_order", COUPLINGS)
def test_every_coupling_is_bit_identical(pair, unzipped, algorithm, first, p, derivatives,
                                         filter_order):
    """Jacobi and Gauss-Seidel with either FMU first, extrapolation of order 0, 1, 2, held step
    averages or fmi2SetRealInputDerivatives, a filtered (no feedthrough) and an unfiltered
    (feedthrough: point inputs at t1 before the outputs are read) controller."""
    sets = ["stop_time=0.2", f"master.algorithm={algorithm}", f"master.first={first}",
            f"master.extrapolation={p}", f"master.input_derivatives={str(derivatives).lower()}",
            f"controller.filter_order={filter_order}"]
    py, c = both("flexible_pd_lowpass", sets, pair, unzipped)
    assert_same_rows(py.result, c.result)


@pytest.mark.parametrize("algorithm,first,p,filter_order",
                         list(itertools.product(["gauss-seidel", "jacobi"], ["controller", "plant"],
                                                [1, 2], [2, 0])))
def test_output_derivative_couplings_are_bit_identical(pair, unzipped, algorithm, first, p,
                                                       filter_order):
    """master.output_derivatives: every source extrapolated by the Taylor polynomial at its
    newest sample (fmi2GetRealOutputDerivatives), no corrected first step; both algorithms,
    either FMU first, linear and quadratic, with and without a feedthrough controller."""
    sets = ["stop_time=0.2", "master.output_derivatives=true", f"master.algorithm={algorithm}",
            f"master.first={first}", f"master.extrapolation={p}",
            f"controller.filter_order={filter_order}"]
    py, c = both("flexible_pd_lowpass", sets, pair, unzipped)
    assert_same_rows(py.result, c.result)
    plain = run_scene(load_scene("flexible_pd_lowpass", [*sets[:1], *sets[2:]]), pair,
                      progress=False, unzipdirs=unzipped)
    # the derivatives change the coupling (a test that cannot pass on the past samples' loop)
    assert np.max(np.abs(plain.result["phi_o"] - c.result["phi_o"])) > 0


# ---------------------------------------------------------------------- the same FMI calls
_PROTO = {
    "fmi2SetReal": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t,
                    ctypes.POINTER(ctypes.c_double)),
    "fmi2GetReal": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint), ctypes.c_size_t,
                    ctypes.POINTER(ctypes.c_double)),
    "fmi2DoStep": (ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int),
    "fmi2SetRealInputDerivatives": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint),
                                    ctypes.c_size_t, ctypes.POINTER(ctypes.c_int),
                                    ctypes.POINTER(ctypes.c_double)),
    "fmi2GetFMUstate": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)),
    "fmi2SetFMUstate": (ctypes.c_void_p, ctypes.c_void_p),
    "fmi2FreeFMUstate": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)),
    "fmi2GetRealOutputDerivatives": (ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint),
                                     ctypes.c_size_t, ctypes.POINTER(ctypes.c_int),
                                     ctypes.POINTER(ctypes.c_double)),
}


class Tap:
    """Wraps the FMI functions of a slave (as fmpy loaded them) in ctypes callbacks that both
    loops call: every call is recorded with its arguments (and what it returned), and one call
    can be made to return a given status instead of running."""

    def __init__(self, trace, fail=None):
        self.trace, self.fail = trace, fail       # fail: (slave, function, n-th call, status)
        self.count = {}
        self.armed = False
        self.keep = []

    def wrap(self, name, slave):
        fun = slave.fmu._functions
        for fname, argtypes in _PROTO.items():
            real = fun[fname]
            proto = ctypes.CFUNCTYPE(ctypes.c_int, *argtypes)

            def call(*args, _f=fname, _real=real):
                return self._call(name, _f, _real, args)
            cb = proto(call)
            cb.argtypes, cb.restype = list(argtypes), ctypes.c_int
            cb.argnames = getattr(real, "argnames", None)
            self.keep.append(cb)
            fun[fname] = cb

    def _call(self, name, fname, real, args):
        if fname == "fmi2DoStep":
            self.armed = True                     # the loop has begun
        key = (name, fname)
        if self.armed or fname.endswith("FMUstate"):
            self.count[key] = self.count.get(key, 0) + 1
        hit = self.fail and self.fail[:2] == key and self.count.get(key) == self.fail[2]
        if hit and self.fail[3] > 1:
            self.trace.append((name, fname, "failed", self.fail[3]))
            return self.fail[3]
        status = real(*args)
        if hit:                                   # a warning: the call ran, and says so
            status = self.fail[3]
        n = args[2] if len(args) > 2 else 0
        if fname in ("fmi2SetReal", "fmi2GetReal"):
            rec = (list(args[1][:n]), list(args[3][:n]))
        elif fname in ("fmi2SetRealInputDerivatives", "fmi2GetRealOutputDerivatives"):
            rec = (list(args[1][:n]), list(args[3][:n]), list(args[4][:n]))
        elif fname == "fmi2DoStep":
            rec = (args[1], args[2], args[3])
        else:
            rec = ()
        self.trace.append((name, fname, rec, status))
        return status


def tapped_run(scene, unzipped, pair, compiled, fail=None, stop=None, t0=0.0):
    """One run of ``scene`` from ``t0`` with every FMI call of the loop traced: (rows or
    exception, stats, trace, master)."""
    trace = []
    tap = Tap(trace, fail)
    slaves = {}
    try:
        slaves["plant"] = Slave(pair["plant"], "plant", plant_start_values(scene),
                                unzipdir=unzipped["plant"])
        slaves["controller"] = Slave(pair["controller"], "controller",
                                     controller_start_values(scene),
                                     unzipdir=unzipped["controller"])
        for n, s in slaves.items():
            tap.wrap(n, s)
        master = Master(slaves, scene.connections, RECORD, scene.master, compiled=compiled)
        assert master.loop == ("compiled" if compiled else "python")
        try:
            res, stats = master.run(t0, t0 + scene.output.stop_time,
                                    scene.output.output_interval, stop=stop)
            return res, stats, trace, master
        except (CoSimulationError, RunInterrupted) as exc:
            return exc, exc.stats, trace, master
    finally:
        for s in slaves.values():
            s.close()


TRACED = {
    "the scene's (Gauss-Seidel, quadratic, input derivatives)": [],
    "Jacobi, linear, held": ["master.algorithm=jacobi", "master.extrapolation=1",
                             "master.input_derivatives=false"],
    "Gauss-Seidel, plant first, zero-order hold": ["master.first=plant",
                                                  "master.extrapolation=0"],
    "feedthrough controller, Jacobi, quadratic": ["controller.filter_order=0",
                                                  "master.algorithm=jacobi"],
    "output derivatives (Gauss-Seidel, quadratic)": ["master.output_derivatives=true"],
    "output derivatives, feedthrough, Jacobi, linear": [
        "master.output_derivatives=true", "controller.filter_order=0", "master.algorithm=jacobi",
        "master.extrapolation=1"],
}


@pytest.mark.parametrize("label", list(TRACED))
def test_the_fmi_calls_are_the_same(pair, unzipped, label):
    """Every FMI call of the run (initialisation and 25 steps), its arguments and the values it
    read, in the same order: the compiled loop makes the Python loop's calls."""
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.05", *TRACED[label]])
    py = tapped_run(scene, unzipped, pair, False)
    c = tapped_run(scene, unzipped, pair, True)
    assert py[2] == c[2]
    assert_same_rows(py[0], c[0])
    calls = {f for _, f, *_ in c[2]}
    assert {"fmi2DoStep", "fmi2SetReal", "fmi2GetReal"} <= calls
    if scene.master.input_derivatives and scene.master.extrapolation >= 1:
        assert "fmi2SetRealInputDerivatives" in calls
    if scene.master.output_derivatives:
        assert "fmi2GetRealOutputDerivatives" in calls
        assert "fmi2GetFMUstate" not in calls            # the Taylor polynomial needs no start-up
    elif scene.master.extrapolation >= 1:
        assert {"fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate"} <= calls


# ---------------------------------------------------------------------- the same failures
FAILURES = [
    ("plant", "fmi2DoStep", 9, 2), ("controller", "fmi2DoStep", 1, 3),
    ("plant", "fmi2SetReal", 7, 3), ("controller", "fmi2SetReal", 12, 2),
    ("controller", "fmi2SetRealInputDerivatives", 5, 3),
    ("plant", "fmi2GetReal", 8, 2), ("controller", "fmi2GetReal", 4, 4),
    ("plant", "fmi2GetFMUstate", 1, 3), ("controller", "fmi2GetFMUstate", 1, 2),
    ("controller", "fmi2SetFMUstate", 1, 3), ("plant", "fmi2FreeFMUstate", 1, 3),
    ("controller", "fmi2FreeFMUstate", 1, 2),
]


@pytest.mark.parametrize("fail", FAILURES, ids=lambda f: f"{f[0]}-{f[1]}-{f[2]}-{f[3]}")
@pytest.mark.parametrize("sets", [[], ["controller.filter_order=0", "master.algorithm=jacobi"]],
                         ids=["scene", "feedthrough-jacobi"])
def test_a_failed_call_raises_the_same_error(pair, unzipped, fail, sets):
    """A call that returns discard, error or fatal ends the run with the same
    CoSimulationError: message (FMU, call, time, status, log), status, time, the output rows
    reached and the steps taken; the calls up to it are the same."""
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.06", "output_interval=0.004", *sets])
    py = tapped_run(scene, unzipped, pair, False, fail)
    c = tapped_run(scene, unzipped, pair, True, fail)
    assert isinstance(py[0], CoSimulationError), py[0]
    assert isinstance(c[0], CoSimulationError), c[0]
    assert str(c[0]) == str(py[0])
    assert (c[0].status, c[0].time) == (py[0].status, py[0].time) == (fail[3], c[0].time)
    assert f"{fail[0]}: " in str(c[0])
    assert_same_rows(py[0].result, c[0].result)
    assert c[1].steps == py[1].steps
    assert c[2] == py[2]
    assert [e[:2] for e in c[2] if e[2] == "failed"] == [fail[:2]]


@pytest.mark.parametrize("fail", [("plant", "fmi2GetRealOutputDerivatives", 6, 3),
                                  ("controller", "fmi2GetRealOutputDerivatives", 3, 2)],
                         ids=lambda f: f"{f[0]}-{f[2]}-{f[3]}")
def test_a_failed_output_derivative_call_raises_the_same_error(pair, unzipped, fail):
    """fmi2GetRealOutputDerivatives returning error or discard ends both loops' runs with the
    same CoSimulationError, rows and calls."""
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.06", "output_interval=0.004",
                                               "master.output_derivatives=true"])
    py = tapped_run(scene, unzipped, pair, False, fail)
    c = tapped_run(scene, unzipped, pair, True, fail)
    assert isinstance(py[0], CoSimulationError) and isinstance(c[0], CoSimulationError), c[0]
    assert str(c[0]) == str(py[0])
    assert "getRealOutputDerivatives" in str(c[0])
    assert (c[0].status, c[0].time) == (py[0].status, py[0].time)
    assert c[0].status == fail[3]
    assert_same_rows(py[0].result, c[0].result)
    assert c[1].steps == py[1].steps
    assert c[2] == py[2]


@pytest.mark.parametrize("compiled", [False, True])
def test_a_warning_does_not_stop_the_run(pair, unzipped, compiled):
    """Status warning (1) is not a failure: the run completes with the rows of a clean run."""
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.05"])
    clean = tapped_run(scene, unzipped, pair, False)
    for fname in ("fmi2DoStep", "fmi2GetReal", "fmi2SetRealInputDerivatives"):
        warned = tapped_run(scene, unzipped, pair, compiled, ("controller", fname, 3, 1))
        assert not isinstance(warned[0], Exception)
        assert warned[1].steps == clean[1].steps == 25
        assert_same_rows(clean[0], warned[0])


@pytest.mark.parametrize("sets", [[], ["master.algorithm=jacobi", "master.extrapolation=0",
                                       "master.input_derivatives=false"]])
def test_divergence_stops_at_the_same_step_with_the_same_message(pair, unzipped, sets):
    """``controller.kp = 0``: the plant falls, and its FMU discards the step where |phi|
    passes phi_limit; both loops stop there with the same message and the same rows."""
    py, c = both("flexible_pd_lowpass", ["controller.kp=0", *sets], pair, unzipped)
    assert py.summary["stopped"] is not None
    assert c.summary["stopped"] == py.summary["stopped"]
    assert "divergence" in c.summary["stopped"]["fmu_message"]       # the FMU's own words
    assert "tilted past plant.phi_limit" in c.summary["stopped"]["reason"]   # the user's
    assert 0.3 < c.summary["stopped"]["time"] < 0.5
    assert_same_rows(py.result, c.result)
    assert c.stats.steps == py.stats.steps


# ---------------------------------------------------------------------- Ctrl-C
def test_stop_is_asked_after_every_step_and_stops_at_the_same_step(pair, unzipped):
    """The ``stop`` callback (Ctrl-C in flexpend run) is asked after every step by both loops;
    returning True after the 51st step gives the same partial rows and time."""
    asked = {}
    out = {}
    for compiled in (False, True):
        calls = []
        scene = load_scene("flexible_pd_lowpass", ["stop_time=0.5",
                                                   f"master.compiled={str(compiled).lower()}"])
        out[compiled] = run_scene(scene, pair, progress=False, unzipdirs=unzipped,
                                  stop=lambda: calls.append(1) or len(calls) > 50)
        asked[compiled] = len(calls)
    py, c = out[False], out[True]
    assert py.interrupted and c.interrupted
    assert asked[True] == asked[False] == 51 == c.stats.steps
    assert c.summary["stopped"] == py.summary["stopped"]
    assert c.summary["stopped"]["time"] == pytest.approx(0.102)
    assert_same_rows(py.result, c.result)


def test_an_exception_in_stop_comes_out_of_the_compiled_loop(pair, unzipped):
    """A third Ctrl-C raises KeyboardInterrupt in the stop callback: it leaves the C loop and
    comes out of the run, as from the Python loop."""
    for compiled in (False, True):
        calls = []

        def stop():
            calls.append(1)
            if len(calls) == 20:
                raise KeyboardInterrupt
            return False
        scene = load_scene("flexible_pd_lowpass", ["stop_time=0.5",
                                                   f"master.compiled={str(compiled).lower()}"])
        with pytest.raises(KeyboardInterrupt):
            run_scene(scene, pair, progress=False, unzipdirs=unzipped, stop=stop)
        assert len(calls) == 20


# ---------------------------------------------------------------------- any run length
def test_a_million_steps_stay_on_the_compiled_loop(pair, unzipped):
    """Issue 25: the extrapolation nodes, rebuilt from absolute float times, drifted off their
    integers by k 2^-52 and the compiled loop handed the run to Python (here at step 400000).
    On the integer grid there is no such limit: 1.1 million steps of the rigid pendulum at
    h = 10 us stay compiled to the end, which agrees with the monolithic reference (the coupling
    error at this step is O(h^3), about 1e-11; the cart has drifted about 3 m by then)."""
    from orchestration.studies.reference import simulate_reference
    scene = load_scene("rigid_pd", ["stop_time=11", "output_interval=0.5", "master.step=1e-5",
                                    "plant.step=1e-5"])
    r = run_scene(scene, pair, progress=False, unzipdirs=unzipped)
    assert r.summary["completed"]
    assert r.summary["master_loop"] == "compiled"
    assert r.stats.steps == 1_100_000
    assert r.result["time"][-1] == 1_100_000 * 1e-5          # t0 + k h, from integers
    ref = simulate_reference(scene)
    assert abs(ref["x"][-1]) > 1.0                   # the end is not a trivial zero
    for c in ("x", "phi_o", "omega_o"):
        assert np.max(np.abs(r.result[c] - ref[c])) < 1e-9, c


@pytest.mark.parametrize("sets", [[], ["master.algorithm=jacobi", "master.extrapolation=0",
                                       "master.input_derivatives=false"]],
                         ids=["scene", "zero-order-hold"])
def test_a_late_start_keeps_the_integer_grid(pair, unzipped, monkeypatch, sets):
    """From t0 = 1e4 s the float times put the nodes 1e-9 off their integers from the first step.
    Both loops take their nodes from the step counters: the Python loop's weights are those of
    integer nodes, the compiled loop runs throughout and makes the same FMI calls, each doStep at
    t0 + k h over h; the system being autonomous, the rows are those of a start at 0 (to the
    FMUs' own time rounding). The scene's coupling, and the paper's zero-order hold."""
    from orchestration.cosim import master as master_module
    nodes = []
    real = master_module._weight_rows

    def spy(tau, kinds, scale):
        nodes.append(tau)
        return real(tau, kinds, scale)
    monkeypatch.setattr(master_module, "_weight_rows", spy)
    t0 = 1e4
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.2", *sets])
    h = scene.master.step
    py = tapped_run(scene, unzipped, pair, False, t0=t0)
    assert nodes and all(float(x).is_integer() for tau in nodes for x in tau)
    c = tapped_run(scene, unzipped, pair, True, t0=t0)
    assert (py[1].loop, c[1].loop) == ("python", "compiled")
    assert c[2] == py[2]
    assert_same_rows(py[0], c[0])
    steps = [rec[:2] for n, f, rec, _ in c[2] if f == "fmi2DoStep" and n == "plant"]
    # with extrapolation the first step is taken twice (predicted, then corrected)
    first = [(t0, h)] if scene.master.extrapolation else []
    assert steps == first + [(t0 + k * h, h) for k in range(100)]
    zero = tapped_run(scene, unzipped, pair, True)
    np.testing.assert_array_equal(c[0]["time"], t0 + np.arange(len(c[0])) * 0.002)
    for col in ("x", "phi_o", "F_c", "eta_1"):
        np.testing.assert_allclose(c[0][col], zero[0][col], rtol=0,
                                   atol=1e-9 * np.max(np.abs(zero[0][col])), err_msg=col)


def test_progress_is_reported_up_to_the_end(pair, unzipped):
    fractions = []
    scene = load_scene("flexible_pd_lowpass", ["stop_time=2"])
    slaves = {"plant": Slave(pair["plant"], "plant", plant_start_values(scene),
                             unzipdir=unzipped["plant"]),
              "controller": Slave(pair["controller"], "controller",
                                  controller_start_values(scene),
                                  unzipdir=unzipped["controller"])}
    try:
        m = Master(slaves, [parse_connection(c) for c in scene.get("connections")], RECORD,
                   step=2e-3, extrapolation=2, input_derivatives=True)
        m.run(0.0, 2.0, 0.002, progress=fractions.append)
    finally:
        for s in slaves.values():
            s.close()
    assert m.loop == "compiled"
    assert fractions and fractions[-1] == 1.0 and fractions == sorted(fractions)


def test_pythonfmu_and_fmi3_run_in_python(pair, fmus):
    """The compiled loop takes FMI 2.0 FMUs that need no execution tool: a pythonfmu FMU (it
    runs Python) and FMI 3.0 FMUs keep the Python loop, and ``compiled = True`` says why (the
    adaptive master's compiled loop: tests/cosim/test_compiled_adaptive.py)."""
    from orchestration.export import build_fmus, fmu_pair

    python = fmu_pair(fmus)
    fmi3 = {k: str(v) for k, v in fmu_pair(build_fmus(flavour="native", fmi_version=3)).items()}
    cases = [(python, [], "needs an execution tool"),
             (fmi3, ["master.input_derivatives=false"], "FMI 3.0")]
    for paths, sets, why in cases:
        scene = load_scene("flexible_pd_lowpass", ["stop_time=0.02", *sets])
        r = run_scene(scene, paths, progress=False)
        assert r.summary["completed"] and r.summary["master_loop"] == "python", why
        with pytest.raises(ConfigError, match=why):
            run_scene(load_scene("flexible_pd_lowpass", ["stop_time=0.02", "master.compiled=true",
                                                         *sets]), paths, progress=False)


def test_master_compiled_key_is_checked():
    with pytest.raises(ConfigError, match="master.compiled = 'yes' is not allowed; allowed: "
                                          "'auto', true, false"):
        load_scene("rigid_pd", ["master.compiled=yes"])
    with pytest.raises(ValueError, match="compiled = 1"):
        Master({}, [], {}, compiled=1)


def test_a_library_that_does_not_load_leaves_auto_on_the_python_loop(pair, unzipped,
                                                                      monkeypatch):
    """A missing or stale library of a broken install: ``auto`` warns and runs the Python loop
    (the summary says which ran), ``true`` is an error naming the library's problem."""
    from fmu_common.kernels import KernelError

    def broken():
        raise KernelError("flexpend_master: no library for linux64 in /nowhere")
    monkeypatch.setattr(compiled_master, "load", broken)
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.02"])
    with pytest.warns(RuntimeWarning, match="does not load: flexpend_master: no library"):
        r = run_scene(scene, pair, progress=False, unzipdirs=unzipped)
    assert r.summary["completed"] and r.summary["master_loop"] == "python"
    with pytest.raises(ConfigError, match="compiled = True, but the compiled loop's library does "
                                          "not load: flexpend_master: no library"):
        run_scene(load_scene("flexible_pd_lowpass", ["stop_time=0.02", "master.compiled=true"]),
                  pair, progress=False, unzipdirs=unzipped)


def test_start_values_are_set_in_one_call_per_type_and_a_refused_one_is_named(pair, unzipped):
    """Slave.initialize sets an FMI 2.0 FMU's start values one call per type; when the FMU
    refuses a call (here an output among the Reals: the native core refuses the whole call and
    sets none of it), each value of that type is set alone, and the error names the one refused,
    as when every value was set alone."""
    scene = load_scene("flexible_pd_lowpass")
    starts = {**plant_start_values(scene), "phi_o": 0.1}
    calls = []
    s = Slave(pair["plant"], "plant", starts, unzipdir=unzipped["plant"])
    try:
        real = s.fmu.setReal

        def traced(vr, values):
            calls.append(len(vr))
            return real(vr, values)
        s.fmu.setReal = traced
        with pytest.raises(CoSimulationError, match=r"setReal\(phi_o\) returned error"):
            s.initialize(0.0, 1.0)
        reals = [n for n in starts if s.variables[n].type == "Real"]
        # the batch, then one by one up to phi_o (the last)
        assert calls == [len(reals)] + [1] * len(reals)
    finally:
        s.close()
    # the same start values without phi_o: one call for the Reals, and the run is the one whose
    # start values are set one by one (the Python loop's reference run of this module)
    ok = Slave(pair["plant"], "plant", plant_start_values(scene), unzipdir=unzipped["plant"])
    try:
        one = Slave(pair["plant"], "plant", plant_start_values(scene),
                    unzipdir=unzipped["plant"])
        try:
            ok.initialize(0.0, 1.0)
            one.fmu.setupExperiment(None, 0.0, 1.0)
            for name, value in plant_start_values(scene).items():
                one._set_start(name, value)
            one.fmu.enterInitializationMode()
            one.fmu.exitInitializationMode()
            a, b = ok.fmu.getFMUstate(), one.fmu.getFMUstate()
            sa, sb = ok.fmu.serializeFMUstate(a), one.fmu.serializeFMUstate(b)
            ok.fmu.freeFMUstate(a)
            one.fmu.freeFMUstate(b)
        finally:
            one.close()
    finally:
        ok.close()
    assert bytes(sa) == bytes(sb)
