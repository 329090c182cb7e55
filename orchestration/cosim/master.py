"""The co-simulation master, on fmpy's ``FMU2Slave`` (the paper's flowchart, Fig. 2).

Two layers, as in FMPy: :class:`Slave` wraps one FMU instance (typed start values, fast real
get/set on preallocated buffers, FMU state, guaranteed cleanup) and turns every FMI status above
warning into a :class:`CoSimulationError` in one place (:meth:`Slave._call`); :class:`Master`
steps the slaves, wired by variable name.

Coupling (one communication step ``[t_k, t_k+1]``; an FMU's input is held over its ``doStep``):

* ``jacobi``: every FMU gets inputs extrapolated from its sources' past outputs, then all step.
* ``gauss-seidel``: the first FMU (``first``) steps on extrapolated inputs, the second on inputs
  interpolated between the first FMU's outputs at ``t_k`` and ``t_k+1``.

* ``master.coupling = "hermite"`` (Gauss-Seidel): the FMUs' exact output derivatives instead of
  past samples: the Taylor polynomial at the step's start, or the Hermite polynomial through both
  ends of the step for an FMU that stepped first, each passed as its least-squares quadratic
  (:attr:`Coupling.hermite <orchestration.cosim.coupling.Coupling>`, :meth:`_hermite_inputs`).

With ``extrapolation`` order ``p`` the held value is the step average of the polynomial through
the last ``p + 1`` samples (``p = 0``: the newest sample, a zero-order hold). Because the input is
held constant over ``doStep`` (pythonfmu FMUs cannot interpolate inputs), the coupling error is of
order 1 for ``p = 0`` and 2 for ``p = 1`` and ``p = 2``; quadratic extrapolation only lowers the
error constant.

Adaptive communication step (``master.error_estimator``): ``extrapolation`` compares after each
step the predicted input polynomial at ``t_k+1`` with the source's actual output there, each
signal relative to its size, times the step (the state's local error,
:meth:`Master._coupling_error`); a step whose weighted error exceeds 1 is rolled back through
the FMU states and retried with a smaller step. ``energy`` takes ECCO's residual energy on the
force-cart bond (:meth:`Master._energy_error`) and never rolls back. A PI controller picks the
next step within ``[min_step, max_step]``. Output points are hit exactly, without slivers:
times are ``t0 + k*dt`` from integers.

The time grid: at a fixed step the signals' history is stamped with the step counters (the
extrapolation nodes are integers, their weights computed once, however long the run) and the FMUs
step from ``t0 + k*h`` over ``h``, as FMPy does; with an adaptive step it is stamped in seconds.
"""
from __future__ import annotations

import math
import time as _time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from fmu_common.kernels import KernelError

from ..scene.records import MasterSettings
from . import compiled as compiled_master
from . import compiled_adaptive
from .coupling import Coupling, _History, _weight_rows, hermite_rows, output_table, taylor_rows
from .slave import CoSimulationError, RunInterrupted

__all__ = ["RunStats", "Master"]


@dataclass
class RunStats:
    steps: int = 0
    rejected: int = 0
    min_step_used: float = math.inf
    max_step_used: float = 0.0
    forced_accepts: int = 0   # steps at min_step whose error still exceeded the tolerance
    wall_time: float = 0.0
    rejected_times: list = field(default_factory=list)
    #: which loop stepped: "compiled" (orchestration/cosim/native/fm_master.c) or "python"
    loop: str = "python"
    #: master.algorithm = "implicit" (orchestration/cosim/implicit.py): the interface's
    #: iterations summed over the steps and the most in one step; the FMU steps spent on
    #: difference Jacobians
    iterations: int = 0
    max_iterations: int = 0
    jacobian_steps: int = 0


