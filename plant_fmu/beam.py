"""Cantilever modes of the beam from cubic Hermite finite elements, and the FFRF invariants.

The beam is clamped in its floating frame at the hinge (``s = 0``) and free at the tip. Its
transverse deflection is ``w(s) = N(s) eta`` with ``N`` the first ``n`` mass-normalised cantilever
modes of an Euler-Bernoulli finite-element model (consistent mass). From these modes come the
invariants of docs/model.md section 3::

    I0 = m + rhoA L     I1 = int rhoA s ds       I2 = int rhoA s^2 ds
    I3 = int rhoA N ds  I4 = int rhoA N^T N ds   I5 = int rhoA s N ds

with ``I4 = identity`` (mass normalisation), the modal stiffness ``K = diag(omega_j^2)``, the
damping ``D`` of the law ``p.damping`` (docs/model.md section 7: ``"modal"``, ``D = diag(2 zeta
omega_j)``; ``"kelvin-voigt"``, ``D = beta K = diag(2 zeta omega_j^2 / omega_1)`` with ``beta =
2 zeta / omega_1``, the material stiffness's alone: the geometric stiffness ``Kg`` is not
damped), the tip deflection ``N(L)`` and the tip slope ``N'(L)``. All integrals of the
interpolated shapes are evaluated exactly, element by element.

With ``gravity_preload`` the geometric stiffness of the self-weight compression is also formed:
``Kg = int rhoA g (L - s) N'^T N' ds``; the potential energy then carries
``-1/2 cos(phi) eta^T Kg eta`` (the beam's foreshortening lowers its centre of mass).

The stiffened model (``fidelity = "stiffened"``, :class:`plant_fmu.dynamics.StiffenedPlantModel`)
takes the foreshortening's kinetic energy over mass points (:func:`mass_points`): Gauss points
along the beam with their masses, the mode shapes ``N(s_p)`` and the foreshortening matrices
``G(s_p) = int_0^s_p N'^T N' ds``, so that the axial shortening there is
``u_p = 1/2 eta^T G(s_p) eta``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .params import PlantParams

__all__ = ["Beam", "beam_model", "damping_diagonal", "MassPoints", "mass_points", "unit_beam",
           "UnitBeam", "Scales", "analytic_beta_L", "analytic_frequencies",
           "analytic_mode_shape"]


@dataclass(frozen=True)
class Beam:
    """Modal data of the beam for one :class:`PlantParams` (arrays are read-only)."""

    frequencies: np.ndarray   # (n,) cantilever circular frequencies, rad/s
    I0: float
    I1: float
    I2: float
    I3: np.ndarray            # (n,)
    I4: np.ndarray            # (n, n)
    I5: np.ndarray            # (n,)
    K: np.ndarray             # (n, n) modal stiffness diag(omega^2)
    D: np.ndarray             # (n, n) damping: diag(2 zeta omega) or beta K (p.damping)
    Kg: np.ndarray            # (n, n) geometric stiffness of the self-weight (zero unless preload)
    tip_deflection: np.ndarray  # (n,) N(L)
    tip_slope: np.ndarray       # (n,) N'(L)
    nodes: np.ndarray           # (n_elements+1,) node positions s
    shapes: np.ndarray          # (n_elements+1, n) mode shapes N_j at the nodes
    slopes: np.ndarray          # (n_elements+1, n) N_j' at the nodes

    @property
    def n_modes(self) -> int:
        return self.frequencies.size


def _element_matrices(le: float, EI: float, rhoA: float):
    """Stiffness and consistent mass of one Hermite element, dofs (w1, w1', w2, w2')."""
    l2 = le * le
    k = EI / le**3 * np.array([[12, 6 * le, -12, 6 * le],
                               [6 * le, 4 * l2, -6 * le, 2 * l2],
                               [-12, -6 * le, 12, -6 * le],
                               [6 * le, 2 * l2, -6 * le, 4 * l2]])
    m = rhoA * le / 420 * np.array([[156, 22 * le, 54, -13 * le],
                                    [22 * le, 4 * l2, 13 * le, -3 * l2],
                                    [54, 13 * le, 156, -22 * le],
                                    [-13 * le, -3 * l2, -22 * le, 4 * l2]])
    return k, m


def _hermite_dN(xi: np.ndarray, le: float) -> np.ndarray:
    """d/ds of the four Hermite shape functions at local coordinates ``xi`` in [0, 1]."""
    return np.stack([(-6 * xi + 6 * xi**2) / le,
                     1 - 4 * xi + 3 * xi**2,
                     (6 * xi - 6 * xi**2) / le,
                     -2 * xi + 3 * xi**2], axis=-1)


@functools.lru_cache(maxsize=64)
def _fe_modes_unit(n_elements: int):
    """The cantilever FE model of the unit beam (``L = EI = rhoA = 1``): (lam, mass-normalised
    modes over all 2*(ne+1) dofs). Every uniform beam's modes are these, scaled (:func:`scales`)."""
    ne = n_elements
    le = 1.0 / ne
    ndof = 2 * (ne + 1)
    K = np.zeros((ndof, ndof))
    M = np.zeros((ndof, ndof))
    ke, me = _element_matrices(le, 1.0, 1.0)
    for e in range(ne):
        sl = slice(2 * e, 2 * e + 4)
        K[sl, sl] += ke
        M[sl, sl] += me
    free = slice(2, ndof)  # clamp w(0) = w'(0) = 0
    lam, vec = _eigh_generalized(K[free, free], M[free, free])
    modes = np.zeros((ndof, lam.size))
    modes[free] = vec
    # Sign convention: positive tip deflection.
    modes *= np.where(modes[-2] < 0, -1.0, 1.0)
    lam.setflags(write=False)
    modes.setflags(write=False)
    return lam, modes


