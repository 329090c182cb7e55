"""The digital controller (docs/design/MODEL.md section 8; docs/sampled.md): the readable
specification of what the native ``PDLowPassSampled`` FMU (``native/controller_model.c`` on
``fp_filter.c``) and the pythonfmu ``PDLowPass`` do when ``sample_period > 0``.

The controller samples the sensors at the ticks ``t_k = t0 + k T`` (``T = sample_period``,
``t0`` the start time), computes

    e_k  = kx x_o + kp phi_o + kd omega_o              (the sensors at t_k)
    u_k  = sat(-(Cd xf_k + Dd e_k)),   xf_{k+1} = Ad xf_k + Bd e_k

and applies ``u_k`` from ``t_k + tau`` (``tau = delay``, ``0 <= tau <= T``) until the next force
takes over (zero-order hold). ``(Ad, Bd, Cd, Dd)`` is the low-pass filter ``H`` of
:class:`~controller_fmu.pd_lowpass.PDLowPassModel` as a difference equation over ``T``:

* ``tustin``: the bilinear map prewarped at the cutoff, ``s = c (z - 1) / (z + 1)`` with
  ``c = cutoff / tan(cutoff T / 2)``; in state space (the generalised bilinear transform with
  ``alpha = 1/2`` over ``2 / c``, as ``scipy.signal.cont2discrete`` and python-control's ``c2d``
  build it): ``M = I - Af / c``, ``Ad = M^-1 (I + Af / c)``, ``Bd = M^-1 Bf 2 / c``,
  ``Cd = Cf M^-1``, ``Dd = Df + Cf Bd / 2``. It has a direct feedthrough ``Dd``: with no delay the
  force at ``t_k`` depends on the sensors at ``t_k``.
* ``zoh``: the zero-order-hold equivalent, ``Ad = exp(Af T)``, ``Bd = int_0^T exp(Af s) ds Bf``
  (one exponential of the augmented matrix), ``Cd = Cf``, ``Dd = Df``: strictly proper (for a
  filter of order 1 or 2).

The filter of order 0 is ``H = 1`` in both: ``u_k = sat(-e_k)``.

In co-simulation the communication points must land on every tick and on every ``t_k + tau``
(a step across one is refused, :meth:`SampledController.step`): the sensors set at a tick are
the samples, and the force is exact as a held input of the plant between those points. With no
delay, the force at a tick is a direct feedthrough of the sensors set there (read it after
setting them); with a delay, it changes at the end of the step that lands on ``t_k + tau``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .pd_lowpass import ControllerParams, PDLowPassModel

__all__ = ["filter_difference_equation", "SampledController", "TICK_TOLERANCE"]

#: Two instants within this fraction of the sample period are the same instant (a master's
#: communication points, ``t0 + j h``, and the ticks, ``t0 + k T``, differ in the last bits).
TICK_TOLERANCE = 1e-9


def filter_difference_equation(p: ControllerParams):
    """``(Ad, Bd, Cd, Dd)`` of the filter over ``p.sample_period`` by ``p.discretization``
    (module docstring): ``Ad`` ``n x n``, ``Bd`` ``n x 1``, ``Cd`` ``1 x n``, ``Dd`` ``1 x 1``, with
    ``n = filter_order``. ValueError for a continuous controller (``sample_period = 0``)."""
    if not p.sampled:
        raise ValueError("the controller is continuous (controller.sample_period = 0): it has "
                         "no difference equation")
    m = PDLowPassModel(p)
    A, B, C, D = m.Af, m.Bf, m.Cf, m.Df
    n, T = m.nx, p.sample_period
    if n == 0:
        return A.copy(), B.copy(), C.copy(), D.copy()
    if p.discretization == "zoh":
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n] = A * T
        aug[:n, n:] = B * T
        import scipy.linalg
        E = scipy.linalg.expm(aug)
        return E[:n, :n], E[:n, n:], C.copy(), D.copy()
    c = p.cutoff / math.tan(0.5 * p.cutoff * T)
    M = np.eye(n) - A / c
    Ad = np.linalg.solve(M, np.eye(n) + A / c)
    Bd = np.linalg.solve(M, B * (2.0 / c))
    Cd = np.linalg.solve(M.T, C.T).T
    Dd = D + 0.5 * (C @ Bd)
    return Ad, Bd, Cd, Dd


@dataclass
class SampledController:
    """The digital controller's state and its co-simulation semantics (module docstring).

    ``xf``: the filter state for the next tick; ``held``: the force applied now; ``pending``:
    the force computed at the last tick, waiting for its delay (None: none); ``k``: the index of
    the next tick; ``t``: the time reached."""

    params: ControllerParams
    t0: float = 0.0
    #: ``(Ad, Bd, Cd, Dd)`` when given (the C kernel's ``fpf_sampled``, as the pythonfmu FMU
    #: takes them), else :func:`filter_difference_equation`'s
    coefficients: tuple | None = None

    def __post_init__(self):
        p = self.params
        if not p.sampled:
            raise ValueError("SampledController needs controller.sample_period > 0")
        self.Ad, self.Bd, self.Cd, self.Dd = (filter_difference_equation(p)
                                              if self.coefficients is None
                                              else self.coefficients)
        self.T, self.tau = p.sample_period, p.delay
        self.gains = np.array([p.kx, p.kp, p.kd])
        self.tol = TICK_TOLERANCE * self.T
        self.xf = np.zeros(self.Ad.shape[0])
        self.held = 0.0
        self.pending = None
        self.k = 0
        self.t = float(self.t0)

    # ------------------------------------------------------------------ the instants
    def tick(self, k: int | None = None) -> float:
        """``t_k = t0 + k T`` (the next tick by default)."""
        return self.t0 + (self.k if k is None else k) * self.T

    def _next(self, k: int, pending) -> float:
        """The first of the tick ``k`` and the ``pending`` force's instant (None: none)."""
        nxt = self.tick(k)
        if pending is not None:
            nxt = min(nxt, pending[1])
        return nxt

    def next_event(self) -> float:
        """The next instant a communication point must land on: the pending force's ``t_k + tau``
        or the next tick, whichever comes first."""
        return self._next(self.k, self.pending)

    def next_instant(self, t: float) -> float:
        """The farthest a step from ``t`` (the time reached) may go: the next instant after the
        tick at ``t`` is taken, when one is due there (the next tick, or the new force's
        ``t + tau``), else :meth:`next_event`."""
        if not self.at_tick(t):
            return self.next_event()
        return self._next(self.k + 1, (None, self.tick() + self.tau) if self.tau > 0.0
                          else self.pending)

    def at_tick(self, t: float) -> bool:
        """Whether ``t`` is the next tick (not taken yet)."""
        return self._at(t, self.tick())

    def _at(self, t: float, instant: float) -> bool:
        return abs(t - instant) <= self.tol

    # ------------------------------------------------------------------ the law
    def _sat(self, F: float) -> float:
        lim = self.params.force_limit
        return min(max(F, -lim), lim)

    def _force(self, e: float) -> float:
        v = (self.Cd @ self.xf).item() if self.xf.size else 0.0
        return self._sat(-(v + self.Dd.item() * e))

    def error_signal(self, y) -> float:
        """``e = kx x_o + kp phi_o + kd omega_o`` of ``y = [x_o, phi_o, omega_o]``."""
        return float(self.gains @ np.asarray(y, dtype=float))

    def output(self, y) -> float:
        """``F_c`` now, with the sensors ``y = [x_o, phi_o, omega_o]`` set now: at a tick not yet
        taken and with no delay, the new force (a feedthrough of ``y``); otherwise the force
        held."""
        if self.tau == 0.0 and self.at_tick(self.t):
            return self._force(self.error_signal(y))
        return self.held

    def step(self, t: float, h: float, y) -> float:
        """A communication step from ``t`` (= the time reached) over ``h > 0`` with the sensors
        ``y`` set at ``t``: the tick at ``t`` (if there is one) samples ``y``; a force whose delay
        runs out at ``t + h`` takes over. Returns ``F_c`` at ``t + h``. ValueError, state
        unchanged, for a step across a tick or a ``t_k + tau``, or one that does not start where
        the last ended."""
        if not self._at(t, self.t) and t != self.t:
            raise ValueError(f"the step starts at t = {t!r}, not where the last ended "
                             f"({self.t!r})")
        tick = self.at_tick(t)
        if t > self.tick() + self.tol:
            raise ValueError(f"the tick at t = {self.tick()!r} was missed (now t = {t!r})")
        k, xf, pending, held = self.k, self.xf, self.pending, self.held
        if tick:
            e = self.error_signal(y)
            u = self._force(e)
            xf = self.Ad @ self.xf + (self.Bd[:, 0] * e if self.xf.size else 0.0)
            k += 1
            if self.tau == 0.0:
                held = u
            else:
                pending = (u, self.tick() + self.tau)
        end = t + h
        nxt = self._next(k, pending)
        if end > nxt + self.tol:
            raise ValueError(f"the step from t = {t!r} over h = {h!r} crosses the controller's "
                             f"instant t = {nxt!r} (a tick every {self.T!r} s, the force "
                             f"{self.tau!r} s after it): land a communication point on it")
        if pending is not None and self._at(end, pending[1]):
            held, pending = pending[0], None
        self.k, self.xf, self.pending, self.held = k, np.asarray(xf, dtype=float), pending, held
        self.t = end
        return held

    # ------------------------------------------------------------------ FMU state
    def state(self) -> dict:
        """The state as plain values (an FMU state's entry)."""
        return {"t0": self.t0, "k": self.k, "xf": [float(v) for v in self.xf],
                "held": self.held,
                "pending": None if self.pending is None else [float(self.pending[0]),
                                                              float(self.pending[1])],
                "t": self.t}

    def restore(self, state: dict) -> None:
        """Take back :meth:`state`'s values, after checking what a state of this controller
        holds (ValueError naming what is wrong; nothing changed then): ``k`` an integer >= 0
        with ``t`` between the last tick taken and the next, a pending force only with a delay
        and before it acts, forces within the limit."""
        try:
            k, xf, held, pending, t = (state[n] for n in ("k", "xf", "held", "pending", "t"))
        except (KeyError, TypeError):
            raise ValueError("the sampled controller's state needs k, xf, held, pending, t") \
                from None
        if isinstance(k, bool) or not isinstance(k, int) or k < 0:
            raise ValueError(f"k = {k!r} is not an integer >= 0")
        xf = np.asarray(xf, dtype=float)
        lim = self.params.force_limit
        if xf.shape != self.xf.shape or not np.all(np.isfinite(xf)):
            raise ValueError(f"xf must be {self.xf.size} finite numbers")
        if not (isinstance(t, (int, float)) and math.isfinite(t)):
            raise ValueError(f"t = {t!r} is not a finite time")
        if not (t <= self.tick(k) + self.tol and (k == 0 or t >= self.tick(k - 1) - self.tol)):
            raise ValueError(f"t = {t!r} is not between the last tick taken and the next")
        if not (isinstance(held, (int, float)) and abs(held) <= lim):
            raise ValueError(f"the held force {held!r} is not one the controller computes")
        if pending is not None:
            if self.tau == 0.0 or k == 0 or len(pending) != 2 or \
                    not abs(float(pending[0])) <= lim or \
                    float(pending[1]) != self.tick(k - 1) + self.tau or \
                    not t < float(pending[1]) - self.tol:
                raise ValueError("a force is pending where none can be")
            pending = (float(pending[0]), float(pending[1]))
        self.k, self.xf, self.held, self.pending, self.t = k, xf, float(held), pending, float(t)
