"""The closed loop from Model Exchange FMUs, solved as one system (``master.interface =
"model-exchange"``): OMSimulator's ME mode, a monolithic reference built from the FMUs themselves.

The continuous states of every FMU form one ODE ``z' = F(t, z)``. One evaluation sets the time and
the states of every FMU, then, in an order where every source comes before its sinks, reads each
FMU's connected outputs and sets them on the inputs they feed (an output that depends directly on
an input, the controller's ``F_c`` without a filter, is read after its inputs are set), and reads
the state derivatives. A stiff solver of scipy (``Radau`` or ``BDF``, ``master.solver``) integrates
it at ``master.rtol`` and ``master.atol`` (the latter scaled by each state's nominal value) with
the exact Jacobian assembled from the FMUs' directional derivatives::

    z' = A z + B u,  y = C z + D u,  u = S y   =>   dF/dz = A + B (I - S D)^-1 S C

(block-diagonal ``A, B, C, D`` of the FMUs' ``d der/d x``, ``d der/d u``, ``d y/d x``,
``d y/d u``; ``S`` the wiring of the connections). After every accepted step each FMU hears
``completedIntegratorStep``; its event indicators are watched for a sign change, an event is
located on the solver's dense output, and the FMUs go through event mode: one that asks to
terminate (the plant past ``phi_limit``) stops the run as a co-simulation's refused step does,
with the FMU's message. Output points are read from the dense output (Radau's collocation
polynomial), the outputs there computed by the FMUs from the interpolated states.

The same results as the co-simulation master: a structured array on the output grid and a
:class:`~orchestration.cosim.master.RunStats` (``steps``: the solver's steps, ``loop``:
``"model-exchange (radau)"``). The solver's largest step is ``master.max_step``.

``master.compiled``: ``"auto"`` (default) runs the integration loop in C
(:mod:`orchestration.cosim.compiled_me`: scipy's Radau ported step for step, the FMUs called
from C) when every FMU can take it (FMI 2.0 FMUs that need no execution tool: the native FMUs)
and ``master.solver = "radau"``, and scipy's solver otherwise; ``False`` always scipy's;
``True`` the C loop or a ValueError saying why not. The loop run below stays the specification
the compiled one is tested against (``loop``: ``"model-exchange (radau, compiled)"``).
"""
from __future__ import annotations

import time as _time

import numpy as np

from ..scene.records import SOLVERS, MasterSettings
from . import compiled_me
from .coupling import checked_connections, output_table
from .master import RunStats
from .slave import CoSimulationError, RunInterrupted, Slave

__all__ = ["ModelExchangeUnit", "ModelExchangeMaster", "solver_class"]


def solver_class(name: str):
    """scipy's solver of ``master.solver`` (imported when a run needs it: scipy.integrate costs
    a co-simulation's start-up time otherwise)."""
    from scipy.integrate import BDF, Radau
    return dict(zip(SOLVERS, (Radau, BDF)))[name]


