"""Sweeps and uncertainty studies: many co-simulations of one scene, as tasks on dask.distributed
(:mod:`orchestration.sweeps.executor`), or one after the other in this process.

    flexpend sweep SCENE [--grid KEY=START:STOP:NUM[:log] ...] [--values KEY=V1,V2,...]
                         [--sample KEY=DIST ... --samples N --seed S] [--set KEY=VALUE ...]
                         [--reference] [--columns COL,COL,...]
                         [--workers N | --scheduler ADDRESS | --serial]
                         [--batch N] [--out DIR] [--retry-failed]

* **What varies.** Every scene key (``flexpend scenes``, the keys of ``flexpend run``) can be
  swept: ``--grid`` gives ``NUM`` values from ``START`` to ``STOP`` (geometric with ``:log``),
  ``--values`` a list; several of them make the full grid. ``--sample KEY=DIST`` draws ``--samples``
  random values, reproducibly from ``--seed`` (numpy's ``Generator``): ``DIST`` is
  ``uniform:LO:HI``, ``loguniform:LO:HI``, ``normal:MEAN:SD``, ``integers:LO:HI`` or ``design``,
  the key's range in the uncertainty set of ``flexpend design``
  (:meth:`orchestration.studies.design.UncertaintySet.sample`; ``--sample design`` draws its four keys
  ``plant.n_modes``, ``plant.zeta``, ``plant.EI``, ``plant.m`` together, and ``--set design.*``
  reshapes the set as in ``flexpend design``). Samples combine with a grid: every grid point gets
  the same samples.
* **Every point is validated before anything runs**: an unknown key, a bad spec or a value the
  scene refuses is a :class:`~orchestration.scene.keys.ConfigError` naming it (one line, exit 2).
* **One row per run** (:func:`summary_row` takes it from the run's summary): the swept values,
  ``status`` (``ok``; ``failed``: the co-simulation stopped or raised, with its ``message``;
  ``lost``: its worker died), the verdict, the fitted rates and frequencies, ``decay_rate`` (minus
  the largest fitted rate), max |F_c|, the error against the monolithic reference with
  ``--reference``, the master's time ``cosim_time`` and the whole task's ``wall_time``; beside
  the fits, the linearised loop's rates (:func:`linear_decay_rate`).
* **Only some columns** (``--columns``, :mod:`orchestration.sweeps.columns`): the table's result
  columns asked for, each run computing only what they need (no mode fit without a fit column).
* **Nothing finished is lost.** Each finished run is appended at once to ``DIR/runs.jsonl``;
  the table (``DIR/sweep.parquet`` with pyarrow, else ``DIR/sweep.csv``) is written from it at
  the end. A run is keyed by the digest of its whole resolved scene (and ``--reference``): a rerun
  with the same ``--out`` runs only the keys without an ``ok`` or ``failed`` row (with
  ``--retry-failed``, without an ``ok`` row).
* **Verdicts**: stable, unstable, or "undetermined" (no fit decides, too short a run, or stopped
  early), counted apart in the terminal, the table (``verdict``) and the plot.
* **Plots** (``DIR/sweep.png``): a heat map of the decay rate over a 2-D grid, line plots of
  the rates over a 1-D grid (each quantity on its own axis), a histogram of the decay rates of a
  sample.
"""
from .engine import *  # noqa: F401,F403
from .plan import *  # noqa: F401,F403
from .plot import plot_sweep  # noqa: F401
