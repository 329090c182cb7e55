"""The coupling of a co-simulation: which FMU gets which signal, in which order, extrapolated how.

:class:`Coupling` is the one description of a communication step that both loops consume, the
Python loops of :class:`~orchestration.cosim.master.Master` and the compiled loop of
:mod:`orchestration.cosim.compiled`: the order of the FMUs, each FMU's inputs (gathered from its
sources' outputs), the outputs exchanged and the ones only recorded, how many input derivatives
each FMU takes, what its inputs are over a step (held step averages, or values and derivatives),
and whether the first step is predicted and corrected. Below it, the arithmetic both loops share:
the extrapolation polynomials' weights (:func:`weight_table` is the compiled loop's copy of
them) and the history of the exchanged signals.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..scene.records import MasterSettings

__all__ = ["Coupling", "extrapolation_weights", "weight_table", "derivative_name", "taylor_rows",
           "hermite_rows", "HERMITE_MAX_ORDER", "checked_connections", "output_table"]

#: The highest output derivative order the Hermite coupling reads from a source (the
#: controller's four; the plant gives two).
HERMITE_MAX_ORDER = 4


def derivative_name(variable: str, order: int) -> str:
    """The input variable that carries the ``order``-th time derivative of ``variable`` on FMUs
    that take input derivatives as variables (pythonfmu has no ``fmi2SetRealInputDerivatives``):
    ``dF_c``, ``d2F_c``."""
    return f"{'d' if order == 1 else 'd2'}{variable}"


def checked_connections(units: dict, connections) -> list:
    """``connections`` as a list, each naming FMUs of ``units`` (name -> slave) and variables
    they have; a ValueError names the first that does not."""
    connections = list(connections)
    for c in connections:
        for fmu, var in ((c.src, c.src_var), (c.dst, c.dst_var)):
            if fmu not in units:
                raise ValueError(f"connection {c}: no FMU named {fmu!r}; FMUs: "
                                 f"{', '.join(units)}")
            units[fmu].vr(var)
    return connections


def output_table(record, t0: float, stop_time: float, output_interval: float) -> np.ndarray:
    """The zeroed rows of a run's output points: time, then the columns of ``record``; a
    ValueError when the run is shorter than one output interval."""
    n_out = int(round((stop_time - t0) / output_interval))
    if n_out < 1:
        raise ValueError(f"stop_time - t0 = {stop_time - t0!r} is shorter than one "
                         f"output_interval = {output_interval!r}")
    return np.zeros(n_out + 1, dtype=[(c, "f8") for c in ("time", *record)])


class Coupling:
    """The coupling of ``slaves`` (name -> :class:`~orchestration.cosim.slave.Slave`) wired by
    ``connections``, recording ``record`` (column -> (slave, variable)), stepped as ``settings``
    says. A ValueError names a connection to an FMU or a variable that does not exist.

    Public attributes, read by both loops: ``settings``, ``algorithm``, ``order`` (the slaves in
    stepping order), ``h`` (the communication step), ``p`` (the extrapolation order),
    ``inputs[n]`` (the connections into ``n``, in order), ``outputs[n]`` (the outputs of ``n``
    exchanged every step, sorted), ``recorded[n]`` (its outputs only recorded), ``out_index[n]``
    (output name -> position in ``outputs[n]``), ``gather[n]`` ((source, input positions, output
    positions) per source of ``n``), ``n_der[n]`` (input derivative orders ``n`` takes, 0 to 2),
    ``bound_inputs[n]`` (the input variables set on ``n``, derivative variables included),
    ``kinds[n]`` (what the inputs of ``n`` are over a step: ``("average",)`` held, or ``(0, 1[,
    2])`` values and derivatives at the step's start), ``out_der[n]`` (the time derivatives of its
    outputs read from ``n`` with every sample: 0, or the extrapolation order; with ``hermite``, every
    order it gives up to :data:`HERMITE_MAX_ORDER`), ``targets`` (where each source's rows go in
    the input buffer), ``correct_startup`` (the first step predicted and corrected) and
    ``hermite`` (``master.coupling = "hermite"``: :func:`hermite_rows`)."""

    def __init__(self, slaves: dict, connections, record: dict,
                 settings: MasterSettings | None = None):
        settings = settings or MasterSettings()
        self.settings = settings
        self.connections = checked_connections(slaves, connections)
        self.record = dict(record)
        self.algorithm = settings.algorithm
        names = list(slaves)
        first = settings.first if settings.first in names else None
        self.order = names if first is None else [first] + [n for n in names if n != first]
        self.h = settings.step
        self.p = settings.extrapolation
        self.inputs = {n: [c for c in self.connections if c.dst == n] for n in names}
        self.outputs = {n: sorted({c.src_var for c in self.connections if c.src == n})
                        for n in names}
        self.recorded = {n: sorted({v for s, v in self.record.values() if s == n}
                                   - set(self.outputs[n])) for n in names}
        self.out_index = {n: {v: i for i, v in enumerate(self.outputs[n])} for n in names}
        self.gather = {n: [(src, np.array([i for i, c in enumerate(self.inputs[n])
                                           if c.src == src]),
                            np.array([self.out_index[src][c.src_var]
                                      for c in self.inputs[n] if c.src == src]))
                           for src in dict.fromkeys(c.src for c in self.inputs[n])]
                       for n in names}
        #: the Hermite coupling (``master.coupling = "hermite"``, Gauss-Seidel): a source's
        #: polynomial over a step is the Taylor polynomial of its newest sample (every output
        #: derivative it gives, up to HERMITE_MAX_ORDER) at the step's start, or, when it
        #: stepped earlier in the same step, the Hermite polynomial through its samples at the
        #: step's start and end; an FMU takes the least-squares quadratic of it over the step
        #: (hermite_rows), and after its step, when every source of its inputs has stepped, its
        #: inputs' values and derivatives at the step's end (the controller FMU's output
        #: derivatives then use them, so that its F_c's are those of the sensors' exact rates;
        #: the plant FMU's keep its step's input polynomial at its end)
        self.hermite = settings.coupling == "hermite"
        hermite = self.hermite
        # input derivatives: FMI's (fmi2SetRealInputDerivatives) or as the input variables
        # d<u> and d2<u>; how many orders each slave takes, 0 to 2
        self.n_der = {n: 0 for n in names}
        if settings.input_derivatives and (self.p >= 1 or hermite):
            for n in names:
                dst_vars = [c.dst_var for c in self.inputs[n]]
                if slaves[n].interpolates_inputs:
                    self.n_der[n] = (2 if self.p >= 2 or hermite else 1) if dst_vars else 0
                    continue
                var = slaves[n].variables
                has = [all(derivative_name(v, k) in var
                           and var[derivative_name(v, k)].causality == "input"
                           for v in dst_vars) for k in (1, 2)]
                self.n_der[n] = 0 if not (dst_vars and has[0]) else (
                    2 if has[1] and (self.p >= 2 or hermite) else 1)
        #: whether an FMU takes its input derivatives through fmi2SetRealInputDerivatives
        self.interpolates = {n: slaves[n].interpolates_inputs for n in names}
        self.bound_inputs = {
            n: [c.dst_var for c in self.inputs[n]] + (
                [] if self.interpolates[n] else
                [derivative_name(c.dst_var, k) for k in range(1, self.n_der[n] + 1)
                 for c in self.inputs[n]])
            for n in names}
        self.targets = {(n, src, nk): pos[None, :] + len(self.inputs[n]) * np.arange(nk)[:, None]
                        for n in names for src, pos, _ in self.gather[n] for nk in (1, 2, 3)}
        self.kinds = {n: tuple(range(self.n_der[n] + 1)) if self.n_der[n] else ("average",)
                      for n in names}
        # output derivatives (``master.output_derivatives``): a source whose FMU gives the time
        # derivatives of its outputs up to the extrapolation order is extrapolated by the
        # Taylor polynomial at its newest sample instead of the polynomial through past samples
        self.out_der = {n: self.p if (settings.output_derivatives and self.p >= 1
                                      and self.outputs[n]
                                      and slaves[n].output_derivative_order >= self.p) else 0
                        for n in names}
        if hermite:
            self.out_der = {n: min(slaves[n].output_derivative_order, HERMITE_MAX_ORDER)
                            if self.outputs[n] else 0 for n in names}
            lacking = [n for n in names if self.outputs[n] and not self.out_der[n]]
            if lacking:
                raise ValueError(f"master.coupling = 'hermite' needs the output derivatives "
                                 f"of every FMU whose outputs are exchanged; "
                                 f"{', '.join(lacking)} gives none (maxOutputDerivativeOrder "
                                 "0); allowed here: master.coupling = 'polynomial'")
        lacking = [n for n in names if settings.output_derivatives and self.p >= 1
                   and self.outputs[n] and not self.out_der[n]]
        if lacking:
            import warnings
            warnings.warn(f"master.output_derivatives: {', '.join(lacking)} gives no output "
                          f"derivatives up to order {self.p}; its outputs are extrapolated from "
                          "past samples", RuntimeWarning, stacklevel=3)
        # the first step needs no prediction when every source's polynomial is complete from
        # one sample (its derivatives)
        self.correct_startup = not hermite and self.p >= 1 and all(
            s.md.coSimulation.canGetAndSetFMUstate for s in slaves.values()) and not all(
            self.out_der[n] for n in names if self.outputs[n])

    def bind(self, slaves: dict):
        """Preallocate every slave's buffers for the signals this coupling exchanges."""
        for n, s in slaves.items():
            s.bind(self.bound_inputs[n], self.outputs[n], self.recorded[n],
                   derivative_orders=self.n_der[n] if self.interpolates[n] else 0,
                   output_derivative_orders=self.out_der[n])

    def table(self) -> str:
        """The connections as a two-column table (``flexpend run --connections``)."""
        rows = [("from", "to")] + [(f"{c.src}.{c.src_var}", f"{c.dst}.{c.dst_var}")
                                   for c in self.connections]
        w = max(len(r[0]) for r in rows)
        return "\n".join(f"{a:<{w}}  ->  {b}" if i else f"{a:<{w}}      {b}"
                         for i, (a, b) in enumerate(rows))


