"""The master's compiled adaptive and implicit loops (orchestration/cosim/native/fm_adaptive.c,
bound in orchestration/cosim/compiled_adaptive.py) against their Python loops
(Master._run_adaptive; orchestration/cosim/implicit.py).

Independent value: the Python loop, the specification. The two differ in one computation, the
extrapolation weights on the adaptive grid (a 1- to 3-node Vandermonde solve: numpy's goes to
LAPACK, the C loop eliminates by itself). With the Python loop given the C loop's weights
(``same_weights``) the runs are bit for bit the same: rows, step counts and every FMI call with
its arguments. With numpy's own weights they agree to a stated tolerance with the same steps and
rejections. Failures, discarded steps and interruptions end both the same way. The implicit
master likewise, to a tolerance (its linear algebra is LAPACK's in Python).
"""
from __future__ import annotations

import ctypes
import functools
import math
import random

import numpy as np
import pytest

from orchestration.cosim import compiled_adaptive, coupling
from orchestration.cosim.slave import CoSimulationError
from orchestration.job import run_scene
from orchestration.scene.keys import ConfigError
from orchestration.scene.schema import PAPER_SCENES, load_scene
from test_compiled import FAILURES, assert_same_rows, pair, tapped_run, unzipped  # noqa: F401,F811

ESTIMATORS = ("extrapolation", "energy")
SHORT = {"rigid_pd": "stop_time=0.4", "flexible_pd": "stop_time=0.15",
         "flexible_pd_lowpass": "stop_time=0.4"}


def adaptive(name, estimator, *sets):
    return load_scene(name, [SHORT[name], "master.adaptive=true",
                             f"master.error_estimator={estimator}", *sets])


@pytest.fixture
def same_weights(monkeypatch):
    """The Python loop with the C loop's extrapolation weights (``fa_weights``)."""
    lib = compiled_adaptive.load()

    @functools.lru_cache(maxsize=4096)
    def weights(tau, kind):
        w = (ctypes.c_double * 3)()
        assert lib.fa_weights((ctypes.c_double * 3)(*tau), len(tau),
                              -1 if kind == "average" else kind, w)
        a = np.array(w[:len(tau)])
        a.flags.writeable = False
        return a
    coupling._weight_rows.cache_clear()
    monkeypatch.setattr(coupling, "_weights", weights)
    yield
    coupling._weight_rows.cache_clear()


def both(scene, pair, unzipped, **kw):  # noqa: F811 - the fixtures' names
    out = {}
    for compiled in (False, True):
        out[compiled] = tapped_run(scene, unzipped, pair, compiled, **kw)
        assert out[compiled][3].loop == ("compiled" if compiled else "python")
    return out[False], out[True]


def same_stats(a, b, rtol=0.0, atol=0.0):
    """The same counts; the same step sizes and rejection times (to ``rtol`` and ``atol``
    seconds: the smallest step is often the remainder before an output point, a difference of
    times)."""
    assert (a.steps, a.rejected, a.forced_accepts) == (b.steps, b.rejected, b.forced_accepts)
    np.testing.assert_allclose([b.min_step_used, b.max_step_used, *b.rejected_times],
                               [a.min_step_used, a.max_step_used, *a.rejected_times], rtol=rtol,
                               atol=atol)


# ---------------------------------------------------------------------- the arithmetic
def test_round9_is_pythons_round():
    """The nodes are rounded to 9 decimals as Python's round(x, 9): ties, near-ties, large."""
    lib = compiled_adaptive.load()
    rng = random.Random(3)
    xs = [0.0, -0.0, 0.5e-9, 1.5e-9, 2.5e-9, -2.5e-9, 1e300, -3.7e7, math.inf, 5e6 + 0.25e-9]
    xs += [rng.uniform(-5, 5) for _ in range(20000)]
    xs += [rng.randint(-10**10, 10**10) / 1e9 + rng.choice((5e-10, -5e-10)) for _ in range(20000)]
    xs += [rng.uniform(-1e8, 1e8) for _ in range(2000)]
    for x in xs:
        assert lib.fa_round9(x) == round(x, 9) and math.copysign(1, lib.fa_round9(x)) == \
            math.copysign(1, round(x, 9)), x


