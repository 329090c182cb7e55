"""The communication steps at which a coupling's linearised co-simulation is stable, as intervals.

The spectral radius ``rho(H)`` of one step's transition matrix
(:func:`~orchestration.studies.stability.transition_matrix`) is not monotonic in the step ``H``:
beyond a few milliseconds a bending mode's alias meets the rigid mode or another mode, and
``rho`` crosses 1 several times. So the first crossing (the "largest stable step") is only the
lower edge of an unstable interval, often a narrow one above which the coupling is stable again.
:func:`scan` finds every crossing up to a maximum step and returns, per coupling, the
alternating stable and unstable intervals of ``[MIN_STEP, max_step]``:

* ``rho`` on a log grid of :data:`GRID_PER_DECADE` points per decade from :data:`MIN_STEP` to the maximum step, every coupling at once: the plant FMU's step
  maps (its substep's matrix and powers formed once,
  :class:`~orchestration.studies.stability.Spectra`) and the filter's
  exponentials are computed once per step and shared by the couplings, whose matrices are built
  and their eigenvalues found as stacks (the states that only add an eigenvalue 0 left out);
* where a complex pair of modulus near 1 comes nearest the real axis (there it can collide and
  split, one eigenvalue leaving the unit circle for a window narrower than the grid, on neither
  side of which ``rho`` shows it), the cells beside that grid point get :data:`REFINE` more
  points;
* at every discrete local maximum of ``rho`` below 1 it is maximised between the neighbouring
  points, at every local minimum above 1 minimised (golden section): one reaching across 1 is a
  window, both its edges refined;
* every change of sign of ``rho - 1`` is bisected to :data:`XTOL` (relative);
* each unstable interval's largest ``rho`` is maximised near the largest value seen in it.

Each refinement runs on the brackets of every coupling at once, the step maps computed once per
iteration. A window narrower than the grid's spacing that none of these signs shows can still
be missed (``docs/stability.md`` says how the scan was checked against a grid ten times finer).

BLAS runs on one thread meanwhile (threadpoolctl): the matrices are small, and scipy's matrix
exponential of a small matrix costs milliseconds instead of microseconds when OpenBLAS wakes its
threads on a busy machine.
"""
from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np

__all__ = ["MIN_STEP", "MAX_STEP", "GRID_PER_DECADE", "XTOL", "NEAR_CIRCLE", "NEAR_AXIS",
           "REFINE", "grid", "scan", "step_intervals", "one_blas_thread", "GROWN", "SETTLED",
           "probe_steps"]

#: the smallest communication step scanned (s); below it the loop is the continuous one
MIN_STEP = 1e-4
#: the default largest step scanned (s): ``flexpend stability --max-step``
MAX_STEP = 0.05
#: grid points per decade of the scan: ratio 1.0046 between neighbours. rho(Phi) exceeds 1 in
#: windows narrower than that too (an eigenvalue's modulus bumping over 1, a complex pair
#: splitting on the real axis), which the scan looks for between the grid points
GRID_PER_DECADE = 500
#: the relative precision of every boundary
XTOL = 1e-7
#: eigenvalues of at least this modulus are watched for collisions on the real axis
NEAR_CIRCLE = 0.98
#: a grid point where such an eigenvalue comes nearest the real axis (``|Im| / |lambda|`` a
#: local minimum below this) has both cells beside it refined by :data:`REFINE` points
NEAR_AXIS = 0.1
#: points added inside each cell refined
REFINE = 6
#: steps evaluated at once (bounds the stacks' memory)
_CHUNK = 512

_BLAS: list = []


@contextmanager
def one_blas_thread():
    """BLAS on one thread inside (threadpoolctl's controller found once per process)."""
    if not _BLAS:
        from threadpoolctl import ThreadpoolController
        _BLAS.append(ThreadpoolController())
    with _BLAS[0].limit(limits=1, user_api="blas"):
        yield


def grid(max_step: float, min_step: float = MIN_STEP,
         per_decade: int = GRID_PER_DECADE) -> np.ndarray:
    """The scan's steps: ``min_step * 10^(j / per_decade)`` up to ``max_step``, then
    ``max_step`` (the same points for every maximum)."""
    j = np.arange(int(math.floor(per_decade * math.log10(max_step / min_step) + 1e-9)) + 1)
    return np.unique(np.append(min_step * 10.0 ** (j / per_decade), max_step))


