"""A sweep from start to end (``flexpend sweep`` and :func:`orchestration.sweeps`): the plan, the
executor (serial, worker processes here, or a dask scheduler), the runs, the statistics and ``sweep.json``."""
from __future__ import annotations

import re
from dataclasses import dataclass

from ..files import check_folder, write_json
from ..report.progress import check_progress, note, sink_for
from ..scene.keys import ConfigError, toml_value
from .engine import fmus_for, pending, run_sweep, sweep_stats
from .executor import (PROCESS_START, Executor, default_workers, local_workers, open_executor,
                       process_limits)
from .plan import design_worst_case, expected_run_seconds, plan_sweep

__all__ = ["Sweep", "sweep"]


@dataclass
class Sweep:
    """A finished (or resumed) sweep: the plan, the runs (:class:`~orchestration.sweeps.engine.
    SweepResult`: rows, table and plot paths), the statistics and the record of ``sweep.json``."""

    plan: object
    result: object
    stats: dict
    record: dict
    executor: str

    @property
    def rows(self) -> list:
        """One dict per run, as the table's rows: the values, the verdict, the fits, the error
        and the wall time, or the message of a failed run."""
        return self.result.rows

    def __repr__(self) -> str:
        """One line: the scene, the keys swept, the runs and how they ended, the executor."""
        keys = ", ".join(self.plan.keys)
        if len(keys) > 60:
            keys = keys[:57] + "..."
        lost = self.stats.get("lost", 0) if isinstance(self.stats, dict) else 0
        return (f"Sweep({self.plan.scene.name!r} over {keys or 'nothing'}: "
                f"{len(self.result.rows)} runs, {lost} lost; {self.executor})"[:200])

    def to_pandas(self):
        """One row per run, as a pandas DataFrame indexed by the run's number."""
        import pandas as pd

        return pd.DataFrame(self.result.rows).set_index("run")


def sweep(scene, *, grid=(), values=(), sample=(), samples: int | None = None,
          seed: int | None = None, overrides=(), reference: bool = False, columns=None,
          workers: int | None = None, scheduler: str | None = None, serial: bool = False,
          batch: int = 1, retry_failed: bool = False, out="out/sweep", progress=False,
          command: str | None = None, on_executor=None, stop=None) -> Sweep:
    """Run a sweep of ``scene`` into the folder ``out`` (see :mod:`orchestration.sweeps`).

    ``grid``, ``values``, ``sample``: the ``--grid``, ``--values``, ``--sample`` items (strings),
    or dicts: ``grid={"controller.kp": (300, 700, 5)}`` (a fourth item ``"log"`` for a geometric
    grid), ``values={"plant.n_modes": [2, 3, 4]}``, ``sample={"plant.EI": "uniform:800:950"}``
    (or ``sample="design"``). ``workers``: that many worker processes on this machine
    (:class:`~orchestration.sweeps.executor.ProcessExecutor`); ``scheduler``: the address of a
    dask scheduler (its cluster's workers run the runs); ``serial``: here, one run after the
    other. ``columns``: the table's result columns, each run computing only what they need
    (:mod:`~orchestration.sweeps.columns`; ``"max_abs_x,max_abs_F_c"`` or a list; None: all).
    Given none of them, one worker process per core where they win against the serial
    runs, by the rule of :func:`~orchestration.sweeps.executor.local_workers` on the runs'
    expected length (:func:`~orchestration.sweeps.plan.expected_run_seconds`), else serial. A
    script that starts worker processes runs its code under ``if __name__ == "__main__":``
    (each process imports the main module again). ``stop``: asked before the first run and after each
    (Ctrl-C): when it returns True the sweep ends with KeyboardInterrupt (the finished runs are
    in the journal, and the same call continues the sweep). ``progress``: ``False`` (the
    default: silent), ``True`` (the runs finished, failed and left on stderr, and a line on
    what runs where) or a callable ``progress(fraction, label)`` told the fraction of the runs
    finished (:mod:`orchestration.report.progress`; a TypeError naming ``progress`` for
    anything else). Errors name the bad argument
    (:class:`~orchestration.scene.keys.ConfigError`, a ``ValueError``)."""
    check_progress(progress)
    if serial and (workers is not None or scheduler):
        raise ConfigError("serial runs here, one run after the other: it takes no workers or "
                          "scheduler")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ConfigError(f"workers = {workers!r} is not allowed; allowed: an integer >= 1")
    if workers is not None and scheduler:
        raise ConfigError("workers starts processes here, scheduler uses an existing dask "
                          "cluster: give one of them")
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ConfigError(f"batch = {batch!r} is not allowed; allowed: an integer >= 1")
    try:
        plan = plan_sweep(scene, grids=_items("grid", grid), values=_items("values", values),
                          samples=_items("sample", sample), n_samples=samples, seed=seed,
                          overrides=_overrides(overrides), reference=reference,
                          columns=columns)
    except ConfigError as exc:
        raise _in_python(exc) from None
    out_dir = check_folder(out)
    todo = pending(plan, out_dir, retry_failed)
    done = len({p.key for p in plan.points}) - todo
    say = note if progress is True else (lambda text: None)
    say(f"sweep of {plan.scene.name}: {len(plan.points)} runs"
        + (f", {done} already finished in {out_dir}" if done else ""))
    fmus = fmus_for(plan, progress is True)
    if not (serial or scheduler or workers is not None or todo == 0):
        seconds = sum(expected_run_seconds(p.scene, plan.reference) for p in plan.points) \
            / len(plan.points)
        workers = local_workers(todo, seconds) or None
        problem = workers and process_limits(workers)
        if problem:
            workers = None
            say(f"running here, one run after the other: {problem}")
        serial = workers is None
        if serial and not problem:
            say(f"running here, one run after the other: worker processes would not win "
                f"for {todo} run{'s' if todo != 1 else ''} of about {seconds:.2g} s on "
                f"{default_workers()} core{'s' if default_workers() != 1 else ''} (they "
                f"take about {PROCESS_START:g} s to start; --workers N starts them anyway)")
    if serial or todo == 0:
        executor = Executor()
    else:
        executor = open_executor(workers, scheduler,
                                 files=[f for pair in fmus.values() for f in pair.values()])
        if on_executor is not None:
            on_executor(executor)
    sink = None if progress is True else sink_for(progress, f"sweep of {plan.scene.name}")
    with executor:
        res = run_sweep(plan, fmus, out_dir, executor, batch=batch, retry_failed=retry_failed,
                        progress=sink or progress, stop=stop)
    if sink is not None:
        sink.finish()
    stats = sweep_stats(res.rows, plan.columns)
    design = design_worst_case(plan)
    if design is not None:
        stats["design_worst_case"] = design.to_json()
    record = {"command": command, **plan.describe(), "executor": executor.describe(),
              "batch": batch, "ran": res.ran, "skipped": res.skipped, "seconds": res.seconds,
              "stats": stats, "table": str(res.table),
              "plot": None if res.plot is None else str(res.plot)}
    write_json(out_dir / "sweep.json", record)
    return Sweep(plan, res, stats, record, executor.describe())


