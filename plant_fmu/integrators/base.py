"""The stepper contract shared by every integration method (the shape of scipy's ``OdeSolver``).

A :class:`Stepper` owns the time ``t``, the state ``y``, the input ``u`` held constant over an
advance (zero-order hold), the status and the counters ``nfev`` (right-hand side evaluations),
``njev`` (Jacobian evaluations), ``nlu`` (LU factorisations or inversions), ``nsteps`` (accepted substeps) and
``nrejected`` (rejected substeps of the adaptive methods). Each method implements one substep:

* fixed-step methods implement ``_step_fixed(t, y, h) -> y_new`` (or ``None`` after setting
  ``self._fail_msg``); the base class keeps the grid ``t = t_base + k*h`` (time from integers),
  lands exactly on the requested end time and shortens the last substep when the end time is off
  the grid (the grid then restarts there);
* adaptive methods implement ``_step_adaptive(t_bound) -> (ok, message)``, which takes one
  accepted step of at most ``t_bound - t`` and updates ``t`` and ``y`` itself.

A failure is a status with a message, never a silent NaN: ``advance`` returns ``(False, reason)``,
sets ``status = "failed"`` and leaves ``y`` at the last good state.

The model is any object with ``rhs(t, x, u)``, ``nq`` and ``nx`` (state ``x = [q, qd]``); some
methods use more (``jac``, ``state_space``). Steppers know nothing of FMI.
"""
from __future__ import annotations

import math

import numpy as np

from fmu_common.checks import check_real

__all__ = ["Stepper", "IntegratorError", "RUNNING", "FAILED", "numerical_jacobian"]

RUNNING = "running"
FAILED = "failed"

_EPS = float(np.finfo(float).eps)
#: A substep that ends within this fraction of h of the requested end time lands on it.
_SNAP = 1e-7


class IntegratorError(RuntimeError):
    """Raised by :meth:`Stepper.step` on a failed stepper and by ``raise_for_status``."""