def _bisect(f, lo, hi, flo, level=1.0, xtol=XTOL):
    """The crossings of ``f = level`` in the brackets ``[lo_i, hi_i]`` (``f(lo_i) - level`` has
    the sign of ``flo_i``, ``f(hi_i)`` the other), all bisected at once in ``log H`` (``f`` takes
    an array of steps, one per bracket)."""
    lo, hi = np.array(lo, dtype=float), np.array(hi, dtype=float)
    if not lo.size:
        return lo
    below = np.asarray(flo) < level
    n = int(math.ceil(math.log2(max(np.max(hi / lo - 1), xtol) / xtol))) + 1
    for _ in range(max(n, 1)):
        mid = np.sqrt(lo * hi)
        same = (f(mid) < level) == below
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    return np.sqrt(lo * hi)


_GOLD = (math.sqrt(5.0) - 1.0) / 2.0


def _extremum(f, lo, hi, sign=1.0, iterations=18):
    """``(x, f(x))``: the maxima (``sign = 1``; minima: -1; one sign per bracket, or one for
    all) of ``f`` in the brackets ``[lo_i, hi_i]`` by golden-section search in ``log H``, all
    brackets at once (``f`` takes an array of steps, one per bracket)."""
    sign = np.broadcast_to(np.asarray(sign, dtype=float), np.shape(lo))
    g = lambda H: sign * f(H)  # noqa: E731
    a, b = np.log(np.asarray(lo, dtype=float)), np.log(np.asarray(hi, dtype=float))
    x1, x2 = b - _GOLD * (b - a), a + _GOLD * (b - a)
    f1, f2 = g(np.exp(x1)), g(np.exp(x2))
    for _ in range(iterations):
        left = f1 >= f2               # the extremum is in [a, x2]: x2 <- x1, a new x1
        b = np.where(left, x2, b)
        a = np.where(left, a, x1)
        new = np.where(left, b - _GOLD * (b - a), a + _GOLD * (b - a))
        fn = g(np.exp(new))
        x1, x2, f1, f2 = (np.where(left, new, x2), np.where(left, x1, new),
                          np.where(left, fn, f2), np.where(left, f1, fn))
    best = np.where(f1 >= f2, x1, x2)
    return np.exp(best), sign * np.maximum(f1, f2)


