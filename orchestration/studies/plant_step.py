"""Whether the plant FMU's own integrator is stable at ``plant.step``: the check before a run.

The plant FMU advances each communication step ``H`` in substeps of ``h = plant.step`` with the
method ``plant.integrator`` (:class:`plant_fmu.integrators.base.Stepper`): whole substeps ``h``,
then one shortened substep when ``H`` is not a multiple of ``h`` (the grid restarts there). The
largest substep is therefore ``min(h, H)`` (``min(h, master.max_step)`` with the adaptive
master): that is the substep judged here. The plant is its linearisation at the upright rest
state ``x' = A x`` (the run's rung: ``linear`` and ``nonlinear`` as the scene's
``plant.gravity_preload`` says; ``stiffened`` with the self-weight's preload, whose
linearisation its model is), with the cart's position and velocity left out: ``x`` appears in no
equation and ``x_dot`` only in ``x``'s, so they add the eigenvalue 0 twice to ``A`` and 1 twice
to every method's substep, neither growing, and would only blur the eigenvalues numerically.

* A Runge-Kutta method (``euler``, ``rk4``: the FMU's own tableau ``(A_rk, b)``) takes one
  substep as ``R(hA)``, ``R(z) = 1 + z b.(I - z A_rk)^-1 1`` its stability function (a
  polynomial for an explicit tableau: ``1 + z + z^2/2 + z^3/6 + z^4/24`` for RK4), whose
  eigenvalues are ``R(h lambda)`` for the eigenvalues ``lambda`` of ``A``. It amplifies a mode
  that the exact flow does not when

      |R(h lambda)| > max(1, |exp(h lambda)|) + TOLERANCE:

  a decaying or undamped mode must not grow, and a growing one (the inverted pendulum's
  ``+sqrt(g/l)``-like root, about +7/s: physics, not numerics) must not grow faster than it does.
* Symplectic Euler is partitioned (velocity, then position with the new velocity): its substep is
  no function of ``hA``, and as the plant's damping is not proportional to its stiffness (the
  modes are damped in the beam's coordinates, coupled to the rigid ones by the mass matrix), a
  mode-by-mode oscillator would move its limit by about 1e-3. Its substep matrix on the whole
  linearised plant is built instead, and the method is unstable when more of its eigenvalues
  exceed ``1 + TOLERANCE`` in modulus than ``A`` has eigenvalues with ``|exp(h lambda)| > 1 +
  TOLERANCE`` (the same criterion with the pairing of discrete and continuous eigenvalues left
  to their count: the growing roots are slow and their discrete ones grow as they do).
* No limit: ``dopri5`` (the FMU runs it adaptively: ``plant.step`` is its initial step, the
  largest is unbounded, and its error control rejects a step that amplifies a mode),
  ``radau`` (adaptive, and A-stable), ``genalpha`` (A-stable for ``rho_inf`` in [0, 1]) and
  ``exponential`` (the exact flow of the linear plant, the only one it runs). The exact rung
  (``plant.fidelity = "exact"``) steps by its own implicit generalized alpha: not checked; nor is
  Model Exchange (``master.interface``), where the plant FMU's method is not used.

The largest stable step is the first ``h`` where the criterion fails (all smaller steps are
stable), found on a log grid of ``h |lambda_max|`` and refined by bisection to rounding. Above it a
run is refused (:func:`check`'s :attr:`PlantStepCheck.error`); within :data:`MARGIN` below it, it
is warned (the nonlinear and stiffened rungs' frequencies move with the motion). numpy only: a
run's preflight imports nothing heavy.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import numpy as np

from plant_fmu.dynamics import plant_model
from plant_fmu.integrators import REGISTRY, ExplicitRungeKutta
from plant_fmu.interface import FIDELITIES
from plant_fmu.params import PlantParams

__all__ = ["TOLERANCE", "MARGIN", "NO_LIMIT", "PlantStepCheck", "rung_params", "drift_free",
           "stability_function", "unstable", "step_limit", "stable_floor", "largest_substep",
           "check", "checks"]

#: growth per substep a method may add to a mode beyond the exact flow's (1e-9: a millionth
#: after a million substeps; far above the rounding of ``|R|``, far below any real instability)
TOLERANCE = 1e-9
#: a substep within this fraction below the limit is warned, not refused
MARGIN = 0.1
#: the methods without a step limit here, and why
NO_LIMIT = {
    "dopri5": "adaptive in the plant FMU: plant.step is its initial step and its error control "
              "keeps it stable",
    "radau": "A-stable (and adaptive in the plant FMU)",
    "genalpha": "A-stable",
    "exponential": "the exact flow of the linear plant",
}
#: the grid of ``h |lambda_max|`` searched for the first unstable substep
_Z_GRID = np.geomspace(1e-6, 20.0, 800)


def rung_params(p: PlantParams, fidelity: str) -> PlantParams | None:
    """The parameters whose linearisation at the upright rest state is the rung's: the
    stiffened rung's is the preload rung's; ``None`` for the exact rung (not checked)."""
    if fidelity == "exact":
        return None
    if fidelity == "stiffened":
        return replace(p, gravity_preload=True)
    return p


def drift_free(p: PlantParams):
    """``(A, nq)``: the linearised plant's ``A`` (state ``[q, qd]``, ``nq`` positions) without
    the cart's position and velocity, when (as here) nothing but ``x`` depends on them."""
    A = np.array(plant_model(p).state_space()[0], dtype=float)
    nq = A.shape[0] // 2
    e = np.zeros(A.shape[0])
    e[0] = 1.0
    if np.any(A[:, 0]) or np.any(A[:, nq] - e):
        return A, nq
    keep = np.r_[1:nq, nq + 1:2 * nq]
    return A[np.ix_(keep, keep)], nq - 1