def _check_tol(name, value, n):
    """A positive finite tolerance, scalar or one per state component."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return check_real(name, float(arr), low=0.0, high=math.inf, high_open=True)
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got shape {arr.shape}")
    if not (np.all(np.isfinite(arr)) and np.all(arr > 0)):
        raise ValueError(f"{name} is out of range; allowed: every entry in (0, inf)")
    return arr.copy()


def _to_json(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def numerical_jacobian(fun, t, y, u, f0, out=None):
    """Forward-difference Jacobian of ``fun(t, y, u)`` at ``y``, given ``f0 = fun(t, y, u)``."""
    n = y.size
    J = np.empty((n, n)) if out is None else out
    yp = y.copy()
    for j in range(n):
        yj = y[j]
        d = math.sqrt(_EPS) * max(abs(yj), 1.0)
        yp[j] = yj + d
        d = yp[j] - yj               # the representable increment
        J[:, j] = (fun(t, yp, u) - f0) / d
        yp[j] = yj
    return J


def _cap_message(max_steps, t, t_end) -> str:
    return (f"the substep cap of {max_steps} per call was reached at t = {t!r} before "
            f"t_end = {t_end!r}")


class Stepper:
    """Base class of all methods. Use :func:`plant_fmu.integrators.make_stepper` to build one.

    Parameters
    ----------
    model : object with ``rhs(t, x, u)``, ``nq``, ``nx`` (per method ``jac``, ``state_space``...).
    t0, y0 : initial time and state ``[q, qd]`` (length ``model.nx``).
    u : input held constant over the next :meth:`advance` (zero-order hold).
    h : the fixed substep (fixed-step methods) or the initial step (adaptive methods).
    rtol, atol : error tolerances of the adaptive methods, Newton tolerances of the implicit ones.
    rho_inf : spectral radius at infinity of the generalized-alpha method (accepted by all).
    **options : method-specific options (each class's ``OPTIONS``); unknown ones raise TypeError.
    """

    #: registry name, set by each subclass
    name: str = ""
    #: order of accuracy of the method
    order: int = 0
    #: whether substeps are chosen by error control (may be switched by an ``adaptive`` option)
    adaptive: bool = False
    #: method-specific options and their defaults
    OPTIONS: dict = {}
    #: whether the method evaluates a polynomial input (:meth:`set_input`) at its stage times;
    #: the others need a held input
    POLYNOMIAL_INPUT: bool = False

    def __init__(self, model, t0, y0, u=0.0, h=1e-3, rtol=1e-6, atol=1e-9, rho_inf=0.8,
                 **options):
        unknown = sorted(set(options) - set(self.OPTIONS))
        if unknown:
            allowed = ", ".join(sorted(self.OPTIONS)) or "none"
            raise TypeError(f"{self.name}: unknown option(s) {', '.join(unknown)}; "
                            f"allowed: {allowed}")
        for attr in ("rhs", "nq", "nx"):
            if not hasattr(model, attr):
                raise TypeError(f"model lacks the attribute {attr!r} that steppers need")
        self.model = model
        self.nq = int(model.nq)
        self.nx = int(model.nx)
        self._fun = model.rhs
        self.t = check_real("t0", t0, allow_inf=False)
        y0 = np.array(y0, dtype=float)
        if y0.shape != (self.nx,):
            raise ValueError(f"y0 must have shape ({self.nx},), got {y0.shape}")
        if not np.all(np.isfinite(y0)):
            raise ValueError("y0 must be finite")
        self.y = y0
        self._u = check_real("u", float(u))
        # polynomial input u(t) = u + du (t - tu) + d2u (t - tu)^2 / 2 (set_input); 0: held
        self._du = self._d2u = 0.0
        self._tu = self.t
        self.h = check_real("h", h, low=0.0, high=math.inf, high_open=True)
        self.rtol = check_real("rtol", rtol, low=0.0, high=1.0)
        self.atol = _check_tol("atol", atol, self.nx)
        self.rho_inf = check_real("rho_inf", rho_inf, low=0.0, high=1.0, low_open=False)
        opts = dict(self.OPTIONS)
        opts.update(options)
        self.options = opts
        self.status = RUNNING
        self.message = None
        self.nfev = self.njev = self.nlu = self.nsteps = self.nrejected = 0
        # the fixed grid t = t_base + k*h
        self._t_base = self.t
        self._k = 0
        self._fail_msg = None
        self._init_method()
        self._u_prev = self._input_key()  # the input the method's cached data were computed with

    # ------------------------------------------------------------------ hooks for the methods
    def _init_method(self):
        """Validate options and precompute; called once at the end of ``__init__``."""

    def _input_changed(self):
        """Called before an advance or step when ``u`` differs from the previous one."""

    def _step_fixed(self, t, y, h):  # pragma: no cover - abstract
        raise NotImplementedError

    def _step_adaptive(self, t_bound):  # pragma: no cover - abstract
        raise NotImplementedError

    def _advance_adaptive(self, t_end, max_steps=None):
        """Adaptive steps up to ``t_end``: ``(ok, message)``; at most ``max_steps`` steps (then
        ``(False, why)``). Methods may replace this loop by a compiled one."""
        step = self._step_adaptive
        n = 0
        while self.t < t_end:
            ok, msg = step(t_end)
            if not ok:
                return False, msg
            n += 1
            if max_steps is not None and n >= max_steps and self.t < t_end:
                return False, _cap_message(max_steps, self.t, t_end)
        return True, None

    def _commit(self):
        """Called after a fixed substep's new state passed the checks (commit auxiliary data)."""

    # ------------------------------------------------------------------ implicit fixed steps
    def _solve_fixed(self, t, y, h):  # pragma: no cover - abstract
        """One implicit substep: ``y_new``, or None (and ``_fail_msg``) if Newton fails."""
        raise NotImplementedError

    def _save_aux(self):
        """The auxiliary data a substep changes on commit (restored if a halving fails)."""

    def _restore_aux(self, saved):
        pass

    def _step_fixed_halving(self, t, y, h, depth):
        """An implicit substep; if its Newton iteration fails even with a fresh Jacobian, it is
        retried as two half substeps, recursively ``depth`` more times (the grid is kept: the
        caller sees one substep of ``h``). Each retry counts in ``nrejected``."""
        y_new = self._solve_fixed(t, y, h)
        if y_new is not None or depth == 0:
            return y_new
        self.nrejected += 1
        saved = self._save_aux()
        hh = 0.5 * h
        y_mid = self._step_fixed_halving(t, y, hh, depth - 1)
        if y_mid is not None:
            self._commit()
            y_new = self._step_fixed_halving(t + hh, y_mid, hh, depth - 1)
        if y_new is None:
            self._restore_aux(saved)
        return y_new

    def _method_state(self) -> dict:
        return {}

    def _set_method_state(self, s: dict):
        pass

    # ------------------------------------------------------------------ input
    @property
    def u(self) -> float:
        return self._u

    @u.setter
    def u(self, value):
        """A held input (zero-order hold)."""
        self._u = float(value)
        self._du = self._d2u = 0.0

    def set_input(self, u, du=0.0, d2u=0.0, t=None):
        """The input over the next advance as the polynomial
        ``u(s) = u + du (s - t) + d2u (s - t)^2 / 2`` (``t``: the current time by default), as the
        input derivatives of FMI's ``fmi2SetRealInputDerivatives``. Methods with
        ``POLYNOMIAL_INPUT`` evaluate it at their stage times; for the others ``du`` and ``d2u``
        must be 0 (``ValueError``): hold the average over the step instead."""
        du, d2u = float(du), float(d2u)
        if (du or d2u) and not self.POLYNOMIAL_INPUT:
            raise ValueError(f"{self.name} takes a held input only (du = d2u = 0), got "
                             f"du = {du!r}, d2u = {d2u!r}")
        self._u, self._du, self._d2u = float(u), du, d2u
        self._tu = self.t if t is None else float(t)

    def _u_at(self, t):
        """The input at time ``t``."""
        if self._du or self._d2u:
            s = t - self._tu
            return self._u + s * (self._du + 0.5 * s * self._d2u)
        return self._u

    def _input_key(self):
        return (self._u, self._du, self._d2u, self._tu) if (self._du or self._d2u) else self._u

    # ------------------------------------------------------------------ public driving API
    def advance(self, t_end, max_steps=None) -> tuple[bool, str | None]:
        """Substep from ``t`` to exactly ``t_end`` with the input ``u`` held constant.

        Returns ``(True, None)``, or ``(False, reason)`` with ``status = "failed"`` and ``y`` left
        at the last good state. A failed stepper stays failed (restore one with :meth:`set_state`).
        ``max_steps`` bounds the substeps of an adaptive method (reaching it fails the stepper).
        """
        t_end = float(t_end)
        if self.status == FAILED:
            return False, self.message
        if not math.isfinite(t_end):
            raise ValueError(f"t_end = {t_end!r} must be finite")
        t = self.t
        if t_end <= t:
            if t_end < t - 8 * _EPS * max(1.0, abs(t)):
                raise ValueError(f"t_end = {t_end!r} is before the current time t = {t!r}")
            return True, None
        if not self._prepare_input():
            return False, self.message
        # Overflow and NaN are reported by the status, not by floating-point warnings.
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            if self.adaptive:
                ok, msg = self._advance_adaptive(t_end, max_steps)
                if not ok:
                    return False, self._fail(msg)
            else:
                ok, msg = self._advance_fixed(t_end)
                if not ok:
                    return False, self._fail(msg)
        return True, None

    def step(self, t_bound=None) -> tuple[bool, str | None]:
        """Take one substep (at most to ``t_bound``); as ``scipy.integrate.OdeSolver.step``.

        Raises :class:`IntegratorError` on a failed stepper.
        """
        if self.status == FAILED:
            raise IntegratorError(f"step() on a failed stepper: {self.message}")
        t_bound = math.inf if t_bound is None else float(t_bound)
        if not t_bound > self.t:
            raise ValueError(f"t_bound = {t_bound!r} must be after the current time t = {self.t!r}")
        if not self._prepare_input():
            return False, self.message
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            ok, msg = self._substep(t_bound)
        if not ok:
            return False, self._fail(msg)
        return True, None

    def raise_for_status(self):
        """Raise :class:`IntegratorError` with the failure message if the stepper has failed."""
        if self.status == FAILED:
            raise IntegratorError(self.message)

    # ------------------------------------------------------------------ internals
    def _prepare_input(self) -> bool:
        key = self._input_key()
        if key != self._u_prev:
            if not math.isfinite(self._u + self._du + self._d2u):
                self._fail(f"non-finite input u = {self._u!r} (du = {self._du!r}, d2u = "
                           f"{self._d2u!r}) at t = {self.t!r}")
                return False
            self._input_changed()
            self._u_prev = key
        return True

    def _fail(self, msg):
        self.status = FAILED
        self.message = msg
        return msg

    @property
    def _substep(self):
        return self._step_adaptive if self.adaptive else self._fixed_substep

    def _advance_fixed(self, t_end):
        """The loop of :meth:`advance` for fixed steps: whole substeps on the grid
        ``t_base + k*h`` (the last one lands exactly on ``t_end`` when that is on the grid), then
        at most one shortened substep (as :meth:`_fixed_substep`, with less bookkeeping)."""
        h, t_base, k = self.h, self._t_base, self._k
        n_grid = (t_end - t_base) / h
        n_round = round(n_grid)
        if abs(n_grid - n_round) <= _SNAP + 4 * _EPS * abs(t_end) / h:
            n_full, short = n_round - k, False
        else:
            n_full, short = math.floor(n_grid) - k, True
        t, y, k, msg = self._full_substeps(self.t, self.y, h, t_base, k, n_full)
        if msg is None and not short:
            t = t_end
        self.nsteps += k - self._k
        self.t, self.y, self._k = t, y, k
        if msg is not None:
            return False, msg
        if short:
            return self._fixed_substep(t_end)
        return True, None

    def _full_substeps(self, t, y, h, t_base, k, n):
        """``n`` substeps of ``h`` from grid point ``k``; ``(t, y, k, failure message or None)``
        after the last good substep. Methods may replace this loop by a compiled one."""
        step, commit = self._step_fixed, self._commit
        for _ in range(n):
            y_new = step(t, y, h)
            if y_new is None:
                return t, y, k, self._fail_msg
            s = y_new.dot(y_new)
            if not s < math.inf and not np.all(np.isfinite(y_new)):
                return t, y, k, f"non-finite state after the substep from t = {t!r} (h = {h!r})"
            commit()
            k += 1
            y = y_new
            t = t_base + k * h
        return t, y, k, None

    def _fixed_substep(self, t_bound):
        """One substep on the grid ``t_base + k*h``, shortened to land on ``t_bound``."""
        h = self.h
        k = self._k + 1
        t_grid = self._t_base + k * h
        snap = _SNAP * h + 4 * _EPS * abs(t_grid)
        rebase = False
        if t_grid < t_bound - snap:
            t_new, hs = t_grid, h
        elif t_grid <= t_bound + snap:
            t_new, hs = t_bound, h        # on the grid: land exactly on t_bound
        else:
            t_new, hs = t_bound, t_bound - self.t
            rebase = True                 # off the grid: shorten, restart the grid at t_bound
        y_new = self._step_fixed(self.t, self.y, hs)
        if y_new is None:
            return False, self._fail_msg
        s = y_new.dot(y_new)
        if not s < math.inf and not np.all(np.isfinite(y_new)):
            return False, f"non-finite state after the substep from t = {self.t!r} (h = {hs!r})"
        self._commit()
        self.y = y_new
        self.t = t_new
        if rebase:
            self._t_base, self._k = t_bound, 0
        else:
            self._k = k
        self.nsteps += 1
        return True, None

    # ------------------------------------------------------------------ snapshots
    _STATE_KEYS = ("t", "y", "_u", "_du", "_d2u", "_tu", "h", "status", "message", "nfev",
                   "njev", "nlu", "nsteps", "nrejected", "_t_base", "_k", "_u_prev")

    def get_state(self) -> dict:
        """A JSON-able snapshot of all internal state (restore it with :meth:`set_state`)."""
        snap = {"method": self.name}
        for key in self._STATE_KEYS:
            snap[key.lstrip("_")] = _to_json(getattr(self, key))
        snap["method_state"] = {k: _to_json(v) for k, v in self._method_state().items()}
        return snap

    def set_state(self, snap: dict):
        """Restore a snapshot of :meth:`get_state`; the following advances are bit-identical."""
        if snap.get("method") != self.name:
            raise ValueError(f"snapshot of method {snap.get('method')!r} given to a "
                             f"{self.name!r} stepper")
        y = np.array(snap["y"], dtype=float)
        if y.shape != (self.nx,):
            raise ValueError(f"snapshot state has shape {y.shape}, expected ({self.nx},)")
        for key in self._STATE_KEYS:
            value = snap[key.lstrip("_")]
            setattr(self, key, value)
        self.y = y
        self.t, self._t_base, self.h = float(self.t), float(self._t_base), float(self.h)
        self._u, self._du, self._d2u, self._tu = (float(self._u), float(self._du),
                                                  float(self._d2u), float(self._tu))
        if isinstance(self._u_prev, list):          # JSON turned the polynomial key to a list
            self._u_prev = tuple(self._u_prev)
        self._set_method_state(snap["method_state"])

    def __repr__(self):
        return (f"<{type(self).__name__} t={self.t!r} status={self.status} nfev={self.nfev} "
                f"njev={self.njev} nlu={self.nlu} nsteps={self.nsteps}>")


def _array_or_none(v, shape=None):
    if v is None:
        return None
    a = np.array(v, dtype=float)
    if shape is not None and a.shape != shape:
        raise ValueError(f"snapshot array has shape {a.shape}, expected {shape}")
    return a
