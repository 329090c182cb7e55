"""The top rung of the fidelity ladder: a geometrically exact planar beam hinged on the cart (the
numpy specification of ``plant.fidelity = "exact"``, which the C kernel's ``fp_exact_*`` and the
native plant FMUs run; docs/exact.md and docs/guide/fidelity.md).

Element: the ANCF cable element (Gerstmayr & Shabana, "Analysis of thin beams and cables using the
absolute nodal co-ordinate formulation", Nonlinear Dyn. 45, 2006). Each node carries its position
``r`` and its slope ``r' = dr/ds`` (four numbers in the plane); between nodes ``r(s)`` is the cubic
Hermite interpolant, the same shape functions as the floating frame's mesh (:mod:`.beam`). Why this
element rather than a co-rotational one or a Reissner/Simo beam:

- its mass matrix is constant and exactly the consistent one (``rhoA int S^T S ds``): the
  kinetic energy is ``1/2 qd^T M qd``, with no velocity-dependent inertia terms at all, gravity is
  a constant load and the pin is linear (the root's position is the cart's);
- it is an Euler-Bernoulli (shear-rigid) beam, like the floating frame, and at small amplitude its
  transverse stiffness and mass are the Hermite matrices of :mod:`.beam` (the two rungs then
  share their linearisation exactly: ``tests/plant/test_exact_beam.py``);
- the sensors are read off the tip node: the tip tangent is ``r'(L)`` itself.

Strains (the shear-rigid limit of Reissner's geometrically exact beam, exact for any rotation):
axial ``eps = |r'| - 1``, bending ``kappa = (r' x r'') / |r'|^2`` (the rate of the tangent angle per
unit reference length). Strain energy ``U = 1/2 int (EA eps^2 + EI kappa^2) ds``, by 5-point Gauss
quadrature per element (exact for the bending term of an inextensible element).

Damping: Kelvin-Voigt, ``sigma = EA (eps + beta eps_dot)``, ``M = EI (kappa + beta kappa_dot)``,
with ``beta = 2 zeta / omega_1`` and ``omega_1`` the first cantilever frequency of the same mesh:
the first cantilever mode has the damping ratio ``zeta``, as in the floating frame, and mode ``j``
has ``zeta omega_j / omega_1`` (stiffness-proportional, i.e. Rayleigh ``C = beta K`` at small
amplitude; the floating frame gives every mode ``zeta``). Rigid motions are not damped.

Integrator: :class:`GeneralizedAlpha`, the generalized-alpha method of Chung & Hulbert (1993) in
the form of Arnold & Bruls (2007; equilibrium holds at the end of each step), fixed step, Newton
with the analytic tangent. Why: the axial modes (first about 8000 rad/s) and the mesh's highest
bending modes (~1e5 rad/s) are far above anything the loop excites; an implicit method is stable at
a step set by the motion of interest, and ``rho_inf < 1`` damps the unresolved modes while staying
second order. ``rho_inf = 1`` is the trapezoidal rule (no numerical damping; energy drift bounded
and of second order: ``tests/plant/test_exact_beam.py``). A caveat, measured: without structural
damping the mesh's bending modes above ``1/h``, once excited (an undeformed start excites them),
ring at ~1e-5 rad in the tip slope, which the method resolves only when ``h`` resolves them; the tip
angle then converges at first order at practical steps (``bench/fidelity_gap.py``). With the paper's
``zeta = 0.1 %`` (Kelvin-Voigt damps them) it converges at second order. The floating frame's few
modes have no such content.

State layout of :class:`ExactPlant`: ``q = [x, r'_0 (2), r_1, r'_1, ..., r_ne, r'_ne]`` (the root's
position is ``(x, 0)``), ``x = [q, qd]``. Sensors as the floating frame's: ``x_o = x``, ``phi_o``
the tip tangent's angle from the upward vertical (counter-clockwise positive, in (-pi, pi]),
``omega_o`` its rate.
"""
from __future__ import annotations

import functools
import math

from typing import NamedTuple

import numpy as np

from .beam import _element_matrices, unit_beam
from .params import PlantParams

__all__ = ["CableMesh", "BeamSystem", "ExactPlant", "GeneralizedAlpha", "RadauIIA", "AffineForce",
           "StageForce", "NoConvergence", "exact_plant", "RADAU_C", "RADAU_A", "RADAU_TOL",
           "RADAU_SPLIT_MAX"]

#: Gauss points per element (exact for the bending energy of an inextensible cubic element).
N_GAUSS = 5
_R = np.array([[0.0, 1.0], [-1.0, 0.0]])       # c = a x b = a^T R b


def _hermite(xi: np.ndarray, le: float):
    """The four Hermite functions (dofs w1, w1', w2, w2') and their first and second derivatives
    with respect to ``s`` at local coordinates ``xi`` in [0, 1]."""
    h = np.stack([1 - 3 * xi**2 + 2 * xi**3, le * (xi - 2 * xi**2 + xi**3),
                  3 * xi**2 - 2 * xi**3, le * (-xi**2 + xi**3)], axis=-1)
    d1 = np.stack([(-6 * xi + 6 * xi**2) / le, 1 - 4 * xi + 3 * xi**2,
                   (6 * xi - 6 * xi**2) / le, -2 * xi + 3 * xi**2], axis=-1)
    d2 = np.stack([(-6 + 12 * xi) / le**2, (-4 + 6 * xi) / le,
                   (6 - 12 * xi) / le**2, (-2 + 6 * xi) / le], axis=-1)
    return h, d1, d2