def test_weights_agree_with_numpys():
    """fa_weights against coupling._weights (numpy's solve) on the node patterns of an adaptive
    run (distinct nodes up to a few steps apart): a few units in the last place."""
    lib = compiled_adaptive.load()
    rng = random.Random(5)
    for _ in range(3000):
        n = rng.choice((1, 2, 3))
        tau = sorted(round(rng.uniform(-3.0, 1.0), 9) for _ in range(n))
        if min((b - a for a, b in zip(tau, tau[1:])), default=1.0) < 0.05:
            continue
        for kind in ("average", 0, 1, 2):
            w = (ctypes.c_double * 3)()
            assert lib.fa_weights((ctypes.c_double * 3)(*tau), n,
                                  -1 if kind == "average" else kind, w)
            np.testing.assert_allclose(w[:n], coupling._weights(tuple(tau), kind),
                                       rtol=1e-12, atol=1e-12 * 10 ** n)


# ---------------------------------------------------------------------- the same numbers
@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_paper_scenes_are_bit_identical_with_the_same_weights(pair, unzipped, same_weights,
                                                             name, estimator):
    """Each paper scene's coupling (Gauss-Seidel, quadratic extrapolation, input derivatives),
    both estimators: the same rows, steps, rejections and FMI calls with the same arguments."""
    py, c = both(adaptive(name, estimator), pair, unzipped)
    assert_same_rows(py[0], c[0])
    same_stats(py[1], c[1])
    assert py[2] == c[2]
    assert np.ptp(c[0]["phi_o"]) > 0.005          # the loop did move
    assert c[1].steps > 20


@pytest.mark.parametrize("sets", [["master.algorithm=jacobi"],
                                  ["master.algorithm=jacobi", "controller.filter_order=0"],
                                  ["master.first=plant", "master.extrapolation=1"],
                                  ["master.extrapolation=0"],
                                  ["master.input_derivatives=false"],
                                  ["master.tolerance=1e-7", "master.max_step=0.005"]],
                         ids=["jacobi", "feedthrough", "plant-first-linear", "zoh", "held",
                              "tight"])
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_other_couplings_are_bit_identical_with_the_same_weights(pair, unzipped, same_weights,
                                                                sets, estimator):
    py, c = both(adaptive("flexible_pd_lowpass", estimator, *sets), pair, unzipped)
    assert_same_rows(py[0], c[0])
    same_stats(py[1], c[1])
    assert py[2] == c[2]


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_with_numpys_weights_the_runs_agree(pair, unzipped, name, estimator):
    """The loops as they run: the same steps and rejections, and rows that agree within 1e-6
    of each column's size. Not bit for bit: the weights differ in their last bits (LAPACK's
    solve against the C loop's), and the oscillating plant and the PI step controller carry
    such differences along (measured: up to 3e-7 absolute in the rows, 1e-6 relative in the step
    sizes, 3e-9 s in the rejected steps' times on these runs; the counts the same)."""
    py, c = both(adaptive(name, estimator), pair, unzipped)
    same_stats(py[1], c[1], rtol=1e-5, atol=1e-8)
    for col in py[0].dtype.names:
        size = max(1.0, float(np.max(np.abs(py[0][col]))))
        np.testing.assert_allclose(c[0][col], py[0][col], rtol=0, atol=1e-6 * size,
                                   err_msg=col)


# ---------------------------------------------------------------------- failures
@pytest.mark.parametrize("fail", FAILURES, ids=lambda f: f"{f[0]}-{f[1]}-{f[2]}-{f[3]}")
@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_a_failed_call_ends_both_loops_the_same_way(pair, unzipped, same_weights, fail,
                                                    estimator):
    """A call that returns discard, error or fatal: the same CoSimulationError (FMU, call, time,
    status) with the same rows, or, for a discarded step with the extrapolation estimator, the
    same rollback and retry at half the step; the calls up to there are the same."""
    scene = adaptive("flexible_pd_lowpass", estimator, "stop_time=0.06",
                     "output_interval=0.004")
    py, c = both(scene, pair, unzipped, fail=fail)
    assert py[2] == c[2]
    assert [e[:2] for e in c[2] if e[2] == "failed"] == [fail[:2]]
    if isinstance(py[0], CoSimulationError):
        assert isinstance(c[0], CoSimulationError), c[0]
        assert str(c[0]) == str(py[0])
        assert (c[0].status, c[0].time) == (py[0].status, py[0].time)
        assert f"{fail[0]}: " in str(c[0])
        assert_same_rows(py[0].result, c[0].result)
    else:                                          # discarded, rolled back, retried
        assert fail[3] == 2 and estimator == "extrapolation"
        assert_same_rows(py[0], c[0])
        assert c[1].rejected == py[1].rejected >= 1
    same_stats(py[1], c[1])