# ---------------------------------------------------------------------- extrapolation
def extrapolation_weights(times, t0: float, t1: float) -> np.ndarray:
    """Weights ``w`` with ``sum(w_i u_i)`` = the average over ``[t0, t1]`` of the polynomial
    through the samples ``(times_i, u_i)`` (degree ``len(times) - 1``)."""
    h = t1 - t0
    # Lagrange basis in a scaled variable for conditioning: tau = (t - t0) / (t1 - t0)
    return _weights(tuple(_key((ti - t0) / h) for ti in times), "average")


def _point_weights(times, t: float, scale: float, derivative: int = 0) -> np.ndarray:
    """Weights evaluating the polynomial through the samples at ``t`` (or its ``derivative``-th
    time derivative there, ``scale`` being the time unit of the weights' construction)."""
    w = _weights(tuple(_key((ti - t) / scale) for ti in times), derivative)
    return w if derivative == 0 else w / scale ** derivative


def _key(tau: float) -> float:
    """``tau`` to 12 significant digits: a fixed communication step gives the same few node
    patterns over and over, whose weights are then computed once."""
    return float(f"{tau:.12g}")


@functools.lru_cache(maxsize=4096)
def _weights(tau: tuple, kind) -> np.ndarray:
    """Weights of the polynomial through nodes ``tau``: its average over ``[0, 1]``
    (``kind = "average"``) or its ``kind``-th derivative at 0 (``kind`` = 0, 1, 2)."""
    n = len(tau)
    if kind != "average" and n <= kind:             # too few samples: that derivative is 0
        return np.zeros(n)
    if n == 1:
        return np.ones(1)
    V = np.vander(np.array(tau), n, increasing=True)       # V[i, j] = tau_i^j
    if kind == "average":
        rhs = 1.0 / np.arange(1, n + 1)                    # the average of tau^j over [0, 1]
    else:
        rhs = np.zeros(n)
        rhs[kind] = math.factorial(kind)                   # d^k/dtau^k of tau^j at 0
    w = np.linalg.solve(V.T, rhs)
    w.flags.writeable = False
    return w


