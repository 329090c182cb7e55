"""An independent host in the FMI project's own style: ``fmi-sim`` 0.7.0 (crates.io, the simulator
of https://github.com/jondo2010/rust-fmi, modelled on the Reference-FMUs' ``fmusim``) runs every
native FMU, FMI 2.0 and 3.0, in each interface its modelDescription declares, on each rung
(``fidelity``) the FMU accepts, from a nonzero initial angle and with every input driven through
fmi-sim's input CSV.

* **Co-simulation**: fmi-sim and ``fmpy.simulate_fmu`` make the same calls (the same start values,
  the inputs at each communication point, ``doStep`` over the same grid), so their outputs agree
  to round-off; in fact to the bit, which the test holds. The grid is dyadic (``h`` = 2^-10 s)
  and the inputs are multiples of 2^-10: every time, step size and linearly interpolated input
  sample is exact on both sides (fmi-sim steps FMI 2.0 by ``h`` and FMI 3.0 by ``t_{k+1} - t_k``,
  as fmpy does; on this grid they are equal).
* **Model Exchange**: fmi-sim 0.7.0 has one solver, forward Euler at the output interval
  (``src/sim/solver/euler.rs``: ``x += h * der(x)`` from the FMU's own derivatives, then
  ``fmi2SetTime``/``fmi3SetTime``, the inputs, ``completedIntegratorStep``, and an event iteration
  when an event indicator changed sign, counted from 0 before the first step). :func:`euler_me`
  makes the same calls through fmpy's Model-Exchange API, so the comparison is again to
  round-off, and again to the bit. The steps are short (``h`` = 2^-14 s over 2^-5 s): Euler is
  unstable on the lightly damped beam modes at any step this size (``|1 + h lambda| > 1``), and
  the run must stay far from the FMU's divergence bounds.
* Every rung gives another trajectory (fmi-sim ignores the status of a start value it sets: a
  refused rung would run the default one).
* fmi-sim 0.7.0 reads the modelDescription with fmi-schema 0.8.0, which refuses ``unit`` on an
  FMI 3.0 ``Float64`` (the standard allows it): the FMI 3.0 runs get a copy of the FMU without
  the real-variable attributes the crate does not know (:func:`for_fmi_schema`), and a test holds
  that the original is refused with that message.

fmi-sim is installed once per machine (``cargo install --locked``, the versions of the crate's own
``Cargo.lock``) into ``$XDG_CACHE_HOME/flexpend/tests/fmi-sim-0.7.0/`` (by default under
``~/.cache``), outside the checkout; a second session reuses it. Concurrent sessions (the workers
of ``-n 2``, two checkouts) take turns on a file lock, and the finished installation is renamed
into place, so nobody sees half of it. The cold build (arrow, the CSV and table crates fmi-sim
uses, bindgen) runs the release profile without optimisation (:data:`UNOPTIMISED`): about 3
CPU-minutes instead of 9 (4.6 minutes of wall time on the 2-core test machine beside other work). Skipped without cargo, when cargo's rustc is older than 1.88
(the crate is edition 2024, and its lock file pins ``zip`` 8.6 and ``time`` 0.3.47, which need
1.88: Debian 12's ``cargo`` package has rustc 1.63; its ``cargo-web`` package, rustc 1.96 in
bookworm-security, builds it, and ``.ci/run`` installs that), when crates.io cannot be reached
and the crates are not cached, or without libclang (``fmi-sys`` generates its bindings with
bindgen). Run alone: ``python -m pytest tests/export/test_fmu_fmisim.py``.
"""
from __future__ import annotations

import csv
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import NativeFmu
from test_fmu_c_host import system_env

FMI_SIM = "0.7.0"
#: the oldest rustc that builds fmi-sim 0.7.0 from its own lock file (``cargo install --locked``)
MIN_RUSTC = (1, 88)
CARGO = shutil.which("cargo") or str(Path.home() / ".cargo" / "bin" / "cargo")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux")
                                 or not os.access(CARGO, os.X_OK),
                                 reason="needs Linux and cargo")]