class ModelExchangeUnit(Slave):
    """One FMU instantiated through its Model Exchange interface (FMI 2.0 or 3.0): the plumbing of
    :class:`Slave` (start values, the log, one error per failed call, cleanup), plus states,
    derivatives, event indicators and directional derivatives on preallocated buffers."""

    interface = "model-exchange"

    def _fmu_class(self):
        if self.fmi3:
            from fmpy.fmi3 import FMU3Model
            return FMU3Model
        from fmpy.fmi2 import FMU2Model
        return FMU2Model

    def __init__(self, path, name, start_values=None, unzipdir=None):
        super().__init__(path, name, start_values, unzipdir=unzipdir)
        self.interpolates_inputs = False
        md = self.md
        self.nx = int(md.numberOfContinuousStates)
        self.nz = int(md.numberOfEventIndicators)
        self.der_vrs = [u.variable.valueReference for u in md.derivatives]
        self.state_vrs = [u.variable.derivative.valueReference for u in md.derivatives]
        self.directional = self._provides_directional_derivatives()
        import ctypes
        dbl = ctypes.c_double
        self._x = (dbl * max(self.nx, 1))()
        self._dx = (dbl * max(self.nx, 1))()
        self._z = (dbl * max(self.nz, 1))()
        self._x_np = np.ctypeslib.as_array(self._x)[:self.nx]
        self._dx_np = np.ctypeslib.as_array(self._dx)[:self.nx]
        self._z_np = np.ctypeslib.as_array(self._z)[:self.nz]
        self._bind_hot()

    def _provides_directional_derivatives(self) -> bool:
        """The ModelExchange element's capability flag (fmpy 0.3 reads FMI 2.0's
        ``providesDirectionalDerivative`` only; FMI 3.0's ``providesDirectionalDerivatives`` is
        read here from the file)."""
        if not self.fmi3:
            return bool(self.md.modelExchange.providesDirectionalDerivative)
        import os
        import xml.etree.ElementTree as ET
        root = ET.parse(os.path.join(self._unzipdir, "modelDescription.xml")).getroot()
        me = root.find("ModelExchange")
        return me is not None and me.get("providesDirectionalDerivatives") == "true"

    # ------------------------------------------------------------------ life cycle
    def initialize(self, t0: float, stop_time: float | None = None):
        """Initialisation, the event iteration at ``t0`` and continuous-time mode."""
        super().initialize(t0, stop_time)
        if self.event_update(t0):
            raise self.stopped("the initial event iteration asked to terminate", t0)
        self._call("enterContinuousTimeMode", self.fmu.enterContinuousTimeMode, t=t0)

    def event_update(self, t) -> bool:
        """The event iteration (``newDiscreteStates`` / ``updateDiscreteStates`` until no new
        discrete states are needed); True if the FMU asks to terminate."""
        update = self.fmu.updateDiscreteStates if self.fmi3 else self.fmu.newDiscreteStates
        for _ in range(100):
            needed, terminate = self._call("the event iteration", update, t=t)[:2]
            if terminate:
                return True
            if not needed:
                return False
        raise self.stopped("the event iteration did not settle in 100 rounds", t)

    def enter_event_mode(self, t):
        self._call("enterEventMode", self.fmu.enterEventMode, t=t)

    def stopped(self, why: str, t) -> CoSimulationError:
        """The error that ends a run this FMU asked to terminate, with the FMU's log."""
        log = "; ".join(self.messages[-3:]) or "no log message"
        return CoSimulationError(f"{self.name}: {why} at t = {t:.6g}: {log}", status=3, time=t)

    def completed_step(self, t) -> tuple[bool, bool]:
        """``completedIntegratorStep``: (enter event mode, terminate)."""
        return self._call("completedIntegratorStep", self.fmu.completedIntegratorStep, True, t=t)

    # ------------------------------------------------------------------ the hot calls
    # straight to the FMU's ctypes functions as fmpy loaded them (fmpy's own wrappers when a
    # call logger is set), on preallocated buffers; the status is checked by Slave._checked

    def _fn(self, name: str):
        """The FMI function ``fmi2<name>`` or ``fmi3<name>``: raw, or fmpy's checked wrapper."""
        full = ("fmi3" if self.fmi3 else "fmi2") + name
        return self.raw_functions().get(full) or getattr(self.fmu, full)

    def _bind_hot(self):
        c = self.fmu.component
        f3 = self.fmi3
        set_time, set_x = self._fn("SetTime"), self._fn("SetContinuousStates")
        get_dx = self._fn("GetContinuousStateDerivatives" if f3 else "GetDerivatives")
        get_z = self._fn("GetEventIndicators")
        x, dx, z, nx, nz = self._x, self._dx, self._z, self.nx, self.nz
        self._set_time_raw = lambda t: set_time(c, t)
        self._set_x_raw = lambda: set_x(c, x, nx)
        self._get_dx_raw = lambda: get_dx(c, dx, nx)
        self._get_z_raw = lambda: get_z(c, z, nz)
        self._get_real = self._fn("GetFloat64" if f3 else "GetReal")
        self._set_real = self._fn("SetFloat64" if f3 else "SetReal")
        self._dd = self._fn("GetDirectionalDerivative")

    def reals(self, vrs) -> "_Reals":
        """Preallocated access to the real variables ``vrs`` (value references)."""
        return _Reals(self, vrs)

    def set_time(self, t):
        self._checked("setTime", self._set_time_raw, t, t=t)

    def states(self) -> np.ndarray:
        self._call("getContinuousStates", self.fmu.getContinuousStates, self._x, self.nx)
        return self._x_np.copy()

    def nominals(self) -> np.ndarray:
        self._call("getNominalsOfContinuousStates", self.fmu.getNominalsOfContinuousStates,
                   self._x, self.nx)
        return self._x_np.copy()

    def set_states(self, x, t=None):
        self._x_np[:] = x
        self._checked("setContinuousStates", self._set_x_raw, t=t)

    def derivatives(self, t=None) -> np.ndarray:
        """The state derivatives (a view, overwritten by the next call)."""
        self._checked("getDerivatives", self._get_dx_raw, t=t)
        return self._dx_np

    def event_indicators(self, t=None) -> np.ndarray:
        """The event indicators (a view, overwritten by the next call)."""
        if self.nz:
            self._checked("getEventIndicators", self._get_z_raw, t=t)
        return self._z_np

    def partials(self, unknowns, knowns, t=None) -> np.ndarray:
        """``d unknowns / d knowns`` (value references), one directional derivative per known."""
        import ctypes
        nu, nk = len(unknowns), len(knowns)
        unk = (ctypes.c_uint * max(nu, 1))(*unknowns)
        one = (ctypes.c_double * 1)(1.0)
        sens = (ctypes.c_double * max(nu, 1))()
        out = np.zeros((nu, nk))
        c = self.fmu.component
        for j, k in enumerate(knowns):
            kn = (ctypes.c_uint * 1)(k)
            if self.fmi3:
                self._checked("getDirectionalDerivative", self._dd, c, unk, nu, kn, 1, one, 1,
                              sens, nu, t=t)
            else:
                self._checked("getDirectionalDerivative", self._dd, c, unk, nu, kn, 1, one,
                              sens, t=t)
            out[:, j] = np.ctypeslib.as_array(sens)[:nu]
        return out


