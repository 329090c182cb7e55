"""The result columns of a sweep's table, and what each costs a run.

``flexpend sweep --columns max_abs_x,max_abs_F_c`` (``columns=`` of :func:`orchestration.sweep`)
asks for some of them only: each run then computes only what those need. The two mode fits of a
run's summary (:func:`orchestration.studies.fit.fit_mode`) cost about half of its stepping; the
columns of :data:`FIT_COLUMNS` need them, the others do not, and the linearised loop's
eigenvalues are computed only for :data:`LINEAR_COLUMNS`. Without ``--columns`` a run computes
every column (the table of a sweep without it is unchanged).

Every table has the run's identity (``run``, ``key``, the swept values, ``sample``),
``status`` and ``message`` (why a run failed), whatever columns are asked for. ``--reference``
(the monolithic reference of every run) needs ``max_error_phi_o`` or ``max_error_eta_1`` among
them.
"""
from __future__ import annotations

__all__ = ["RESULT_COLUMNS", "FIT_COLUMNS", "LINEAR_COLUMNS", "ALWAYS", "parse_columns",
           "needs_fits", "needs_linear", "project", "serves"]

#: The result columns a sweep can be asked for, in the table's order, and what each holds.
RESULT_COLUMNS = {
    "stable": "the verdict as True (stable), False (unstable) or empty (undetermined)",
    "verdict": "stable, unstable, undetermined or stopped",
    "verdict_reason": "why the verdict is what it is",
    "slow_rate": "the slow (rigid) mode's fitted rate, 1/s",
    "slow_frequency": "its fitted frequency, rad/s",
    "slow_rate_linear": "the linearised loop's rate of that mode, 1/s",
    "slow_note": "why the slow fit is not reliable",
    "bending_rate": "the bending mode's fitted rate, 1/s",
    "bending_frequency": "its fitted frequency, rad/s",
    "bending_rate_linear": "the linearised loop's rate of that mode, 1/s",
    "bending_note": "why the bending fit is not reliable",
    "decay_rate": "minus the largest fitted rate that counts toward the verdict, 1/s",
    "max_abs_F_c": "the largest |F_c|, N",
    "max_abs_x": "the largest cart travel |x|, m",
    "valid": "False when the run left its rung's measured range",
    "validity": "how it left it",
    "model_form_error": "the run's error figure or its rung's measured bound, rad",
    "model_form_basis": "what that figure compares with",
    "max_error_phi_o": "with --reference: the largest error of phi_o, rad",
    "max_error_eta_1": "with --reference: the largest error of eta_1",
    "model": "the model the run chose (plant.n_modes or plant.fidelity auto)",
    "steps": "the master's steps",
    "cosim_time": "the master's wall time, s",
    "stopped_at": "when a run stopped early, the time it stopped, s",
    "fmu_message": "when an FMU stopped the run, its own message",
    "linear_decay_rate": "the linearised loop's smallest decay rate -max Re(lambda), 1/s",
    "linear_stable": "whether the linearised loop is stable",
    "wall_time": "the run's whole wall time on its worker, s",
}
#: The columns that need the summary's mode fits.
FIT_COLUMNS = frozenset({"stable", "verdict", "verdict_reason", "decay_rate",
                         *(f"{m}_{q}" for m in ("slow", "bending")
                           for q in ("rate", "frequency", "rate_linear", "note"))})
#: The columns that need the linearised loop's eigenvalues.
LINEAR_COLUMNS = frozenset({"linear_decay_rate", "linear_stable"})
#: The columns of every table, asked for or not (besides the swept keys).
ALWAYS = ("run", "key", "sample", "status", "message")


def parse_columns(spec) -> tuple | None:
    """``None`` (every column) or the tuple of the columns ``spec`` names: a comma-separated
    string (``--columns``) or a sequence of names; each named once, in the table's order as
    given. A ValueError names an unknown column and lists the allowed ones; a TypeError names
    a ``spec`` of another type."""
    if spec is None:
        return None
    if isinstance(spec, str):
        names = [c.strip() for c in spec.split(",")]
    elif isinstance(spec, (list, tuple)) and all(isinstance(c, str) for c in spec):
        names = [c.strip() for c in spec]
    else:
        raise TypeError(f"columns = {spec!r} is not allowed; allowed: a comma-separated string "
                        f"or a list of column names")
    allowed = (f"allowed: {', '.join(RESULT_COLUMNS)} (run, key, the swept keys, sample, status "
               f"and message are in every table)")
    out = []
    for name in names:
        if name in ALWAYS:
            continue                    # in every table anyway
        if name not in RESULT_COLUMNS:
            what = f"unknown column {name!r}" if name else "an empty column name"
            raise ValueError(f"--columns: {what}; {allowed}")
        if name in out:
            raise ValueError(f"--columns: {name} is named twice; name each column once")
        out.append(name)
    if not out:
        raise ValueError(f"--columns names no result column; {allowed}")
    return tuple(out)


def needs_fits(columns) -> bool:
    """Whether a run of a sweep asking for ``columns`` (None: all) fits its modes."""
    return columns is None or not FIT_COLUMNS.isdisjoint(columns)


def needs_linear(columns) -> bool:
    """Whether it computes the linearised loop's eigenvalues for its row."""
    return columns is None or not LINEAR_COLUMNS.isdisjoint(columns)


def project(row: dict, columns) -> dict:
    """``row``'s result fields that a sweep asking for ``columns`` shows: all of them for
    ``None``; else ``status``, the columns in their order (None where the row has no value), then
    ``message``."""
    if columns is None:
        return row
    out = {"status": row.get("status")}
    out.update((c, row.get(c)) for c in columns)
    out["message"] = row.get("message")
    return out


def serves(row: dict, columns) -> bool:
    """Whether a finished run's journal row has what a sweep asking for ``columns`` shows: a
    row of every column serves any sweep; a row made for some columns (its ``columns`` field)
    serves only a sweep asking for some of those."""
    made = row.get("columns")
    if made is None:
        return True
    return columns is not None and set(columns) <= set(made)