#: what a build fails with when libclang or clang's own headers are missing (bindgen)
NO_LIBCLANG = ("Unable to find libclang", "'stddef.h' file not found")
#: what cargo says when it cannot reach crates.io (and the crates are not in its cache)
NO_NETWORK = ("failed to download", "failed to query replaced source", "Couldn't resolve host",
              "Could not resolve host", "failed to get `", "network failure",
              "failed to load source for dependency", "failed to update registry",
              "spurious network error")

#: the co-simulation problem: 2^-10 s steps over 0.25 s (256 steps)
CS_STEP, CS_STOP = 2.0 ** -10, 0.25
#: the Model-Exchange problem: fmi-sim's Euler at 2^-14 s over 2^-5 s (512 steps)
ME_STEP, ME_STOP = 2.0 ** -14, 2.0 ** -5
#: the plant's initial angle (rad): the runs do not start at the upright rest state
PHI0 = 0.3
#: each input's amplitude (its unit); another input has 0.5
AMPLITUDE = {"F_c": 5.0, "phi_o": 0.3, "omega_o": 2.0, "x_o": 0.1}
#: The attributes of FMI 3.0 ``Float32``/``Float64`` variables (fmi3RealVariableAttributes, all
#: in the standard's schema) that fmi-schema 0.8.0, the crate fmi-sim 0.7.0 reads the
#: modelDescription with, does not declare: it parses strictly and stops on the first ("unknown
#: field "unit" in element "FmiFloat64"").
FMI3_UNKNOWN_TO_FMI_SCHEMA = ("quantity", "unit", "displayUnit", "relativeQuantity", "unbounded",
                              "nominal")
#: the rungs of today's single plant FMU, until plant_fmu.interface.PLANT_FMUS names one FMU per
#: rung family; that FMU refuses the exact rung in Model Exchange
FALLBACK_RUNGS = {"FlexiblePendulum": ("nonlinear", "linear", "stiffened", "exact")}


# ---------------------------------------------------------------------- the installation
def rustc_version() -> tuple | None:
    """The version of the rustc cargo runs (the one beside cargo, else on PATH), or None."""
    beside = Path(CARGO).with_name("rustc")
    rustc = str(beside) if os.access(beside, os.X_OK) else shutil.which("rustc")
    if rustc is None:
        return None
    out = subprocess.run([rustc, "--version"], capture_output=True, text=True, timeout=60)
    m = re.match(r"rustc (\d+)\.(\d+)", out.stdout)
    return (int(m[1]), int(m[2])) if m else None