class _Reals:
    """Get and set a fixed list of real variables of one unit on preallocated buffers."""

    def __init__(self, unit: ModelExchangeUnit, vrs):
        import ctypes
        self.unit = unit
        self.n = n = len(vrs)
        self._vr = (ctypes.c_uint * max(n, 1))(*vrs)
        self._val = (ctypes.c_double * max(n, 1))()
        self.values = np.ctypeslib.as_array(self._val)[:n]
        c = unit.fmu.component
        get, put = unit._get_real, unit._set_real
        if unit.fmi3:
            self._get = lambda: get(c, self._vr, n, self._val, n)
            self._put = lambda: put(c, self._vr, n, self._val, n)
        else:
            self._get = lambda: get(c, self._vr, n, self._val)
            self._put = lambda: put(c, self._vr, n, self._val)

    def get(self, t=None) -> np.ndarray:
        """The values (a view, overwritten by the next call)."""
        if self.n:
            self.unit._checked("getReal", self._get, t=t)
        return self.values

    def set(self, values, t=None):
        if self.n:
            self.values[:] = values
            self.unit._checked("setReal", self._put, t=t)


class ModelExchangeMaster:
    """The FMUs' states as one ODE (see the module's text). ``units``: name ->
    :class:`ModelExchangeUnit`; ``connections``, ``record`` and ``settings`` as for
    :class:`~orchestration.cosim.master.Master`."""

    def __init__(self, units: dict, connections, record: dict,
                 settings: MasterSettings | None = None):
        self.settings = settings or MasterSettings()
        self.units = units
        self.connections = checked_connections(units, connections)
        for name, u in units.items():
            if not u.directional:
                raise ValueError(f"{name}: {u.path} gives no directional derivatives; the "
                                 "model-exchange master needs them for its Jacobian")
        self.record = dict(record)
        #: why the compiled loop cannot run (None: it can), and the loop :meth:`run` uses:
        #: "compiled" or "python"
        self.compiled_unavailable, self.loop = compiled_me.choose(units, self.settings)
        names = list(units)
        self.inputs = {n: [c for c in self.connections if c.dst == n] for n in names}
        self.in_vrs = {n: [units[n].vr(c.dst_var) for c in self.inputs[n]] for n in names}
        self.outputs = {n: sorted({c.src_var for c in self.connections if c.src == n})
                        for n in names}
        self.out_vrs = {n: [units[n].vr(v) for v in self.outputs[n]] for n in names}
        self.order = self._evaluation_order()
        rank = {n: i for i, n in enumerate(self.order)}
        #: per unit, its inputs whose sources come before it in the order, and the others
        self._early = {n: [i for i, c in enumerate(self.inputs[n]) if rank[c.src] < rank[n]]
                       for n in names}
        self._late = {n: [i for i, c in enumerate(self.inputs[n]) if rank[c.src] >= rank[n]]
                      for n in names}
        # offsets of each unit's states in z, of its outputs in y and its inputs in u
        self.sx, self.sy, self.su = {}, {}, {}
        nx = ny = nu = 0
        for n in names:
            self.sx[n] = slice(nx, nx + units[n].nx)
            self.sy[n] = slice(ny, ny + len(self.outputs[n]))
            self.su[n] = slice(nu, nu + len(self.inputs[n]))
            nx, ny, nu = nx + units[n].nx, ny + len(self.outputs[n]), nu + len(self.inputs[n])
        self.nx, self.ny, self.nu = nx, ny, nu
        self.S = np.zeros((nu, ny))                 # u = S y
        for n in names:
            for i, c in enumerate(self.inputs[n]):
                src = c.src
                self.S[self.su[n].start + i,
                       self.sy[src].start + self.outputs[src].index(c.src_var)] = 1.0
        self.recorded = {n: sorted({v for s, v in self.record.values() if s == n})
                         for n in names}
        self.rec_vrs = {n: [units[n].vr(v) for v in self.recorded[n]] for n in names}
        self.evaluations = 0
        self.jacobians = 0
        # preallocated exchange: all connected outputs in one vector y (unit after unit), each
        # unit's early and late inputs as (buffer, positions in y)
        self._yall = np.zeros(ny)
        self._outs = {n: units[n].reals(self.out_vrs[n]) for n in names}
        self._recs = {n: units[n].reals(self.rec_vrs[n]) for n in names}
        src_pos = self.S.argmax(axis=1)             # the output each input reads

        def io(n, which):
            if not which:
                return None
            return (units[n].reals([self.in_vrs[n][i] for i in which]),
                    np.array([src_pos[self.su[n].start + i] for i in which]))
        self._early_io = {n: io(n, self._early[n]) for n in names}
        self._late_io = {n: io(n, self._late[n]) for n in names}

    def _evaluation_order(self):
        """The units in an order where each one that reads an input in its outputs comes after
        the sources of that input (a ValueError names an algebraic loop)."""
        names = list(self.units)
        feeds = {n: {c.src for c in self.inputs[n]} - {n} for n in names}
        direct = {n: self.units[n].feedthrough for n in names}
        order, left = [], list(names)
        while left:
            ready = [n for n in left if not direct[n] or feeds[n] <= set(order)]
            if not ready:
                raise ValueError("the FMUs' outputs depend on each other's directly (an "
                                 f"algebraic loop among {', '.join(left)}): the model-exchange "
                                 "master cannot order them")
            order.append(ready[0])
            left.remove(ready[0])
        return order

    # ------------------------------------------------------------------ the ODE
    def _set_point(self, t, z):
        """Time and states of every unit, then the connected outputs and inputs: in evaluation
        order each unit gets the inputs whose sources came before it (all of them, for a unit
        whose outputs read its inputs) and hands on its outputs; then every unit gets the
        inputs whose sources came after it."""
        for n, u in self.units.items():
            u.set_time(t)
            if u.nx:
                u.set_states(z[self.sx[n]], t)
        y = self._yall
        for n in self.order:
            early = self._early_io[n]
            if early is not None:
                early[0].set(y[early[1]], t)
            if self._outs[n].n:
                y[self.sy[n]] = self._outs[n].get(t)
        for n in self.order:
            late = self._late_io[n]
            if late is not None:
                late[0].set(y[late[1]], t)

    def rhs(self, t, z):
        self.evaluations += 1
        self._set_point(t, z)
        dz = np.empty(self.nx)
        for n, u in self.units.items():
            if u.nx:
                dz[self.sx[n]] = u.derivatives(t)
        return dz

    def jacobian(self, t, z):
        """``dF/dz = A + B (I - S D)^-1 S C`` from the units' directional derivatives."""
        self.jacobians += 1
        self._set_point(t, z)
        A = np.zeros((self.nx, self.nx))
        B = np.zeros((self.nx, self.nu))
        C = np.zeros((self.ny, self.nx))
        D = np.zeros((self.ny, self.nu))
        for n, u in self.units.items():
            unknowns = u.der_vrs + self.out_vrs[n]
            knowns = u.state_vrs + self.in_vrs[n]
            if not unknowns or not knowns:
                continue
            P = u.partials(unknowns, knowns, t)
            k = u.nx
            sx, sy, su = self.sx[n], self.sy[n], self.su[n]
            A[sx, sx] = P[:k, :k]
            B[sx, su] = P[:k, k:]
            C[sy, sx] = P[k:, :k]
            D[sy, su] = P[k:, k:]
        if self.nu == 0:
            return A
        dudz = np.linalg.solve(np.eye(self.nu) - self.S @ D, self.S @ C)
        return A + B @ dudz

    # ------------------------------------------------------------------ the run
    def run(self, t0: float, stop_time: float, output_interval: float, progress=None, stop=None):
        """Run from ``t0`` to ``stop_time`` with outputs every ``output_interval``; a structured
        array (time first) and :class:`RunStats`, as :meth:`Master.run`."""
        wall = _time.perf_counter()
        compiled = self.loop == "compiled"
        stats = RunStats(loop=f"model-exchange ({self.settings.solver}"
                              f"{', compiled' if compiled else ''})")
        out = output_table(self.record, t0, stop_time, output_interval)
        n_out = len(out) - 1
        rows = 0
        t = t0
        try:
            for u in self.units.values():
                u.initialize(t0, stop_time)
            z = np.concatenate([u.states() for u in self.units.values()]) if self.nx else \
                np.zeros(0)
            nominal = np.concatenate([u.nominals() for u in self.units.values()]) if self.nx \
                else np.zeros(0)
            self._store(out, 0, t0, z)
            rows = 1
            if compiled:
                run = compiled_me.CompiledME(self, out, t0, stop_time, output_interval,
                                             self.settings.atol * np.abs(nominal))
                try:
                    run.start(t0, z)
                    run.run(stats, progress, stop)
                finally:
                    rows, t = run.rows_written, run.t
                stats.wall_time = _time.perf_counter() - wall
                return out, stats
            z_ind = self._indicators(t0, z)
            solver = solver_class(self.settings.solver)(
                self.rhs, t0, z, stop_time, rtol=self.settings.rtol,
                atol=self.settings.atol * np.abs(nominal), jac=self.jacobian,
                max_step=self.settings.max_step)
            while rows <= n_out:
                msg = solver.step()
                if solver.status == "failed":
                    raise CoSimulationError(f"the {self.settings.solver} solver failed at t = "
                                            f"{solver.t:.6g}: {msg}", status=3, time=solver.t)
                stats.steps += 1
                t_old, t = solver.t_old, solver.t
                dense = solver.dense_output()
                stats.min_step_used = min(stats.min_step_used, t - t_old)
                stats.max_step_used = max(stats.max_step_used, t - t_old)
                z_new = self._indicators(t, solver.y)
                t_event = self._event_time(dense, z_ind, z_new, t_old, t)
                t_end = t if t_event is None else t_event
                while rows <= n_out and t0 + rows * output_interval <= t_end + 1e-12 * \
                        output_interval:
                    ti = t0 + rows * output_interval
                    self._store(out, rows, ti, dense(min(ti, t)))
                    rows += 1
                    if progress is not None:
                        progress((rows - 1) / n_out)
                if t_event is not None:
                    self._event(t_event, dense(t_event))
                    # no FMU of this product changes its states at an event; go on from there
                    solver = solver_class(self.settings.solver)(
                        self.rhs, t_event, dense(t_event), stop_time, rtol=self.settings.rtol,
                        atol=self.settings.atol * np.abs(nominal), jac=self.jacobian,
                        max_step=self.settings.max_step)
                    z_ind = self._indicators(t_event, dense(t_event))
                    continue
                self._set_point(t, solver.y)
                for u in self.units.values():
                    enter, terminate = u.completed_step(t)
                    if terminate:
                        raise u.stopped("completedIntegratorStep asked to terminate", t)
                    if enter:
                        self._event(t, solver.y)
                z_ind = z_new
                if stop is not None and stop():
                    raise RunInterrupted(t)
                if solver.status == "finished" and rows <= n_out:
                    raise CoSimulationError(f"the solver finished at t = {t:.9g} before the "
                                            f"last output point", status=3, time=t)
        except (CoSimulationError, RunInterrupted) as exc:
            stats.wall_time = _time.perf_counter() - wall
            exc.result, exc.stats = out[:rows].copy(), stats
            if exc.time is None:
                exc.time = t
            raise
        stats.wall_time = _time.perf_counter() - wall
        return out, stats

    def _indicators(self, t, z):
        self._set_point(t, z)
        return np.concatenate([u.event_indicators(t).copy() for u in self.units.values()]) \
            if any(u.nz for u in self.units.values()) else np.zeros(0)

    def _event_time(self, dense, z_old, z_new, t_old, t):
        """The earliest sign change of an event indicator within the step, located on the dense
        output to the solver's time resolution; None when none changes sign."""
        changed = np.flatnonzero((z_old > 0) != (z_new > 0))
        if changed.size == 0:
            return None
        first = t
        for i in changed:
            g = (lambda s, i=i: self._indicators(s, dense(s))[i])
            first = min(first, _brentq(g, t_old, t, xtol=1e-14 * max(1.0, abs(t)),
                                      rtol=4 * np.finfo(float).eps))
        return first

    def _event(self, t, z):
        """Event mode for every unit; the run stops if one asks to terminate."""
        self._set_point(t, z)
        for u in self.units.values():
            u.enter_event_mode(t)
        for u in self.units.values():
            if u.event_update(t):
                raise u.stopped("the event iteration asked to terminate", t)
        for u in self.units.values():
            u._call("enterContinuousTimeMode", u.fmu.enterContinuousTimeMode, t=t)

    def _store(self, out, i, t, z):
        """Row ``i``: time, then the recorded variables at ``(t, z)``."""
        self._set_point(t, z)
        vals = {n: dict(zip(self.recorded[n], self._recs[n].get(t).tolist()))
                for n in self.units}
        out[i] = (t, *(vals[s][v] for s, v in self.record.values()))

    def close(self):
        for u in self.units.values():
            u.close()


def _brentq(*args, **kwargs):
    from scipy.optimize import brentq
    return brentq(*args, **kwargs)
