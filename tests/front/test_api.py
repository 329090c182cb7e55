"""The front door (``import orchestration``): one call runs a scene and returns a Run that turns
into a DataFrame, a Figure or the files of ``flexpend run``; the other studies follow the same
rules (keyword arguments, typed results, errors naming the bad key)."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

import orchestration as fp
from orchestration.scene.keys import ConfigError


@pytest.fixture(scope="module")
def run(native):
    return fp.simulate("flexible_pd_lowpass", {"stop_time": 0.5, "controller.kp": 450})


def test_import_is_light_and_exports_the_front_door():
    """``import orchestration`` loads none of numpy, fmpy, matplotlib, dask (a fresh process)."""
    code = ("import sys, orchestration as fp; print(sorted(fp.__all__)); "
            "print([m for m in ('numpy', 'fmpy', 'matplotlib', 'distributed', 'scipy') "
            "if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert eval(out[1]) == []
    assert {"simulate", "load_scene", "analyze", "design", "sweep", "build_fmus", "Run",
            "Scene", "ConfigError", "__version__"} <= set(eval(out[0]))
    assert fp.__version__ != "0+unknown"


def test_simulate_returns_a_run_of_the_scene_asked_for(run):
    assert isinstance(run, fp.Run) and run.scene.controller.kp == 450.0
    assert run.scene.output.stop_time == 0.5 and run.completed
    assert run.result["time"][-1] == pytest.approx(0.5)
    assert run.result["phi_o"][0] == pytest.approx(math.pi / 6)
    assert run.summary["max_abs_F_c"] == pytest.approx(np.max(np.abs(run.result["F_c"])))


def test_to_pandas_is_indexed_by_time_with_the_csv_columns(run, tmp_path):
    df = run.to_pandas()
    assert df.index.name == "time" and np.array_equal(df.index.to_numpy(), run.result["time"])
    assert list(df.columns) == list(run.result.dtype.names[1:])
    assert np.array_equal(df["phi_o"].to_numpy(), run.result["phi_o"])


def test_plot_returns_a_figure_and_leaves_the_backend_alone(run):
    """In a fresh process with a backend of the user's, ``Run.plot()`` gives a Figure, the
    backend is still the user's, and pyplot holds no figure of ours (python-control imports
    pyplot: it may be loaded, but nothing is drawn through it)."""
    code = ("import matplotlib; matplotlib.use('svg'); import orchestration as fp; "
            "r = fp.simulate('rigid_pd', {'stop_time': 0.1}); f = r.plot(); s = r.plot_shapes(); "
            "import sys; plt = sys.modules.get('matplotlib.pyplot'); "
            "print(type(f).__name__, type(s).__name__, matplotlib.get_backend(), "
            "plt.get_fignums() if plt else [], len(f.axes))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[:4] == ["Figure", "Figure", "svg", "[]"] and int(out[4]) >= 3


def test_save_writes_what_flexpend_run_writes(run, tmp_path):
    written = run.save(tmp_path)
    names = {p.name for p in written}
    assert names == {"flexible_pd_lowpass.csv", "flexible_pd_lowpass.png",
                     "flexible_pd_lowpass_shapes.png", "summary.json"}
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["flexible_pd_lowpass"]["max_abs_F_c"] == pytest.approx(
        run.summary["max_abs_F_c"])
    from fmpy.util import read_csv
    csv = read_csv(str(tmp_path / "flexible_pd_lowpass.csv"))
    assert np.allclose(csv["phi_o"], run.result["phi_o"], rtol=1e-12, atol=0)
    # a second run's save keeps the first's entry of summary.json
    other = fp.simulate("rigid_pd", {"stop_time": 0.1})
    other.save(tmp_path)
    assert set(json.loads((tmp_path / "summary.json").read_text())) == {
        "flexible_pd_lowpass", "rigid_pd"}
    assert not list(tmp_path.glob(".*part*"))          # no temporary file left


def test_simulate_takes_a_record_and_the_python_fmus(fmus):
    scene = fp.load_scene("rigid_pd", {"stop_time": 0.2})
    native = fp.simulate(scene)
    python = fp.simulate(scene, fmus="python")
    assert python.scene.master.fmus == "python" and native.scene.master.fmus == "native"
    assert np.allclose(python.result["phi_o"], native.result["phi_o"], rtol=0, atol=1e-9)


def test_simulate_with_reference_reports_the_error(native):
    r = fp.simulate("rigid_pd", {"stop_time": 1.0}, reference=True)
    err = float(np.max(np.abs(r.result["phi_o"] - r.reference["phi_o"])))
    assert r.summary["max_error_phi_o"] == pytest.approx(err) and err < 1e-4


@pytest.mark.parametrize("call,kind,fragment", [
    (lambda: fp.simulate("nosuch"), ConfigError, "no scene 'nosuch'"),
    (lambda: fp.simulate("rigid_pd", {"controller.kpp": 1}), ConfigError,
     "unknown key 'controller.kpp'; did you mean 'controller.kp'?"),
    (lambda: fp.simulate("rigid_pd", {"master.step": -1}), ConfigError,
     "master.step = -1.0 is out of range"),
    (lambda: fp.simulate("rigid_pd", fmus="java"), ValueError, "fmus = 'java' is not allowed"),
    (lambda: fp.simulate("rigid_pd", reference="yes"), TypeError, "reference must be True"),
    (lambda: fp.simulate(3.5), TypeError, "scene must be a name, a path, a dict"),
    (lambda: fp.analyze(overrides={"plant.n_modes": "auto"}), ConfigError,
     "plant.n_modes = 'auto' is chosen by a run"),
    (lambda: fp.design(design={"design.levels": 1}), ConfigError,
     "design.levels = 1 is out of range"),
    (lambda: fp.build_fmus("java"), ValueError, "flavour = 'java' is not allowed"),
    (lambda: fp.sweep("rigid_pd"), ConfigError, "nothing to sweep"),
])
def test_bad_input_raises_a_value_or_type_error_naming_it(call, kind, fragment):
    with pytest.raises(kind) as info:
        call()
    assert fragment in str(info.value) and isinstance(info.value, (ValueError, TypeError))


def test_analyze_gives_the_linear_loop_of_the_scene():
    """docs/model.md: n >= 2 + PD alone: +1.64 +- 151.3j, unstable."""
    a = fp.analyze(overrides={"plant.n_modes": 3, "controller.filter_order": 0})
    assert isinstance(a, fp.Analysis) and not a.stable
    bending = max((z for z in a.eigenvalues if 140 < z.imag < 160), key=lambda z: z.real)
    assert bending.real == pytest.approx(1.64, rel=0.02)
    assert a.plant.n_modes == 3 and a.controller.filter_order == 0


def test_sweep_returns_the_table_as_a_dataframe(native, tmp_path):
    s = fp.sweep("rigid_pd", values={"controller.kp": [400, 600]}, overrides={"stop_time": 0.2},
                 serial=True, out=tmp_path, progress=False)
    df = s.to_pandas()
    assert list(df["controller.kp"]) == [400.0, 600.0] and set(df["status"]) == {"ok"}
    assert (tmp_path / "sweep.json").is_file()