def stability_function(method: str, z):
    """``R(z)`` of an explicit Runge-Kutta ``method`` of the plant FMU (its tableau), at the
    complex ``z`` (an array)."""
    cls = REGISTRY.get(method)
    if cls is None or not issubclass(cls, ExplicitRungeKutta):
        raise ValueError(f"method = {method!r} has no stability function here; allowed: "
                         + ", ".join(k for k, c in REGISTRY.items()
                                     if issubclass(c, ExplicitRungeKutta)))
    a, b = np.asarray(cls.A, dtype=float), np.asarray(cls.B, dtype=float)
    z = np.asarray(z, dtype=complex)
    g = []                                  # g_i = 1 + z sum_j a_ij g_j (explicit: j < i)
    for i in range(b.size):
        g.append(1.0 + z * sum((a[i, j] * g[j] for j in range(i) if a[i, j]), 0.0))
    return 1.0 + z * sum(bi * gi for bi, gi in zip(b, g) if bi)


def _symplectic_euler(A, nq, h):
    """Symplectic Euler substeps on ``[q, qd]' = A [q, qd]`` as matrices, one per entry of the
    array ``h``: ``qd+ = qd + h (A21 q + A22 qd)``, then ``q+ = q + h qd+``."""
    h = np.asarray(h, dtype=float)[..., None, None]
    E = np.eye(A.shape[0])
    S = np.empty(h.shape[:-2] + E.shape)
    S[..., nq:, :] = E[nq:] + h * A[nq:]
    S[..., :nq, :] = E[:nq] + h * S[..., nq:, :]
    return S


def _rk_excess(method, lam, h):
    """``|R(h lambda)| - max(1, |exp(h lambda)|)`` per eigenvalue (last axis) and step."""
    z = np.asarray(h, dtype=float)[..., None] * lam
    return np.abs(stability_function(method, z)) - np.maximum(1.0, np.exp(z.real))


def unstable(method: str, A, nq: int, h, lam=None):
    """Whether one substep ``h`` (a number or an array of them) of ``method`` amplifies a mode
    of ``x' = A x`` that the exact flow does not (the module docstring's criterion); ``lam``:
    ``A``'s eigenvalues, if known."""
    lam = np.linalg.eigvals(A) if lam is None else lam
    h = np.asarray(h, dtype=float)
    if method == "symplectic_euler":
        mu = np.abs(np.linalg.eigvals(_symplectic_euler(A, nq, h)))
        growing = np.sum(np.exp(h[..., None] * lam.real) > 1.0 + TOLERANCE, axis=-1)
        return np.sum(mu > 1.0 + TOLERANCE, axis=-1) > growing
    return np.max(_rk_excess(method, lam, h), axis=-1) > TOLERANCE


#: Levels of the bisection evaluated at once by :func:`_bisect`.
_BISECT_LEVELS = 6