def test_a_step_discarded_at_min_step_ends_the_run(pair, unzipped, same_weights):
    """``controller.kp = 0``: the plant falls and its FMU discards the step past phi_limit;
    both loops halve the step down to min_step and stop with the same message and rows."""
    out = {}
    for compiled in ("false", "true"):
        out[compiled] = run_scene(load_scene("flexible_pd_lowpass", [
            "controller.kp=0", "stop_time=1", "master.min_step=1e-4", "master.adaptive=true",
            f"master.compiled={compiled}"]), pair, progress=False, unzipdirs=unzipped)
    py, c = out["false"], out["true"]
    assert c.stats.loop == "compiled" and c.stats.rejected > 0
    assert py.summary["stopped"] is not None and c.summary["stopped"] == py.summary["stopped"]
    assert "discarded the step" in c.summary["stopped"]["fmu_message"]
    assert_same_rows(py.result, c.result)
    same_stats(py.stats, c.stats)


# ---------------------------------------------------------------------- Ctrl-C
def test_stop_is_asked_after_every_accepted_step(pair, unzipped, same_weights):
    """The ``stop`` callback is asked after every accepted step; True after the 40th gives the
    same partial rows, time and counts; an exception raised in it leaves the C loop."""
    out, asked = {}, {}
    for compiled in ("false", "true"):
        calls = []
        scene = load_scene("flexible_pd_lowpass", ["stop_time=0.5", "master.adaptive=true",
                                                   f"master.compiled={compiled}"])
        out[compiled] = run_scene(scene, pair, progress=False, unzipdirs=unzipped,
                                  stop=lambda: calls.append(1) or len(calls) >= 40)
        asked[compiled] = len(calls)
    py, c = out["false"], out["true"]
    assert py.interrupted and c.interrupted
    assert asked["true"] == asked["false"] == 40 == c.stats.steps
    assert c.summary["stopped"] == py.summary["stopped"]
    assert_same_rows(py.result, c.result)

    def stop():
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run_scene(load_scene("flexible_pd_lowpass", ["stop_time=0.5", "master.adaptive=true",
                                                     "master.compiled=true"]),
                  pair, progress=False, unzipdirs=unzipped, stop=stop)


def test_progress_is_reported_up_to_the_end(pair, unzipped):
    seen = []
    scene = load_scene("flexible_pd_lowpass", ["stop_time=0.5", "master.adaptive=true"])
    r = run_scene(scene, pair, progress=lambda fraction, label: seen.append(fraction),
                  unzipdirs=unzipped)
    assert r.stats.loop == "compiled"
    assert seen and seen[-1] == 1.0 and seen == sorted(seen)


# ---------------------------------------------------------------------- the implicit master
IMPLICIT_SHORT = {"rigid_pd": "stop_time=0.3", "flexible_pd": "stop_time=0.1",
                  "flexible_pd_lowpass": "stop_time=0.3"}


def implicit(name, update, *sets):
    return load_scene(name, [IMPLICIT_SHORT[name], "master.algorithm=implicit",
                             f"master.implicit_jacobian={update}", *sets])


def same_counts(a, b):
    assert (a.steps, a.iterations, a.max_iterations, a.jacobian_steps) == \
        (b.steps, b.iterations, b.max_iterations, b.jacobian_steps)


def evaluations_per_step(trace) -> dict:
    """``{a step's start time: its evaluations}`` of an implicit run's FMI trace: the plant's
    ``fmi2DoStep`` calls from that time (each evaluation of a step steps the plant once from the
    step's start)."""
    out = {}
    for role, fn, args, _ in trace:
        if role == "plant" and fn == "fmi2DoStep":
            out[args[0]] = out.get(args[0], 0) + 1
    return out


