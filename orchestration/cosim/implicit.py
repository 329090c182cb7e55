"""The strongly coupled communication step (``master.algorithm = "implicit"``).

Each step ``[t_k, t_k+1]`` iterates the interface: the unknowns ``u`` are every exchanged output
at ``t_k+1``. An iterate is pushed as the sources' sample at ``t_k+1``, so that every FMU's
inputs over the step are the polynomial through its source's samples up to ``t_k+1``
(``master.extrapolation`` = 1: the line between ``t_k`` and ``t_k+1``; 2: the parabola through
``t_k-1 .. t_k+1``; 0: the value at ``t_k+1``, held), passed as input derivatives (or held as the
step average) exactly as the explicit couplings pass theirs. Every FMU then steps from the
step's start (its FMU state restored, except in the step's first evaluation, where it is still
there) and gives its outputs at ``t_k+1``: ``G(u)``. The step is
converged when ``|G(u) - u| <= implicit_tolerance * max(1, |G(u)|)`` for every output (the
adaptive master's scaling of its error); the FMUs are then at ``t_k+1`` with the inputs ``u``
and their outputs ``G(u)`` are the new samples. ``master.max_iterations`` evaluations of ``G``
without convergence stop the run with one line naming the time and the residual.

The unknowns (``master.implicit_scheme``):

* ``"parallel"``: every exchanged output; every FMU steps on the assumed values (block Jacobi).
* ``"serial"``: only the outputs fed back to an FMU at or before their source in the coupling
  order (``master.first`` first); the FMUs step one after the other, each later one on the
  earlier ones' new outputs (block Gauss-Seidel; preCICE's serial-implicit coupling). The two
  solve the same equations; the serial scheme has fewer unknowns, and with the plant first
  its one unknown is the controller's force, a low-pass filter's output that extrapolates far
  better than the tip rate with its bending: about 2 iterations per step where the parallel
  scheme takes 2.3 to 2.8 (the filtered scene at 2 ms).

The update (``master.implicit_jacobian``):

* ``"newton"``: ``u <- u - (J - I)^-1 (G(u) - u)`` with ``J = dG/du``, the sensitivity of the
  FMUs' outputs at ``t_k+1`` to the interface values they were driven with over the step. A
  co-simulation FMU's directional derivatives (FMI 2.0 ``fmi2GetDirectionalDerivative`` on the
  co-simulation interface) give the outputs' partial derivatives at one instant, not the
  sensitivity of a step, so ``J`` is formed by forward differences of the FMU step through state
  restore: one extra step of the FMUs fed by a source per unknown output of that source (in
  the serial scheme of every FMU). ``J`` is kept from step to step, corrected after every
  iteration by Broyden's update with the iteration's secant (``J du = dg`` for the change
  ``du`` of the interface and ``dg`` of the outputs: what the step taught about ``G`` as the
  state moves on), and formed again only when an iteration fails to cut the residual tenfold
  (for a linear plant at a fixed step ``G`` is affine with a constant ``J``: it is formed once,
  and the secants leave it as it is up to rounding).
* ``"iqn-ils"``: interface quasi-Newton with an inverse Jacobian from least squares (Degroote,
  Bathe and Vierendeels 2009; preCICE's IQN-ILS). It needs no derivative from the FMUs: from the
  differences ``V`` of the residuals and ``W`` of the outputs ``G`` between the iterates,
  ``alpha = argmin |V alpha + r|`` and ``u <- G(u) + W alpha``; the columns of the last
  :data:`REUSED_STEPS` steps are reused (preCICE's reused time windows); without any column the
  first update is a relaxed fixed-point step ``u + INITIAL_RELAXATION r``.

The first guess of a step is the unknown sources' polynomials extrapolated to ``t_k+1``.

This module is the specification: with FMUs the compiled loop takes, ``master.compiled``
(``auto``) runs the same iteration in C (:class:`orchestration.cosim.compiled_adaptive.
ImplicitRun`), which reports its counts into this class.
"""
from __future__ import annotations

import math

import numpy as np

from .slave import CoSimulationError

__all__ = ["InterfaceIteration", "REUSED_STEPS", "INITIAL_RELAXATION"]

#: IQN-ILS: the steps whose difference columns are reused
REUSED_STEPS = 8
#: IQN-ILS: the relaxation of the first update when no column is known
INITIAL_RELAXATION = 0.5
#: Newton: the forward-difference step, relative to max(1, |u|)
_FD_STEP = 1e-6