def cache_dir() -> Path:
    """Where fmi-sim is installed: outside the checkout, one folder per version."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "flexpend" / "tests" / f"fmi-sim-{FMI_SIM}"


#: cargo install's release profile without optimisation: a third of the CPU time of the cold
#: build (3.1 to 3.4 instead of 9.2 CPU-minutes here), and the simulator's own work is small
#: beside the FMU's (the test's runs take as long as with the optimised build)
UNOPTIMISED = {"CARGO_PROFILE_RELEASE_OPT_LEVEL": "0", "CARGO_PROFILE_RELEASE_LTO": "false",
               "CARGO_PROFILE_RELEASE_CODEGEN_UNITS": "256", "CARGO_PROFILE_RELEASE_DEBUG": "false"}


def _cargo_install(root: Path, *flags) -> subprocess.CompletedProcess:
    env = {**os.environ, **UNOPTIMISED,
           "PATH": f"{Path(CARGO).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("CARGO_TARGET_DIR", None)         # cargo install's own temporary target folder
    return subprocess.run([CARGO, "install", "fmi-sim", "--version", FMI_SIM, "--locked",
                           "--root", str(root), *flags], capture_output=True, text=True,
                          env=env, timeout=3600)


def install_fmi_sim() -> Path:
    """fmi-sim's executable: the cached one, else built now (offline from the crates cargo has
    cached, else from crates.io) under the folder's lock, and renamed into place when complete.
    Skips (never fails) where the machine cannot build it; fails when the build itself does."""
    import fcntl

    final = cache_dir()
    exe = final / "bin" / "fmi-sim"
    if exe.is_file():
        return exe
    version = rustc_version()
    if version is None or version < MIN_RUSTC:
        pytest.skip(f"fmi-sim {FMI_SIM} needs rustc >= {'.'.join(map(str, MIN_RUSTC))} (edition "
                    f"2024; its Cargo.lock pins zip 8.6 and time 0.3.47); cargo's rustc is "
                    f"{'.'.join(map(str, version)) if version else 'not found'} (Debian 12: "
                    f"apt-get install cargo-web)")
    final.parent.mkdir(parents=True, exist_ok=True)
    with open(final.parent / f"fmi-sim-{FMI_SIM}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)           # another session may be building it
        if exe.is_file():
            return exe
        staging = Path(tempfile.mkdtemp(prefix=f".fmi-sim-{FMI_SIM}-", dir=final.parent))
        staging.chmod(0o755)                       # mkdtemp's 0700: the installed folder's mode
        try:
            built = _cargo_install(staging, "--offline")
            if built.returncode != 0:
                built = _cargo_install(staging)
            if built.returncode != 0:
                if any(s in built.stderr for s in NO_LIBCLANG):
                    pytest.skip("fmi-sim's FMI bindings need libclang (bindgen): apt-get install "
                                "libclang1-14 libclang-common-14-dev")
                if any(s in built.stderr for s in NO_NETWORK):
                    pytest.skip(f"cargo could not fetch fmi-sim {FMI_SIM} from crates.io: "
                                f"{built.stderr[-500:]}")
            assert built.returncode == 0, built.stderr[-3000:]
            assert (staging / "bin" / "fmi-sim").is_file()
            shutil.rmtree(final, ignore_errors=True)   # an incomplete one (no executable)
            staging.rename(final)                  # atomic: the folder appears complete
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return exe


@pytest.fixture(scope="module")
def fmi_sim():
    return install_fmi_sim()


# ---------------------------------------------------------------------- the problems
def rungs() -> tuple[dict, bool]:
    """``{FMU name: its rungs}`` and whether that is the fallback (one plant FMU for all)."""
    from plant_fmu import interface

    plants = getattr(interface, "PLANT_FMUS", None)
    if plants is None:
        return FALLBACK_RUNGS, True
    return {name: tuple(record.fidelities) for name, record in plants.items()}, False


def interfaces(md) -> list[str]:
    """The interfaces the modelDescription declares, in fmi-sim's names."""
    return [name for name, declared in (("co-simulation", md.coSimulation),
                                        ("model-exchange", md.modelExchange)) if declared]


def quantised(values):
    """Multiples of 2^-10: linear interpolation at a grid point gives them back exactly."""
    return np.round(np.asarray(values) * 1024.0) / 1024.0


def input_signals(md, stop, step) -> np.ndarray:
    """A structured array (fmpy's input format): every continuous real input as a sine of its own
    phase and frequency, sampled at each point of the grid."""
    n = round(stop / step)
    t = np.arange(n + 1) * step
    names = [v.name for v in md.modelVariables
             if v.causality == "input" and v.type in ("Real", "Float64")]
    sig = np.zeros(n + 1, dtype=[("time", float)] + [(name, float) for name in names])
    sig["time"] = t
    for j, name in enumerate(names):
        sig[name] = quantised(AMPLITUDE.get(name, 0.5)
                              * np.sin(2 * math.pi * (3.0 + j) * t + 0.7 * (j + 1)))
    return sig