#: The command line's options of a sweep and the arguments of :func:`sweep` that take them.
_ARGUMENTS = {"--grid": "grid", "--values": "values", "--sample": "sample",
              "--samples": "samples", "--seed": "seed", "--set": "overrides",
              "--columns": "columns", "--reference": "reference=True"}


def _in_python(exc: ConfigError) -> ConfigError:
    """A plan's error (worded for the command line: ``--grid ...``) with the arguments of
    :func:`sweep` for the options; :attr:`ConfigError.cli` keeps the command line's words."""
    text = re.sub(r"(?<![\w-])--(grid|values|samples|sample|seed|set|columns|reference)(?![\w-])",
                  lambda m: _ARGUMENTS[m[0]], str(exc))
    out = type(exc)(text, cli=exc.cli)
    return out


def _items(option: str, spec) -> list:
    """``--grid``/``--values``/``--sample`` items from strings, a list of them, or a dict."""
    if spec is None:
        return []
    if isinstance(spec, str):
        return [spec]
    if isinstance(spec, dict):
        out = []
        for key, v in spec.items():
            if option == "grid":
                if not isinstance(v, (list, tuple)) or len(v) not in (3, 4):
                    raise ConfigError(f"grid[{key!r}] = {v!r}: expected (start, stop, num) or "
                                      "(start, stop, num, 'log')")
                out.append(f"{key}=" + ":".join(str(x) for x in v))
            elif option == "values":
                if isinstance(v, str) or not isinstance(v, (list, tuple)) or not v:
                    raise ConfigError(f"values[{key!r}] = {v!r}: expected a non-empty list")
                out.append(f"{key}=" + ",".join(toml_value(x) for x in v))
            else:
                out.append(f"{key}={v}")
        return out
    if not all(isinstance(x, str) for x in spec):
        raise TypeError(f"{option} must be a dict or a list of strings, got {spec!r}")
    return list(spec)


def _overrides(overrides) -> list:
    if isinstance(overrides, dict):
        return [f"{k}={toml_value(v)}" for k, v in overrides.items()]
    return list(overrides or ())