def _broyden(J, du, dg):
    """Broyden's (good) update of ``J`` in place: ``J += (dg - J du) du^T / (du . du)``, the
    least change that makes ``J du = dg``. Written out element by element, in the compiled
    loop's order, so that both loops round alike."""
    n = len(du)
    dd = 0.0
    for j in range(n):
        dd = dd + du[j] * du[j]
    if not dd > 0.0:
        return
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc = acc + J[i, j] * du[j]
        c = (dg[i] - acc) / dd
        for j in range(n):
            J[i, j] = J[i, j] + c * du[j]


class InterfaceIteration:
    """The implicit step of ``master`` (a :class:`~orchestration.cosim.master.Master`); its
    counters feed :class:`~orchestration.cosim.master.RunStats` (``iterations``,
    ``max_iterations``, ``jacobian_steps``)."""

    def __init__(self, master):
        self.m = master
        c = master.coupling
        s = master.settings
        self.tol, self.cap, self.method = s.implicit_tolerance, s.max_iterations, \
            s.implicit_jacobian
        self.serial = s.implicit_scheme == "serial"
        #: the slaves whose outputs are exchanged
        self.sources = [n for n in c.order if c.outputs[n]]
        #: the slaves fed by each source
        self.consumers = {n: [d for d in c.order if any(x.src == n for x in c.inputs[d])]
                          for n in self.sources}
        #: the sources whose outputs are unknowns (all, or in the serial scheme those feeding a
        #: slave at or before them in the coupling order), each one's slice of ``u``
        self.unknowns = [n for n in self.sources if not self.serial or any(
            c.order.index(d) <= c.order.index(n) for d in self.consumers[n])]
        sizes = [len(c.outputs[n]) for n in self.unknowns]
        ends = np.cumsum([0] + sizes)
        self.slices = {n: slice(int(a), int(b)) for n, a, b in zip(self.unknowns, ends, ends[1:])}
        self.size = int(ends[-1])
        self.J = None
        self._V, self._W = [], []        # IQN-ILS: columns per past step (lists of arrays)
        self.iterations = self.max_iterations = self.jacobian_steps = 0

    # ------------------------------------------------------------------ one evaluation of G
    def _evaluate(self, hist, snaps, states, t0, t1, u, names, at_start):
        """The outputs at ``t1`` of ``names`` stepped from their states at ``t0`` with the
        interface ``u`` as the sources' samples at ``t1``; a dict name -> outputs. ``at_start``:
        the slaves not stepped since their state was taken, which need no restore (the step's
        first evaluation); a slave leaves it when it steps."""
        m = self.m
        ta, h = m._time(t0), (t1 - t0) * m._unit
        for n in self.sources:
            hist[n].restore(snaps[n])
            if n in self.slices:
                hist[n].push(t1, u[self.slices[n]])
        try:
            out = {}
            for n in names:
                s = m.slaves[n]
                if n in at_start:
                    at_start.discard(n)
                else:
                    s.set_state(states[n])
                s.set_inputs(m._held_inputs(n, hist, t0, t1), ta)
                s.do_step(ta, h)
                if self.serial:             # the slaves after it step on its new outputs
                    out[n] = m._outputs_after_step(n, hist, t1)
                    if n in self.consumers and n not in self.slices:
                        hist[n].push(t1, out[n][:len(m.coupling.outputs[n])])
            return out if self.serial else {n: m._outputs_after_step(n, hist, t1)
                                            for n in names}
        finally:
            for n in self.sources:
                hist[n].restore(snaps[n])

    def _residual(self, g, u):
        """The scaled residual: ``max |g - u| / (tol * max(1, |g|))``."""
        if not self.size:
            return 0.0
        return float(np.max(np.abs(g - u) / (self.tol * np.maximum(1.0, np.abs(g)))))

    def _stack(self, new):
        return np.concatenate([new[n][:self.slices[n].stop - self.slices[n].start]
                               for n in self.unknowns]) if self.size else np.zeros(0)

    # ------------------------------------------------------------------ updates
    def _jacobian(self, hist, snaps, states, t0, t1, u, g, at_start):
        """``dG/du`` by forward differences of the step (only the consumers of the perturbed
        source step again; in the serial scheme every slave)."""
        J = np.zeros((self.size, self.size))
        for src in self.unknowns:
            names = self.m.coupling.order if self.serial else self.consumers[src]
            for j in range(self.slices[src].start, self.slices[src].stop):
                d = _FD_STEP * max(1.0, abs(u[j]))
                up = u.copy()
                up[j] += d
                out = self._evaluate(hist, snaps, states, t0, t1, up, names, at_start)
                self.jacobian_steps += len(names)
                col = g.copy()
                for n in names:
                    if n in self.slices:
                        col[self.slices[n]] = out[n][:self.slices[n].stop - self.slices[n].start]
                J[:, j] = (col - g) / d
        return J

    def _iqn(self, u, g, r, V, W):
        """The IQN-ILS update from this step's columns ``V``, ``W`` and the reused ones."""
        cols_v = [v for step in self._V for v in step] + V
        cols_w = [w for step in self._W for w in step] + W
        if not cols_v:
            return u + INITIAL_RELAXATION * r
        Vm, Wm = np.column_stack(cols_v), np.column_stack(cols_w)
        scale = 1.0 / np.maximum(1.0, np.abs(g))
        alpha = np.linalg.lstsq(Vm * scale[:, None], -r * scale, rcond=1e-12)[0]
        return g + Wm @ alpha

    # ------------------------------------------------------------------ the step
    def step(self, hist, t0, t1) -> dict:
        """One converged communication step from ``t0`` to ``t1`` (the history's clock); the
        new outputs of every slave (the caller pushes them)."""
        m = self.m
        order = m.coupling.order
        snaps = {n: hist[n].snapshot() for n in m.slaves}
        states = {}
        try:
            for n, s in m.slaves.items():     # the states taken are freed however it ends
                states[n] = s.get_state()
            at_start = set(states)
            u = self._stack({n: m._combination(hist[n], t1, m.h / m._unit, (0,))[0]
                             for n in self.unknowns})
            V, W = [], []
            prev = None                  # (r, g) of the previous iteration (IQN-ILS)
            last = None                  # (u, g) of the previous iteration (Newton)
            err_prev, fresh = math.inf, False
            for it in range(1, self.cap + 1):
                new = self._evaluate(hist, snaps, states, t0, t1, u, order, at_start)
                g = self._stack(new)
                r = g - u
                err = self._residual(g, u)
                if err <= 1.0:
                    self._count(it)
                    if self.method == "iqn-ils" and V:
                        self._V = (self._V + [V])[-REUSED_STEPS:]
                        self._W = (self._W + [W])[-REUSED_STEPS:]
                    return new
                if it == self.cap or not math.isfinite(err):
                    break
                if self.method == "newton":
                    if last is not None and self.J is not None:
                        _broyden(self.J, u - last[0], g - last[1])
                    last = (u, g)
                    if self.J is None or (err > 0.1 * err_prev and not fresh):
                        self.J = self._jacobian(hist, snaps, states, t0, t1, u, g, at_start)
                        fresh = True
                    try:
                        u = u - np.linalg.solve(self.J - np.eye(self.size), r)
                    except np.linalg.LinAlgError:
                        raise self.singular(t0, t1, err) from None
                else:
                    if prev is not None:
                        V.append(r - prev[0])
                        W.append(g - prev[1])
                    prev = (r, g)
                    u = self._iqn(u, g, r, V, W)
                err_prev = err
            self._count(it)
            raise self.not_converged(t0, t1, err, it)
        finally:
            for n, state in states.items():
                m.slaves[n].free_state(state)

    def not_converged(self, t0, t1, err: float, it: int) -> CoSimulationError:
        """The error of a step from ``t0`` to ``t1`` whose residual after ``it`` iterations is
        ``err`` (not finite: an output is not finite)."""
        return self._failed(t0, t1, f"in master.max_iterations = {self.cap} iterations "
                            f"(residual {err:.3g} times master.implicit_tolerance = "
                            f"{self.tol:g})" if math.isfinite(err) else
                            f"after {it} iterations: an output is not finite")

    def singular(self, t0, t1, err: float) -> CoSimulationError:
        """The error of a Newton step whose ``J - I`` is singular (residual ``err``)."""
        return self._failed(t0, t1, "the interface Jacobian is singular (residual "
                            f"{err:.3g} times master.implicit_tolerance = {self.tol:g})")

    def _failed(self, t0, t1, why: str) -> CoSimulationError:
        """The error that stops a run whose step from ``t0`` to ``t1`` did not converge."""
        m = self.m
        return CoSimulationError(f"master.algorithm = 'implicit': the interface did not converge "
                                 f"by t = {m._time(t1):.6g} {why}", time=m._time(t0))

    def _count(self, it):
        self.iterations += it
        self.max_iterations = max(self.max_iterations, it)