def for_fmi_schema(path: Path, tmp: Path) -> Path:
    """A copy of the FMI 3.0 FMU ``path`` whose variables lack the attributes fmi-schema 0.8.0
    refuses (:data:`FMI3_UNKNOWN_TO_FMI_SCHEMA`): metadata no simulation reads; the binaries and
    every other file are the FMU's own."""
    pattern = re.compile(r'(<Float(?:32|64)\b[^>]*?)\s(?:%s)="[^"]*"'
                         % "|".join(FMI3_UNKNOWN_TO_FMI_SCHEMA))
    out = tmp / Path(path).name
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                while True:
                    text, n = pattern.subn(r"\1", text)
                    if n == 0:
                        break
                data = text.encode()
            dst.writestr(item, data)
    return out


def write_csv(path: Path, sig: np.ndarray):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(sig.dtype.names)
        w.writerows([repr(float(x)) for x in row] for row in sig)


def start_values(md, fidelity) -> dict:
    """The plant's initial angle and rung, where the FMU declares them."""
    names = {v.name for v in md.modelVariables}
    start = {"phi0": PHI0} if "phi0" in names else {}
    if fidelity is not None and "fidelity" in names:
        start["fidelity"] = fidelity
    if md.modelName == "PDLowPassSampled":          # its ticks and delay on the CS grid
        start.update(sample_period=4 * CS_STEP, delay=2 * CS_STEP)
    return start


def cases(paths: dict, version: int):
    """``(name, interface, fidelity)`` for every FMU, declared interface and accepted rung."""
    from fmpy import read_model_description

    table, fallback = rungs()
    for name, path in sorted(paths.items()):
        md = read_model_description(path)
        for interface in interfaces(md):
            for fidelity in table.get(name, (None,)):
                if fallback and interface == "model-exchange" and fidelity == "exact":
                    continue                      # the single FMU refuses it in ME (issue 37)
                yield name, path, md, interface, fidelity


def run_fmi_sim(exe, path, interface, start, sig, step, stop, tmp) -> dict:
    """fmi-sim's outputs, column name -> array (time first)."""
    inp, out = tmp / "input.csv", tmp / "output.csv"
    write_csv(inp, sig)
    cmd = [str(exe), "--model", str(path), "-i", str(inp), "-o", str(out), interface,
           "--output-interval", repr(step), "-s", "0", "-f", repr(stop)]
    for k, v in start.items():
        cmd += ["--init-values", f"{k}={v}"]
    proc = subprocess.run(cmd, env=system_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr[-3000:]}"
    with open(out, newline="") as f:
        rows = list(csv.reader(f))
    return {k: np.array([float(r[j]) for r in rows[1:]]) for j, k in enumerate(rows[0])}


def fmpy_cs(path, md, start, sig, step, stop) -> dict:
    """The same co-simulation through fmpy.simulate_fmu."""
    from fmpy import simulate_fmu

    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    res = simulate_fmu(str(path), fmi_type="CoSimulation", start_time=0.0, stop_time=stop,
                       output_interval=step, start_values=start, input=sig, output=outputs)
    return {k: np.asarray(res[k], dtype=float) for k in ("time", *outputs)}


def euler_me(unzipdir, version, md, start, sig, step, stop) -> dict:
    """fmi-sim's Model-Exchange run (``src/sim/me.rs`` and ``solver/euler.rs``) through fmpy:
    record, Euler step, set time and inputs, completed step, and on an event indicator's sign
    change (from 0 before the first step) a second record and the event iteration."""
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    inputs = [k for k in sig.dtype.names if k != "time"]
    fmu = NativeFmu(unzipdir, version, cs=False, **start)
    try:
        fmu.set(**{k: sig[k][0] for k in inputs})
        fmu.initialize(event=True)
        rows = []
        n, t, prez = 0, 0.0, np.zeros(fmu.nz)

        def event_iteration():
            rows.append([t, *fmu.get(*outputs)])
            fmu.fmu.enterEventMode()
            while True:
                flags = (fmu.fmu.newDiscreteStates() if version == 2
                         else fmu.fmu.updateDiscreteStates())
                assert not flags[1] and not flags[4]    # no termination, no time event
                if not flags[0]:
                    break
            fmu.fmu.enterContinuousTimeMode()

        while True:
            rows.append([t, *fmu.get(*outputs)])
            if t >= stop:
                break
            t_next = (n + 1) * step
            if fmu.nx:
                fmu.set_states(fmu.states() + fmu.derivatives() * (t_next - t))
            z = fmu.indicators()
            crossed = bool(np.any(((prez <= 0) & (z > 0)) | ((prez > 0) & (z <= 0))))
            prez = z
            t = t_next
            n += 1
            fmu.set_time(t)
            fmu.set(**{k: sig[k][n] for k in inputs})
            step_event, terminate = fmu.fmu.completedIntegratorStep(True)
            assert not terminate
            if crossed or step_event:
                event_iteration()
    finally:
        fmu.close()
    a = np.array(rows)
    return {k: a[:, j] for j, k in enumerate(("time", *outputs))}