@dataclass(frozen=True)
class Scales:
    """Factors that turn the unit beam's modal data into those of a uniform beam of length
    ``L``, bending stiffness ``EI``, mass per length ``rhoA`` under gravity ``g``.

    With ``s = L xi``, the mass-normalised modes are ``N(s) = N_unit(xi) / sqrt(rhoA L)`` and the
    eigenvalues ``omega^2 = lam_unit EI / (rhoA L^4)``; so ``I3 = int rhoA N ds`` scales with
    ``rhoA L / sqrt(rhoA L)``, ``I5`` with one more ``L``, the tip slope with ``1 / (L sqrt(rhoA
    L))`` and the geometric stiffness ``int rhoA g (L - s) N'^2 ds`` with ``g / L``.

    The native FMUs (``plant_fmu/native/plant_model.c``, ``fpm_scales``) compute the same factors with
    the same operations in the same order, so that both flavours have bit-identical modal data."""

    lam: float
    w: float
    slope: float
    I3: float
    I5: float
    Kg: float

    @classmethod
    def of(cls, L: float, EI: float, rhoA: float, g: float) -> "Scales":
        w = 1.0 / math.sqrt(rhoA * L)
        I3 = (rhoA * L) * w
        return cls(lam=EI / (rhoA * ((L * L) * (L * L))), w=w, slope=w / L, I3=I3, I5=I3 * L,
                   Kg=g / L)


def _fe_modes(L: float, EI: float, rhoA: float, n_elements: int):
    """Global cantilever FE model: (omega^2, mass-normalised modes over all 2*(ne+1) dofs), the
    unit beam's scaled."""
    lam, modes = _fe_modes_unit(n_elements)
    sc = Scales.of(L, EI, rhoA, 1.0)
    out = modes.copy()
    out[0::2] *= sc.w
    out[1::2] *= sc.slope
    return lam * sc.lam, out