class CableMesh:
    """A uniform mesh of ``ne`` ANCF cable elements over ``[0, L]``: the beam's constant mass
    matrix, gravity load, strain energy, internal forces and their tangents, all over the full
    nodal vector ``e = [r_0, r'_0, ..., r_ne, r'_ne]`` (length ``4 (ne + 1)``)."""

    def __init__(self, L: float, EA: float, EI: float, rhoA: float, ne: int, g: float = 0.0):
        self.L, self.EA, self.EI, self.rhoA, self.ne, self.g = L, EA, EI, rhoA, ne, g
        self.le = le = L / ne
        self.ndof = 4 * (ne + 1)
        self.nodes = np.linspace(0.0, L, ne + 1)
        _, me = _element_matrices(le, EI, rhoA)
        me2 = np.kron(me, np.eye(2))                    # (8, 8): x and y alike
        self.element_dofs = 4 * np.arange(ne)[:, None] + np.arange(8)[None, :]
        M = np.zeros((self.ndof, self.ndof))
        for idx in self.element_dofs:
            M[np.ix_(idx, idx)] += me2
        self.M = M
        # gravity: -g rhoA int dr_y/de ds (int of the Hermite functions, exact)
        int_h = le * np.array([0.5, le / 12, 0.5, -le / 12])
        fg = np.zeros(self.ndof)
        for e in range(ne):
            fg[4 * e + 1:4 * e + 9:2] -= g * rhoA * int_h
        self.f_gravity = fg
        x, w = np.polynomial.legendre.leggauss(N_GAUSS)
        xi = 0.5 * (x + 1.0)
        self.gauss_weights = 0.5 * w * le                # (ng,) ds weights
        _, d1, d2 = _hermite(xi, le)
        # G maps the element's 8 dofs to (a, b) = (r', r'') at each Gauss point: (ng, 4, 8)
        G = np.zeros((N_GAUSS, 4, 8))
        for k in range(4):
            G[:, 0, 2 * k] = G[:, 1, 2 * k + 1] = d1[:, k]
            G[:, 2, 2 * k] = G[:, 3, 2 * k + 1] = d2[:, k]
        self.G = G

    # ------------------------------------------------------------------ strains
    def _ab(self, e: np.ndarray) -> np.ndarray:
        """(a, b) = (r', r'') at every Gauss point: (ne, ng, 4)."""
        return np.einsum("gij,ej->egi", self.G, e[self.element_dofs])

    @staticmethod
    def _strains(ab: np.ndarray, hessians: bool):
        """eps, kappa, their gradients in (a, b) space (..., 4) and, if asked, Hessians (..., 4, 4)."""
        a, b = ab[..., :2], ab[..., 2:]
        n = np.einsum("...i,...i->...", a, a)
        la = np.sqrt(n)
        c = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        eps, kap = la - 1.0, c / n
        Rb = b @ _R.T                                    # R b
        RTa = a @ _R                                     # R^T a
        deps = np.zeros(ab.shape)
        deps[..., :2] = a / la[..., None]
        dkap = np.empty(ab.shape)
        dkap[..., :2] = Rb / n[..., None] - 2.0 * (c / n**2)[..., None] * a
        dkap[..., 2:] = RTa / n[..., None]
        if not hessians:
            return eps, kap, deps, dkap, None, None
        shape = ab.shape + (4,)
        Heps = np.zeros(shape)
        I2 = np.eye(2)
        aa = a[..., :, None] * a[..., None, :]
        Heps[..., :2, :2] = I2 / la[..., None, None] - aa / (la**3)[..., None, None]
        Hkap = np.zeros(shape)
        n2, n3 = (n**2)[..., None, None], (n**3)[..., None, None]
        Rba = Rb[..., :, None] * a[..., None, :]
        Hkap[..., :2, :2] = (-2.0 * (Rba + np.swapaxes(Rba, -1, -2)) / n2
                             - 2.0 * c[..., None, None] * I2 / n2 + 8.0 * c[..., None, None] * aa / n3)
        Hab = _R / n[..., None, None] - 2.0 * (aa @ _R) / n2
        Hkap[..., :2, 2:] = Hab
        Hkap[..., 2:, :2] = np.swapaxes(Hab, -1, -2)
        return eps, kap, deps, dkap, Heps, Hkap

    def strain_energy(self, e: np.ndarray) -> float:
        eps, kap, *_ = self._strains(self._ab(e), hessians=False)
        return float(0.5 * np.sum((self.EA * eps**2 + self.EI * kap**2) * self.gauss_weights))

    def potential(self, e: np.ndarray) -> float:
        """Strain energy plus the beam's weight ``g int rhoA r_y ds`` (zero at the root's height)."""
        return self.strain_energy(e) - float(self.f_gravity @ e)

    def internal(self, e: np.ndarray, ed: np.ndarray | None = None, beta: float = 0.0,
                 tangent: bool = True):
        """``(f, K, C)``: the elastic and Kelvin-Voigt forces ``f = dU/de + beta K_mat ed`` and,
        if ``tangent``, ``K = df/de`` and ``C = df/ded`` (dense, ndof x ndof)."""
        ab = self._ab(e)
        eps, kap, deps, dkap, Heps, Hkap = self._strains(ab, hessians=tangent)
        EA, EI, w = self.EA, self.EI, self.gauss_weights
        sig, mom = EA * eps, EI * kap
        damp = beta > 0.0 and ed is not None
        if damp:
            abd = self._ab(ed)
            epsd = np.einsum("egi,egi->eg", deps, abd)
            kapd = np.einsum("egi,egi->eg", dkap, abd)
            sig, mom = sig + beta * EA * epsd, mom + beta * EI * kapd
        grad = (sig[..., None] * deps + mom[..., None] * dkap) * w[None, :, None]      # (ne, ng, 4)
        fe = np.einsum("gij,egi->ej", self.G, grad)
        f = np.zeros(self.ndof)
        f[:-4] += fe[:, :4].ravel()
        f[4:] += fe[:, 4:].ravel()
        if not tangent:
            return f, None, None
        outer = lambda u, v: u[..., :, None] * v[..., None, :]   # noqa: E731
        H = EA * outer(deps, deps) + EI * outer(dkap, dkap)
        Cg = beta * H if damp else None
        H = H + sig[..., None, None] * Heps + mom[..., None, None] * Hkap
        if damp:
            He_abd = np.einsum("egij,egj->egi", Heps, abd)
            Hk_abd = np.einsum("egij,egj->egi", Hkap, abd)
            H = H + beta * (EA * outer(deps, He_abd) + EI * outer(dkap, Hk_abd))
        K = self._assemble(H * w[None, :, None, None])
        C = self._assemble(Cg * w[None, :, None, None]) if damp else None
        return f, K, C

    def _assemble(self, H: np.ndarray) -> np.ndarray:
        ke = np.einsum("gia,egij,gjb->eab", self.G, H, self.G)
        K = np.zeros((self.ndof, self.ndof))
        for idx, k in zip(self.element_dofs, ke):
            K[idx[0]:idx[-1] + 1, idx[0]:idx[-1] + 1] += k
        return K

    def straight(self, origin, angle_from_vertical: float, rate: float = 0.0, velocity=(0.0, 0.0)):
        """``(e, ed)`` of the undeformed beam from ``origin`` along ``(-sin phi, cos phi)``,
        rotating rigidly about its root at ``rate`` while the root moves at ``velocity``."""
        c, s = math.cos(angle_from_vertical), math.sin(angle_from_vertical)
        t, nrm = np.array([-s, c]), np.array([-c, -s])
        e = np.zeros(self.ndof)
        ed = np.zeros(self.ndof)
        for i, si in enumerate(self.nodes):
            e[4 * i:4 * i + 2] = np.asarray(origin) + si * t
            e[4 * i + 2:4 * i + 4] = t
            ed[4 * i:4 * i + 2] = np.asarray(velocity) + rate * si * nrm
            ed[4 * i + 2:4 * i + 4] = rate * nrm
        return e, ed


