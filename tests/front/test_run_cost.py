"""What a warm ``flexpend run`` costs beyond its co-simulation: nothing on its path imports a
module it does not use (python-control, scipy's signal, integrate, interpolate, optimize, ndimage,
pandas, dask, matplotlib: each costs a large part of a run; its PNGs are drawn by the raster
renderer), and its CSV is written in one block in fmpy's
format. (The timings themselves are measured by ``bench/bench_run_profile.py``, not asserted.)"""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from orchestration.export.places import ROOT
from orchestration.files import write_csv

#: Modules the paper's scenes do not use (an SSP archive, ``--reference``, a design, a sweep or
#: ``to_pandas()`` import theirs when asked).
UNUSED = ["control", "scipy.signal", "scipy.integrate", "scipy.interpolate", "scipy.optimize",
          "scipy.ndimage", "scipy.stats", "scipy.sparse", "pandas", "dask", "matplotlib"]
#: Until the fit's rewrite (issue 25) lands, ``orchestration/studies/fit.py`` imports scipy.signal
#: (and with it most of scipy) for its low-pass (``butter``, ``sosfiltfilt``): while its source
#: does, what it imports is allowed here and :func:`test_the_fit_imports_no_scipy_signal` is
#: expected to fail; once it does not, both hold strictly (and these lines can go).
FIT = "orchestration/studies/fit.py"
FIT_USES_SIGNAL = "scipy.signal" in (ROOT / FIT).read_text()

_CHILD = r"""
import builtins, io, json, os, sys, contextlib
root, out, watched = sys.argv[1], sys.argv[2], sys.argv[3:]
first = {}                    # module -> the project's file:function whose import loaded it
_import = builtins.__import__

def spy(*args, **kwargs):
    pending = [m for m in watched if m not in sys.modules]
    try:
        return _import(*args, **kwargs)
    finally:
        for m in pending:
            if m in sys.modules and m not in first:
                f = sys._getframe(1)
                while f is not None and not (f.f_code.co_filename.startswith(root)
                                             and "site-packages" not in f.f_code.co_filename):
                    f = f.f_back
                first[m] = ("?" if f is None else os.path.relpath(f.f_code.co_filename, root)
                            + ":" + f.f_code.co_name)

builtins.__import__ = spy
from orchestration.cli import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    code = main(["run", "--out", out, "--set", "stop_time=1"])
print(json.dumps({"code": code, "first": first}))
"""


@pytest.fixture(scope="module")
def importers(native, tmp_path_factory):
    """``{module: "file:function" that first imported it}`` for the modules of :data:`UNUSED`
    that ``flexpend run`` of the paper's three scenes (1 s each) loads, in a new process, the FMUs
    built, and warm: a first run fills the caches a warm run reads (the step warnings: a cold run
    searches the stable step with scipy), whatever ran before this test."""
    for folder in ("cold", "run"):
        out = tmp_path_factory.mktemp(folder)
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT), str(out), *UNUSED],
                              cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout.splitlines()[-1])
    assert res["code"] == 0
    assert {"rigid_pd.png", "flexible_pd_shapes.png", "paper_overview.png"} <= \
        {p.name for p in out.iterdir()}
    return res["first"]


@pytest.mark.parametrize("module", UNUSED)
def test_a_default_run_does_not_import_what_it_does_not_use(importers, module):
    importer = importers.get(module)
    assert importer is None or (FIT_USES_SIGNAL and importer.startswith(FIT + ":")), \
        f"{module} imported by {importer}"


@pytest.mark.xfail(FIT_USES_SIGNAL, strict=True, reason=f"{FIT} still imports scipy.signal")
def test_the_fit_imports_no_scipy_signal(importers):
    assert "scipy.signal" not in importers


def test_csv_is_fmpys_format_byte_for_byte(tmp_path):
    """The CSV writer (one block) writes what ``fmpy.util.write_csv`` (row by row) writes:
    quoted names, each float as Python prints it, non-finite values and signed zeros included."""
    from fmpy.util import write_csv as fmpy_write_csv

    special = [0.0, -0.0, 0.1, 1 / 3, 1e-300, 5e-324, 1e16, -2.5e-7, math.pi * 1e22,
               math.inf, -math.inf, math.nan, 123456789.0, 1.0]
    result = np.zeros(len(special), dtype=[("time", "f8"), ("x", "f8"), ("phi_o", "f8")])
    result["time"] = np.arange(len(special)) * 0.01
    result["x"] = special
    result["phi_o"] = np.random.default_rng(3).standard_normal(len(special))
    for rows in (result, result[:0]):
        fmpy_write_csv(str(tmp_path / "fmpy.csv"), rows)
        assert write_csv(tmp_path / "ours.csv", rows) == tmp_path / "ours.csv"
        assert (tmp_path / "ours.csv").read_bytes() == (tmp_path / "fmpy.csv").read_bytes()