def _intervals(grids, radii, f, level: float = 1.0):
    """:func:`step_intervals` of several couplings at once: ``grids[c]``, ``radii[c]`` the steps
    and ``rho`` of coupling ``c``; ``f(H, c)``: ``rho`` at the steps ``H`` of the couplings
    ``c`` (arrays). Every refinement's brackets, of every coupling, go to ``f`` together."""
    n = len(grids)
    Hs = [np.asarray(g, dtype=float) for g in grids]
    rho = [np.asarray(r, dtype=float) for r in radii]
    up = [r >= level for r in rho]
    # the windows between the points: local maxima below the level, minima above it
    lo, hi, sign, who, at = [], [], [], [], []
    for c in range(n):
        r, u = rho[c], up[c]
        top = (r[1:-1] >= r[:-2]) & (r[1:-1] >= r[2:]) & ~u[1:-1]
        bottom = (r[1:-1] <= r[:-2]) & (r[1:-1] <= r[2:]) & u[1:-1]
        for mask, sg in ((top, 1.0), (bottom, -1.0)):
            i = np.flatnonzero(mask) + 1
            lo += list(Hs[c][i - 1])
            hi += list(Hs[c][i + 1])
            sign += [sg] * i.size
            who += [c] * i.size
            at += list(i)
    windows = [[] for _ in range(n)]          # (point index, where, rho there)
    if lo:
        who_a = np.array(who)
        x, v = _extremum(lambda H: f(H, who_a), lo, hi, sign)
        for c, k, t, w, sg in zip(who, at, x, v, sign):
            if (w >= level) if sg > 0 else (w < level):
                windows[c].append((int(k), float(t), float(w)))
    # the brackets: the sign changes, and both edges of every window
    lo, hi, flo, who = [], [], [], []
    for c in range(n):
        j = np.flatnonzero(up[c][1:] != up[c][:-1])
        lo += list(Hs[c][j])
        hi += list(Hs[c][j + 1])
        flo += list(rho[c][j])
        who += [c] * j.size
        for k, t, v in windows[c]:
            # the window holds t and lies between the points beside it, which are across
            left = Hs[c][k] if t > Hs[c][k] else Hs[c][k - 1]
            right = Hs[c][k] if t < Hs[c][k] else Hs[c][k + 1]
            lo += [left, t]
            hi += [t, right]
            flo += [rho[c][int(np.searchsorted(Hs[c], left))], v]
            who += [c, c]
    who_a = np.array(who, dtype=int)
    edges = _bisect(lambda H: f(H, who_a), lo, hi, flo, level) if lo else np.zeros(0)
    out, value = [], []
    for c in range(n):
        # every boundary with the side it opens: a crossing upwards opens an unstable interval
        mine = who_a == c
        marks = sorted(zip(edges[mine].tolist(), [f0 < level for f0, m in zip(flo, mine) if m]))
        iv = []
        start, stable = float(Hs[c][0]), bool(rho[c][0] < level)
        for x, opens_unstable in marks:
            if opens_unstable == stable:          # a boundary of the interval in hand
                iv.append((start, x, stable))
                start, stable = x, not stable
        iv.append((start, float(Hs[c][-1]), stable))
        out.append(iv)
        value.append(dict(zip(Hs[c].tolist(), rho[c].tolist()))
                     | {t: v for _, t, v in windows[c]})
    # each unstable interval's largest rho: maximised between the neighbours of the largest
    # value seen in it (on the grid, or a window's top), within the interval
    lo, hi, best, who = [], [], [], []
    for c in range(n):
        for a, b, st in out[c]:
            if st:
                continue
            pts = sorted([a, b] + [h for h in value[c] if a < h < b])
            vals = [value[c].get(x, -math.inf) if a < x < b else -math.inf for x in pts]
            m = int(np.argmax(vals))
            lo.append(pts[max(m - 1, 0)])
            hi.append(pts[min(m + 1, len(pts) - 1)])
            best.append(vals[m])
            who.append(c)
    peaks = iter([])
    if lo:
        who_a = np.array(who)
        _, top = _extremum(lambda H: f(H, who_a), lo, hi, iterations=16)
        peaks = iter(np.maximum(top, best).tolist())
    return [[(a, b, st, None if st else next(peaks)) for a, b, st in iv] for iv in out]


def step_intervals(Hs, rho, f, level: float = 1.0):
    """The stable and unstable intervals of ``[Hs[0], Hs[-1]]`` from ``rho`` on the increasing
    steps ``Hs`` and ``f`` (``rho`` of an array of steps, this coupling's): ``[(lo, hi, stable,
    peak)]`` in order, each boundary bisected (to :data:`XTOL`). The windows between the points
    are looked for at every discrete local maximum of ``rho`` below ``level`` (``rho``
    maximised between the neighbouring points, golden section) and every local minimum above it
    (minimised): one that reaches across ``level`` is a window, both its edges bisected.
    ``peak``: of an unstable interval, its largest ``rho`` (maximised near the largest value
    seen in it), how fast it grows per step at worst; ``None`` for a stable one."""
    return _intervals([Hs], [rho], lambda H, c: f(H), level)[0]


def _collisions(gap) -> np.ndarray:
    """The grid points near which a complex pair of modulus near 1 may meet the real axis and
    split (a window of ``rho`` narrower than the grid, on neither side of which ``rho`` need
    show it): where ``gap`` (:meth:`~orchestration.studies.stability.Spectra.spectra`: of the
    eigenvalues of modulus above :data:`NEAR_CIRCLE`, the smallest ``|Im| / |lambda|``) has a
    local minimum below
    :data:`NEAR_AXIS`, and where a real eigenvalue of that modulus appears or disappears."""
    gap = np.asarray(gap, dtype=float)
    i = np.arange(1, gap.size - 1)
    low = (gap[i] < gap[i - 1]) & (gap[i] <= gap[i + 1]) & (gap[i] < NEAR_AXIS)
    real = gap == 0.0
    change = np.flatnonzero(real[1:] != real[:-1])
    return np.unique(np.concatenate([i[low], change, change + 1]))