class FrameModalDamping:
    """The modal damping law (``damping = "modal"``) on the exact beam: every mode of the beam
    clamped in the frame of its root tangent gets the damping ratio ``zeta``, as the floating
    frame gives each of its cantilever modes.

    The frame is the floating frame's: its origin the root ``r_0 = (x, 0)``, its axes
    ``b1 = r'_0 / |r'_0|`` along the root tangent and ``b2 = (-b1_y, b1_x)`` (docs/model.md's
    ``b2 = (-cos phi, -sin phi)``). The beam's deformation in it, ``d``, is the root slope's
    stretch ``|r'_0| - 1`` and, at every other node, ``u = b1.(r_i - r_0) - s_i``,
    ``w = b2.(r_i - r_0)``, ``u' = b1.r'_i - 1``, ``w' = b2.r'_i``; a rigid motion of the beam
    with its frame leaves ``d`` unchanged. The dissipation is ``1/2 d_t^T C_f d_t`` with
    ``C_f = M_f Phi diag(2 zeta omega_k) Phi^T M_f`` from the clamped beam's modes
    ``(K_f - omega_k^2 M_f) phi_k = 0``, ``Phi^T M_f Phi = I`` (``M_f``, ``K_f``: the mesh's mass
    and tangent stiffness at the straight beam, in ``d``; bending and axial apart, as they are
    there), and the generalised force is ``-G^T C_f d_t`` with ``d_t = G(e) e_t``. Linearised at
    rest this is the floating frame's ``D = diag(2 zeta omega_j)`` on the mesh's cantilever
    modes (and ``zeta`` on its axial ones); it is objective (a rigid rotation is not damped) and
    it only dissipates (``dE/dt = -d_t^T C_f d_t``). Kelvin-Voigt damping is the other law
    (``beta`` of :class:`BeamSystem`)."""

    def __init__(self, mesh: "CableMesh", zeta: float):
        ne = mesh.ne
        self.mesh, self.zeta, self.ne = mesh, zeta, ne
        self.nd = 4 * ne + 1
        # d <- e at the straight vertical beam: (index of e, sign) per entry of d
        rows = [(3, 1.0)]
        for i in range(1, ne + 1):
            b = 4 * i
            rows += [(b + 1, 1.0), (b, -1.0), (b + 3, 1.0), (b + 2, -1.0)]
        P = np.zeros((self.nd, mesh.ndof))
        for k, (j, sgn) in enumerate(rows):
            P[k, j] = sgn
        e0, _ = mesh.straight((0.0, 0.0), 0.0)
        _, K, _ = mesh.internal(e0, None, 0.0, True)
        Mf, Kf = P @ mesh.M @ P.T, P @ K @ P.T
        self.axial = np.array([0] + [1 + 4 * i + k for i in range(ne) for k in (0, 2)])
        self.bending = np.array([1 + 4 * i + k for i in range(ne) for k in (1, 3)])
        self.Ca = self._block(Mf, Kf, self.axial)
        self.Cb = self._block(Mf, Kf, self.bending)

    def _block(self, Mf, Kf, idx):
        import scipy.linalg

        M, K = Mf[np.ix_(idx, idx)], Kf[np.ix_(idx, idx)]
        lam, Phi = scipy.linalg.eigh(K, M)
        MP = M @ Phi
        return MP @ np.diag(2.0 * self.zeta * np.sqrt(np.maximum(lam, 0.0))) @ MP.T

    @staticmethod
    def _frame(e):
        a0 = e[2:4]
        n0 = float(a0 @ a0)
        b1 = a0 / math.sqrt(n0)
        return b1, np.array([-b1[1], b1[0]]), np.array([-a0[1], a0[0]]) / n0

    def rates(self, e, ed) -> np.ndarray:
        """``d_t`` at the nodal vectors ``e``, ``ed``."""
        b1, b2, gth = self._frame(e)
        th = float(gth @ ed[2:4])
        out = np.empty(self.nd)
        out[0] = b1 @ ed[2:4]
        r0, v0 = e[0:2], ed[0:2]
        for i in range(1, self.ne + 1):
            r, rp = e[4 * i:4 * i + 2] - r0, e[4 * i + 2:4 * i + 4]
            v, vp = ed[4 * i:4 * i + 2] - v0, ed[4 * i + 2:4 * i + 4]
            k = 1 + 4 * (i - 1)
            out[k] = th * (b2 @ r) + b1 @ v
            out[k + 1] = -th * (b1 @ r) + b2 @ v
            out[k + 2] = th * (b2 @ rp) + b1 @ vp
            out[k + 3] = -th * (b1 @ rp) + b2 @ vp
        return out

    def transpose(self, e, g) -> np.ndarray:
        """``G(e)^T g``, over the full nodal vector."""
        b1, b2, gth = self._frame(e)
        out = np.zeros(self.mesh.ndof)
        out[2:4] += g[0] * b1
        coef = 0.0
        r0 = e[0:2]
        for i in range(1, self.ne + 1):
            r, rp = e[4 * i:4 * i + 2] - r0, e[4 * i + 2:4 * i + 4]
            k = 1 + 4 * (i - 1)
            coef += (g[k] * (b2 @ r) - g[k + 1] * (b1 @ r) + g[k + 2] * (b2 @ rp)
                     - g[k + 3] * (b1 @ rp))
            pos = g[k] * b1 + g[k + 1] * b2
            out[4 * i:4 * i + 2] += pos
            out[0:2] -= pos
            out[4 * i + 2:4 * i + 4] += g[k + 2] * b1 + g[k + 3] * b2
        out[2:4] += coef * gth
        return out

    def force(self, e, ed) -> np.ndarray:
        """The damping's generalised force ``-G^T C_f d_t`` over the full nodal vector."""
        d = self.rates(e, ed)
        c = np.zeros(self.nd)
        c[self.axial] = self.Ca @ d[self.axial]
        c[self.bending] = self.Cb @ d[self.bending]
        return -self.transpose(e, c)

    def matrix(self, e) -> np.ndarray:
        """``G^T C_f G`` at ``e`` (dense, full nodal): the law's velocity tangent, and its
        linearisation at rest."""
        n = self.mesh.ndof
        return np.stack([-self.force(e, col) for col in np.eye(n)], axis=1)