def _compare(got: dict, ref: dict, what: str):
    """The same columns, rows and bits; and the run is not of a rest state."""
    assert list(got) == list(ref), what
    assert len(got["time"]) == len(ref["time"]), what
    for k in ref:
        err = float(np.max(np.abs(got[k] - ref[k])))
        assert np.array_equal(got[k], ref[k]), f"{what}: {k} differs by up to {err:.3g}"
    assert max(float(np.ptp(ref[k])) for k in ref if k != "time") > 1e-3, what


@pytest.mark.parametrize("version", [2, 3])
def test_fmi_sim_runs_every_native_fmu_as_flexpend_does(fmi_sim, native, native3, version,
                                                         tmp_path):
    from fmpy import extract

    paths = native if version == 2 else native3
    finals = {}
    for name, path, md, interface, fidelity in cases(paths, version):
        what = f"FMI {version} {name} {interface} fidelity={fidelity}"
        start = start_values(md, fidelity)
        tmp = tmp_path / f"{name}-{interface}-{fidelity}"
        tmp.mkdir()
        sim_path = for_fmi_schema(path, tmp) if version == 3 else path
        if interface == "co-simulation":
            sig = input_signals(md, CS_STOP, CS_STEP)
            got = run_fmi_sim(fmi_sim, sim_path, interface, start, sig, CS_STEP, CS_STOP, tmp)
            ref = fmpy_cs(path, md, start, sig, CS_STEP, CS_STOP)
        else:
            sig = input_signals(md, ME_STOP, ME_STEP)
            got = run_fmi_sim(fmi_sim, sim_path, interface, start, sig, ME_STEP, ME_STOP, tmp)
            unzipdir = extract(path)
            try:
                ref = euler_me(unzipdir, version, md, start, sig, ME_STEP, ME_STOP)
            finally:
                shutil.rmtree(unzipdir, ignore_errors=True)
        _compare(got, ref, what)
        finals.setdefault((name, interface), {})[fidelity] = tuple(
            float(got[k][-1]) for k in got)
    assert finals
    for (name, interface), by_rung in finals.items():   # each rung was set, none ignored
        assert len(set(by_rung.values())) == len(by_rung), (name, interface, by_rung)


def test_fmi_sim_0_7_refuses_the_unit_of_an_fmi3_variable(fmi_sim, native3, tmp_path):
    """Why the FMI 3.0 runs go through :func:`for_fmi_schema`: fmi-sim 0.7.0 (fmi-schema 0.8.0,
    the newest on crates.io) stops on ``unit``, an attribute the FMI 3.0 schema allows on every
    ``Float64`` variable. Should :data:`FMI_SIM` move to a version that reads it, this fails: then
    drop the workaround."""
    proc = subprocess.run([str(fmi_sim), "--model", native3["FlexiblePendulum"], "co-simulation",
                           "-s", "0", "-f", "0.01"], env=system_env(), capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode != 0
    assert 'unknown field "unit" in element "FmiFloat64"' in proc.stderr