@functools.lru_cache(maxsize=4096)
def _weight_rows(tau: tuple, kinds: tuple, scale: float) -> np.ndarray:
    """Rows of weights on the samples at nodes ``tau`` (times in units of ``scale`` from the
    origin): per ``kind``, the polynomial's average over ``[0, 1]`` (``"average"``) or its
    ``kind``-th time derivative at 0 (``scale ** -kind`` included)."""
    W = np.array([_weights(tau, kd) if kd == "average" or kd == 0
                  else _weights(tau, kd) / scale ** kd for kd in kinds])
    W.flags.writeable = False
    return W


def taylor_rows(delta: float, kinds: tuple, scale: float, order: int) -> np.ndarray:
    """Rows of weights on ``[y, y', ..., y^(order)]`` at a sample time ``t_s``, for the Taylor
    polynomial ``y(t_s + r) = sum_j y^(j) r^j / j!`` evaluated from ``t = t_s + delta``: per
    ``kind``, its average over ``[t, t + scale]`` (``"average"``) or its ``kind``-th time
    derivative at ``t``."""
    W = np.zeros((len(kinds), order + 1))
    for i, kind in enumerate(kinds):
        for j in range(order + 1):
            if kind == "average":
                W[i, j] = ((delta + scale) ** (j + 1) - delta ** (j + 1)) / (
                    math.factorial(j + 1) * scale)
            elif j >= kind:
                W[i, j] = delta ** (j - kind) / math.factorial(j - kind)
    return W