class BeamSystem:
    """A cable mesh with some nodal coordinates held (``fixed``: index -> value) and, optionally,
    a cart of mass ``cart_mass`` that carries the root's x coordinate (``e[0]``) and takes the
    force ``u``. The free coordinates are ``q``; ``e = embed(q)``."""

    def __init__(self, mesh: CableMesh, fixed: dict, cart_mass: float = 0.0, beta: float = 0.0,
                 modal: FrameModalDamping | None = None):
        self.mesh, self.beta, self.modal = mesh, beta, modal
        self.fixed = dict(fixed)
        self.free = np.array([i for i in range(mesh.ndof) if i not in self.fixed])
        self.nq = self.free.size
        self.e_fixed = np.zeros(mesh.ndof)
        for i, v in self.fixed.items():
            self.e_fixed[i] = v
        M = mesh.M[np.ix_(self.free, self.free)].copy()
        self.cart = cart_mass > 0.0
        if self.cart:
            if 0 in self.fixed:
                raise ValueError("a cart needs the root's x coordinate free")
            M[0, 0] += cart_mass
        self.M = M
        self.f_gravity = mesh.f_gravity[self.free]

    def embed(self, q: np.ndarray, rate: bool = False) -> np.ndarray:
        e = np.zeros(self.mesh.ndof) if rate else self.e_fixed.copy()
        e[self.free] = q
        return e

    def forces(self, q, qd, u: float = 0.0, tangent: bool = True):
        """``(f, K, C)``: ``M qdd = f(q, qd, u)``, ``K = -df/dq``, ``C = -df/dqd``. The modal
        law's force (``modal``) is in ``f``; its tangent is not in ``K`` and ``C`` (the Newton
        iterations converge without it: the law is light against the stiffness, and the C
        kernel's band would not hold it; :meth:`modal_matrix` gives it)."""
        e, ed = self.embed(q), self.embed(qd, rate=True)
        fi, Ki, Ci = self.mesh.internal(e, ed, self.beta, tangent)
        f = self.f_gravity - fi[self.free]
        if self.modal is not None:
            f = f + self.modal.force(e, ed)[self.free]
        if self.cart:
            f[0] += u
        if not tangent:
            return f, None, None
        ix = np.ix_(self.free, self.free)
        return f, Ki[ix], (Ci[ix] if Ci is not None else np.zeros((self.nq, self.nq)))

    def energy(self, q, qd) -> float:
        """``T + V`` (the cart's own weight left out: it does not move vertically)."""
        return float(0.5 * qd @ self.M @ qd) + self.mesh.potential(self.embed(q))

    def modal_matrix(self, q) -> np.ndarray:
        """The modal law's damping matrix ``-d f / d qd`` at ``q`` (zeros without it)."""
        if self.modal is None:
            return np.zeros((self.nq, self.nq))
        return self.modal.matrix(self.embed(q))[np.ix_(self.free, self.free)]

    def static(self, q0, u: float = 0.0, hold=(), load=None, steps: int = 1, tol: float = 1e-12,
               max_iter: int = 50):
        """The equilibrium ``f(q) + load = 0`` by Newton from ``q0`` (``hold``: indices of ``q``
        kept at their value, e.g. a neutral cart), ``load`` applied in ``steps`` increments."""
        q = np.array(q0, dtype=float)
        act = np.array([i for i in range(self.nq) if i not in set(hold)])
        zero = np.zeros(self.nq)
        load = zero if load is None else np.asarray(load, dtype=float)
        for k in range(1, steps + 1):
            lk = load * k / steps
            for _ in range(max_iter):
                f, K, _ = self.forces(q, zero, u)
                r = (f + lk)[act]
                dq = np.linalg.solve(K[np.ix_(act, act)], r)
                q[act] += dq
                if np.max(np.abs(dq)) <= tol * max(1.0, np.max(np.abs(q))):
                    break
            else:
                raise RuntimeError(f"static Newton did not converge at load step {k}")
        return q


