"""Coverage-guided fuzzing as a test (issue 23; tests/fuzz/fuzz.py, docs/fuzzing.md).

The libFuzzer targets (one per model, both FMI versions, under address and undefined-behaviour
sanitizers, with the harness's contract checks: a message for every non-OK status, finite
outputs, exact time after an OK step) first replay the committed corpus, in which every defect
of issue 23 is a regression input, then fuzz for a bounded time each (FLEXPEND_FUZZ_SECONDS,
default 40 s per target). Any finding fails the test and names the input; the run's
executions per second and coverage are printed (pytest -s) and kept in the test's report.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parents[1]
sys.path.insert(0, str(HERE / "fuzz"))

import fuzz  # noqa: E402

pytestmark = pytest.mark.skipif(fuzz.find_clang() is None or not sys.platform.startswith("linux"),
                                reason="needs Linux and clang (apt-get install clang-14; "
                                       ".ci/run installs it)")


@pytest.fixture(scope="module")
def targets(tmp_path_factory) -> dict:
    work = tmp_path_factory.mktemp("fuzz")
    return {m: (fuzz.build(m, work), work) for m in fuzz.MODELS}


@pytest.mark.parametrize("model", fuzz.MODELS)
def test_every_regression_input_of_the_corpus_runs_clean(targets, model):
    exe, work = targets[model]
    corpus = fuzz.CORPUS / model
    names = sorted(p.name for p in corpus.iterdir())
    assert any(n.startswith("regress-fmi2-") for n in names)
    if model == "FlexiblePendulum":     # one per defect of the issue, both versions
        for v in (2, 3):
            for defect in ("crafted-n-modes", "crafted-not-ready", "step-1e19",
                           "plant-step-5e-324", "phi-dot0-1e160", "L-underflow",
                           "crafted-exact-nan", "crafted-exact-tip-slope"):
                assert f"regress-fmi{v}-{defect}" in names
            for seed in ("exact", "exact-modal", "stiffened", "stiffened-largest",
                         "kelvin-voigt"):                # the rungs' and the damping laws' seeds
                assert f"seed-fmi{v}-{seed}" in names
        assert "regress-fmi3-fmi3-null-arrays" in names
    r = fuzz.replay(exe, corpus, work)
    assert r["ok"], r["output"]
    assert r["inputs"] == len(names)


@pytest.mark.slow
@pytest.mark.parametrize("model", fuzz.MODELS)
def test_a_bounded_fuzz_run_finds_nothing(targets, model, record_property):
    exe, work = targets[model]
    seconds = int(os.environ.get("FLEXPEND_FUZZ_SECONDS", "40"))
    r = fuzz.fuzz(exe, fuzz.CORPUS / model, seconds, work)
    line = (f"{model}: {r.get('number_of_executed_units', 0)} executions in {seconds} s "
            f"({r.get('average_exec_per_sec', 0)} exec/s), cov {r.get('cov', 0)} of "
            f"{r.get('edges', 0)} edges, ft {r.get('ft', 0)}")
    print(line)
    record_property("fuzz", line)
    assert r["ok"], (r["findings"], r["output"])
    assert r.get("number_of_executed_units", 0) > 0 and r.get("cov", 0) > 0


@pytest.mark.slow
def test_the_harness_fails_a_call_over_its_time_limit(tmp_path):
    """The time check can fail: the controller's target built with a limit below any call's
    time (CALL_LIMIT_S = -1 s) stops on the first operation of a regression input, naming the
    limit; the same input runs clean in the target of the real limit (the test above)."""
    model = "PDLowPass"
    exe = fuzz.build(model, tmp_path, flags=[*fuzz.FLAGS, "-DCALL_LIMIT_S=-1.0"],
                     suffix="_no_time")
    corpus = tmp_path / "one"
    corpus.mkdir()
    first = sorted((fuzz.CORPUS / model).glob("regress-fmi2-*"))[0]
    (corpus / first.name).write_bytes(first.read_bytes())
    r = fuzz.replay(exe, corpus, tmp_path)
    assert not r["ok"]
    assert "of CPU time, over the limit of -1 s" in r["output"], r["output"]