#: the implicit master's schemes: every output iterated, or those fed back (either FMU first)
SCHEMES = {"parallel": [], "serial, plant first": ["master.implicit_scheme=serial",
                                                   "master.first=plant"],
           "serial, controller first": ["master.implicit_scheme=serial",
                                        "master.first=controller"]}


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("update", ["newton", "iqn-ils"])
@pytest.mark.parametrize("name", PAPER_SCENES)
def test_the_implicit_master_agrees(pair, unzipped, name, update, scheme):
    """The implicit master in C: the same steps, iterations and Jacobian steps, the same FMI
    calls, and rows within 1e-6 of each column's size. The weights are the Python master's own
    (the step counters' grid); the linear algebra is not (numpy's LAPACK solve and SVD least
    squares against the C loop's elimination and Jacobi SVD), and the converged interface
    carries its last bits (measured on 0.5 s runs: Newton bit for bit here, IQN-ILS within
    1.3e-8 absolute)."""
    py, c = both(implicit(name, update, *SCHEMES[scheme]), pair, unzipped)
    assert c[1].iterations > c[1].steps                 # it did iterate
    if update == "newton":
        same_counts(py[1], c[1])
        assert [e[:2] for e in py[2]] == [e[:2] for e in c[2]]
    else:
        # IQN-ILS: a step whose residual lands within rounding of the tolerance may take one
        # iteration more in one loop than in the other, as the two least squares round (numpy's
        # LAPACK picks its kernels by the CPU): on flexible_pd one machine gives the same
        # counts, another 36 steps of 400 one iteration apart, one loop's extra iteration
        # followed by one fewer (its better start) in a later step (1054 against 1052 in all).
        # The same steps; a step's evaluations at most one apart; the totals within 1 %
        assert (py[1].steps, py[1].jacobian_steps) == (c[1].steps, c[1].jacobian_steps)
        a, b = evaluations_per_step(py[2]), evaluations_per_step(c[2])
        assert a.keys() == b.keys() and len(a) == c[1].steps
        apart = {t: (a[t], b[t]) for t in a if a[t] != b[t]}
        assert all(abs(x - y) == 1 for x, y in apart.values()), apart
        assert abs(py[1].iterations - c[1].iterations) <= max(2, py[1].iterations // 100)
        assert abs(py[1].max_iterations - c[1].max_iterations) <= 1
    for col in py[0].dtype.names:
        size = max(1.0, float(np.max(np.abs(py[0][col]))))
        np.testing.assert_allclose(c[0][col], py[0][col], rtol=0, atol=1e-6 * size,
                                   err_msg=col)


@pytest.mark.parametrize("sets", [["master.max_iterations=2"],
                                  ["master.max_iterations=2", "master.implicit_jacobian=iqn-ils"]],
                         ids=["newton", "iqn-ils"])
def test_an_implicit_step_that_does_not_converge_ends_both_loops_the_same_way(pair, unzipped,
                                                                             sets):
    py, c = both(implicit("flexible_pd_lowpass", "newton", *sets), pair, unzipped)
    assert isinstance(py[0], CoSimulationError) and isinstance(c[0], CoSimulationError)
    assert str(c[0]) == str(py[0]) and "did not converge" in str(c[0])
    assert c[0].time == py[0].time
    same_counts(py[1], c[1])
    assert_same_rows(py[0].result, c[0].result)


@pytest.mark.parametrize("fail", [("plant", "fmi2DoStep", 9, 3),
                                  ("controller", "fmi2SetReal", 7, 2),
                                  ("plant", "fmi2SetFMUstate", 4, 3),
                                  ("controller", "fmi2GetFMUstate", 3, 3)],
                         ids=lambda f: f"{f[0]}-{f[1]}-{f[2]}-{f[3]}")
def test_a_failed_call_ends_both_implicit_loops_the_same_way(pair, unzipped, fail):
    scene = implicit("flexible_pd_lowpass", "newton", "stop_time=0.06", "output_interval=0.004")
    py, c = both(scene, pair, unzipped, fail=fail)
    assert isinstance(c[0], CoSimulationError), c[0]
    assert str(c[0]) == str(py[0]) and f"{fail[0]}: " in str(c[0])
    assert (c[0].status, c[0].time) == (py[0].status, py[0].time)
    assert_same_rows(py[0].result, c[0].result)
    assert [e[:2] for e in py[2]] == [e[:2] for e in c[2]]


def test_stop_is_asked_after_every_implicit_step(pair, unzipped):
    out, asked = {}, {}
    for compiled in ("false", "true"):
        calls = []
        scene = implicit("flexible_pd_lowpass", "newton", f"master.compiled={compiled}")
        out[compiled] = run_scene(scene, pair, progress=False, unzipdirs=unzipped,
                                  stop=lambda: calls.append(1) or len(calls) >= 30)
        asked[compiled] = len(calls)
    py, c = out["false"], out["true"]
    assert c.stats.loop == "compiled" and py.interrupted and c.interrupted
    assert asked["true"] == asked["false"] == 30 == c.stats.steps
    assert c.summary["stopped"] == py.summary["stopped"]
    assert len(c.result) == len(py.result)


# ---------------------------------------------------------------------- which loop
def test_pythonfmu_fmus_keep_the_python_loop(fmus):
    """auto runs an adaptive run of pythonfmu FMUs (they run Python) in Python; true says why
    not."""
    from orchestration.export import fmu_pair

    python = fmu_pair(fmus)
    sets = ["stop_time=0.02", "master.adaptive=true"]
    r = run_scene(load_scene("flexible_pd_lowpass", sets), python, progress=False)
    assert r.summary["completed"] and r.summary["master_loop"] == "python"
    with pytest.raises(ConfigError, match="needs an execution tool"):
        run_scene(load_scene("flexible_pd_lowpass", [*sets, "master.compiled=true"]), python,
                  progress=False)


@pytest.mark.parametrize("estimator", ["extrapolation", "energy"])
def test_output_derivatives_keep_the_adaptive_master_in_python_and_run(pair, estimator):
    """master.output_derivatives with the adaptive step: the compiled adaptive loop does not read
    output derivatives, so the Python loop runs it (the compiled fixed-step loop's functions
    include fmi2GetRealOutputDerivatives since issue 39: the adaptive loop must not take them as
    its own). Its error estimate compared the outputs' values with their derivatives' rows
    too and failed (a broadcast error). The run agrees with the one without output derivatives
    to well within the coupling error at the tolerance."""
    keys = ["stop_time=1", "master.adaptive=true", f"master.error_estimator={estimator}"]
    runs = {od: run_scene(load_scene("flexible_pd_lowpass", keys + [
        f"master.output_derivatives={str(od).lower()}"]), pair, progress=False)
            for od in (False, True)}
    assert runs[True].stats.loop == "python" and runs[False].stats.loop == "compiled"
    diff = np.abs(runs[True].result["phi_o"] - runs[False].result["phi_o"]).max()
    assert diff < 1e-3, diff


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("update", ["newton", "iqn-ils"])
def test_an_implicit_step_restores_an_fmu_only_after_stepping_it(pair, unzipped, update,
                                                                 scheme):
    """Each step takes every FMU's state once, and restores it before each of that FMU's steps
    but the first (the FMU is still at the step's start then): per FMU, in both loops,
    restores = steps - states taken, and the step's first call after taking a state is no
    restore."""
    for res in both(implicit("flexible_pd_lowpass", update, *SCHEMES[scheme]), pair, unzipped):
        assert res[1].iterations > res[1].steps
        for name in ("plant", "controller"):
            calls = [e[1] for e in res[2] if e[0] == name]
            count = {f: sum(c == f"fmi2{f}" for c in calls)
                     for f in ("GetFMUstate", "SetFMUstate", "DoStep")}
            assert count["GetFMUstate"] == res[1].steps
            assert count["SetFMUstate"] == count["DoStep"] - count["GetFMUstate"]
            after = [b for a, b in zip(calls, calls[1:]) if a == "fmi2GetFMUstate"]
            assert "fmi2SetFMUstate" not in after


@pytest.mark.parametrize("scheme,fed_back", [("parallel", ["controller", "plant"]),
                                             ("serial, plant first", ["controller"]),
                                             ("serial, controller first", ["plant"])])
def test_the_serial_scheme_iterates_on_the_outputs_fed_back(pair, unzipped, scheme, fed_back):
    """The unknowns: every exchanged output (parallel), or the outputs of the FMU that feeds the
    one stepped first (serial): the controller's force when the plant steps first, the plant's
    outputs when the controller does."""
    scene = implicit("flexible_pd_lowpass", "newton", "stop_time=0.01", *SCHEMES[scheme])
    for res in both(scene, pair, unzipped):
        it = res[3].implicit
        assert sorted(it.unknowns) == fed_back
        assert it.size == sum(len(it.m.coupling.outputs[n]) for n in fed_back)
        assert it.serial == (scheme != "parallel")