def _refined(Hs, points) -> np.ndarray:
    """:data:`REFINE` steps inside each grid cell beside the grid ``points`` (log spaced)."""
    cells = np.unique(np.concatenate([points - 1, points]))
    cells = cells[(cells >= 0) & (cells < Hs.size - 1)]
    t = np.arange(1, REFINE + 1) / (REFINE + 1)
    return np.ravel(Hs[cells, None] * (Hs[cells + 1, None] / Hs[cells, None]) ** t)


def scan(spectra, max_step: float = MAX_STEP, *, min_step: float = MIN_STEP,
         per_decade: int = GRID_PER_DECADE, progress=None) -> list[list[tuple]]:
    """Every coupling's intervals (:func:`step_intervals`' ``[(lo, hi, stable, peak)]``) on
    ``[min_step, max_step]``, in the order of ``spectra.couplings`` (the module's description
    says how). ``spectra``: a :class:`~orchestration.studies.stability.Spectra` (its
    ``spectra(H)``, every coupling's ``(rho, gap)`` at the steps ``H``, and ``spectra(H,
    which)``, ``rho`` of the coupling ``which[i]`` at ``H[i]``). ``progress``: called with the fraction done after each stack of grid points and
    each refinement."""
    Hs = grid(max_step, min_step, per_decade)
    n = len(spectra.couplings)
    rho, gap = np.empty((n, Hs.size)), np.empty((n, Hs.size))
    chunks = range(0, Hs.size, _CHUNK)
    with one_blas_thread():
        for m, a in enumerate(chunks):
            rho[:, a:a + _CHUNK], gap[:, a:a + _CHUNK] = spectra.spectra(Hs[a:a + _CHUNK])
            if progress:
                progress(0.7 * (m + 1) / len(chunks))
        extra = [_refined(Hs, _collisions(gap[c])) for c in range(n)]
        who = np.concatenate([np.full(e.size, c) for c, e in enumerate(extra)])
        grids, radii = [], []
        if who.size:
            more = spectra(np.concatenate(extra), who)
        for c in range(n):
            H_c = np.concatenate([Hs, extra[c]])
            r_c = np.concatenate([rho[c], more[who == c] if who.size else []])
            order = np.argsort(H_c)
            grids.append(H_c[order])
            radii.append(r_c[order])
        if progress:
            progress(0.8)
        out = _intervals(grids, radii, spectra)
        if progress:
            progress(1.0)
    return out


# ---------------------------------------------------------------------- checking against runs
#: a run whose amplitude ends above this times its early one (the exchanged outputs, each against
#: its own) has grown; below that, settled
GROWN, SETTLED = 1.0, 0.01


def probe_steps(intervals, margin: float = 0.05) -> list[tuple[float, bool]]:
    """Steps just inside and just outside each boundary of ``intervals`` (:func:`step_intervals`'s
    or the report's): ``(1 - margin)`` and ``(1 + margin)`` times it where that lies in the
    interval beside it with ``margin`` to spare before that interval's far edge, else the middle
    of that interval (in ``log H``: a narrow one); each with the side's verdict, ``True`` for
    stable. No boundary: ``(1 - margin)`` times the last interval's top. In increasing order,
    each step once."""
    iv = [(i["from"], i["to"], i["stable"]) if isinstance(i, dict) else tuple(i[:3])
          for i in intervals]
    out = []
    for (a, b, s1), (_, c, s2) in zip(iv, iv[1:]):
        left = (1 - margin) * b
        right = (1 + margin) * b
        out.append((left if a <= left * (1 - margin) else math.sqrt(a * b), s1))
        out.append((right if right * (1 + margin) <= c else math.sqrt(b * c), s2))
    if len(iv) == 1:
        out.append(((1 - margin) * iv[0][1], iv[0][2]))
    seen = []
    for H, s in sorted(out):
        if not seen or H > seen[-1][0] * (1 + 1e-9):
            seen.append((H, s))
    return seen