class GeneralizedAlpha:
    """Fixed-step generalized alpha (Chung & Hulbert 1993) for ``M qdd = f(q, qd, F)`` in the form
    of Arnold & Bruls (2007): ``M qdd_{n+1} = f(q_{n+1}, qd_{n+1}, F_{n+1})`` at every step end,

        q_{n+1}  = q_n + h qd_n + h^2 (1/2 - beta) a_n + h^2 beta a_{n+1}
        qd_{n+1} = qd_n + h (1 - gamma) a_n + h gamma a_{n+1}
        (1 - alpha_m) a_{n+1} + alpha_m a_n = (1 - alpha_f) qdd_{n+1} + alpha_f qdd_n

    with the parameters of the spectral radius ``rho_inf`` at infinite frequency (1: the
    trapezoidal rule). Newton on ``qdd_{n+1}`` with the analytic tangent
    ``M + b' (h^2 beta K + h gamma C)``, ``b' = (1 - alpha_f) / (1 - alpha_m)``.

    The force ``F`` on the cart is given per step by ``force(q, qd) -> (F, dF/dq, dF/dqd)`` at the
    step's end (a closed loop), or held (a number)."""

    def __init__(self, system: BeamSystem, h: float, rho_inf: float = 0.9, tol: float = 1e-11,
                 max_iter: int = 30):
        if not 0.0 <= rho_inf <= 1.0:
            raise ValueError(f"rho_inf = {rho_inf!r} is out of range; allowed: [0, 1]")
        self.sys, self.h, self.tol, self.max_iter = system, h, tol, max_iter
        r = rho_inf
        self.am = (2 * r - 1) / (r + 1)
        self.af = r / (r + 1)
        self.gamma = 0.5 + self.af - self.am
        self.beta = 0.25 * (self.gamma + 0.5) ** 2
        self.bp = (1 - self.af) / (1 - self.am)
        self.newton_iterations = 0

    def start(self, q, qd, force=0.0):
        """The integrator's state ``(q, qd, qdd, a)`` from consistent accelerations."""
        F = self._force(force, q, qd)[0]
        f, _, _ = self.sys.forces(q, qd, F, tangent=False)
        qdd = np.linalg.solve(self.sys.M, f)
        return (np.array(q, float), np.array(qd, float), qdd, qdd.copy())

    @staticmethod
    def _force(force, q, qd):
        if callable(force):
            return force(q, qd)
        return float(force), None, None

    def step(self, state, force=0.0):
        q0, v0, qdd0, a0 = state
        h, b, gm, bp, am, af = self.h, self.beta, self.gamma, self.bp, self.am, self.af
        sys = self.sys
        qdd = qdd0.copy()
        qpred = q0 + h * v0 + h * h * (0.5 - b) * a0
        vpred = v0 + h * (1 - gm) * a0
        aconst = (af * qdd0 - am * a0) / (1 - am)
        lu, last = None, math.inf
        for it in range(self.max_iter):
            a = aconst + bp * qdd
            q = qpred + h * h * b * a
            v = vpred + h * gm * a
            F, dFq, dFv = self._force(force, q, v)
            need_tangent = lu is None
            f, K, C = sys.forces(q, v, F, tangent=need_tangent)
            r = sys.M @ qdd - f
            if need_tangent:
                if dFq is not None and sys.cart:
                    K = K.copy()
                    C = C.copy()
                    K[0] -= dFq
                    C[0] -= dFv
                S = sys.M + bp * (h * h * b * K + h * gm * C)
                lu = _lu(S)
            dqdd = -_solve(lu, r)
            qdd += dqdd
            self.newton_iterations += 1
            size = h * gm * bp * np.max(np.abs(dqdd))           # the correction of qd
            scale = self.tol * max(1.0, np.max(np.abs(v)))
            if size <= scale:
                break
            if need_tangent and it > 0 and size >= 0.5 * last and size <= 1e3 * scale:
                break                       # a fresh tangent gains nothing: round-off
            if size > 0.1 * last:
                lu = None                   # modified Newton converges slowly: a new tangent
            last = size
        else:
            raise RuntimeError(f"generalized-alpha: Newton did not converge in {self.max_iter} "
                               f"iterations (h = {h})")
        a = aconst + bp * qdd
        q = qpred + h * h * b * a
        v = vpred + h * gm * a
        return (q, v, qdd, a)


#: Radau IIA with three stages (order 5, L-stable; Hairer & Wanner, Solving ODEs II, IV.5):
#: the nodes ``c``, the matrix ``A`` and the real Schur-like form of ``A^-1`` that the transformed
#: Newton iteration uses, ``T^-1 A^-1 T = [[gamma, 0, 0], [0, alpha, -beta], [0, beta, alpha]]``
#: (RADAU5's constants, ``tests/plant/test_exact_beam.py`` checks them against ``A``).
_S6 = math.sqrt(6.0)
RADAU_C = np.array([(4.0 - _S6) / 10.0, (4.0 + _S6) / 10.0, 1.0])
RADAU_A = np.array([[(88.0 - 7.0 * _S6) / 360.0, (296.0 - 169.0 * _S6) / 1800.0,
                     (-2.0 + 3.0 * _S6) / 225.0],
                    [(296.0 + 169.0 * _S6) / 1800.0, (88.0 + 7.0 * _S6) / 360.0,
                     (-2.0 - 3.0 * _S6) / 225.0],
                    [(16.0 - _S6) / 36.0, (16.0 + _S6) / 36.0, 1.0 / 9.0]])