def _eigh_generalized(K: np.ndarray, M: np.ndarray):
    """Eigenvalues (ascending) and M-orthonormal eigenvectors of ``K v = lam M v`` (K and M
    symmetric positive definite), with numpy alone (the FMUs then start without importing scipy).

    Reduced by the Cholesky factor of K, ``K = U U^T``: ``B = U^-1 M U^-T`` has the eigenvalues
    ``mu = 1 / lam``, so the low modes, which are what the model keeps, are B's largest
    eigenvalues and come out to a relative accuracy of ~eps cond-free; ``v = U^-T w / sqrt(mu)``,
    then made M-orthonormal to round-off (the model takes ``I4 = v^T M v = I``).
    (Reducing by M's factor, as LAPACK's ``sygvd`` behind ``scipy.linalg.eigh(K, M)`` does,
    resolves the low modes only to ``eps lam_max / lam``: at 24 elements the first eigenvalue is
    off by 1.5e-9 there and by 1.4e-11 here, against a 40-digit solution.)"""
    U = np.linalg.cholesky(K)
    B = np.linalg.solve(U, np.linalg.solve(U, M).T)        # U^-1 (U^-1 M)^T = U^-1 M U^-T
    mu, w = np.linalg.eigh(0.5 * (B + B.T))
    mu, w = mu[::-1], w[:, ::-1]                            # descending mu: ascending lam
    v = np.linalg.solve(U.T, w) / np.sqrt(mu)
    # M-orthonormal to round-off (the back-substitution through U leaves ~1e-10): v <- v C^-T
    # with C C^T = v^T M v, which changes each vector by that much and keeps the order
    C = np.linalg.cholesky(0.5 * (v.T @ M @ v + (v.T @ M @ v).T))
    return 1.0 / mu, np.linalg.solve(C, v.T).T


@dataclass(frozen=True)
class UnitBeam:
    """The modal data of the unit beam (``L = EI = rhoA = g = 1``) for one mesh, first
    ``n_modes`` modes: what :func:`beam_model` scales, and what the native FMUs carry as tables."""

    lam: np.ndarray             # (n,) eigenvalues omega^2
    I3: np.ndarray              # (n,) int N dxi
    I5: np.ndarray              # (n,) int xi N dxi
    Kg: np.ndarray              # (n, n) int (1 - xi) N'^T N' dxi
    tip_deflection: np.ndarray  # (n,) N(1)
    tip_slope: np.ndarray       # (n,) N'(1)
    shapes: np.ndarray          # (ne+1, n) N at the nodes
    slopes: np.ndarray          # (ne+1, n) N' at the nodes


@functools.lru_cache(maxsize=512)
def unit_beam(n_elements: int, n_modes: int) -> UnitBeam:
    """The first ``n_modes`` modes of the unit beam meshed with ``n_elements`` elements, and
    their invariants (integrals of the Hermite interpolants, exact element by element)."""
    ne, n = n_elements, n_modes
    lam, modes = _fe_modes_unit(ne)
    le = 1.0 / ne
    phi = modes[:, :n]
    w_dofs, r_dofs = phi[0::2], phi[1::2]          # (ne+1, n) deflections and slopes at nodes
    # Exact integrals of the Hermite interpolants: int H_k ds and int s H_k ds per element.
    int_h = le * np.array([0.5, le / 12, 0.5, -le / 12])
    int_xh = le * le * np.array([3 / 20, le / 30, 7 / 20, -le / 20])
    I3 = np.zeros(n)
    I5 = np.zeros(n)
    # Geometric stiffness: P(xi) = 1 - xi, 3-point Gauss is exact for the degree-5 integrand.
    gx, gw = np.polynomial.legendre.leggauss(3)
    xi = 0.5 * (gx + 1.0)
    gw = 0.5 * gw
    dH = _hermite_dN(xi, le)                          # (3, 4)
    Kg = np.zeros((n, n))
    for e in range(ne):
        ve = phi[2 * e:2 * e + 4]                     # (4, n)
        s0 = e * le
        I3 += int_h @ ve
        I5 += (s0 * int_h + int_xh) @ ve
        dw = dH @ ve                                   # (3, n): N' at the Gauss points
        load = 1.0 - (s0 + le * xi)                    # compressive axial force
        Kg += (dw * (gw * load * le)[:, None]).T @ dw
    arrays = dict(lam=lam[:n].copy(), I3=I3, I5=I5, Kg=Kg, tip_deflection=w_dofs[-1].copy(),
                  tip_slope=r_dofs[-1].copy(), shapes=w_dofs.copy(), slopes=r_dofs.copy())
    for a in arrays.values():
        a.setflags(write=False)
    return UnitBeam(**arrays)


