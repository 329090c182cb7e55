"""The exact exponential integrator of a linear time-invariant plant with a zero-order-hold input.

For ``x' = A x + B u`` with ``u`` constant over the substep ``h``::

    x(t + h) = Phi x(t) + Gamma u,    [[Phi, Gamma], [0, I]] = expm([[A, B], [0, 0]] h)

(Van Loan's block matrix; no inverse of ``A``, which is singular for the plant: the cart drifts).
This is exact for any ``h``, so the substep only sets where the state is sampled: ``h`` equal to
the communication step costs one matrix-vector product per communication step.

``A`` and ``B`` come from ``model.state_space()``. With the nonlinear :class:`PlantModel` that is
the plant **linearised** at the upright rest state: this stepper then integrates the linearised
plant, not the nonlinear one (``x`` is the deviation from the rest state, which is zero). It never
calls ``rhs``: ``nfev`` stays 0.
"""
from __future__ import annotations

import numpy as np

from .base import Stepper

__all__ = ["ExactExponential", "zoh_discretize"]


def zoh_discretize(A: np.ndarray, B: np.ndarray, h: float):
    """``(Phi, Gamma)`` of the zero-order-hold discretisation of ``(A, B)`` over ``h``."""
    nx, m = B.shape
    M = np.zeros((nx + m, nx + m))
    M[:nx, :nx] = A * h
    M[:nx, nx:] = B * h
    E = _expm(M)
    return np.ascontiguousarray(E[:nx, :nx]), np.ascontiguousarray(E[:nx, nx:])


class ExactExponential(Stepper):
    """Exact exponential (matrix exponential, zero-order hold) for the linearised plant."""

    name = "exponential"
    order = np.inf  # exact on the linear model for every h

    def _init_method(self):
        if not hasattr(self.model, "state_space"):
            raise TypeError("the exponential stepper needs model.state_space() -> (A, B, C, D)")
        A, B = self.model.state_space()[:2]
        A = np.asarray(A, dtype=float)
        B = np.asarray(B, dtype=float).reshape(self.nx, -1)
        if A.shape != (self.nx, self.nx) or B.shape[1] != 1:
            raise ValueError(f"exponential: need A of shape ({self.nx}, {self.nx}) and B with one "
                             f"column, got {A.shape} and {B.shape}")
        self._A, self._B = A, B
        self._cache = {}          # h -> (Phi, gamma) for the last few substep sizes
        self._key = None

    def _matrices(self, h, u):
        """``Phi(h)`` and ``Gamma(h) u``, cached for the last ``(h, u)``."""
        if (h, u) != self._key:
            pair = self._cache.get(h)
            if pair is None:
                Phi, Gamma = zoh_discretize(self._A, self._B, h)
                pair = (Phi, Gamma[:, 0].copy())
                if len(self._cache) >= 4:
                    self._cache.pop(next(iter(self._cache)))
                self._cache[h] = pair
            self._Phi, self._gu = pair[0], pair[1] * u
            self._key = (h, u)
        return self._Phi, self._gu

    def _step_fixed(self, t, y, h):
        Phi, gu = self._matrices(h, self._u)
        return Phi.dot(y) + gu


def _expm(M):
    """scipy's matrix exponential (imported on first use: an FMU's start does not need it)."""
    import scipy.linalg

    return scipy.linalg.expm(M)