RADAU_T = np.array([[9.1232394870892942792e-02, -0.14125529502095420843,
                     -3.0029194105147424492e-02],
                    [0.24171793270710701896, 0.20412935229379993199, 0.38294211275726193779],
                    [0.96604818261509293619, 1.0, 0.0]])
RADAU_TI = np.array([[4.3255798900631553510, 0.33919925181580986954, 0.54177053993587487119],
                     [-4.1787185915519047273, -0.32768282076106238708, 0.47662355450055045196],
                     [-0.50287263494578687595, 2.5719269498556054292, -0.59603920482822492497]])
_CBRT81 = 81.0 ** (1.0 / 3.0)
_CBRT9 = 9.0 ** (1.0 / 3.0)
#: the real eigenvalue of ``A^-1`` and its complex pair ``alpha +- i beta`` (RADAU5's)
RADAU_GAMMA = (6.0 + _CBRT81 - _CBRT9) / 30.0
RADAU_GAMMA = 1.0 / RADAU_GAMMA
_ALPHA = (12.0 - _CBRT81 + _CBRT9) / 60.0
_BETA = (_CBRT81 + _CBRT9) * math.sqrt(3.0) / 60.0
RADAU_MU = 1.0 / complex(_ALPHA, -_BETA)          # alpha + i beta of A^-1
#: the derivative at ``tau = 1`` of the quadratic through the stages (nodes ``c``), per stage
RADAU_DEND = np.array([(1.0 - RADAU_C[1]) / ((RADAU_C[0] - RADAU_C[1]) * (RADAU_C[0] - 1.0)),
                       (1.0 - RADAU_C[0]) / ((RADAU_C[1] - RADAU_C[0]) * (RADAU_C[1] - 1.0)),
                       (2.0 - RADAU_C[0] - RADAU_C[1])
                       / ((1.0 - RADAU_C[0]) * (1.0 - RADAU_C[1]))])


#: Radau IIA's Newton tolerance: the stage accelerations' last correction, times h, at most this
#: times max(1, the largest stage velocity) (the correction of the velocities; an iteration that
#: stalls near round-off also ends it).
RADAU_TOL = 1e-9
#: A Radau iteration whose correction shrinks by less than this factor gets a new tangent.
RADAU_SLOW = 0.1
#: The deepest halving of a Radau step whose Newton iteration does not converge (the native
#: FMU's XB_SPLIT_MAX; :class:`orchestration.studies.exact_loop.ExactLoop` does the same).
RADAU_SPLIT_MAX = 4


class NoConvergence(RuntimeError):
    """An implicit step's Newton iteration did not converge."""


class StageForce(NamedTuple):
    """The force law of a Radau IIA step at its three stages: ``F_i = F0[i] - sum_j Q[i][j] e_j``
    with ``e_j = kx x + kp phi_o + kd omega_o`` at stage ``j`` (``Q = 0``: the forces ``F0``
    given, e.g. an input polynomial at the stage times; the closed loop with a linear filter
    integrated in the same stages: :mod:`orchestration.studies.exact_loop`). The form the C
    kernel takes (``fp_radau_force``)."""

    F0: tuple
    Q: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    kx: float = 0.0
    kp: float = 0.0
    kd: float = 0.0

    @classmethod
    def held(cls, F: float) -> "StageForce":
        return cls((float(F),) * 3)

    @classmethod
    def polynomial(cls, u: float, du: float, d2u: float, h: float, t0: float = 0.0):
        """The input ``u + du s + d2u s^2 / 2`` (``s`` from the polynomial's time) at the stage
        times ``t0 + c_i h``."""
        s = t0 + RADAU_C * h
        return cls(tuple(float(v) for v in u + s * (du + 0.5 * s * d2u)))

    def error(self, q, qd):
        """``(e, de/dq, de/dqd)`` at one stage."""
        phi, om, dphi, dom_q, dom_v = tip_angle_gradient(q, qd)
        de_q = self.kp * dphi + self.kd * dom_q
        de_q[0] += self.kx
        return self.kx * q[0] + self.kp * phi + self.kd * om, de_q, self.kd * dom_v

    @property
    def feedback(self) -> bool:
        return any(v != 0.0 for row in self.Q for v in row)


def _stage_force(force) -> StageForce:
    return force if isinstance(force, StageForce) else StageForce.held(force)


