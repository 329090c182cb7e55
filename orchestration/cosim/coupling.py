"""The coupling's arithmetic: the extrapolation polynomials' weights and the history of the signals
exchanged (the Python and the compiled loop use the same weights).
"""
from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["extrapolation_weights"]


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


class _History:
    """The last few communication-point values of every connection source."""

    def __init__(self, depth: int):
        self.t: list[float] = []
        self.u: list[np.ndarray] = []
        self.depth = depth

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

