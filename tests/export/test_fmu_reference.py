"""Reference results in the FMI cross-check layout: each FMU alone, simulated by fmpy.simulate_fmu
with its committed input file and options, must reproduce its committed reference within
REFERENCE_RULE (1e-6 of each signal's range at every sample). It is the code of ``flexpend
check`` (orchestration/export/check.py) with the tight rule. Regenerate the references on purpose
with ``python build/build_fmus.py --references``."""
import csv

import numpy as np
import pytest
from fmpy.util import read_csv, read_ref_opt_file, validate_result

from orchestration.export.check import (REFERENCE_RULE, check_fmu, compare, reference_files,
                                        simulate_reference_case, write_references)

MODELS = ["FlexiblePendulum", "PDLowPass"]


def reference(name):
    return read_csv(str(reference_files(name)["ref"]))


def largest_relative_deviation(result, ref):
    return max(s.relative_deviation for s in compare(result, ref, REFERENCE_RULE).values())


@pytest.mark.parametrize("name", MODELS)
def test_fresh_run_matches_the_committed_reference(fmus, name):
    report = check_fmu(fmus[name], reference_files(name)["dir"], REFERENCE_RULE)
    assert report.passed, "\n".join(report.lines())
    assert all(s.outliers == 0 and s.samples == 1001 for s in report.signals.values())
    assert max(s.relative_deviation for s in report.signals.values()) <= REFERENCE_RULE.tolerance
    # and FMPy's own cross-check band (fmpy.util.validate_result): no outlier
    assert validate_result(report.run.result, reference(name)) == 0


@pytest.mark.parametrize("name, change", [
    ("FlexiblePendulum", {"EI": 875.0 * 1.001}),       # 0.1 % stiffer beam
    ("FlexiblePendulum", {"zeta": 0.0011}),            # 10 % more structural damping
    ("FlexiblePendulum", {"gravity_preload": True}),   # another fidelity option
    ("PDLowPass", {"filter_damping": 0.5005}),         # 0.1 % more filter damping
], ids=["EI+0.1%", "zeta+10%", "preload", "filter_damping+0.1%"])
def test_a_small_change_of_the_physics_leaves_the_band(fmus, name, change):
    result = simulate_reference_case(fmus[name], name, start_values=change)
    assert largest_relative_deviation(result, reference(name)) > 10 * REFERENCE_RULE.tolerance
    report = check_fmu(fmus[name], reference_files(name)["dir"], REFERENCE_RULE,
                       start_values=change)
    assert not report.passed


@pytest.mark.parametrize("name", MODELS)
def test_files_follow_the_cross_check_layout(name):
    files = reference_files(name)
    opt = read_ref_opt_file(str(files["opt"]))
    assert (opt["StartTime"], opt["StopTime"], opt["StepSize"]) == (0.0, 1.0, 1e-3)
    for kind in ("in", "ref"):
        with open(files[kind], newline="") as f:
            header = f.readline().strip()
            assert header.startswith('"time",') and all(
                h.startswith('"') and h.endswith('"') for h in header.split(","))
            rows = list(csv.reader(f))
        t = np.array([float(r[0]) for r in rows])
        assert t[0] == 0.0 and t[-1] == 1.0 and np.all(np.diff(t) > 0)
        assert len(header.split(",")) <= 10


def test_regeneration_reproduces_the_committed_files(fmus, tmp_path):
    """The one command writes the same inputs and options, and a reference within the band."""
    written = write_references(fmus, tmp_path)
    for name, files in written.items():
        committed = reference_files(name)
        assert files["in"].read_bytes() == committed["in"].read_bytes()
        assert files["opt"].read_bytes() == committed["opt"].read_bytes()
        new = read_csv(str(files["ref"]))
        assert new.dtype.names == reference(name).dtype.names
        assert largest_relative_deviation(new, reference(name)) <= REFERENCE_RULE.tolerance