def _bisect(bad, lo: float, hi: float, levels: int = _BISECT_LEVELS):
    """The bisection of ``[lo, hi]`` (``bad(lo)`` false, ``bad(hi)`` true) down to
    ``hi - lo <= 4 eps hi``: ``(lo, hi)``, the very pair the plain loop (``mid = (lo + hi) / 2``,
    then ``hi = mid`` where ``bad(mid)``, else ``lo = mid``) ends with, at a sixth of the
    calls (``levels = 6``). ``bad`` takes an array of steps: the midpoints of the next ``levels`` levels of the
    bisection's tree are judged in one call (each computed as the loop computes
    it), and the walk down the tree takes the loop's path through them."""
    eps = np.finfo(float).eps
    while hi - lo > 4 * eps * hi:
        # the tree in heap order: node i halves the interval of its parent; its children are
        # 2 i + 1 (the lower half) and 2 i + 2 (the upper)
        spans, mids = [(lo, hi)], []
        for i in range(2 ** levels - 1):
            a, b = spans[i]
            m = 0.5 * (a + b)
            mids.append(m)
            spans += [(a, m), (m, b)]
        verdict = bad(np.array(mids))
        i = 0
        for _ in range(levels):
            if not hi - lo > 4 * eps * hi:
                break
            if verdict[i]:
                hi, i = mids[i], 2 * i + 1
            else:
                lo, i = mids[i], 2 * i + 2
    return lo, hi


def _limited(method: str) -> bool:
    """Whether ``method`` has a step limit (False: :data:`NO_LIMIT`); a ValueError names an
    unknown one."""
    if method in NO_LIMIT:
        return False
    if method not in REGISTRY:
        raise ValueError(f"method = {method!r} is unknown; allowed: {', '.join(REGISTRY)}")
    return True


@functools.lru_cache(maxsize=256)
def _grid(method: str, p: PlantParams):
    """``(A, nq, lam, fastest, hs, first)``: the search of :func:`step_limit` on its log grid
    ``hs`` of steps, ``first`` the index of the first unstable one (``None``: none is)."""
    A, nq = drift_free(p)
    lam = np.linalg.eigvals(A)
    fastest = complex(lam[np.argmax(np.abs(lam))])
    hs = _Z_GRID / abs(fastest)
    bad = np.flatnonzero(unstable(method, A, nq, hs, lam))
    return A, nq, lam, fastest, hs, (int(bad[0]) if bad.size else None)


def stable_floor(method: str, p: PlantParams) -> float:
    """A step at or below :func:`step_limit`'s ``h``, from its grid alone (no bisection): the
    last stable step of the grid before the first unstable one (the bisection starts there and
    only moves up), ``inf`` when there is no limit, 0 when every step is unstable."""
    if not _limited(method):
        return math.inf
    *_, hs, first = _grid(method, p)
    return math.inf if first is None else 0.0 if first == 0 else float(hs[first - 1])


@functools.lru_cache(maxsize=256)
def step_limit(method: str, p: PlantParams):
    """``(h, lambda)``: the largest stable substep of ``method`` on the plant ``p`` linearised at
    the upright rest state (the first ``h`` where :func:`unstable`; every smaller step on the
    search grid is stable) and the eigenvalue that limits it (Runge-Kutta) or the fastest
    (symplectic Euler); ``None`` for a method without a limit (:data:`NO_LIMIT`). ``h = 0``:
    unstable at every step (explicit Euler on an undamped mode)."""
    if not _limited(method):
        return None
    A, nq, lam, fastest, hs, first = _grid(method, p)
    if first is None:
        return None
    if first == 0:
        return 0.0, fastest
    # a Runge-Kutta step's verdict is a few array operations, whatever the number of steps
    # judged at once; symplectic Euler's an eigenvalue problem per step
    lo, hi = _bisect(lambda h: unstable(method, A, nq, h, lam),
                     float(hs[first - 1]), float(hs[first]),
                     1 if method == "symplectic_euler" else _BISECT_LEVELS)
    if method == "symplectic_euler":
        return lo, fastest
    return lo, complex(lam[np.argmax(_rk_excess(method, lam, hi))])


def largest_substep(scene) -> float:
    """The largest substep the plant FMU takes in a run of ``scene``: ``plant.step``, or the
    communication step when that is shorter (one shortened substep per step)."""
    m = scene.master
    H = m.max_step if m.adaptive else m.step
    return min(scene.plant.step, H)


def _floor(x: float, digits: int = 7) -> float:
    """``x`` rounded down to ``digits`` significant digits (a step that is itself stable)."""
    if x <= 0:
        return x
    e = math.floor(math.log10(x)) - digits + 1
    return math.floor(x / 10.0 ** e) * 10.0 ** e


