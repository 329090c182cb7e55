"""Regress an FMU against reference results in the FMI cross-check layout.

    check_fmu(fmu, reference, rule=Rule())   -> CheckReport (``flexpend check``)
    write_reference(fmu, reference)          -> the files (``flexpend check --write-reference``)
    simulate_case(fmu, files)                -> Run: the FMU alone, its input file and options
    compare(result, reference, rule)         -> {signal: SignalCheck}
    validate(t, y, t_ref, y_ref, rule)       -> fmpy.util.validate_signal's band and outliers

A reference is three files in one folder, named after the model (cross-check layout):
``<Model>_in.csv`` (inputs, optional), ``<Model>_ref.csv`` (the expected result: time first, then
the signals compared) and ``<Model>_ref.opt`` (``StartTime``, ``StopTime``, ``StepSize``,
``RelTol``). The FMU is simulated alone by ``fmpy.simulate_fmu`` with the input file, from
``StartTime`` to ``StopTime`` in steps of ``StepSize`` (also the output interval), in a fresh
isolated Python process: a pythonfmu FMU runs the first copy of its packages that a process has
imported, so in the checker's own process a modified FMU would run the installed code and pass.

The comparison is FMPy's band rule, computed by ``fmpy.util.validate_signal`` (:func:`validate`):
around each reference signal a band of half-width ``tolerance`` times the signal's range (max -
min), widened over ``window`` neighbouring samples (the band's lower edge is the smallest
reference value within the window, minus the half-width; the upper edge likewise), and a signal
passes when at most ``max_outliers`` of the result's samples fall outside. The defaults are those
of FMPy's cross-check (``fmpy.cross_check``): 10 %, 21 samples, 10 %. Where ``validate_signal``
does not fit, :func:`validate` says why and adds to it: the band is built on as many points as the
reference has samples (FMPy: 1000, and linear interpolation between 1000 points of a 1001-sample
signal is off by far more than 1e-6 of the range), both ends count, a NaN is outside, and repeated
times are separated first. ``fmpy.cross_check.validate_signal`` is the same rule with both ends
counted, but it imports ``scipy.ndimage.filters``, deprecated and gone in SciPy 2.0.

A reference signal that does not vary has no band (FMPy's is +-0.5 around zero, whatever the
tolerance): an FMU whose outputs were all held at zero passed against the reference of the plant
at rest that ``--write-reference`` recorded when there was no input file. :func:`check_fmu` refuses
such a reference (:func:`check_reference`, exit 2), and :func:`write_reference` does not write one:
without an input file it drives the FMU with flexpend's excitation (:data:`EXCITATIONS`), and it
leaves out the outputs that still do not vary, or refuses those asked for.

A run that does not reach ``StopTime`` fails, whatever its samples: ``fmpy.simulate_fmu`` returns
normally, with a shorter result, when an FMU discards a step (fmi2Discard, then
``fmi2Terminated``), so the discard is watched for (through fmpy's FMI call logger) and the run
stopped there, and the result's last time is checked against ``StopTime``.

The project's own references (``tests/reference/``, regenerated on purpose by ``python
build/build_fmus.py --references``) use the same code with :data:`REFERENCE_RULE`: 1e-6 of the
range at every sample, no widening, no outlier.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fmu_common.checks import check_real
from fmu_common.kernels import ROOT

from ..files import write_csv, write_text
from ..scene import fmu as fmu_check
from ..scene.keys import ConfigError
from . import places

__all__ = ["Rule", "FMPY_RULE", "REFERENCE_RULE", "REFERENCE_DIR", "ReferenceError", "Run",
           "SignalCheck", "CheckReport", "reference_files", "find_reference", "read_opt",
           "simulate_case", "compare", "validate", "band", "constant_signals", "check_reference",
           "check_fmu", "write_reference", "Excitation", "EXCITATIONS", "excitation_for",
           "simulate_reference_case", "write_references"]

REFERENCE_DIR = ROOT / "tests" / "reference"


class ReferenceError(ValueError):
    """The reference files are missing or unreadable, or the FMU cannot be opened (one line)."""


@dataclass(frozen=True)
class Rule:
    """The comparison band: half-width ``tolerance`` x the reference's range, widened over
    ``window`` samples; a signal passes with at most ``max_outliers`` of its samples outside."""

    tolerance: float = 0.1
    window: int = 21
    max_outliers: float = 0.1

    def __post_init__(self):
        # a number > 0, finite and not subnormal (the scene keys' rule: fmu_common.checks)
        check_real("tolerance", self.tolerance, low=0.0, high=1e6)
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 1:
            raise ValueError(f"window = {self.window!r}; allowed: an integer >= 1 (samples)")
        if not (isinstance(self.max_outliers, (int, float)) and 0 <= self.max_outliers < 1):
            raise ValueError(f"max_outliers = {self.max_outliers!r}; allowed: 0 <= fraction < 1")

    def describe(self) -> str:
        widen = f", widened over {self.window} samples" if self.window > 1 else ""
        return (f"band +-{self.tolerance:g} x range{widen}, at most "
                f"{100 * self.max_outliers:g} % of the samples outside")


#: FMPy's cross-check rule (the defaults of ``flexpend check``).
FMPY_RULE = Rule()
#: The project's own reference test: every sample within 1e-6 of the signal's range. Round-off
#: grows at most ~1e3 times over the second (the pendulum's unstable root is +7/s), so a run on
#: another machine stays ~1e-10 inside it, while a change of the physics by 1e-3 leaves it.
REFERENCE_RULE = Rule(tolerance=1e-6, window=1, max_outliers=0.0)


# ---------------------------------------------------------------------- files
def reference_files(name: str, ref_dir: Path = REFERENCE_DIR) -> dict:
    """The three files of model ``name`` under ``ref_dir/<name>/`` (the project's layout)."""
    d = Path(ref_dir) / name
    return _files(d, name)


def _files(d: Path, name: str) -> dict:
    return {"in": d / f"{name}_in.csv", "ref": d / f"{name}_ref.csv", "opt": d / f"{name}_ref.opt",
            "model": name, "dir": d}


def _plain_name(name) -> bool:
    """Whether ``name`` is one plain file name (no folder, not ``.`` or ``..``, no drive): the
    only model names a reference is looked up by, so that the FMU cannot choose a path."""
    return (isinstance(name, str) and name.strip(".") != ""
            and not any(c in name for c in "/\\:\0"))


def _model_names(fmu: Path) -> list[str]:
    """The names the reference of ``fmu`` may have: its file's, its model identifier, its model
    name; only those that are plain file names (:func:`_plain_name`)."""
    md = _description(fmu)
    names = []
    for n in (fmu.stem, getattr(md.coSimulation, "modelIdentifier", None), md.modelName):
        if _plain_name(n) and n not in names:
            names.append(n)
    if not names:
        raise ReferenceError(f"{fmu}: neither its file name, nor its model identifier, nor its "
                             "model name is a plain file name to look its reference up by")
    return names


def _description(fmu):
    """The model description of ``fmu``, read after the checks of
    :mod:`orchestration.scene.fmu` (the archive's limits and member names, before anything
    inflates it; the model identifiers); a :class:`ReferenceError` names any problem."""
    try:
        return fmu_check.model_description(fmu, str(fmu))
    except ConfigError as exc:
        raise ReferenceError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - any reason the FMU cannot be read
        raise ReferenceError(f"{fmu}: not a readable FMU: {exc}") from None


def find_reference(fmu, ref_dir, must_exist: bool = True) -> dict:
    """The reference files of ``fmu`` in ``ref_dir`` or in ``ref_dir/<Model>/``, where
    ``<Model>`` is the FMU's file name (without ``.fmu``), its model identifier or its model
    name. With ``must_exist=False``, where they would go (for ``--write-reference``)."""
    fmu, ref_dir = Path(fmu), Path(ref_dir)
    if not fmu.is_file():
        hint = (f"; `flexpend build` builds flexpend's FMUs into {places.fmu_dir()}"
                if fmu.suffix == ".fmu" else "")
        raise ReferenceError(f"{fmu}: no such FMU{hint}")
    names = _model_names(fmu)
    for kind in ("ref", "opt"):
        for name in names:
            for d in (ref_dir, ref_dir / name):
                files = _files(d, name)
                if files[kind].is_file():
                    return files
    if must_exist:
        wanted = " or ".join(f"{n}_ref.csv" for n in names)
        raise ReferenceError(f"{ref_dir}: no reference of {fmu.name} ({wanted}, in the folder "
                             "or in a subfolder of that name)")
    name = names[0]
    return _files(ref_dir if ref_dir.name == name else ref_dir / name, name)


def read_opt(path) -> dict:
    """The options file: lines ``Name,value`` with ``StartTime``, ``StopTime``, ``StepSize`` and
    optionally ``RelTol`` (FMPy's reader requires it; a co-simulation FMU rarely needs it)."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ReferenceError(f"{path}: cannot read the options: {exc}") from None
    opt = {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        name, sep, value = line.partition(",")
        try:
            opt[name.strip()] = float(value)
        except ValueError:
            raise ReferenceError(f"{path}: line {n}: {line.strip()!r} is not 'Name,value'") \
                from None
    missing = [k for k in ("StartTime", "StopTime", "StepSize") if k not in opt]
    if missing:
        raise ReferenceError(f"{path}: {', '.join(missing)} missing")
    start, stop, step = opt["StartTime"], opt["StopTime"], opt["StepSize"]
    if not (math.isfinite(start) and math.isfinite(stop) and stop > start
            and 0 < step <= stop - start):
        raise ReferenceError(f"{path}: StartTime = {start:g}, StopTime = {stop:g}, StepSize = "
                             f"{step:g}: need StartTime < StopTime and 0 < StepSize <= the run")
    return opt


def _read_csv(path):
    from fmpy.util import read_csv

    try:
        data = read_csv(str(path))
    except OSError as exc:
        raise ReferenceError(f"{path}: cannot read: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - malformed CSV
        raise ReferenceError(f"{path}: not a result CSV (quoted header, time first): {exc}") \
            from None
    if data.dtype.names is None or len(data.dtype.names) < 2 or data.size < 2:
        raise ReferenceError(f"{path}: needs a time column, at least one signal and two rows")
    t = data[data.dtype.names[0]]
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise ReferenceError(f"{path}: the time column must be finite and non-decreasing")
    return data


# ---------------------------------------------------------------------- simulation
@dataclass
class Run:
    """A simulation of one FMU: the result (None if it failed before producing one), why it did
    not reach the stop time (None when it did), the FMU's log messages and fmpy's notes."""

    result: np.ndarray | None
    failure: str | None = None
    log: list = field(default_factory=list)
    notes: list = field(default_factory=list)


def simulate_case(fmu, files: dict, start_values=None, outputs=None, timeout=None) -> Run:
    """Simulate ``fmu`` alone with the input file and options of ``files`` (a reference's
    files); record ``outputs`` (default: the reference's signals).

    The simulation runs in a fresh, isolated Python process (``python -I``) that imports nothing
    but fmpy and numpy: a pythonfmu FMU runs whatever copy of its packages the process has
    imported first, so in a process that has imported this project (the checker itself) a
    modified FMU would run the installed code, not its own, and pass. The child also keeps a
    crashing FMU from taking the checker down."""
    import json
    import subprocess
    import sys
    import tempfile

    opt = read_opt(files["opt"])
    if files["in"].is_file():
        _read_csv(files["in"])                       # a malformed input file: ReferenceError
    if outputs is None:
        outputs = list(_read_csv(files["ref"]).dtype.names[1:])
    # the FMU unpacked, and the child's temporary files, in our folder, removed however the run
    # ends (fmpy keeps the folder it unpacked an FMU into when the simulation raises); unpacked
    # here, within the archive limits, and the libraries the child may load checked to lie in it
    with tempfile.TemporaryDirectory(prefix="flexpend_check_") as tmp:
        label, fmu = str(fmu), Path(fmu)
        try:
            if not fmu.is_dir():
                fmu = Path(fmu_check.unpack(fmu, Path(tmp) / "fmu", label))
            fmu_check.check_unpacked(fmu, label)
        except ConfigError as exc:
            raise ReferenceError(str(exc)) from None
        args = {"fmu": str(fmu.resolve()), "opt": opt, "outputs": list(outputs),
                "input": str(files["in"].resolve()) if files["in"].is_file() else None,
                "start_values": dict(start_values or {}),
                "result": str(Path(tmp) / "result.npy"), "meta": str(Path(tmp) / "meta.json")}
        try:
            proc = subprocess.run([sys.executable, "-I", "-c", _WORKER, json.dumps(args)],
                                  cwd=tmp, capture_output=True, text=True, timeout=timeout,
                                  env={**os.environ, "TMPDIR": tmp})
        except subprocess.TimeoutExpired:
            return Run(None, f"the simulation did not finish within {timeout:g} s")
        meta_path = Path(args["meta"])
        if not meta_path.is_file():
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
            return Run(None, f"the FMU crashed the simulating process (exit code "
                             f"{proc.returncode}): {tail[0]}")
        meta = json.loads(meta_path.read_text())
        result = np.load(args["result"]) if Path(args["result"]).is_file() else None
    run = Run(result, meta["failure"], meta["log"], meta["notes"])
    if result is not None and run.failure is None:
        stop = opt["StopTime"]
        if result.size == 0 or result["time"][-1] < stop - 1e-9 * max(1.0, abs(stop)):
            end = result["time"][-1] if result.size else opt["StartTime"]
            run.failure = f"stopped early: the run ended at t = {end:g}, before StopTime = {stop:g}"
            if run.log:
                run.failure += f": {run.log[-1]}"
    return run


#: The child process of :func:`simulate_case`: fmpy.simulate_fmu with the FMU's log and every
#: doStep's status watched; a discard (or error) stops the run there. It exits with os._exit
#: once its files are written: an FMU's teardown at interpreter exit cannot fail the check.
_WORKER = r"""
import contextlib, io, json, os, re, sys
import numpy as np
from fmpy import simulate_fmu
from fmpy.util import read_csv

a = json.loads(sys.argv[1])
opt = a["opt"]
log, bad = [], []
DOSTEP = re.compile(r"fmi[23]DoStep\((.*)\) -> (\w+)$")

def logger(component, instance, status, category, message):
    if status >= 2:              # discard, error, fatal: the reason of a failure
        log.append((message or b"").decode(errors="replace"))

def call_logger(message):
    m = DOSTEP.search(message)
    if m and m.group(2) in ("DISCARD", "ERROR", "FATAL"):
        t = re.search(r"currentCommunicationPoint=([^,]+)", m.group(1))
        bad.append((m.group(2).lower(), t.group(1) if t else "?"))

out = io.StringIO()
failure, result = None, None
try:
    with contextlib.redirect_stdout(out):
        result = simulate_fmu(a["fmu"], start_time=opt["StartTime"], stop_time=opt["StopTime"],
                              step_size=opt["StepSize"], output_interval=opt["StepSize"],
                              relative_tolerance=opt.get("RelTol"),
                              input=read_csv(a["input"]) if a["input"] else None,
                              output=a["outputs"], start_values=a["start_values"],
                              debug_logging=True, logger=logger, fmi_call_logger=call_logger,
                              step_finished=lambda time, recorder: not bad)
except Exception as exc:
    failure = f"the FMU failed to simulate: {type(exc).__name__}: {exc}"
    if log:
        failure += f" ({log[-1]})"
if failure is None and bad:
    status, t = bad[0]
    failure = (f"stopped early: doStep at t = {t} returned {status}"
               + (f": {log[-1]}" if log else ""))
if result is not None:
    np.save(a["result"], result)
notes = [line.strip() for line in out.getvalue().splitlines() if line.strip()]
with open(a["meta"], "w") as f:
    json.dump({"failure": failure, "log": log, "notes": notes}, f)
sys.stdout.flush()
sys.stderr.flush()
os._exit(0)
"""


# ---------------------------------------------------------------------- comparison
@dataclass
class SignalCheck:
    """One signal against its band."""

    name: str
    passed: bool
    max_deviation: float = math.nan    # largest |result - reference|
    span: float = math.nan             # the reference's range (max - min)
    half_width: float = math.nan       # the band's half-width
    outliers: int = 0
    samples: int = 0
    problem: str | None = None         # e.g. the signal is missing from the result
    band: tuple = ()                   # (t_ref, lower, upper), for plotting

    @property
    def relative_deviation(self) -> float:
        return self.max_deviation / self.span if self.span > 0 else self.max_deviation

    def line(self) -> str:
        verdict = "pass" if self.passed else "FAIL"
        if self.problem:
            return f"{self.name:<16} {self.problem}: {verdict}"
        return (f"{self.name:<16} max |deviation| {self.max_deviation:.3e} "
                f"({self.relative_deviation:.2e} of range {self.span:.4g}), band +-"
                f"{self.half_width:.3e}, {self.outliers}/{self.samples} outside: {verdict}")


def _strictly_increasing(t):
    """``t`` with each repeated time (an event's two samples) moved up to the next float.
    ``fmpy.util.validate_signal`` moves it by 1e-13 s in a loop that never ends beyond 2**10 s,
    where 1e-13 is below the spacing of the floats."""
    t = np.array(t, dtype=float)
    for i in np.flatnonzero(np.diff(t) <= 0) + 1:          # ascending: a run of repeats too
        if t[i] <= t[i - 1]:
            t[i] = np.nextafter(t[i - 1], np.inf)
    return t


def _half_width(y_band, rule: Rule) -> float:
    """The band's half-width as ``fmpy.util.validate_signal`` computes it from its samples."""
    lo, hi = float(np.min(y_band)), float(np.max(y_band))
    if lo == hi:
        return 0.5 if lo == 0 else abs(lo) * rule.tolerance
    return (hi - lo) * rule.tolerance


def validate(t, y, t_ref, y_ref, rule: Rule = FMPY_RULE):
    """FMPy's band, by ``fmpy.util.validate_signal``, and the samples of ``y(t)`` outside it:
    ``(t_band, lower, upper, outside)``, ``outside`` a mask over ``t``.

    ``validate_signal`` resamples the reference linearly onto ``num`` evenly spaced points
    (FMPy: 1000); it is given the reference's own number of samples, so that on an evenly sampled
    reference (every one ``--write-reference`` writes) the band's points are its samples: linear
    interpolation between 1000 points of a 1001-sample signal is off by far more than 1e-6 of its
    range. A reference with uneven steps or repeated times (events) is resampled as FMPy does,
    onto as many even points. The band's width is ``dx = window`` samples (clipped to the whole
    signal: scipy overflows on a huge one), its half-width ``dy = tolerance`` of the range.

    Where ``validate_signal`` does not fit, this adds to it: it leaves the first and the last
    sample out of its count (``t > t_start``, ``t < t_stop``), and a NaN, which no comparison
    finds outside, passes; here both ends count and a sample that is not finite is outside. It
    moves a repeated reference time by 1e-13 s in a loop that never ends beyond 2**10 s (where
    1e-13 is below the spacing of the floats): they are moved apart to the next float first.
    (``fmpy.cross_check.validate_signal`` counts both ends, but imports ``scipy.ndimage.filters``,
    deprecated and gone in SciPy 2.0.)"""
    from fmpy.util import validate_signal

    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    t_ref = _strictly_increasing(t_ref)
    y_ref = np.asarray(y_ref, dtype=float)
    n = t_ref.size
    t_band, lower, upper, out = validate_signal(t=t, y=y, t_ref=t_ref, y_ref=y_ref, num=n,
                                                dx=min(rule.window, 2 * n + 1),
                                                dy=rule.tolerance)
    inside = (t >= t_band[0]) & (t <= t_band[-1])
    ends = inside & ((t == t_band[0]) | (t == t_band[-1]))
    lo, hi = np.interp(t, t_band, lower), np.interp(t, t_band, upper)
    out = out | (ends & ((y < lo) | (y > hi))) | (inside & ~np.isfinite(y))
    return t_band, lower, upper, out


def band(t_ref, y_ref, rule: Rule):
    """``(t_band, lower, upper, half_width)``: FMPy's band around ``y_ref`` (:func:`validate`)."""
    t_band, lower, upper, _ = validate(t_ref, y_ref, t_ref, y_ref, rule)
    y_band = np.interp(t_band, _strictly_increasing(t_ref), np.asarray(y_ref, dtype=float))
    return t_band, lower, upper, _half_width(y_band, rule)


def compare(result, reference, rule: Rule = FMPY_RULE) -> dict:
    """Each signal of ``reference`` (a structured array, time first) against its band, at the
    samples of ``result`` within the reference's time span (:func:`validate`). A reference
    signal that does not vary fails here (:func:`constant_signals`)."""
    t_ref = _strictly_increasing(reference[reference.dtype.names[0]])
    t = np.asarray(result[result.dtype.names[0]], dtype=float)
    # a sample within round-off of the reference's first or last time is at it
    eps = 1e-9 * max(1.0, abs(t_ref[-1]))
    t = np.where(np.abs(t - t_ref[0]) <= eps, t_ref[0],
                 np.where(np.abs(t - t_ref[-1]) <= eps, t_ref[-1], t))
    inside = (t >= t_ref[0]) & (t <= t_ref[-1])
    constant = set(constant_signals(reference))
    out = {}
    for name in reference.dtype.names[1:]:
        if name not in (result.dtype.names or ()):
            out[name] = SignalCheck(name, False, problem="missing from the result")
            continue
        y_ref = np.asarray(reference[name], dtype=float)
        span = float(np.max(y_ref) - np.min(y_ref))
        if not np.all(np.isfinite(y_ref)):
            out[name] = SignalCheck(name, False, problem="not finite in the reference")
            continue
        if name in constant:
            out[name] = SignalCheck(name, False, span=span,
                                    problem="constant in the reference: no band")
            continue
        y = np.asarray(result[name], dtype=float)
        t_band, lower, upper, outside = validate(t, y, t_ref, y_ref, rule)
        w = _half_width(np.interp(t_band, t_ref, y_ref), rule)
        yy = y[inside]
        n_out = int(np.count_nonzero(outside[inside]))
        dev = float(np.max(np.abs(yy - np.interp(t[inside], t_ref, y_ref)))) if yy.size \
            else math.nan
        if yy.size and not math.isfinite(dev):
            dev = math.inf
        passed = yy.size > 0 and n_out <= rule.max_outliers * yy.size
        out[name] = SignalCheck(name, bool(passed), dev, span, w, n_out, int(yy.size),
                                band=(t_band, lower, upper))
    return out


def constant_signals(reference) -> list[str]:
    """The signals of ``reference`` that do not vary (max == min): around a constant there is
    no band (FMPy puts one of half-width 0.5 around zero, which no tolerance tightens, and
    ``tolerance`` x the value elsewhere), so that an FMU whose output is held there passes."""
    return [n for n in reference.dtype.names[1:]
            if np.all(np.isfinite(reference[n])) and np.ptp(reference[n]) == 0]


@dataclass
class CheckReport:
    """The verdict of ``flexpend check``: per signal, and whether the run itself completed."""

    fmu: Path
    files: dict
    rule: Rule
    run: Run
    reference: np.ndarray
    signals: dict = field(default_factory=dict)
    #: ``{variable: unit}`` of the FMU's variables (:func:`variable_units`).
    units: dict = field(default_factory=dict)

    @property
    def failure(self) -> str | None:
        return self.run.failure

    @property
    def passed(self) -> bool:
        return (self.failure is None and bool(self.signals)
                and all(s.passed for s in self.signals.values()))

    def lines(self) -> list[str]:
        out = [f"{self.fmu.name} against {self.files['ref']} ({self.rule.describe()})"]
        out += [f"  {s.line()}" for s in self.signals.values()]
        if self.failure:
            out.append(f"  run: {self.failure}: FAIL")
        n_bad = sum(not s.passed for s in self.signals.values())
        verdict = "PASSED" if self.passed else "FAILED"
        why = []
        if n_bad:
            why.append(f"{n_bad} of {len(self.signals)} signals outside their band")
        if self.failure:
            why.append("the run did not complete")
        out.append(f"{verdict}" + (f": {'; '.join(why)}" if why else
                                   f": {len(self.signals)} signals within their band"))
        return out


def _names(names) -> str:
    """``a does``, ``a, b do``: the subject of a sentence about signals."""
    return f"{', '.join(names)} {'does' if len(names) == 1 else 'do'}"


def check_reference(ref, files: dict) -> None:
    """Refuse (:class:`ReferenceError`, one line) a reference that cannot fail: a signal that
    is not finite, or that does not vary (:func:`constant_signals`)."""
    model = files["model"]
    bad = [n for n in ref.dtype.names[1:] if not np.all(np.isfinite(ref[n]))]
    if bad:
        raise ReferenceError(f"{files['ref']}: {', '.join(bad)} {'is' if len(bad) == 1 else 'are'}"
                             f" not finite (NaN or inf): a band needs finite values; record the "
                             f"reference again or leave them out of {model}_ref.csv")
    constant = constant_signals(ref)
    if constant:
        raise ReferenceError(
            f"{files['ref']}: {_names(constant)} not vary (a constant gives no band: an FMU "
            f"held there would pass); record a run that moves them (--write-reference drives "
            f"the FMU with flexpend's excitation when there is no {model}_in.csv) or leave "
            f"them out of {model}_ref.csv")


def check_fmu(fmu, reference, rule: Rule = FMPY_RULE, start_values=None) -> CheckReport:
    """Simulate ``fmu`` with the input file and options of its reference in ``reference`` (a
    folder) and compare every reference signal (see the module's docstring). A reference whose
    signals cannot fail is refused first (:func:`check_reference`)."""
    files = find_reference(fmu, reference)
    for kind in ("ref", "opt"):
        if not files[kind].is_file():
            raise ReferenceError(f"{files[kind]}: missing")
    ref = _read_csv(files["ref"])
    check_reference(ref, files)
    run = simulate_case(fmu, files, start_values, outputs=list(ref.dtype.names[1:]))
    signals = compare(run.result, ref, rule) if run.result is not None and run.result.size else {}
    if run.result is not None and run.result.size and run.failure is None:
        t, t_ref = run.result["time"], ref[ref.dtype.names[0]]
        if t[0] > t_ref[0] + 1e-9 or t[-1] < t_ref[-1] - 1e-9 * max(1.0, abs(t_ref[-1])):
            run.failure = (f"the run covers {t[0]:g}..{t[-1]:g} s, the reference "
                           f"{t_ref[0]:g}..{t_ref[-1]:g} s")
    return CheckReport(Path(fmu), files, rule, run, ref, signals, variable_units(fmu))


def variable_units(fmu) -> dict:
    """``{name: unit}`` of every variable of ``fmu``'s model description: its ``unit``, else its
    declared type's, else ``"1"`` (dimensionless)."""
    md = _description(fmu)
    return {v.name: v.unit or getattr(v.declaredType, "unit", None) or "1"
            for v in md.modelVariables}


def write_reference(fmu, reference, outputs=None) -> dict:
    """Write ``<Model>_ref.csv`` from a run of ``fmu`` with the input file and options in
    ``reference`` (or ``reference/<Model>/``); return its files, with ``"written"`` (the files
    written), ``"excitation"`` (the kind of :data:`EXCITATIONS` written as the input file, or
    None), ``"signals"`` (those recorded) and ``"left_out"`` (outputs left out as constant).

    Without ``<Model>_in.csv``, an FMU with inputs is driven by flexpend's excitation for them
    (:func:`excitation_for`), written as the input file, with its options when
    ``<Model>_ref.opt`` is missing too (an FMU whose inputs it does not know is refused); an
    options file still missing is written from the FMU's default experiment. ``outputs``: the
    signals (default: those of an existing ``<Model>_ref.csv``, else every output of the FMU
    that varies in the run: the others are left out). A chosen signal that does not vary, or a
    run that does not complete, writes nothing (:class:`ReferenceError`): the files written
    before the run are removed."""
    fmu = Path(fmu)
    files = find_reference(fmu, reference, must_exist=False)
    md = _description(fmu)
    files.update(written=[], excitation=None, signals=[], left_out=[])
    new_dirs = [d for d in (files["dir"], *files["dir"].parents) if not d.exists()]
    try:
        _write_experiment(fmu, md, files)
        _write_result(fmu, md, files, outputs)
    except BaseException:
        for path in files["written"]:
            Path(path).unlink(missing_ok=True)
        for d in new_dirs:                              # the folders it made, if still empty
            if d.is_dir() and not any(d.iterdir()):
                d.rmdir()
        files["written"].clear()
        raise
    return files


def _write_experiment(fmu: Path, md, files: dict) -> None:
    """The input file (flexpend's excitation, when it is missing and the FMU has inputs) and the
    options (the excitation's, else the FMU's default experiment, when they are missing)."""
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    if inputs and not files["in"].is_file():
        found = excitation_for(inputs)
        if found is None:
            kinds = "; ".join(f"the {k}'s: {', '.join(e.inputs)}" for k, e in EXCITATIONS.items())
            raise ReferenceError(
                f"{files['in']}: missing, and flexpend has no excitation for the inputs of "
                f"{fmu.name} ({', '.join(inputs)}; it has {kinds}): write {files['model']}_in.csv"
                f" (quoted header, \"time\" first) with inputs that move every signal compared")
        kind, opt, columns = found
        files["dir"].mkdir(parents=True, exist_ok=True)
        if not files["opt"].is_file():
            write_text(files["opt"], _opt_text(opt))
            files["written"].append(files["opt"])
        write_csv(files["in"], _input_table(read_opt(files["opt"]), columns))
        files["written"].append(files["in"])
        files["excitation"] = kind
    if not files["opt"].is_file():
        de = md.defaultExperiment
        step = getattr(de, "stepSize", None) if de is not None else None
        if de is None or step is None or de.stopTime is None:
            raise ReferenceError(f"{files['opt']}: missing, and {fmu.name} has no default "
                                 "experiment with a stop time and a step size to write it from")
        opt = {"StartTime": float(de.startTime or 0.0), "StopTime": float(de.stopTime),
               "StepSize": float(step)}
        if de.tolerance is not None:
            opt["RelTol"] = float(de.tolerance)
        files["dir"].mkdir(parents=True, exist_ok=True)
        write_text(files["opt"], _opt_text(opt))
        files["written"].append(files["opt"])


def _write_result(fmu: Path, md, files: dict, outputs) -> list:
    """Run the FMU and write the signals that vary; a chosen one that does not is refused."""
    chosen = outputs is not None or files["ref"].is_file()
    if outputs is None:
        if files["ref"].is_file():
            outputs = list(_read_csv(files["ref"]).dtype.names[1:])
        else:
            outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    known = {v.name for v in md.modelVariables}
    unknown = [o for o in outputs if o not in known]
    if unknown or not outputs:
        raise ReferenceError(f"{fmu.name} has no variable {', '.join(map(repr, unknown))}"
                             if unknown else f"{fmu.name}: no output to record")
    run = simulate_case(fmu, files, outputs=list(outputs))
    if run.failure is not None:
        hint = ""
        if files["excitation"]:
            opt, case = read_opt(files["opt"]), _reference_cases()[
                EXCITATIONS[files["excitation"]].model][0]
            if opt["StopTime"] - opt["StartTime"] > case["StopTime"] - case["StartTime"]:
                hint = (f" (flexpend's excitation of the {files['excitation']} is meant for "
                        f"{case['StopTime'] - case['StartTime']:g} s, {files['opt'].name} asks "
                        f"{opt['StopTime'] - opt['StartTime']:g} s: remove it to have the "
                        "excitation's written)")
        raise ReferenceError(f"{fmu.name}: no reference written: {run.failure}{hint}")
    bad = [n for n in outputs if not np.all(np.isfinite(run.result[n]))]
    if bad:
        raise ReferenceError(f"{fmu.name}: no reference written: {', '.join(bad)} "
                             f"{'is' if len(bad) == 1 else 'are'} not finite in this run (NaN or "
                             "inf): a band needs finite values")
    constant = constant_signals(run.result)
    if constant and (chosen or len(constant) == len(outputs)):
        if files["excitation"]:
            how = f"flexpend's excitation of the {files['excitation']} does not move them"
        elif files["in"].is_file():
            how = f"make {files['in'].name} move them"
        else:
            how = f"{fmu.name} has no input to move them"
        raise ReferenceError(
            f"{fmu.name}: no reference written: {_names(constant)} not vary in this run (a "
            f"constant gives no band: an FMU held there would pass); {how}, or leave them out "
            f"(--outputs)")
    kept = [n for n in run.result.dtype.names if n not in constant]
    files["dir"].mkdir(parents=True, exist_ok=True)
    write_csv(files["ref"], run.result[kept])
    files["written"].append(files["ref"])
    files["signals"], files["left_out"] = kept[1:], constant
    return kept[1:]


# ---------------------------------------------------------------------- the project's references
#: The signals each FMU's reference records.
REFERENCE_OUTPUTS = {
    "FlexiblePendulum": ["x_o", "x_dot", "phi_o", "omega_o", "tip_deflection", "eta_1", "energy"],
    "PDLowPass": ["F_c"],
}


def _reference_cases():
    """name -> (options of the .opt file, input columns {name: f(t)})."""
    two_pi = 2 * np.pi

    def held(*names):
        """The input-derivative columns, all 0: fmpy holds each input over a step (zero-order
        hold), and an input file that names every input keeps fmpy from warning."""
        return {n: (lambda t: np.zeros_like(t)) for n in names}

    return {
        # the plant alone (defaults: 4 modes, rk4), pushed then pulled, with a ripple at the
        # closed-loop bending frequency (24 Hz = 150 rad/s). The pull is sized so that the pair
        # leaves the unstable pendulum mode (+7/s) almost unexcited: the pendulum stays within
        # 0.02 rad for the whole second while the bending modes ring
        "FlexiblePendulum": (
            {"StartTime": 0.0, "StopTime": 1.0, "StepSize": 1e-3, "RelTol": 1e-6},
            {"F_c": lambda t: (np.where(t < 0.05, 20.0, 0.0)
                               - np.where((t >= 0.05) & (t < 0.1), 29.148, 0.0)
                               + 3.0 * np.sin(two_pi * 24.0 * t)),
             **held("dF_c", "d2F_c")}),
        # the controller alone (defaults: PD + the designed 2nd-order filter, 97.3 rad/s, damping
        # 0.1) on sensor signals with a step, a slow swing and a bending-frequency ripple
        "PDLowPass": (
            {"StartTime": 0.0, "StopTime": 1.0, "StepSize": 1e-3, "RelTol": 1e-6},
            {"phi_o": lambda t: (0.1 * np.sin(two_pi * 2.0 * t) + 0.01 * np.sin(150.0 * t)
                                 + np.where(t >= 0.5, 0.05, 0.0)),
             "omega_o": lambda t: (0.2 * np.pi * 2.0 * np.cos(two_pi * 2.0 * t)
                                   + 1.5 * np.cos(150.0 * t)),
             "x_o": lambda t: 0.5 * t * t,
             **held(*(f"{d}{n}" for d in ("d", "d2") for n in ("phi_o", "omega_o", "x_o")))}),
    }


@dataclass(frozen=True)
class Excitation:
    """An input file flexpend writes for an FMU with these ``inputs``: the one of the project's
    reference of ``model`` (:func:`_reference_cases`), with its options."""

    model: str
    inputs: tuple
    what: str


#: flexpend's excitations, by the kind of FMU whose inputs they drive: what ``--write-reference``
#: writes as ``<Model>_in.csv`` when there is none. Not the scene's closed loop: the cross-check
#: layout has one FMU, its inputs from a file and no start values, and the plant alone is
#: unstable (+7/s). The scenes start the pendulum at pi/6, the FMU at its default, 0; and even
#: started at pi/6, the plant fed the force of flexible_pd_lowpass's run (recorded every master
#: step) drifts from that run (the master's quadratic extrapolation and input derivatives are
#: not the input file's interpolation) and topples within 1.1 s (0.3 s from its own start). The
#: excitations are short (1 s) and leave the unstable mode nearly unexcited, so that round-off
#: grows at most ~1e3 times: a run on another machine stays within 1e-6 of the range.
EXCITATIONS = {
    "plant": Excitation("FlexiblePendulum", ("F_c",),
                        "F_c: a push, a pull, a ripple at 24 Hz"),
    "controller": Excitation("PDLowPass", ("phi_o", "omega_o", "x_o"),
                             "phi_o, omega_o, x_o: a swing, a step, a ripple, a cart speeding up"),
}


def excitation_for(inputs) -> tuple | None:
    """``(kind, options, columns)`` of the excitation for an FMU with ``inputs`` (names): the
    one whose inputs the FMU has, all of its inputs being among the excitation's columns (the
    input derivatives of a pythonfmu FMU, held at 0, are); None if there is none."""
    have = set(inputs)
    cases = _reference_cases()
    for kind, exc in EXCITATIONS.items():
        opt, columns = cases[exc.model]
        if set(exc.inputs) <= have <= set(columns):
            return kind, dict(opt), {k: f for k, f in columns.items() if k in have}
    return None


def simulate_reference_case(fmu, name: str, ref_dir: Path = REFERENCE_DIR, start_values=None):
    """A fresh run of one of the project's FMUs with its committed input file and options (the
    result array; a run that does not complete raises ``RuntimeError``)."""
    run = simulate_case(fmu, reference_files(name, ref_dir), start_values,
                        outputs=REFERENCE_OUTPUTS[name])
    if run.failure is not None:
        raise RuntimeError(f"{name}: {run.failure}")
    return run.result


def _input_table(opt: dict, inputs: dict) -> np.ndarray:
    """The input file's table: ``inputs`` (name -> f(t)) at every step of the options ``opt``."""
    n = round((opt["StopTime"] - opt["StartTime"]) / opt["StepSize"])
    t = opt["StartTime"] + np.arange(n + 1) * opt["StepSize"]
    arr = np.zeros(t.size, dtype=[("time", "f8")] + [(k, "f8") for k in inputs])
    arr["time"] = t
    for k, f in inputs.items():
        arr[k] = f(t)
    return arr


def _opt_text(opt: dict) -> str:
    """The text of a ``<Model>_ref.opt``."""
    return "".join(f"{k},{v!r}\n" for k, v in opt.items())


def write_references(fmus: dict, ref_dir: Path = REFERENCE_DIR) -> dict:
    """Regenerate the input files, options and reference results of the project's FMUs (``fmus``:
    name -> path); return the files of each."""
    written = {}
    for name, (opt, inputs) in _reference_cases().items():
        files = reference_files(name, ref_dir)
        files["dir"].mkdir(parents=True, exist_ok=True)
        write_csv(files["in"], _input_table(opt, inputs))
        write_text(files["opt"], _opt_text(opt))
        written[name] = write_reference(fmus[name], files["dir"], REFERENCE_OUTPUTS[name])
    return written