@functools.lru_cache(maxsize=64)
def beam_model(p: PlantParams) -> Beam:
    """The modal data of the beam described by ``p`` (cached per parameter record): the unit
    beam's (:func:`unit_beam`), scaled by :class:`Scales` (``tests/plant/test_beam.py`` checks the
    scaling against the FE model solved for the beam itself)."""
    n, ne, L, rhoA = p.n_modes, p.n_elements, p.L, p.rhoA
    u = unit_beam(ne, n)
    sc = Scales.of(L, p.EI, rhoA, p.g)
    K = u.lam * sc.lam
    omega = np.sqrt(K)
    arrays = dict(
        frequencies=omega,
        I3=u.I3 * sc.I3, I4=np.eye(n), I5=u.I5 * sc.I5,   # I4 = identity: mass-normalised modes
        K=np.diag(K),
        D=np.diag(damping_diagonal(p, K)),
        Kg=u.Kg * sc.Kg if p.gravity_preload else np.zeros((n, n)),
        tip_deflection=u.tip_deflection * sc.w,
        tip_slope=u.tip_slope * sc.slope,
        nodes=np.linspace(0.0, L, ne + 1),
        shapes=u.shapes * sc.w,
        slopes=u.slopes * sc.slope
    )
    for a in arrays.values():
        a.setflags(write=False)
    return Beam(I0=p.m + rhoA * L, I1=rhoA * (L * L) / 2, I2=rhoA * (L * L * L) / 3, **arrays)


def damping_diagonal(p: PlantParams, K: np.ndarray) -> np.ndarray:
    """The diagonal of the damping matrix in the mass-normalised cantilever modes, for the law
    ``p.damping``, from the modal stiffnesses ``K = omega_j^2`` of the mesh (the native FMUs,
    ``plant_model.c``'s ``prepare``, take the same operations in the same order): ``2 zeta
    omega_j`` (modal), or ``beta K_j`` with ``beta = 2 zeta / omega_1`` (Kelvin-Voigt)."""
    if p.damping == "modal":
        return 2.0 * p.zeta * np.sqrt(K)
    if not K.size:
        return np.zeros(0)
    beta = 2.0 * p.zeta / math.sqrt(K[0])
    return beta * K


@dataclass(frozen=True)
class MassPoints:
    """The beam as mass points for the stiffened model's foreshortening terms: a Gauss-Legendre
    rule over the beam (``4 max(n, 4)`` points), with the mode shapes there and the foreshortening
    matrices ``G(s) = int_0^s N'^T N' ds`` (the shortening is ``1/2 eta.G(s).eta``)."""

    s: np.ndarray   # (P,) arc length of each point, m
    m: np.ndarray   # (P,) its mass, kg
    N: np.ndarray   # (P, n) the mode shapes there
    G: np.ndarray   # (P, n, n) int_0^s N'^T N' ds


def _hermite_N(xi: np.ndarray, le: float) -> np.ndarray:
    """The four Hermite shape functions at local coordinates ``xi`` in [0, 1]."""
    return np.stack([1 - 3 * xi**2 + 2 * xi**3, le * (xi - 2 * xi**2 + xi**3),
                     3 * xi**2 - 2 * xi**3, le * (xi**3 - xi**2)], axis=-1)