@functools.lru_cache(maxsize=64)
def hermite_rows(q: int, two_point: bool, scale: float) -> np.ndarray:
    """The Hermite coupling's weights (:attr:`Coupling.hermite`): rows (the average over the step,
    the value, the first and the second derivative at its start) of the least-squares quadratic
    over a step of ``scale`` seconds of a source's polynomial, on its samples' values and
    derivatives up to order ``q``: ``two_point`` False, the Taylor polynomial of the sample at
    the step's start, on ``[y, y', ..., y^(q)]``; True, the Hermite polynomial (degree 2q + 1)
    through the samples at the step's start (a) and end (b), on ``[y_a, ..., y_a^(q), y_b, ...,
    y_b^(q)]``.

    In the step's scaled time tau = s / scale the polynomial's coefficients are ``c = P y``
    (Taylor: ``scale^m / m!``; Hermite: the inverse of its conditions' matrix, times
    ``scale^j``); its least-squares quadratic over [0, 1] is ``a = G^-1 B c`` (``G_ik = 1 / (i +
    k + 1)``, ``B_im = 1 / (i + m + 1)``), which keeps its average; the rows are ``a_0 + a_1 / 2 +
    a_2 / 3``, ``a_0``, ``a_1 / scale`` and ``2 a_2 / scale^2``. A quadratic is its own
    least-squares quadratic: for the Taylor polynomial of order q <= 2 these are
    :func:`taylor_rows`'s rows."""
    if two_point:
        n = 2 * (q + 1)
        V = np.zeros((n, n))
        for j in range(q + 1):
            V[j, j] = math.factorial(j)                         # d^j/dtau^j at tau = 0
            for m in range(j, n):                               # ... at tau = 1
                V[q + 1 + j, m] = math.factorial(m) / math.factorial(m - j)
        D = np.array([scale ** j for j in range(q + 1)] * 2)
        P = np.linalg.solve(V, np.diag(D))
    else:
        n = q + 1
        P = np.diag([scale ** m / math.factorial(m) for m in range(n)])
    G = np.array([[1.0 / (i + k + 1) for k in range(3)] for i in range(3)])
    B = np.array([[1.0 / (i + m + 1) for m in range(n)] for i in range(3)])
    a = np.linalg.solve(G, B @ P)                               # rows a_0, a_1, a_2
    W = np.array([a[0] + a[1] / 2 + a[2] / 3, a[0], a[1] / scale, 2.0 * a[2] / scale ** 2])
    W.flags.writeable = False
    return W


class _History:
    """The last few communication-point values of every connection source. With ``derivatives``
    = ``q`` > 0 each sample is the outputs followed by their first ``q`` time derivatives
    (``(q + 1) * outputs`` values)."""

    def __init__(self, depth: int, derivatives: int = 0):
        self.t: list[float] = []
        self.u: list[np.ndarray] = []
        self.depth = depth
        self.derivatives = derivatives

    def push(self, t, u):
        self.t.append(t)
        self.u.append(np.asarray(u, dtype=float))
        if len(self.t) > self.depth:
            del self.t[0], self.u[0]

    def pop(self):
        self.t.pop()
        self.u.pop()

    def snapshot(self):
        return list(self.t), list(self.u)

    def restore(self, snap):
        self.t, self.u = list(snap[0]), list(snap[1])


@functools.lru_cache(maxsize=1)
def weight_table() -> np.ndarray:
    """``W[e + 1, k - 1, kind, :k]``: the weights the Python master uses for the ``k`` nodes
    ``e - k + 1 .. e`` (``e`` the newest node, -1, 0 or 1, in communication steps from the point
    of evaluation), per kind: the average over [0, 1], the value, the first and the second
    derivative at 0 (the derivatives unscaled: the loop divides them by ``scale ** kind``).
    Computed once (read-only): every compiled run reads the same table."""
    W = np.zeros((3, 3, 4, 3))
    for e in (-1, 0, 1):
        for k in (1, 2, 3):
            tau = tuple(float(j) for j in range(e - k + 1, e + 1))
            for i, kind in enumerate(("average", 0, 1, 2)):
                W[e + 1, k - 1, i, :k] = _weights(tau, kind)
    W.flags.writeable = False
    return W