class Master:
    """Steps FMUs wired by name.

    ``slaves``: name -> :class:`Slave`; ``connections``: :class:`Connection` list;
    ``record``: column -> (slave name, variable) to store at every output point; ``settings``:
    the scene's :class:`~orchestration.scene.records.MasterSettings` (the coupling), with
    ``changes`` to its fields applied (``Master(..., step=1e-3)``).

    ``settings.compiled``: ``"auto"`` (default) runs a fixed-step run in C
    (:mod:`orchestration.cosim.compiled`), and an adaptive one in C
    (:mod:`orchestration.cosim.compiled_adaptive`), when every FMU can take it (FMI 2.0 FMUs that
    need no execution tool: the native FMUs) and in Python otherwise; ``False`` always in Python;
    ``True`` in C or a ValueError saying why not. The fixed-step loops give bit-identical
    results, the adaptive ones agree to a few units in the last place (their extrapolation
    weights solve a Vandermonde system, numpy's by LAPACK);
    :attr:`loop` says which one runs.
    """

    def __init__(self, slaves: dict, connections, record: dict,
                 settings: MasterSettings | None = None, **changes):
        settings = settings or MasterSettings()
        if changes:
            settings = replace(settings, **changes)
        compiled = settings.compiled
        self.settings = settings
        self.slaves = slaves
        #: the coupling both loops step (order, inputs, extrapolation, start-up)
        self.coupling = coupling = Coupling(slaves, connections, record, settings)
        coupling.bind(slaves)
        self.record = coupling.record
        self.h = settings.step
        self.adaptive = settings.adaptive
        self.tol = settings.tolerance
        self.min_step, self.max_step = settings.min_step, settings.max_step
        if self.adaptive and settings.error_estimator == "energy":
            fsrc, fvar, xsrc, xvar = self.BOND
            if (fvar not in coupling.out_index.get(fsrc, {})
                    or xvar not in coupling.out_index.get(xsrc, {})):
                raise ValueError(f"master.error_estimator = 'energy' needs the outputs "
                                 f"{fsrc}.{fvar} and {xsrc}.{xvar} connected; allowed here: "
                                 "'extrapolation'")
        self._in_buf = {n: np.zeros(len(coupling.inputs[n]) * (1 + coupling.n_der[n]))
                        for n in slaves}
        #: the strongly coupled step (master.algorithm = "implicit"), None otherwise
        self.implicit = None
        if settings.algorithm == "implicit":
            from .implicit import InterfaceIteration
            self.implicit = InterfaceIteration(self)
        # the compiled loop of this run: the adaptive and implicit ones, or the fixed-step one
        other = self.adaptive or self.implicit is not None
        backend = compiled_adaptive if other else compiled_master
        #: why the compiled loop cannot run these FMUs (None: it can)
        self.compiled_unavailable = (compiled_adaptive.unavailable(coupling, slaves) if other
                                     else compiled_master.unavailable(coupling, slaves, False))
        if compiled and not self.compiled_unavailable:
            try:
                backend.load()               # before any run
            except KernelError as exc:       # missing or stale library of a broken install
                self.compiled_unavailable = f"the compiled loop's library does not load: {exc}"
                if compiled == "auto":
                    warnings.warn(f"{self.compiled_unavailable}; the Python loop runs",
                                  RuntimeWarning, stacklevel=2)
        if compiled is True and self.compiled_unavailable:
            raise ValueError(f"compiled = True, but {self.compiled_unavailable}")
        #: the loop :meth:`run` uses: "compiled" or "python"
        self.loop = "compiled" if compiled and not self.compiled_unavailable else "python"
        #: the history's clock: a sample stamped ``a`` is at ``_origin + a * _unit`` seconds
        #: (:meth:`run` sets it: steps from t0 at a fixed step, seconds with an adaptive one)
        self._origin, self._unit = 0.0, 1.0

    def connection_table(self) -> str:
        return self.coupling.table()

    # ------------------------------------------------------------------ stepping
    def _time(self, a) -> float:
        """The time in seconds of the history's stamp ``a``."""
        return self._origin + a * self._unit

    def _combination(self, h: "_History", t, scale, kinds: tuple):
        """Rows ``kinds`` (``"average"`` over ``[t, t + scale]``, or the ``j``-th derivative at
        ``t``) of the polynomial through the newest ``p + 1`` samples of ``h`` (fewer at the
        start): an array ``len(kinds) x outputs``, derivatives in seconds. ``t`` and ``scale``
        are on the history's clock (:meth:`_time`): at a fixed step the nodes are integers."""
        unit = self._unit
        if h.derivatives:                   # the Taylor polynomial at the newest sample
            q = h.derivatives
            Y = h.u[-1].reshape(q + 1, -1)
            W = taylor_rows((t - h.t[-1]) * unit, kinds, scale * unit, q)
            acc = W[:, 0:1] * Y[0]
            for j in range(1, q + 1):
                acc = acc + W[:, j:j + 1] * Y[j]
            return acc
        k = min(self.coupling.p + 1, len(h.t))
        ts = h.t
        if k == 1:
            tau = (round((ts[-1] - t) / scale, 9),)
        elif k == 2:
            tau = (round((ts[-2] - t) / scale, 9), round((ts[-1] - t) / scale, 9))
        else:
            tau = (round((ts[-3] - t) / scale, 9), round((ts[-2] - t) / scale, 9),
                   round((ts[-1] - t) / scale, 9))
        W = _weight_rows(tau, kinds, scale * unit)
        if k == 1:
            return W * h.u[-1]
        # summed left to right, one rounding per operation (a matrix product would go to BLAS,
        # whose order and fused multiply-adds depend on the CPU): the compiled loop sums the same
        u = h.u
        acc = W[:, 0:1] * u[-k]
        for i in range(1, k):
            acc = acc + W[:, i:i + 1] * u[i - k]
        return acc

    def _fill(self, dst, hist, t, scale, kinds):
        """The inputs of ``dst`` from the sources' polynomials: value rows, then derivative
        rows, as bound (``kinds[j]`` fills the ``j``-th block of ``len(inputs)`` entries)."""
        buf = self._in_buf[dst]
        nk = len(kinds)
        for src, pos, idx in self.coupling.gather[dst]:
            buf[self.coupling.targets[dst, src, nk]] = self._combination(hist[src], t, scale, kinds)[:, idx]
        return buf

    def _held_inputs(self, dst, hist, t0, t1):
        """Input values for ``dst`` over ``[t0, t1]`` (on the history's clock): the polynomials'
        step averages, held; or, for a slave taking input derivatives, the polynomials at ``t0``
        and their derivatives (the FMU integrates the polynomial over its step)."""
        if self.coupling.hermite:
            return self._hermite_inputs(dst, hist, t0, t1)
        return self._fill(dst, hist, t0, t1 - t0, self.coupling.kinds[dst])

    _KIND_ROW = {"average": 0, 0: 1, 1: 2, 2: 3}     # hermite_rows' rows

    def _hermite_inputs(self, dst, hist, t0, t1):
        """The Hermite coupling's inputs for ``dst`` over ``[t0, t1]``: per source, the
        least-squares quadratic over the step of its Taylor polynomial at ``t0`` (its newest
        sample), or, when it stepped earlier in this step (its newest sample at ``t1``), of the
        Hermite polynomial through its samples at ``t0`` and ``t1`` (:func:`hermite_rows`);
        summed left to right, as the compiled loop sums."""
        buf = self._in_buf[dst]
        kinds = self.coupling.kinds[dst]
        rows = [self._KIND_ROW[k] for k in kinds]
        scale = (t1 - t0) * self._unit
        for src, pos, idx in self.coupling.gather[dst]:
            h = hist[src]
            q = h.derivatives
            if h.t[-1] == t0:
                ys = list(h.u[-1].reshape(q + 1, -1))
                W = hermite_rows(q, False, scale)
            else:
                ys = [*h.u[-2].reshape(q + 1, -1), *h.u[-1].reshape(q + 1, -1)]
                W = hermite_rows(q, True, scale)
            W = W[rows]
            acc = W[:, 0:1] * ys[0]
            for j in range(1, len(ys)):
                acc = acc + W[:, j:j + 1] * ys[j]
            buf[self.coupling.targets[dst, src, len(kinds)]] = acc[:, idx]
        return buf

    def _sample_inputs(self, dst, samples: dict):
        """The inputs of ``dst`` at an instant from its sources' ``samples`` (outputs, then their
        derivatives): the values, and the derivatives of the orders ``dst`` takes (0 beyond the
        source's)."""
        c = self.coupling
        nd = c.n_der[dst] if c.interpolates[dst] else 0
        buf = np.zeros(len(c.inputs[dst]) * (1 + nd))
        for src, pos, idx in c.gather[dst]:
            q = c.out_der[src]
            y = np.asarray(samples[src], dtype=float).reshape(q + 1, -1)
            rows = np.zeros((1 + nd, y.shape[1]))
            rows[:min(q, nd) + 1] = y[:min(q, nd) + 1]
            buf[c.targets[dst, src, 1 + nd]] = rows[:, idx]
        return buf

    def _point_inputs(self, dst, hist, t1):
        """Input values for ``dst`` at the instant ``t1`` (the sources' polynomials there; only
        the first ``len(self.coupling.inputs[dst])`` entries, the values, are meant)."""
        return self._fill(dst, hist, t1, self.h / self._unit, (0,))

    def _outputs_after_step(self, n, hist, t1):
        """Outputs of slave ``n`` at ``t1``. A feedthrough slave's output read right after
        ``doStep`` reflects the held (step-average) input, i.e. the middle of the step; its
        inputs are first moved to their values at ``t1``, so that every sample of the history
        belongs to its time stamp."""
        s = self.slaves[n]
        t = self._time(t1)
        c = self.coupling
        if c.hermite and c.inputs[n] and all(hist[src].t[-1] == t1 for src, _, _ in c.gather[n]):
            # every source has stepped: the inputs' values and derivatives at t1 (the controller
            # FMU's output derivatives then use them: its F_c's are those of the sources' exact
            # rates; the plant FMU's keep its step's input polynomial at its end)
            s.set_inputs(self._sample_inputs(n, {src: hist[src].u[-1]
                                                 for src, _, _ in c.gather[n]}), t)
            return s.get_outputs(t)
        if s.feedthrough and self.coupling.inputs[n]:
            s.set_inputs(self._point_inputs(n, hist, t1), t, n=len(self.coupling.inputs[n]))
        return s.get_outputs(t)

    def _macro_step(self, hist, t0, t1):
        """One communication step from ``t0`` to ``t1`` on the history's clock; returns the new
        outputs of every slave."""
        ta, h = self._time(t0), (t1 - t0) * self._unit
        new = {}
        if self.coupling.algorithm == "jacobi":
            for n in self.coupling.order:
                self.slaves[n].set_inputs(self._held_inputs(n, hist, t0, t1), ta)
            for n in self.coupling.order:
                self.slaves[n].do_step(ta, h)
            sampled = [n for n in self.coupling.order if self.slaves[n].sampled]
            for n in self.coupling.order:
                if n not in sampled:
                    new[n] = self._outputs_after_step(n, hist, t1)
            if sampled:
                # a sampled controller's force at a tick is a feedthrough of the sensors there:
                # read it with its inputs at the others' outputs at t1 (held: exact)
                for n in new:
                    hist[n].push(t1, new[n])
                try:
                    for n in sampled:
                        new[n] = self._outputs_after_step(n, hist, t1)
                finally:
                    for n in list(new):
                        if n not in sampled:
                            hist[n].pop()
        else:
            pushed, replaced = [], []
            for n in self.coupling.order:
                self.slaves[n].set_inputs(self._held_inputs(n, hist, t0, t1), ta)
                self.slaves[n].do_step(ta, h)
                new[n] = self._outputs_after_step(n, hist, t1)
                # later slaves interpolate between t0 and t1
                if hist[n].t and hist[n].t[-1] == t1:   # a predicted sample (_startup_step)
                    replaced.append((n, hist[n].u[-1]))
                    hist[n].u[-1] = new[n]
                else:
                    hist[n].push(t1, new[n])
                    pushed.append(n)
            for n in pushed:                # undo: the caller pushes all at once
                hist[n].pop()
            for n, u in replaced:
                hist[n].u[-1] = u
        return new

    def _startup_step(self, hist, t0, t1):
        """The first step with extrapolation: with one sample per signal the inputs would be
        held at their initial values, an O(h) error over one step that leaves an O(h^2)
        global error, and caps higher-order couplings at order 2. So the step is predicted
        (held inputs), rolled back through the FMU states, and taken again with inputs
        interpolated between the samples at ``t0`` and the predicted ones at ``t1``."""
        states = {n: s.get_state() for n, s in self.slaves.items()}
        try:
            predicted = self._macro_step(hist, t0, t1)
            for n in self.slaves:
                hist[n].push(t1, predicted[n])
            for n, s in self.slaves.items():
                s.set_state(states[n])
            new = self._macro_step(hist, t0, t1)
            for n in self.slaves:
                hist[n].pop()
        finally:
            for n, s in self.slaves.items():
                s.free_state(states[n])
        return new

    def _step(self, hist, t0, t1):
        if self.implicit is not None:
            return self.implicit.step(hist, t0, t1)
        if self.coupling.correct_startup and len(hist[self.coupling.order[0]].t) == 1:
            return self._startup_step(hist, t0, t1)
        return self._macro_step(hist, t0, t1)

    def _coupling_error(self, hist, new, t1, step):
        """The coupling's local error estimate, weighted (1 = at the tolerance): the predicted
        source outputs at ``t1`` against the actual ones, each signal scaled by ``tolerance``
        times its size: the largest magnitude it has had, at least its source's largest output
        before the step (a signal starting at 0), at least its change over one scene step at its
        present rate (a signal rising from 0 as ``t^n``, whose relative error does not fall
        with the step); a force through zero does not blow up, a small angle is not swamped by
        an absolute floor. Times ``step / master.step``: a jump or noise in an output that no
        step resolves cannot drive the step to ``min_step``. The state's error after the step is
        the input's error integrated over the step, one order above the input's: ``p + 2`` for
        an order-p polynomial (see :meth:`_run_adaptive`). The first step (one sample) is taken
        at the scene's step unchecked."""
        err = 0.0
        for src in dict.fromkeys(c.src for c in self.coupling.connections):
            pred = self._combination(hist[src], t1, self.h, (0,))[0]
            actual = new[src][:len(pred)]
            # a signal starting at 0 takes its source's largest output before the step; a
            # source whose outputs have all been 0 so far has no scale: not estimated
            floor = float(np.max(self._peak[src]))
            peak = self._peak[src] = np.maximum(self._peak[src], np.abs(actual))
            if floor == 0.0:
                continue
            # a signal rising from 0 has a relative error that does not fall with the step
            # (t^n is self-similar): its size is at least what it changes over the scene's step
            rate = np.abs(actual - hist[src].u[-1][:len(pred)]) * (self.h / step)
            scale = self.tol * np.maximum(np.maximum(peak, floor), rate)
            err = max(err, float(np.max(np.abs(pred - actual) / scale)))
        return err * step / self.h

    #: the force-cart power bond of :meth:`_energy_error`: (force source, force, position source,
    #: position); the work of the force over a step is ``F * dx`` exactly for a held force
    BOND = ("controller", "F_c", "plant", "x_o")

    def _energy_error(self, hist, new, t1, step):
        """ECCO's residual energy on the force-cart power bond (Sadjina et al. 2017), weighted:
        the work the controller's force does on the cart as the controller sees the cart move
        (its extrapolation of ``x_o`` to ``t1``) against the work it does as the cart really
        moves, ``|F_mean * (x_pred - x)|``, plus, where the plant's force is extrapolated, the
        force's error times the cart's travel. Scaled by ``tolerance`` times the work through the
        bond so far, at least the step's work over one ``master.step``."""
        fsrc, fvar, xsrc, xvar = self.BOND
        i_f, i_x = self.coupling.out_index[fsrc][fvar], self.coupling.out_index[xsrc][xvar]
        f0, f1 = hist[fsrc].u[-1][i_f], new[fsrc][i_f]
        x0, x1 = hist[xsrc].u[-1][i_x], new[xsrc][i_x]
        x_pred = self._combination(hist[xsrc], t1, self.h, (0,))[0][i_x]
        f_mean = 0.5 * (f0 + f1)
        residual = abs(f_mean * (x_pred - x1))
        if self.coupling.algorithm == "jacobi" or self.coupling.order[0] == xsrc:
            f_pred = self._combination(hist[fsrc], t1, self.h, (0,))[0][i_f]
            residual += 0.5 * abs((f_pred - f1) * (x1 - x0))
        work = abs(f_mean * (x1 - x0))
        self._work += work
        scale = self.tol * max(self._work, work * self.h / step, 1e-300)
        return residual / scale

    def _initial_outputs(self, t0):
        """Consistent outputs at ``t0``: the sources' initial outputs are passed to the inputs
        (in coupling order, twice, which settles any chain without an algebraic loop) before a
        feedthrough output is read."""
        cur = {n: s.get_outputs(t0) for n, s in self.slaves.items()}
        for _ in range(2):
            for n in self.coupling.order:
                if self.coupling.inputs[n] and self.coupling.hermite:
                    # the sources' output derivatives as the input derivatives
                    self.slaves[n].set_inputs(self._sample_inputs(n, cur), t0)
                    cur[n] = self.slaves[n].get_outputs(t0)
                elif self.coupling.inputs[n]:
                    vals = np.zeros(self._in_buf[n].size)     # input derivatives 0
                    vals[:len(self.coupling.inputs[n])] = [cur[c.src][self.coupling.out_index[c.src][c.src_var]]
                                                  for c in self.coupling.inputs[n]]
                    self.slaves[n].set_inputs(vals, t0)
                    cur[n] = self.slaves[n].get_outputs(t0)
        return cur

    def run(self, t0: float, stop_time: float, output_interval: float, progress=None, stop=None):
        """Run from ``t0`` to ``stop_time``; a structured array (time first) and :class:`RunStats`.

        ``stop``: a callable asked after every communication step; when it returns True the run
        ends with :class:`RunInterrupted`. On a failed FMU call the :class:`CoSimulationError`
        (and a :class:`RunInterrupted`) carries the rows of the output points reached so far."""
        wall = _time.perf_counter()
        stats = RunStats()
        if self.implicit is not None:               # a new run: no Jacobian, no counts
            self.implicit = type(self.implicit)(self)
        out = output_table(self.record, t0, stop_time, output_interval)
        n_out = len(out) - 1
        self._rows = 0
        self._t_reached = t0
        # the history's clock: steps from t0 at a fixed step, seconds with an adaptive one
        self._origin, self._unit = (0.0, 1.0) if self.adaptive else (t0, self.h)
        try:
            for s in self.slaves.values():
                s.initialize(t0, stop_time)
            hist = {n: _History(3, self.coupling.out_der[n]) for n in self.slaves}
            cur = self._initial_outputs(t0)
            for n in self.slaves:
                hist[n].push(t0 if self.adaptive else 0, cur[n])
            self._store(out, 0, t0, cur)
            if self.adaptive and self.loop == "compiled":
                stats.loop = "compiled"
                run = compiled_adaptive.AdaptiveRun(self, cur, t0, output_interval, n_out, out)
                try:
                    run.run(stats, progress, stop)
                finally:
                    self._rows = max(self._rows, run.rows_written)
                    self._t_reached = run.t_reached
            elif self.adaptive:
                self._run_adaptive(t0, output_interval, n_out, out, hist, cur, stats, progress,
                                   stop)
            else:
                m = int(round(output_interval / self.h))
                if abs(m * self.h - output_interval) > 1e-9 * output_interval:
                    raise ValueError(f"output_interval = {output_interval} is not a multiple of "
                                     f"step = {self.h}")
                total = n_out * m
                if self.loop == "compiled":
                    stats.loop = "compiled"
                    run = (compiled_adaptive.ImplicitRun(self, self.implicit, cur, t0, m, total,
                                                         out) if self.implicit is not None else
                           compiled_master.CompiledRun(self.coupling, self.slaves, hist, t0, m,
                                                       total, out))
                    try:
                        run.run(stats, progress, stop)
                    finally:
                        self._rows = max(self._rows, run.rows_written)
                        self._t_reached = run.t_reached
                else:
                    self._run_fixed(t0, m, total, out, hist, stats, progress, stop)
                stats.min_step_used = stats.max_step_used = self.h
        except (CoSimulationError, RunInterrupted) as exc:
            self._count_iterations(stats)
            stats.wall_time = _time.perf_counter() - wall
            exc.result, exc.stats = out[:self._rows].copy(), stats
            if exc.time is None:
                exc.time = self._t_reached
            raise
        self._count_iterations(stats)
        stats.wall_time = _time.perf_counter() - wall
        return out, stats

    def _count_iterations(self, stats):
        if self.implicit is not None:
            it = self.implicit
            stats.iterations, stats.max_iterations = it.iterations, it.max_iterations
            stats.jacobian_steps = it.jacobian_steps

    def _run_fixed(self, t0, m, total, out, hist, stats, progress, stop):
        """The fixed-step loop in Python (the compiled loop's twin): ``total`` steps of ``h``
        from ``t0``, the history stamped with the step counters, a row every ``m`` steps."""
        for k in range(total):
            tb = t0 + (k + 1) * self.h
            cur = self._step(hist, k, k + 1)
            for n in self.slaves:
                hist[n].push(k + 1, cur[n])
            stats.steps += 1
            self._t_reached = tb
            if (k + 1) % m == 0:
                self._store(out, (k + 1) // m, tb, cur)
                if progress is not None:
                    progress((k + 1) / total)
            if stop is not None and stop():
                raise RunInterrupted(tb)

    def _run_adaptive(self, t0, dt_out, n_out, out, hist, cur, stats, progress, stop=None):
        """Steps of ``h`` within ``[min_step, max_step]``, chosen by a PI controller
        (Gustafsson; Hairer & Wanner II, IV.2) on :meth:`_coupling_error` of order
        ``k = min(p + 1, samples) + 1``: ``h_new = h * 0.9 * err**(-0.7/k) * err_prev**(0.4/k)``,
        growth at most 5, shrink at least 0.2. A rejected step is retried with the I-part alone
        (no rollback loop on stale history). Output points are hit exactly without slivers: a
        remainder under two steps is split in two equal ones, and the step chosen before an
        output point is kept after it."""
        h = min(self.h, self.max_step)
        t = t0
        err_prev = 1.0
        # the outputs' values (with output derivatives, their derivatives follow them)
        self._peak = {n: np.abs(np.asarray(cur[n], dtype=float))[:len(self.coupling.outputs[n])]
                      for n in self.slaves}
        self._work = 0.0
        # the energy residual is never rolled back (ECCO): it only sets the next step
        rollback = self.settings.error_estimator == "extrapolation"
        estimate = self._coupling_error if rollback else self._energy_error
        for j in range(1, n_out + 1):
            t_target = t0 + j * dt_out
            while t < t_target - 1e-12 * dt_out:
                rest = t_target - t
                last = rest <= h * (1 + 1e-9)
                t1 = t_target if last else t + (min(h, 0.5 * rest) if rest < 2 * h else h)
                if rollback:                  # what a rejected step restores
                    states = {n: s.get_state() for n, s in self.slaves.items()}
                    snaps = {n: hist[n].snapshot() for n in self.slaves}
                    peaks = {n: v.copy() for n, v in self._peak.items()}
                else:
                    states = {}
                step = t1 - t
                try:
                    new = self._step(hist, t, t1)
                    err = estimate(hist, new, t1, step)
                    discarded = False
                except CoSimulationError as exc:
                    if exc.status != 2 or not rollback:   # only Discard is retried
                        for n, state in states.items():
                            self.slaves[n].free_state(state)
                        raise
                    err, discarded = math.inf, True
                k = min(self.coupling.p + 1, len(hist[self.coupling.order[0]].t)) + 1
                if rollback and err > 1.0 and step > self.min_step * (1 + 1e-9):
                    stats.rejected += 1
                    stats.rejected_times.append(t)
                    for n, s in self.slaves.items():
                        s.set_state(states[n])
                        s.free_state(states[n])
                        hist[n].restore(snaps[n])
                    self._peak = peaks
                    factor = 0.5 if discarded else min(0.9, max(0.2, 0.9 * err ** (-1.0 / k)))
                    h = max(self.min_step, step * factor)
                    continue
                if discarded:
                    raise CoSimulationError(f"an FMU discarded the step at t = {t:.6g} even at "
                                            f"min_step = {self.min_step}", status=2, time=t)
                if err > 1.0 and rollback:
                    stats.forced_accepts += 1
                for n, state in states.items():
                    self.slaves[n].free_state(state)
                for n in self.slaves:
                    hist[n].push(t1, new[n])
                cur = new
                stats.steps += 1
                stats.min_step_used = min(stats.min_step_used, step)
                stats.max_step_used = max(stats.max_step_used, step)
                t = t1
                self._t_reached = t1
                if stop is not None and stop():
                    if abs(t1 - t_target) <= 1e-12 * dt_out:
                        self._store(out, j, t_target, cur)
                    raise RunInterrupted(t1)
                e = max(err, 1e-10)
                # without rollback (energy) a step is at most halved: no retry catches an outlier
                grow = min(5.0, max(0.2 if rollback else 0.5,
                                    0.9 * e ** (-0.7 / k) * err_prev ** (0.4 / k)))
                err_prev = e
                h_new = step * grow           # a shortened step (an output point) shrinks
                h = h_new if step >= h * (1 - 1e-9) else (min(h, h_new) if grow < 1 else
                                                         max(h, h_new))
                h = min(self.max_step, max(self.min_step, h))
            t = t_target
            self._store(out, j, t_target, cur)
            if progress is not None:
                progress(j / n_out)

    def _store(self, out, i, t, cur):
        """Row ``i``: time, then the recorded outputs (the slaves are at ``t``)."""
        rec = {n: (dict(zip(self.coupling.recorded[n], s.get_recorded(t).tolist()))
                   if self.coupling.recorded[n] else {}) for n, s in self.slaves.items()}
        row = [t]
        for col, (s, v) in self.record.items():
            i_out = self.coupling.out_index[s].get(v)
            row.append(cur[s][i_out] if i_out is not None else rec[s][v])
        out[i] = tuple(row)
        self._rows = max(self._rows, i + 1)

    def close(self):
        for s in self.slaves.values():
            s.close()