@functools.lru_cache(maxsize=64)
def _unit_points(n_elements: int, n_modes: int):
    """``(xi, weight, N, G)`` of the unit beam (``L = rhoA = 1``) at the Gauss-Legendre points:
    the modes' Hermite interpolants there, ``G`` exact (3-point Gauss on each element before a
    point and on the part of its own element: N'^2 is of degree 4)."""
    ne, n = n_elements, n_modes
    phi = _fe_modes_unit(ne)[1][:, :n]
    le = 1.0 / ne
    gx, gw = np.polynomial.legendre.leggauss(4 * max(n, 4))
    xs, ws = 0.5 * (gx + 1.0), 0.5 * gw
    hx, hw = np.polynomial.legendre.leggauss(3)
    hx, hw = 0.5 * (hx + 1.0), 0.5 * hw
    acc = [np.zeros((n, n))]                            # G at each node
    for e in range(ne):
        dw = _hermite_dN(hx, le) @ phi[2 * e:2 * e + 4]
        acc.append(acc[-1] + (dw * (hw * le)[:, None]).T @ dw)
    N, G = np.empty((xs.size, n)), np.empty((xs.size, n, n))
    for k, x in enumerate(xs):
        e = min(int(x * ne), ne - 1)
        t = x * ne - e
        ve = phi[2 * e:2 * e + 4]
        N[k] = _hermite_N(np.array([t]), le)[0] @ ve
        dw = _hermite_dN(hx * t, le) @ ve               # N' on [s_e, s]
        G[k] = acc[e] + (dw * (hw * t * le)[:, None]).T @ dw
    out = (xs, ws, N, G)
    for a in out:
        a.setflags(write=False)
    return out


@functools.lru_cache(maxsize=64)
def mass_points(p: PlantParams) -> MassPoints:
    """The :class:`MassPoints` of the beam of ``p``: the unit beam's, scaled by :class:`Scales`
    (``N`` by ``w``, ``G = int N'^2 ds`` by ``w^2 / L``)."""
    xi, wt, N, G = _unit_points(p.n_elements, p.n_modes)
    sc = Scales.of(p.L, p.EI, p.rhoA, 1.0)
    arrays = dict(s=xi * p.L, m=wt * (p.rhoA * p.L), N=N * sc.w, G=G * (sc.w * sc.w / p.L))
    for a in arrays.values():
        a.setflags(write=False)
    return MassPoints(**arrays)


def fe_mass_matrix_check(p: PlantParams) -> np.ndarray:
    """``int rhoA N^T N ds`` evaluated from the FE consistent mass matrix (should be identity)."""
    lam, modes = _fe_modes(p.L, p.EI, p.rhoA, p.n_elements)
    ne = p.n_elements
    _, me = _element_matrices(p.L / ne, p.EI, p.rhoA)
    phi = modes[:, :p.n_modes]
    out = np.zeros((p.n_modes, p.n_modes))
    for e in range(ne):
        ve = phi[2 * e:2 * e + 4]
        out += ve.T @ me @ ve
    return out


# --------------------------------------------------------------------------- analytic cross-check
def analytic_beta_L(n: int) -> np.ndarray:
    """The first ``n`` roots of ``cos(bL) cosh(bL) + 1 = 0`` (clamped-free beam)."""
    import scipy.optimize     # here: a slow import that an FMU's start does not need

    f = lambda x: np.cos(x) + 1.0 / np.cosh(x)  # same roots, no overflow  # noqa: E731
    return np.array([scipy.optimize.brentq(f, (j - 0.5) * np.pi - 1.2, (j - 0.5) * np.pi + 0.5,
                                           xtol=1e-15) for j in range(1, n + 1)])


def analytic_frequencies(p: PlantParams, n: int | None = None) -> np.ndarray:
    """``(beta_j L)^2 sqrt(EI / (rhoA L^4))`` for the first ``n`` cantilever modes."""
    bl = analytic_beta_L(p.n_modes if n is None else n)
    return bl**2 * np.sqrt(p.EI / (p.rhoA * p.L**4))


def analytic_mode_shape(p: PlantParams, j: int):
    """Mass-normalised analytic cantilever shape ``N_j(s)`` (j from 1), positive at the tip."""
    bl = analytic_beta_L(j)[-1]
    b = bl / p.L
    sigma = (np.cosh(bl) + np.cos(bl)) / (np.sinh(bl) + np.sin(bl))

    def raw(s):
        s = np.asarray(s, dtype=float)
        return np.cosh(b * s) - np.cos(b * s) - sigma * (np.sinh(b * s) - np.sin(b * s))

    # int_0^L W^2 ds = L for this normalisation of W (a classical identity), times rhoA.
    scale = 1.0 / np.sqrt(p.rhoA * p.L)
    sign = np.sign(raw(p.L))
    return lambda s: sign * scale * raw(s)