class RadauIIA:
    """Fixed-step Radau IIA (three stages, order 5, stiffly accurate and L-stable) for
    ``M qdd = f(q, qd, F)``, in the second-order form: the unknowns are the stage accelerations
    ``W_i``, ``V_i = v0 + h sum_j a_ij W_j``, ``Q_i = q0 + h c_i v0 + h^2 sum_j (A^2)_ij W_j``,
    ``M W_i = f(Q_i, V_i, F_i)``; the step ends at the last stage (``c_3 = 1``).

    Simplified Newton on the stage system with the tangent ``K = -df/dq``, ``C = -df/dqd`` (and
    the force law's gradient) at the first guess's second stage (again at the iterate's when an
    iteration shrinks the correction by less than :data:`RADAU_SLOW`), decoupled by the eigenvectors of ``A``
    (Hairer & Wanner's transformation, here for the second-order form): one real system
    ``gamma^2 M + h gamma C + h^2 K`` and one complex ``mu^2 M + h mu C + h^2 K`` (``gamma``,
    ``mu`` the eigenvalues of ``A^-1``), each the Newton matrix of generalized alpha's shape. The
    first guess extrapolates the accelerations by the jerk at the previous step's end. The
    integrator's state is ``(q, qd, qdd, jerk)``.

    Why this method for the exact beam: its fifth order keeps the phase of the loop's bending
    modes over thousands of steps (the trapezoidal rule's period error ``(omega h)^2 / 12``
    drifts the undamped second bending mode, 425 rad/s, by a radian over 3 s at 0.25 ms), and
    L-stability damps what the step does not resolve (the axial modes near 8000 rad/s, the mesh's
    highest bending modes) instead of folding it into the resolved band."""

    def __init__(self, system: BeamSystem, h: float, tol: float = RADAU_TOL, max_iter: int = 30):
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"h = {h!r} is out of range; allowed: a finite step > 0")
        self.sys, self.h, self.tol, self.max_iter = system, h, tol, max_iter
        self.newton_iterations = 0
        self.stage_error = (0.0, 0.0, 0.0)       # e at the last step's stages (feedback laws)
        self.A2 = RADAU_A @ RADAU_A

    def start(self, q, qd, force=0.0):
        """The integrator's state ``(q, qd, qdd, jerk)``: accelerations consistent with the
        force at the first stage's law (its value ``F0[0]``, or the law at ``(q, qd)``), jerk 0."""
        F = _stage_force(force)
        u = F.F0[0]
        if F.feedback:
            u = F.F0[0] - sum(F.Q[0]) * F.error(q, qd)[0]
        f, _, _ = self.sys.forces(q, qd, u, tangent=False)
        qdd = np.linalg.solve(self.sys.M, f)
        return (np.array(q, float), np.array(qd, float), qdd, np.zeros_like(qdd))

    def _stages(self, q0, v0, W):
        h = self.h
        V = v0[None, :] + h * (RADAU_A @ W)
        Q = q0[None, :] + h * RADAU_C[:, None] * v0[None, :] + h * h * (self.A2 @ W)
        return Q, V

    def _factor(self, Qs, Vs, F, q1, q2):
        """The two transformed Newton matrices, factored, at the second stage ``(Qs, Vs)``."""
        h, sys_, nq = self.h, self.sys, self.sys.nq
        gq = gv = np.zeros(nq)
        u1 = F.F0[1]
        if F.feedback:
            e1, gq, gv = F.error(Qs, Vs)
            u1 = F.F0[1] - sum(F.Q[1]) * e1
        _, K, C = sys_.forces(Qs, Vs, u1, tangent=True)
        M = sys_.M
        ex = np.zeros(nq)
        ex[0] = 1.0
        g, mu = RADAU_GAMMA, RADAU_MU
        S1 = g * g * M + h * g * C + h * h * K + q1 * np.outer(ex, h * h * gq + h * g * gv)
        S2 = mu * mu * M + h * mu * C + h * h * K + q2 * np.outer(ex, h * h * gq + h * mu * gv)
        return _lu(S1), _lu(S2)

    def step(self, state, force=0.0):
        q0, v0, qdd0, jerk0 = (np.asarray(s, float) for s in state)
        h, sys_, F = self.h, self.sys, _stage_force(force)
        nq = q0.size
        Qm = np.asarray(F.Q, float)
        QT = RADAU_TI @ Qm @ RADAU_T                     # Q in the transformed stages
        q1 = QT[0, 0]
        q2 = complex(0.5 * (QT[1, 1] + QT[2, 2]), 0.5 * (QT[2, 1] - QT[1, 2]))
        g, mu, M = RADAU_GAMMA, RADAU_MU, sys_.M
        W = qdd0[None, :] + (RADAU_C * h)[:, None] * jerk0[None, :]     # the first guess
        last, lus = math.inf, None
        for it in range(self.max_iter):
            Q, V = self._stages(q0, v0, W)
            if lus is None:                # at the first guess, or when the iteration is slow
                lus = self._factor(Q[1], V[1], F, q1, q2)
            e = np.zeros(3)
            if F.feedback:
                e = np.array([F.error(Q[i], V[i])[0] for i in range(3)])
            u = np.asarray(F.F0, float) - Qm @ e
            R = np.empty((3, nq))
            for i in range(3):
                f, _, _ = sys_.forces(Q[i], V[i], float(u[i]), tangent=False)
                R[i] = M @ W[i] - f
            Z = RADAU_TI @ R
            d1 = _solve(lus[0], -g * g * Z[0])
            d2 = _solve(lus[1], -mu * mu * (Z[1] + 1j * Z[2]))
            dW = RADAU_T @ np.stack([d1, d2.real, d2.imag])
            W = W + dW
            self.newton_iterations += 1
            if not np.all(np.isfinite(W)):
                raise RuntimeError("Radau IIA: the stage accelerations are not finite "
                                   f"(h = {h})")
            size = h * np.max(np.abs(dW))
            scale = self.tol * max(1.0, np.max(np.abs(V)))
            if size <= scale:
                break
            if it > 0 and size >= 0.5 * last and size <= 1e3 * scale:
                break                        # round-off: the iteration gains nothing more
            if it > 0 and size > RADAU_SLOW * last:
                lus = None                   # slow: a tangent at the iterate
            last = size
        else:
            raise NoConvergence(f"Radau IIA: Newton did not converge in {self.max_iter} "
                                f"iterations (h = {h})")
        Q, V = self._stages(q0, v0, W)
        self.stage_error = (tuple(F.error(Q[i], V[i])[0] for i in range(3)) if F.feedback
                            else (0.0, 0.0, 0.0))
        jerk = (RADAU_DEND @ W) / h
        return (Q[2].copy(), V[2].copy(), W[2].copy(), jerk)


