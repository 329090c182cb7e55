"""flexpend analyze: JSON output, overrides, one-line errors with exit code 2."""
import json
import subprocess
import sys

import numpy as np
import pytest

from orchestration.cli import main


def run(*args):
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", *args],
                          capture_output=True, text=True, timeout=120)
    return proc.returncode, proc.stdout, proc.stderr


def test_analyze_json_paper_pd_on_flexible_beam(capsys):
    assert main(["analyze", "--json", "--set", "plant.n_modes=3",
                 "--set", "controller.filter_order=0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is False
    assert out["max_real_part"] == pytest.approx(1.66, abs=0.02)
    assert len(out["cantilever_frequencies"]) == 3
    assert out["cantilever_frequencies"][0] == pytest.approx(26.33, abs=0.01)
    eig = [complex(*z) for z in out["eigenvalues"]]
    assert min(abs(z - (1.64 + 151.3j)) for z in eig) < 1.6
    assert set(out["margins"]) >= {"gain_margin_upper", "phase_margin_deg"}


def test_analyze_json_filtered_is_stable(capsys):
    assert main(["analyze", "--json", "--set", "controller.filter_order=1",
                 "--set", "controller.cutoff=130", "--set", "plant.zeta=0.001",
                 "--set", "plant.gravity_preload=false", "--set", "controller.kp=500",
                 "--set", "controller.kd=5", "--set", "controller.filter_damping=0.7"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is True and out["max_real_part"] == pytest.approx(-0.18, abs=0.01)


def test_analyze_table_names_the_verdict():
    code, out, err = run("analyze", "--set", "plant.n_modes=0")
    assert code == 0 and "STABLE" in out and "closed-loop eigenvalue" in out


@pytest.mark.parametrize("args,fragment", [
    (["--set", "plant.n_mode=3"], "unknown key 'plant.n_mode'; did you mean 'plant.n_modes'?"),
    (["--set", "plant.zeta=1.5"], "plant.zeta = 1.5 is out of range"),
    (["--set", "controller.filter_order=3"], "controller.filter_order = 3 is out of range"),
    (["--set", "plant.n_modes=two"], "plant.n_modes = 'two' is not allowed; allowed: an integer"),
    (["--set", "plant.fidelity=exactly"], "plant.fidelity = 'exactly' is not allowed"),
    (["--set", "plant.fidelity=exact", "--set", "plant.damping=kelvin-voigt"],
     "plant.fidelity = 'exact': analyze works on the floating frame's linearised loop"),
    (["--set", "plant.damping=viscous"], "plant.damping = 'viscous' is not allowed; allowed: "
                                         "modal, kelvin-voigt"),
    (["--set", "plant.n_modes"], "--set expects key=value"),
    (["--bogus"], "unrecognized arguments: --bogus"),
])
def test_bad_input_one_line_exit_2(args, fragment):
    code, out, err = run("analyze", *args)
    assert code == 2
    assert fragment in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_run_writes_csv_plots_and_summary(fmus, tmp_path):
    from fmpy.util import read_csv
    code, out, err = run("run", "rigid_pd", "flexible_pd_lowpass", "--set", "stop_time=1.0",
                         "--out", str(tmp_path), "--json", "--connections")
    assert code == 0, err
    summary = json.loads(out)
    assert set(summary) == {"rigid_pd", "flexible_pd_lowpass"}
    # 1 s from pi/6 never reaches the linear range (|phi| <= 0.2 from t = 1.4 s): no verdict
    assert summary["rigid_pd"]["stable"] is None and summary["rigid_pd"]["completed"]
    assert summary["rigid_pd"]["slow"]["reliable"] is False
    assert summary["rigid_pd"]["steps"] == 500                   # H = 2 ms
    assert "plant.phi_o     ->  controller.phi_o" in err
    res = read_csv(str(tmp_path / "flexible_pd_lowpass.csv"))
    assert list(res.dtype.names[:9]) == ["time", "x", "x_dot", "phi_o", "omega_o", "F_c",
                                         "tip_deflection", "eta_1", "energy"]
    assert res["time"][-1] == pytest.approx(1.0) and res["phi_o"][0] == pytest.approx(np.pi / 6)
    assert summary["flexible_pd_lowpass"]["max_abs_F_c"] == pytest.approx(np.max(np.abs(res["F_c"])))
    for name in ("rigid_pd.png", "rigid_pd_shapes.png", "flexible_pd_lowpass_shapes.png"):
        assert (tmp_path / name).stat().st_size > 10_000


def test_run_bad_wiring_one_line_exit_2(fmus, tmp_path):
    code, out, err = run("run", "rigid_pd", "--out", str(tmp_path),
                         "--set", 'connections=["plant.phi_oo -> controller.phi_o"]')
    assert code == 2 and "plant has no variable 'phi_oo'" in err
    assert len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------- limits of the machine
def _limited(limits: dict, *args, timeout=300):
    """``flexpend ARGS`` in a child process whose resource limits (soft and hard) are
    ``limits`` ({resource.RLIMIT_*: value}), as after ``ulimit -n`` or ``ulimit -v``."""
    import resource

    def apply():
        for which, value in limits.items():
            resource.setrlimit(which, (value, value))
    proc = subprocess.run([sys.executable, "-m", "orchestration.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, preexec_fn=apply)
    return proc.returncode, proc.stdout, proc.stderr


def test_too_few_file_handles_for_worker_processes_is_one_line(tmp_path):
    """ulimit -n 20 with --workers 2: one line and exit 2, before any run (a LocalCluster's
    nannies failed to start at 32: dask's logged tracebacks, then RuntimeError: Nanny failed
    to start; worker processes run there, the next test)."""
    import resource

    code, out, err = _limited({resource.RLIMIT_NOFILE: 20}, "sweep", "rigid_pd", "--values",
                              "controller.kp=500,600", "--set", "stop_time=0.5", "--workers", "2",
                              "--out", tmp_path / "sweep")
    assert code == 2, (out, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith("flexpend: error: too few file handles for 2 worker processes: they "
                          "need about 32, this process may open 20 (ulimit -n)")
    assert not (tmp_path / "sweep" / "runs.jsonl").exists()


def test_worker_processes_run_with_32_file_handles(tmp_path):
    import resource

    code, out, err = _limited({resource.RLIMIT_NOFILE: 32}, "sweep", "rigid_pd", "--values",
                              "controller.kp=500,600", "--set", "stop_time=0.5", "--workers", "2",
                              "--out", tmp_path / "sweep")
    assert code == 0, (out, err)
    assert "on 2 worker processes on this machine" in out, out


def test_too_little_address_space_for_worker_processes_is_one_line(tmp_path):
    """ulimit -v 512 MiB with --workers 2: the workers' OpenBLAS failed to allocate (and a
    LocalCluster's client crashed at 1 GiB, a segmentation fault). Failed before."""
    import resource

    code, out, err = _limited({resource.RLIMIT_AS: 512 << 20}, "sweep", "rigid_pd", "--values",
                              "controller.kp=500,600", "--set", "stop_time=0.5", "--workers", "2",
                              "--out", tmp_path / "sweep")
    assert code == 2, (out, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith("flexpend: error: too little memory for worker processes: each needs "
                          "about 1024 MiB of address space, this process may use 512 MiB "
                          "(ulimit -v)")


@pytest.mark.parametrize("mib", [100, 128, 160])
def test_too_little_address_space_is_one_line(tmp_path, mib):
    """ulimit -v below the floor: one line before numpy is imported (at 100 MiB the `resource`
    module's own library could not be mapped, a traceback; at 128 OpenBLAS ended the process
    with exit 1 and a line of its own)."""
    import resource

    from orchestration.cli import MIN_ADDRESS_SPACE

    assert mib << 20 < MIN_ADDRESS_SPACE
    code, out, err = _limited({resource.RLIMIT_AS: mib << 20}, "run", "rigid_pd", "--set",
                              "stop_time=0.5", "--out", tmp_path / "out")
    assert code == 2, (out, err)
    assert err == (f"flexpend: error: out of memory: this process may use {mib} MiB of address "
                   f"space (ulimit -v); flexpend needs at least {MIN_ADDRESS_SPACE >> 20} MiB\n")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("mib", [200, 224, 256])
def test_out_of_memory_is_one_line(tmp_path, mib):
    """ulimit -v just above the floor, around what a run needs: the run fits (exit 0), or it
    fails in one line that names the limit, exit 2 (an ImportError of a library that could not
    be mapped, a MemoryError, PIL's "codec configuration error" when zlib gets no memory, all
    tracebacks or misleading before). Which of the two depends on the libraries' footprint."""
    import resource

    code, out, err = _limited({resource.RLIMIT_AS: mib << 20}, "run", "rigid_pd", "--set",
                              "stop_time=0.5", "--out", tmp_path / "out")
    assert code in (0, 2), (out, err)
    assert "Traceback" not in err, err
    if code == 2:
        *_, last = err.strip().splitlines()
        assert last.startswith("flexpend: error: ") and f"{mib} MiB of address space" in last \
            and "ulimit -v" in last, err


def test_a_process_out_of_file_handles_is_one_line(monkeypatch, capsys):
    """An EMFILE anywhere (here: the scene file cannot be opened), whatever wraps it."""
    import errno
    import resource

    from orchestration.scene import schema

    def no_handles(*args, **kw):
        try:
            raise OSError(errno.EMFILE, "Too many open files")
        except OSError as exc:
            raise RuntimeError("something failed to start") from exc
    monkeypatch.setattr(schema, "_read_toml", no_handles)
    assert main(["run", str(schema.SCENE_DIR / "rigid_pd.toml")]) == 2
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    assert capsys.readouterr().err == (f"flexpend: error: too many open files: this process may "
                                       f"open {soft} (ulimit -n); raise the limit\n")


@pytest.mark.parametrize("failure", ["MemoryError", "ENOMEM", "unmapped library"])
def test_a_process_out_of_memory_is_one_line(failure, monkeypatch, capsys):
    """Out of memory anywhere, however it surfaces (a MemoryError, an OSError ENOMEM, an
    ImportError of a library that could not be mapped), whatever wraps it: one line, exit 2."""
    import errno
    import resource

    from orchestration.scene import schema

    def no_memory(*args, **kw):
        try:
            if failure == "MemoryError":
                raise MemoryError()
            if failure == "ENOMEM":
                raise OSError(errno.ENOMEM, "Cannot allocate memory")
            raise ImportError("libx.so: failed to map segment from shared object")
        except Exception as exc:
            raise RuntimeError("something failed to start") from exc
    monkeypatch.setattr(schema, "_read_toml", no_memory)
    assert main(["run", str(schema.SCENE_DIR / "rigid_pd.toml")]) == 2
    space = resource.getrlimit(resource.RLIMIT_AS)[0]
    limit = ("" if space == resource.RLIM_INFINITY else
             f": this process may use {space >> 20} MiB of address space (ulimit -v); raise the "
             "limit")
    assert capsys.readouterr().err == f"flexpend: error: out of memory{limit}\n"


def test_workers_the_default_rule_picks_are_checked_too(fmus, monkeypatch, capsys, tmp_path):
    """With no executor option, where the rule would start worker processes that do not fit the
    process's limits (here: an address space below what they need), the sweep runs here, saying
    why (before, only --workers was checked: a LocalCluster's client crashed at 1 GiB)."""
    import resource

    from orchestration.cli import main
    from orchestration.sweeps import executor, job

    monkeypatch.setattr(job, "local_workers", lambda runs, seconds: 2)
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    space = 1 << 50 if hard == resource.RLIM_INFINITY else hard
    monkeypatch.setattr(executor, "PROCESS_ADDRESS_SPACE", space + 1)
    resource.setrlimit(resource.RLIMIT_AS, (space, hard))
    try:
        code = main(["sweep", "rigid_pd", "--values", "controller.kp=500,600", "--set",
                     "stop_time=0.5", "--out", str(tmp_path / "out")])
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    err = capsys.readouterr().err
    assert code == 0, err
    assert ("running here, one run after the other: too little memory for worker processes: "
            f"each needs about {(space + 1) >> 20} MiB of address space") in err, err
    assert "2 worker processes" not in err


def test_the_soft_limit_of_open_files_is_raised_for_a_cluster():
    """Where the hard limit allows, --workers raises the soft one (ulimit -S -n) instead of
    refusing: 64 + 16 per worker."""
    import resource

    from orchestration.sweeps import executor

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 128:
        pytest.skip("the hard limit of open files is below 128 here")
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (64, hard))
        assert executor.cluster_limits(4) is None
        assert resource.getrlimit(resource.RLIMIT_NOFILE) == (64 + 16 * 4, hard)
        assert executor.cluster_limits(1) is None                # never lowered
        assert resource.getrlimit(resource.RLIMIT_NOFILE)[0] == 128
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_run_renderer_draws_the_pngs_with_pillow_or_matplotlib(fmus, tmp_path):
    """``flexpend run`` draws its PNGs with the raster renderer unless ``--renderer
    matplotlib`` (whose PNGs carry matplotlib's "Software" text chunk); a bad value is one line,
    exit 2."""
    from PIL import Image

    made = {}
    for renderer in ("raster", "matplotlib"):
        out = tmp_path / renderer
        code, _, err = run("run", "rigid_pd", "--set", "stop_time=1.0", "--out", str(out),
                           "--renderer", renderer)
        assert code == 0, err
        with Image.open(out / "rigid_pd.png") as png:
            made[renderer] = (png.size, png.info.get("Software", ""))
    assert made["raster"][0] == made["matplotlib"][0]                # the same figure size
    assert made["matplotlib"][1].startswith("Matplotlib") and made["raster"][1] == ""
    code, _, err = run("run", "rigid_pd", "--out", str(tmp_path / "bad"), "--renderer", "svg")
    assert code == 2 and "--renderer: invalid choice: 'svg'" in err
    assert len(err.strip().splitlines()) == 1