@dataclass(frozen=True)
class PlantStepCheck:
    """The verdict on one rung: ``method``, ``plant.step``, the largest ``substep``, the
    ``fastest`` mode's ``|lambda|`` (rad/s), the ``rung``, the FMU flavour (``fmus``), the
    linearised rung's parameters and :func:`stable_floor`; the largest stable :attr:`limit`
    (``None``: none) and the :attr:`mode` (eigenvalue, 1/s) that sets it are found (by
    :func:`step_limit`'s bisection) only when the verdict needs them: a substep well below the
    floor is ``"ok"`` whatever the limit above it (a sweep's preflight, about a millisecond a run
    less)."""

    method: str
    step: float
    substep: float
    fastest: float
    rung: str
    fmus: str
    params: PlantParams = field(repr=False)
    floor: float = field(repr=False)

    @functools.cached_property
    def _found(self):
        return step_limit(self.method, self.params)

    @property
    def limit(self) -> float | None:
        return None if self._found is None else self._found[0]

    @property
    def mode(self) -> complex | None:
        return None if self._found is None else self._found[1]

    @property
    def verdict(self) -> str:
        """``"beyond"`` the limit, ``"near"`` it (within :data:`MARGIN`), or ``"ok"``."""
        if self.substep <= (1.0 - MARGIN) * self.floor:     # the limit is at least the floor
            return "ok"
        if self.limit is None:
            return "ok"
        if self.substep > self.limit:
            return "beyond"
        return "near" if self.substep > (1.0 - MARGIN) * self.limit else "ok"

    def _what(self) -> str:
        sub = ("" if self.substep == self.step else
               f" (its substeps: the communication step, {self.substep:g} s)")
        return f"plant.step = {self.step:g} s{sub}"

    def _where(self) -> str:
        lam = self.fastest if self.mode is None else abs(self.mode)
        if math.isclose(lam, self.fastest, rel_tol=1e-9):
            mode = f"fastest mode ({lam:.6g} rad/s"
        else:
            mode = f"mode at {lam:.6g} rad/s (its fastest: {self.fastest:.6g} rad/s"
        return (f"plant.integrator = {self.method!r} on the {self.rung} plant's {mode}, "
                "linearised upright)")

    def _instead(self) -> str:
        others = ("'dopri5' (adaptive)" if self.fmus == "native" else
                  "'radau' or 'genalpha' (A-stable) or 'dopri5' (adaptive)")
        return f"plant.integrator = {others} has no limit"

    @property
    def error(self) -> str | None:
        """One line when the substep is beyond the limit, else ``None``."""
        if self.verdict != "beyond":
            return None
        if self.limit == 0.0:
            return (f"{self._what()} is unstable: {self._where()} amplifies it at every step; "
                    f"{self._instead()}")
        return (f"{self._what()} is beyond the stability limit of {self._where()}: the largest "
                f"stable plant.step is {_floor(self.limit):.7g} s; {self._instead()}")

    @property
    def warning(self) -> str | None:
        """One line when the substep is within :data:`MARGIN` of the limit, else ``None``."""
        if self.verdict != "near":
            return None
        return (f"{self._what()} is within {100 * MARGIN:g} % of the stability limit of "
                f"{self._where()}, {_floor(self.limit):.7g} s; the motion moves the "
                f"{self.rung} rung's frequencies: a smaller plant.step is safer")


def check(scene, fidelity: str | None = None) -> PlantStepCheck | None:
    """The verdict on ``scene``'s plant step on its rung (or on ``fidelity``'s, for a ladder's
    rung); ``None`` where it does not apply: the exact rung, Model Exchange, or a model not
    chosen yet (``plant.n_modes`` or the rung ``"auto"``)."""
    fidelity = scene.plant.fidelity if fidelity is None else fidelity
    if (scene.master.interface != "co-simulation" or scene.plant.n_modes_auto
            or fidelity == "auto"):
        return None
    p = rung_params(scene.plant.params, fidelity)
    if p is None:
        return None
    method = scene.plant.integrator
    floor = stable_floor(method, p)
    lam = _grid(method, p)[2] if _limited(method) else np.linalg.eigvals(drift_free(p)[0])
    fastest = float(np.max(np.abs(lam))) if lam.size else 0.0
    return PlantStepCheck(method, scene.plant.step, largest_substep(scene), fastest, fidelity,
                          scene.master.fmus, p, floor)


def checks(scene, rungs=None) -> list[PlantStepCheck]:
    """:func:`check` on each of ``rungs`` (default: the scene's rung; with ``plant.fidelity =
    "auto"`` every floating-frame rung, which its ladder may climb to), those that apply."""
    if rungs is None:
        rungs = (scene.plant.fidelity,) if scene.plant.fidelity != "auto" else \
            tuple(f for f in FIDELITIES if f != "exact")
    out = [check(scene, f) for f in rungs]
    return [c for c in out if c is not None]