class AffineForce(NamedTuple):
    """The force law of a step: ``F = F0 - Q0 (kx x + kp phi_o + kd omega_o)`` at the step's
    end (``Q0 = 0``: the force ``F0`` held), as a ``force`` for :meth:`GeneralizedAlpha.step`
    and the form the C kernel takes (``fp_exact_force``)."""

    F0: float
    Q0: float = 0.0
    kx: float = 0.0
    kp: float = 0.0
    kd: float = 0.0

    def __call__(self, q, qd):
        """``(F, dF/dq, dF/dqd)``."""
        phi, om, dphi, dom_q, dom_v = tip_angle_gradient(q, qd)
        de_q = self.kp * dphi + self.kd * dom_q
        de_q[0] += self.kx
        e = self.kx * q[0] + self.kp * phi + self.kd * om
        return self.F0 - self.Q0 * e, -self.Q0 * de_q, -self.Q0 * (self.kd * dom_v)


def tip_angle_gradient(q, qd):
    """``(phi_o, omega_o, dphi/dq, domega/dq, domega/dqd)`` from the tip node's slope (the last
    two coordinates of ``q``) and its rate."""
    nq = len(q)
    ax, ay, adx, ady = q[-2], q[-1], qd[-2], qd[-1]
    n = ax * ax + ay * ay
    om = (ax * ady - ay * adx) / n
    dphi = np.zeros(nq)
    dphi[-2:] = (-ay / n, ax / n)
    dom_q = np.zeros(nq)
    dom_q[-2:] = (ady / n - 2 * om * ax / n, -adx / n - 2 * om * ay / n)
    dom_v = np.zeros(nq)
    dom_v[-2:] = (-ay / n, ax / n)
    return math.atan2(-ax, ay), om, dphi, dom_q, dom_v


def _lu(S):
    import scipy.linalg

    return scipy.linalg.lu_factor(S)


def _solve(lu, r):
    import scipy.linalg

    return scipy.linalg.lu_solve(lu, r)


class ExactPlant:
    """The cart with the geometrically exact beam pinned on it, for one :class:`PlantParams`
    (``n_elements`` is the beam's mesh; ``n_modes`` and ``gravity_preload`` do not apply: the
    model has every mode the mesh has, and the self-weight's stiffness by construction)."""

    def __init__(self, p: PlantParams):
        self.params = p
        self.mesh = CableMesh(p.L, p.EA, p.EI, p.rhoA, p.n_elements, p.g)
        self.omega1 = math.sqrt(unit_beam(p.n_elements, 1).lam[0] * p.EI / (p.rhoA * p.L**4))
        kv = p.damping == "kelvin-voigt"
        self.beta_kv = 2.0 * p.zeta / self.omega1 if kv else 0.0
        self.modal = (FrameModalDamping(self.mesh, p.zeta)
                      if p.damping == "modal" and p.zeta > 0 else None)
        self.system = BeamSystem(self.mesh, {1: 0.0}, cart_mass=p.m, beta=self.beta_kv,
                                 modal=self.modal)
        self.nq = self.system.nq
        self.nx = 2 * self.nq

    def initial_state(self, phi: float = 0.0, x: float = 0.0, phi_dot: float = 0.0,
                      x_dot: float = 0.0) -> np.ndarray:
        """The undeformed beam at ``phi``, rotating at ``phi_dot``, on the cart at ``x, x_dot``."""
        e, ed = self.mesh.straight((x, 0.0), phi, phi_dot, (x_dot, 0.0))
        free = self.system.free
        return np.concatenate([e[free], ed[free]])

    def tip_angle(self, x: np.ndarray) -> tuple[float, float]:
        """``(phi_o, omega_o)`` from the tip node's slope ``r'(L)`` and its rate."""
        nq = self.nq
        ax, ay = x[nq - 2], x[nq - 1]
        adx, ady = x[-2], x[-1]
        n = ax * ax + ay * ay
        return math.atan2(-ax, ay), (ax * ady - ay * adx) / n

    def tip_angle_gradient(self, q, qd):
        """``(phi_o, omega_o, dphi/dq, domega/dq, domega/dqd)``."""
        return tip_angle_gradient(q, qd)

    def tip_deflection(self, x: np.ndarray) -> float:
        """The tip's distance from the line of the root tangent, along the floating frame's
        ``b2`` (the clamped-frame reading of the floating frame's ``N(L) eta``)."""
        e = self.system.embed(x[:self.nq])
        t0 = e[2:4] / math.hypot(e[2], e[3])
        b2 = np.array([-t0[1], t0[0]])                 # b1 = (-sin, cos) -> b2 = (-cos, -sin)
        return float((e[-4:-2] - e[0:2]) @ b2)

    def energy(self, x: np.ndarray) -> float:
        return self.system.energy(x[:self.nq], x[self.nq:])

    def upright_equilibrium(self) -> np.ndarray:
        """``q`` of the upright beam compressed by its weight (cart at 0, no force)."""
        q0 = self.initial_state()[:self.nq]
        return self.system.static(q0, hold=(0,))

    def state_space(self):
        """``(A, B, C)`` linearised at :meth:`upright_equilibrium`; outputs ``x_o, phi_o,
        omega_o``."""
        nq, nx = self.nq, self.nx
        q = self.upright_equilibrium()
        _, K, Cd = self.system.forces(q, np.zeros(nq))
        Cd = Cd + self.system.modal_matrix(q)
        Minv = np.linalg.inv(self.system.M)
        A = np.zeros((nx, nx))
        A[:nq, nq:] = np.eye(nq)
        A[nq:, :nq] = -Minv @ K
        A[nq:, nq:] = -Minv @ Cd
        B = np.zeros((nx, 1))
        B[nq:, 0] = Minv[:, 0]
        _, _, dphi, dom_q, dom_v = self.tip_angle_gradient(q, np.zeros(nq))
        C = np.zeros((3, nx))
        C[0, 0] = 1.0
        C[1, :nq] = dphi
        C[2, :nq] = dom_q
        C[2, nq:] = dom_v
        return A, B, C


@functools.lru_cache(maxsize=16)
def exact_plant(p: PlantParams) -> ExactPlant:
    """The (cached) :class:`ExactPlant` of a parameter record."""
    return ExactPlant(p)

