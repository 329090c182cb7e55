"""Equations of motion of the cart with a flexible beam (docs/model.md section 4), their exact
Jacobian and their linearisation.

Generalised coordinates ``q = [x, phi, eta_1..eta_n]``; the state is ``[q, qd]`` (length
``2*(n+2)``), the input is the force on the cart ``F_c``. With ``c = cos(phi)``, ``s = sin(phi)``::

    M(q) = [[ I0,              -I1 c + I3.eta s,   -I3 c ],
            [ .,               I2 + eta.eta,        I5   ],
            [ -I3^T c,         I5^T,                I    ]]

    f_x   = F_c - (I1 s + I3.eta c) phid^2 - 2 phid s I3.etad
    f_phi = -2 phid eta.etad + g (I1 s + I3.eta c) [- 1/2 s eta^T Kg eta]
    f_eta = phid^2 eta + g s I3 - K eta - D etad [+ c Kg eta]

and ``M(q) qdd = f``; the bracketed terms are the optional self-weight (geometric) stiffness.
Because the modes are mass-normalised (``I4 = I``), ``M`` is solved by a 2x2 Schur complement on the
rigid coordinates, which costs O(n).

Outputs: ``x_o = x``, ``phi_o = phi + atan(N'(L) eta)``, ``omega_o = d phi_o/dt``, the tip
deflection ``N(L) eta``, the modal coordinates and the total energy ``T + V``.

The Jacobian at any state (``jacobian_numpy``, ``output_jacobian_numpy``): ``d qdd/dz = M^-1
(df/dz - (dM/dz) qdd)`` with ``df/dz`` and ``dM/dz`` by hand, checked against sympy's derivatives
of the Lagrange equations (``tests/plant/test_lagrange.py``); ``state_space`` is its value at the
upright rest state.

:class:`StiffenedPlantModel` (``fidelity = "stiffened"``) adds the kinetic energy of the beam's
foreshortening to this model with the preload: the motion-dependent geometric stiffness
(:func:`model_for` picks the model of a fidelity).

The hot paths (``rhs``, ``tip_angle``, ``energy`` and the steppers' loops) run the compiled C
kernel (:mod:`plant_fmu.kernel`, ``native/fp_plant.c``), which receives the invariants computed
here; the ``*_numpy`` methods are the readable specification it is tested against.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from .beam import Beam, beam_model, mass_points
from .params import PlantParams

__all__ = ["PlantModel", "LinearPlantModel", "StiffenedPlantModel", "plant_model",
           "linear_plant_model", "stiffened_plant_model", "model_for", "rhs", "outputs", "energy",
           "linearize", "state_space", "OUTPUT_NAMES"]

#: Names of the sensor outputs, in the order of the rows of ``C``.
OUTPUT_NAMES = ("x_o", "phi_o", "omega_o")


class PlantModel:
    """The plant for one parameter record, with everything state-independent precomputed."""

    def __init__(self, p: PlantParams):
        self.params = p
        self.beam: Beam = beam_model(p)
        b = self.beam
        n = self.n = p.n_modes
        self.nq = n + 2
        self.nx = 2 * self.nq
        self.g = p.g
        self.I0, self.I1, self.I2 = b.I0, b.I1, b.I2
        self.I3, self.I5 = b.I3, b.I5
        self.Kdiag = np.diag(b.K).copy()
        self.Ddiag = np.diag(b.D).copy()
        self.Kg = b.Kg if p.gravity_preload else np.zeros((n, n))
        self.preload = bool(p.gravity_preload) and n > 0
        self.tip_slope = b.tip_slope
        self.tip_defl = b.tip_deflection
        self._I5I5 = float(self.I5 @ self.I5)
        self._I3I3 = float(self.I3 @ self.I3)
        self._I3I5 = float(self.I3 @ self.I5)
        self._kernel = None

    @property
    def kernel(self):
        """The compiled kernel with this plant's data (:class:`plant_fmu.kernel.PlantKernel`),
        built on first use; :class:`plant_fmu.kernel.KernelError` if it cannot be loaded."""
        if self._kernel is None:
            self._kernel = _make_kernel(self, linear=False)
        return self._kernel

    # ------------------------------------------------------------------ nonlinear model
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        n = self.n
        phi, eta = q[1], q[2:]
        c, s = math.cos(phi), math.sin(phi)
        M = np.zeros((n + 2, n + 2))
        M[0, 0] = self.I0
        M[0, 1] = M[1, 0] = -self.I1 * c + s * float(self.I3 @ eta)
        M[0, 2:] = M[2:, 0] = -c * self.I3
        M[1, 1] = self.I2 + float(eta @ eta)
        M[1, 2:] = M[2:, 1] = self.I5
        M[2:, 2:] = np.eye(n)
        return M

    def forces(self, q: np.ndarray, qd: np.ndarray, u: float) -> np.ndarray:
        """Right-hand side ``f(q, qd, u)`` of ``M(q) qdd = f``."""
        phi, eta = q[1], q[2:]
        phid, etad = qd[1], qd[2:]
        c, s = math.cos(phi), math.sin(phi)
        I3eta = float(self.I3 @ eta)
        f = np.empty(self.nq)
        f[0] = u - (self.I1 * s + I3eta * c) * phid * phid - 2.0 * phid * s * float(self.I3 @ etad)
        f[1] = -2.0 * phid * float(eta @ etad) + self.g * (self.I1 * s + I3eta * c)
        f[2:] = (phid * phid) * eta + (self.g * s) * self.I3 - self.Kdiag * eta - self.Ddiag * etad
        if self.preload:
            Kge = self.Kg @ eta
            f[1] -= 0.5 * s * float(eta @ Kge)
            f[2:] += c * Kge
        return f

    def accelerations(self, q: np.ndarray, qd: np.ndarray, u: float) -> np.ndarray:
        """Solve ``M(q) qdd = f(q, qd, u)`` by the Schur complement on (x, phi)."""
        f = self.forces(q, qd, u)
        phi, eta = q[1], q[2:]
        c, s = math.cos(phi), math.sin(phi)
        # M = [[A, B], [B^T, I]] with A 2x2 and B = [-c I3; I5]
        a00 = self.I0 - c * c * self._I3I3
        m01 = -self.I1 * c + s * float(self.I3 @ eta)
        a01 = m01 + c * self._I3I5
        a11 = self.I2 + float(eta @ eta) - self._I5I5
        fe = f[2:]
        r0 = f[0] + c * float(self.I3 @ fe)
        r1 = f[1] - float(self.I5 @ fe)
        det = a00 * a11 - a01 * a01
        xdd = (a11 * r0 - a01 * r1) / det
        phidd = (a00 * r1 - a01 * r0) / det
        qdd = np.empty(self.nq)
        qdd[0] = xdd
        qdd[1] = phidd
        qdd[2:] = fe + (c * xdd) * self.I3 - phidd * self.I5
        return qdd

    def rhs(self, t: float, x: np.ndarray, u: float) -> np.ndarray:
        """``dx/dt`` of the nonlinear model; ``x = [q, qd]``, ``u = F_c``.

        Runs the compiled kernel (same equations as :meth:`rhs_numpy`)."""
        return self.kernel.rhs(x, u)

    def rhs_numpy(self, t: float, x: np.ndarray, u: float) -> np.ndarray:
        """``dx/dt`` from :meth:`accelerations`: the readable version of :meth:`rhs`."""
        nq = self.nq
        dx = np.empty(self.nx)
        dx[:nq] = x[nq:]
        dx[nq:] = self.accelerations(x[:nq], x[nq:], u)
        return dx

    def tip_angle(self, x: np.ndarray) -> tuple[float, float]:
        """``(phi_o, omega_o)``: the tip tangent's angle from the vertical and its rate (the
        compiled kernel; the same formula as :meth:`tip_angle_numpy`)."""
        return self.kernel.tip(x)

    def tip_angle_numpy(self, x: np.ndarray) -> tuple[float, float]:
        """``(phi_o, omega_o)``: the tip tangent's angle from the vertical and its rate."""
        nq = self.nq
        if self.n == 0:
            return float(x[1]), float(x[nq + 1])
        sl = float(self.tip_slope @ x[2:nq])
        sld = float(self.tip_slope @ x[nq + 2:])
        return float(x[1]) + math.atan(sl), float(x[nq + 1]) + sld / (1.0 + sl * sl)

    # ------------------------------------------------------------------ Jacobians
    def jacobian_numpy(self, x: np.ndarray, u: float):
        """``(J, b)``: the exact Jacobian of :meth:`rhs_numpy` with respect to the state
        (``J = d(dx/dt)/dx``, nx x nx) and to the force (``b = d(dx/dt)/dF_c``), at any state.

        From ``M(q) qdd = f(q, qd, u)``: ``d qdd/dz = M^-1 (df/dz - (dM/dz) qdd)``, with ``df/dz``
        and ``dM/dz`` differentiated by hand below (``tests/plant/test_lagrange.py`` checks them
        against sympy's derivatives of the Lagrange equations; the kernel's ``fp_jacobian``
        computes the same by Jacobian-vector products)."""
        n, nq, nx = self.n, self.nq, self.nx
        q, qd = x[:nq], x[nq:]
        phi, eta = q[1], q[2:]
        phid, etad = qd[1], qd[2:]
        c, s = math.cos(phi), math.sin(phi)
        I1, I3, I5, g = self.I1, self.I3, self.I5, self.g
        I3eta, I3etad = float(I3 @ eta), float(I3 @ etad)
        a = self.accelerations(q, qd, u)
        # df/dq (columns x, phi, eta) and df/dqd (columns xd, phid, etad)
        dfdq = np.zeros((nq, nq))
        dfdq[0, 1] = -(I1 * c - I3eta * s) * phid * phid - 2.0 * phid * c * I3etad
        dfdq[1, 1] = g * (I1 * c - I3eta * s)
        dfdq[2:, 1] = g * c * I3
        dfdq[0, 2:] = -c * phid * phid * I3
        dfdq[1, 2:] = -2.0 * phid * etad + g * c * I3
        dfdq[2:, 2:] = np.diag(phid * phid - self.Kdiag)
        if self.preload:
            Kg = self.Kg
            Kge = Kg @ eta
            dfdq[1, 1] -= 0.5 * c * float(eta @ Kge)
            dfdq[2:, 1] -= s * Kge
            dfdq[1, 2:] -= s * (0.5 * (Kg + Kg.T) @ eta)        # d/deta of 1/2 s eta.Kg.eta
            dfdq[2:, 2:] += c * Kg
        dfdv = np.zeros((nq, nq))
        dfdv[0, 1] = -2.0 * (I1 * s + I3eta * c) * phid - 2.0 * s * I3etad
        dfdv[1, 1] = -2.0 * float(eta @ etad)
        dfdv[2:, 1] = 2.0 * phid * eta
        dfdv[0, 2:] = -2.0 * phid * s * I3
        dfdv[1, 2:] = -2.0 * phid * eta
        dfdv[2:, 2:] = -np.diag(self.Ddiag)
        # (dM/dq_k) qdd, column k: M01 = -I1 c + s I3.eta, M0e = -c I3, M11 = I2 + eta.eta
        dMa = np.zeros((nq, nq))
        dm01 = I1 * s + c * I3eta
        dMa[0, 1] = dm01 * a[1] + s * float(I3 @ a[2:])
        dMa[1, 1] = dm01 * a[0]
        dMa[2:, 1] = s * I3 * a[0]
        dMa[0, 2:] = s * I3 * a[1]
        dMa[1, 2:] = s * I3 * a[0] + 2.0 * eta * a[1]
        M = self.mass_matrix(q)
        J = np.zeros((nx, nx))
        J[:nq, nq:] = np.eye(nq)
        J[nq:, :nq] = np.linalg.solve(M, dfdq - dMa)
        J[nq:, nq:] = np.linalg.solve(M, dfdv)
        b = np.zeros(nx)
        b[nq:] = np.linalg.solve(M, np.eye(nq)[:, 0])
        return J, b

    def output_jacobian_numpy(self, x: np.ndarray) -> np.ndarray:
        """``C = d(outputs)/dx`` at ``x``: one row per output in the kernel's layout
        (:data:`plant_fmu.kernel.OUT`: x_o, x_dot, phi_o, omega_o, phi, tip_deflection, energy,
        eta_1..eta_n). No output depends on the force (no direct feedthrough)."""
        n, nq, nx = self.n, self.nq, self.nx
        phi, eta = x[1], x[2:nq]
        xd, phid, etad = x[nq], x[nq + 1], x[nq + 2:]
        c, s = math.cos(phi), math.sin(phi)
        I1, I3, I5, g = self.I1, self.I3, self.I5, self.g
        I3eta, I3etad = float(I3 @ eta), float(I3 @ etad)
        C = np.zeros((7 + n, nx))
        C[0, 0] = 1.0
        C[1, nq] = 1.0
        sl, sld = float(self.tip_slope @ eta), float(self.tip_slope @ etad)
        w = 1.0 + sl * sl
        C[2, 1] = 1.0
        C[2, 2:nq] = self.tip_slope / w
        C[3, nq + 1] = 1.0
        C[3, nq + 2:] = self.tip_slope / w
        C[3, 2:nq] = -2.0 * sl * sld / (w * w) * self.tip_slope
        C[4, 1] = 1.0
        C[5, 2:nq] = self.tip_defl
        # energy: T + V of energy_numpy, differentiated
        dE = C[6]
        dE[1] = (xd * ((I1 * phid + I3etad) * s + phid * c * I3eta)
                 - g * (I1 * s + c * I3eta))
        dE[2:nq] = xd * phid * s * I3 + phid * phid * eta - g * s * I3 + self.Kdiag * eta
        dE[nq] = self.I0 * xd - (I1 * phid + I3etad) * c + phid * s * I3eta
        dE[nq + 1] = xd * (-I1 * c + s * I3eta) + phid * (self.I2 + float(eta @ eta)) \
            + float(I5 @ etad)
        dE[nq + 2:] = -xd * c * I3 + phid * I5 + etad
        if self.preload:
            Kg = self.Kg
            dE[1] += 0.5 * s * float(eta @ (Kg @ eta))
            dE[2:nq] -= c * (0.5 * (Kg + Kg.T) @ eta)
        C[7:, 2:nq] = np.eye(n)
        return C

    def output_derivatives_numpy(self, x: np.ndarray, u: float, du: float = 0.0):
        """``(d1, d2)``: the first and second time derivatives of every output (the kernel's
        layout, as :meth:`output_jacobian_numpy`) at ``x`` with the force ``u`` and its rate
        ``du`` at that instant (see :func:`_output_derivatives`; the kernel's
        ``fp_output_derivatives`` computes the same)."""
        return _output_derivatives(self, x, u, du, linear=False)

    def energy(self, x: np.ndarray) -> float:
        """Total energy ``T + V`` (the compiled kernel; same terms as :meth:`energy_numpy`)."""
        return self.kernel.energy(x)

    def energy_numpy(self, x: np.ndarray) -> float:
        """Total energy ``T + V`` (kinetic, gravity, strain and, with preload, foreshortening)."""
        nq = self.nq
        phi, eta = x[1], x[2:nq]
        xd, phid, etad = x[nq], x[nq + 1], x[nq + 2:]
        c, s = math.cos(phi), math.sin(phi)
        I3eta, I3etad = float(self.I3 @ eta), float(self.I3 @ etad)
        T = (0.5 * self.I0 * xd * xd
             + xd * (-(self.I1 * phid + I3etad) * c + phid * s * I3eta)
             + 0.5 * phid * phid * (self.I2 + float(eta @ eta))
             + phid * float(self.I5 @ etad) + 0.5 * float(etad @ etad))
        V = self.g * (self.I1 * c - s * I3eta) + 0.5 * float(self.Kdiag @ (eta * eta))
        if self.preload:
            V -= 0.5 * c * float(eta @ (self.Kg @ eta))
        return float(T + V)

    def outputs(self, t: float, x: np.ndarray, u: float = 0.0) -> dict:
        """All outputs: sensors, tip deflection, modal coordinates and energy."""
        nq = self.nq
        phi_o, omega_o = self.tip_angle(x)
        eta = x[2:nq]
        return {
            "x_o": float(x[0]),
            "x_dot": float(x[nq]),
            "phi_o": phi_o,
            "omega_o": omega_o,
            "tip_deflection": float(self.tip_defl @ eta) if self.n else 0.0,
            "eta": np.array(eta, dtype=float),
            "energy": self.energy(x),
        }

    def initial_state(self, phi: float = 0.0, x: float = 0.0, phi_dot: float = 0.0,
                      x_dot: float = 0.0) -> np.ndarray:
        """A state with the beam undeformed at angle ``phi`` (modal coordinates zero)."""
        st = np.zeros(self.nx)
        st[0], st[1], st[self.nq], st[self.nq + 1] = x, phi, x_dot, phi_dot
        return st

    # ------------------------------------------------------------------ linear model
    def linearize(self):
        """``(M0, D0, K0)`` of ``M0 qdd + D0 qd + K0 q = e_x F_c`` at the upright rest state."""
        nq = self.nq
        M0 = self.mass_matrix(np.zeros(nq))
        D0 = np.zeros((nq, nq))
        D0[2:, 2:] = np.diag(self.Ddiag)
        K0 = np.zeros((nq, nq))
        K0[1, 1] = -self.g * self.I1
        K0[1, 2:] = K0[2:, 1] = -self.g * self.I3
        K0[2:, 2:] = np.diag(self.Kdiag) - self.Kg
        return M0, D0, K0

    def state_space(self):
        """``(A, B, C, D)`` of the linearised plant; outputs are ``x_o, phi_o, omega_o``."""
        nq, nx = self.nq, self.nx
        M0, D0, K0 = self.linearize()
        Minv = np.linalg.inv(M0)
        A = np.zeros((nx, nx))
        A[:nq, nq:] = np.eye(nq)
        A[nq:, :nq] = -Minv @ K0
        A[nq:, nq:] = -Minv @ D0
        B = np.zeros((nx, 1))
        B[nq:, 0] = Minv[:, 0]
        C = np.zeros((3, nx))
        C[0, 0] = 1.0
        C[1, 1] = 1.0
        C[1, 2:nq] = self.tip_slope
        C[2, nq + 1] = 1.0
        C[2, nq + 2:] = self.tip_slope
        D = np.zeros((3, 1))
        return A, B, C, D


class LinearPlantModel:
    """The plant linearised at the upright rest state, with the interface of :class:`PlantModel`.

    ``M0 qdd + D0 qd + K0 q = e_x F_c``; outputs use the linear tip angle ``phi + N'(L) eta``, and
    the energy is the quadratic form ``1/2 qd.M0.qd + 1/2 q.K0.q + g I1`` (the nonlinear energy to
    second order).
    """

    def __init__(self, p: PlantParams):
        nl = plant_model(p)
        self._nl = nl
        self.params = p
        self.beam = nl.beam
        self.n, self.nq, self.nx = nl.n, nl.nq, nl.nx
        self.M0, self.D0, self.K0 = nl.linearize()
        self.A, self.B, self.C, self.D = nl.state_space()
        self._b = self.B[:, 0].copy()
        self._Minv = np.linalg.inv(self.M0)
        self._offset = nl.g * nl.I1
        self.tip_slope, self.tip_defl = nl.tip_slope, nl.tip_defl
        for a in (self.M0, self.D0, self.K0, self.A, self.B, self.C, self.D):
            a.setflags(write=False)
        self._kernel = None

    @property
    def kernel(self):
        """The compiled kernel of the linearised plant (built on first use)."""
        if self._kernel is None:
            self._kernel = _make_kernel(self._nl, linear=True)
        return self._kernel

    def mass_matrix(self, q):
        return self.M0

    def forces(self, q, qd, u):
        f = -(self.D0 @ qd) - self.K0 @ q
        f[0] += u
        return f

    def accelerations(self, q, qd, u):
        return self._Minv @ self.forces(q, qd, u)

    def rhs(self, t, x, u):
        """``A x + B u`` by the compiled kernel (the same Schur complement as the nonlinear
        model, at the rest state; :meth:`rhs_numpy` is the specification)."""
        return self.kernel.rhs(x, u)

    def rhs_numpy(self, t, x, u):
        """``A x + B u`` as ``M0 qdd = f`` solved by the Schur complement on (x, phi), as
        :meth:`PlantModel.accelerations` does at the rest state (the product with ``A``, through
        the inverse of ``M0``, loses about ``cond(M0) eps``, ~1e-12 relative at n_modes = 8)."""
        nl, nq = self._nl, self.nq
        f = self.forces(x[:nq], x[nq:], u)
        a00 = nl.I0 - nl._I3I3
        a01 = -nl.I1 + nl._I3I5
        a11 = nl.I2 - nl._I5I5
        fe = f[2:]
        r0 = f[0] + float(nl.I3 @ fe)
        r1 = f[1] - float(nl.I5 @ fe)
        det = a00 * a11 - a01 * a01
        xdd = (a11 * r0 - a01 * r1) / det
        phidd = (a00 * r1 - a01 * r0) / det
        dx = np.empty(self.nx)
        dx[:nq] = x[nq:]
        dx[nq] = xdd
        dx[nq + 1] = phidd
        dx[nq + 2:] = fe + xdd * nl.I3 - phidd * nl.I5
        return dx

    def jac(self, t, x, u):
        """The exact Jacobian ``A`` (constant)."""
        return self.A

    def jacobian_numpy(self, x, u):
        """``(J, b)`` of :meth:`rhs_numpy`: ``A`` and ``B`` by solving ``M0`` (constant)."""
        nq, nx = self.nq, self.nx
        J = np.zeros((nx, nx))
        J[:nq, nq:] = np.eye(nq)
        J[nq:, :nq] = np.linalg.solve(self.M0, -self.K0)
        J[nq:, nq:] = np.linalg.solve(self.M0, -self.D0)
        b = np.zeros(nx)
        b[nq:] = np.linalg.solve(self.M0, np.eye(nq)[:, 0])
        return J, b

    def output_jacobian_numpy(self, x):
        """``C = d(outputs)/dx`` in the kernel's layout (see
        :meth:`PlantModel.output_jacobian_numpy`): the linear tip angle and the gradient of the
        quadratic energy ``[K0 q, M0 qd]``."""
        n, nq, nx = self.n, self.nq, self.nx
        C = np.zeros((7 + n, nx))
        C[0, 0] = 1.0
        C[1, nq] = 1.0
        C[2, 1] = 1.0
        C[2, 2:nq] = self.tip_slope
        C[3, nq + 1] = 1.0
        C[3, nq + 2:] = self.tip_slope
        C[4, 1] = 1.0
        C[5, 2:nq] = self.tip_defl
        K0s = 0.5 * (self.K0 + self.K0.T)
        C[6, :nq] = K0s @ x[:nq]
        C[6, nq:] = self.M0 @ x[nq:]
        C[7:, 2:nq] = np.eye(n)
        return C

    def output_derivatives_numpy(self, x, u, du=0.0):
        """``(d1, d2)`` of the outputs (see :meth:`PlantModel.output_derivatives_numpy`)."""
        return _output_derivatives(self, x, u, du, linear=True)

    def tip_angle(self, x):
        return self.kernel.tip(x)

    def tip_angle_numpy(self, x):
        nq = self.nq
        return (float(x[1] + self.tip_slope @ x[2:nq]),
                float(x[nq + 1] + self.tip_slope @ x[nq + 2:]))

    def energy(self, x):
        return self.kernel.energy(x)

    def energy_numpy(self, x):
        q, qd = x[:self.nq], x[self.nq:]
        return float(0.5 * qd @ self.M0 @ qd + 0.5 * q @ self.K0 @ q + self._offset)

    def outputs(self, t, x, u=0.0):
        nq = self.nq
        phi_o, omega_o = self.tip_angle(x)
        eta = x[2:nq]
        return {"x_o": float(x[0]), "x_dot": float(x[nq]), "phi_o": phi_o, "omega_o": omega_o,
                "tip_deflection": float(self.tip_defl @ eta) if self.n else 0.0,
                "eta": np.array(eta, dtype=float), "energy": self.energy(x)}

    initial_state = PlantModel.initial_state

    def linearize(self):
        return self.M0, self.D0, self.K0

    def state_space(self):
        return self.A, self.B, self.C, self.D


def _output_derivatives(m, x, u, du, linear):
    """``(d1, d2)`` of every output (the kernel's layout) of the model ``m`` at ``x`` for the force
    ``u`` and its rate ``du``.

    ``d1 = C f`` with ``f = dx/dt`` and ``C`` the output Jacobian (the energy's row: its gradient).
    ``d2 = d/dt (C(x) f(x, u)) = f^T H_k f + C (J f + b du)``, written per output by the chain rule:
    the outputs linear in ``x`` take ``C g`` with ``g = J f + b du = d^2x/dt^2``; the tip angle
    ``phi + atan(sl)`` (``sl = N'(L) eta``) and its rate ``omega_o = phid + sld / (1 + sl^2)`` are
    differentiated once more by hand; the energy's second derivative is that of the power balance
    ``dE/dt = F_c xd - etad.D.etad + c etad.Kga.eta`` (``Kga`` the skew part of ``Kg``, ``c = cos
    phi``, 1 in the linear model): the equations are Lagrange's for this energy with the Rayleigh
    damping and the force on the cart (``tests/plant/test_lagrange.py``), and ``Kg eta``'s skew
    part is the only force of ``f`` no potential gives.
    """
    n, nq = m.n, m.nq
    f = m.rhs_numpy(0.0, x, u)
    J, b = m.jacobian_numpy(x, u)
    g = J @ f + b * du
    C = m.output_jacobian_numpy(x)
    d1 = C @ f
    d2 = C @ g                      # exact for the outputs linear in x
    qd, a, j3 = x[nq:], f[nq:], g[nq:]
    ts = m.tip_slope
    sl, sld, sldd, slddd = (float(ts @ v[2:]) for v in (x[:nq], qd, a, j3))
    if not linear:
        w = 1.0 + sl * sl
        d2[2] = a[1] + sldd / w - 2.0 * sl * sld ** 2 / w ** 2
        d2[3] = (j3[1] + slddd / w - 6.0 * sl * sld * sldd / w ** 2 - 2.0 * sld ** 3 / w ** 2
                 + 8.0 * sl * sl * sld ** 3 / w ** 3)
    eta, etad, etadd = x[2:nq], qd[2:], a[2:]
    Dd = m.Ddiag if not linear else np.diag(m.D0)[2:]
    Kg = m.Kg if not linear else m._nl.Kg
    Kga = 0.5 * (Kg - Kg.T)
    c, s = (math.cos(x[1]), math.sin(x[1])) if not linear else (1.0, 0.0)
    d2[6] = (du * qd[0] + u * a[0] - 2.0 * float(Dd @ (etad * etadd))
             + c * float(etadd @ Kga @ eta) - s * qd[1] * float(etad @ Kga @ eta))
    assert d1.shape == (7 + n,)
    return d1, d2


def _make_kernel(m: PlantModel, linear: bool):
    """The compiled kernel with the data of the nonlinear model ``m`` (its linearisation if
    ``linear``; the stiffened model's if ``m`` is one)."""
    from .kernel import PlantKernel

    extra = dict(points=m.points) if isinstance(m, StiffenedPlantModel) else {}
    return PlantKernel(n=m.n, linear=linear, preload=m.preload, I0=m.I0, I1=m.I1, I2=m.I2, g=m.g,
                       I3=m.I3, I5=m.I5, K=m.Kdiag, D=m.Ddiag, Kg=m.Kg, tip_slope=m.tip_slope,
                       tip_defl=m.tip_defl, **extra)


class StiffenedPlantModel(PlantModel):
    """The floating frame with motion-dependent geometric stiffness (``fidelity = "stiffened"``).

    The beam is inextensible: a point at arc length ``s`` sits at ``s - u(s)`` along the beam axis
    ``b1 = (-sin phi, cos phi)`` and at ``w(s) = N(s) eta`` along ``b2 = (-cos phi, -sin phi)``,
    with the foreshortening ``u(s) = 1/2 int_0^s w'^2 = 1/2 eta.G(s).eta``. The Lagrangian is the
    nonlinear model's with the preload (its kinetic energy, the weight with the foreshortening's
    ``-1/2 cos(phi) eta.Kg.eta``, the strain) plus the kinetic energy the foreshortening adds,
    ``dT = 1/2 int rhoA (|rd|^2 - |rd_0|^2) ds`` (``r_0``: the same point without ``u``), taken in
    full over the mass points of :func:`plant_fmu.beam.mass_points`. The equations are Lagrange's
    (``dT``'s as Kane's: ``r_p'' = J_p qdd + c_p``): ``M(q) qdd = f`` with ``M`` the nonlinear
    model's plus ``sum m_p (J_p^T J_p - J0_p^T J0_p)``, symmetric, positive definite and
    state-dependent, solved each evaluation; ``T + dT + V`` is conserved without damping and force.

    In the frame ``(b1, b2)``, with ``c, s = cos, sin phi``, ``w_p = N_p eta``,
    ``u_p = 1/2 eta.G_p.eta``, ``Ge_p = G_p eta``::

        J_p, b1 row:  [-s, -w_p, -Ge_p^T]         J_p, b2 row:  [-c, s_p - u_p, N_p]
        -c_p, b1:  etad.G_p.etad + 2 wd_p phid + (s_p - u_p) phid^2
        -c_p, b2:  2 ud_p phid + w_p phid^2                      (J0_p, c0_p: u_p = Ge_p = 0)

    To first order in ``eta`` the modal equations then carry the geometric stiffness
    ``K_G(t) = int N(s, t) N'^T N' ds = -(g c - s xdd) Fa + phid^2 Fb`` of the axial load
    ``N(s, t) = -rhoA (L - s) (g c - s xdd) + rhoA phid^2 (L^2 - s^2)/2``
    (``Fa = int rhoA (L - s) N'^T N' = Kg / g``, ``Fb = int rhoA (L^2 - s^2)/2 N'^T N'``): the
    gravity and the cart's acceleration along the beam compress it, the centrifugal load stretches
    it; the angular acceleration and the accelerations across the beam load it transversely and
    enter at third order. The load's ``xdd`` is a term of the mass matrix (``M_x,eta`` gains
    ``s Fa eta``), not a lagged acceleration (``tests/plant/test_stiffened.py`` checks this
    ``K_G``). ``dT`` is kept in full rather than to second order: truncated, the mass matrix loses
    positive definiteness once ``eta.(Fb - I).eta`` exceeds the rotation's residual inertia ``I2 -
    I5.I5`` (3.2e-3 kg m^2 at 4 modes, 4.1e-4 at 8), which the filtered scene reaches from pi/6 at 8
    modes within 0.04 s.

    At the upright rest state ``dT`` is of fourth order: the linearisation is the preload rung's,
    whatever ``gravity_preload`` says (the stiffened model always carries the self-weight).
    """

    def __init__(self, p: PlantParams):
        super().__init__(p.replace(gravity_preload=True))
        self.params = p
        self.points = mass_points(p.replace(gravity_preload=False))

    def _rows(self, q, qd):
        """Per point, the rows of ``J_p`` along b1 and b2 (P x nq) with and without ``u``, and
        ``-c_p`` with and without it."""
        pts, n = self.points, self.n
        c, s = math.cos(q[1]), math.sin(q[1])
        eta, phid, etad = q[2:], qd[1], qd[2:]
        w, Ge = pts.N @ eta, pts.G @ eta
        u = 0.5 * (Ge @ eta)
        P = pts.s.size
        J1, J2 = np.zeros((P, n + 2)), np.zeros((P, n + 2))
        J1[:, 0], J1[:, 1] = -s, -w
        J2[:, 0], J2[:, 1], J2[:, 2:] = -c, pts.s, pts.N
        J01, J02 = J1.copy(), J2.copy()
        J1[:, 2:] = -Ge
        J2[:, 1] -= u
        wd, ud = pts.N @ etad, Ge @ etad
        r01 = 2.0 * wd * phid + pts.s * phid * phid
        r02 = w * phid * phid
        r1 = (pts.G @ etad) @ etad + 2.0 * wd * phid + (pts.s - u) * phid * phid
        r2 = 2.0 * ud * phid + w * phid * phid
        return (J1, J2, r1, r2), (J01, J02, r01, r02)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        (J1, J2, *_), (J01, J02, *_) = self._rows(q, np.zeros(self.nq))
        m = self.points.m[:, None]
        dM = J1.T @ (m * J1) + J2.T @ (m * J2) - J01.T @ (m * J01) - J02.T @ (m * J02)
        return super().mass_matrix(q) + dM

    def forces(self, q: np.ndarray, qd: np.ndarray, u: float) -> np.ndarray:
        (J1, J2, r1, r2), (J01, J02, r01, r02) = self._rows(q, qd)
        m = self.points.m
        df = J1.T @ (m * r1) + J2.T @ (m * r2) - J01.T @ (m * r01) - J02.T @ (m * r02)
        return super().forces(q, qd, u) + df

    def accelerations(self, q: np.ndarray, qd: np.ndarray, u: float) -> np.ndarray:
        return np.linalg.solve(self.mass_matrix(q), self.forces(q, qd, u))

    def energy_numpy(self, x: np.ndarray) -> float:
        """The nonlinear model's ``T + V`` with the preload, plus ``dT``."""
        nq = self.nq
        qd = x[nq:]
        (J1, J2, *_), (J01, J02, *_) = self._rows(x[:nq], qd)
        dT = 0.5 * float(self.points.m @ ((J1 @ qd) ** 2 + (J2 @ qd) ** 2 - (J01 @ qd) ** 2
                                          - (J02 @ qd) ** 2))
        return super().energy_numpy(x) + dT

    def _no_jacobian(self, *args, **kwargs):
        raise ValueError("the exact Jacobians and output derivatives are not available for "
                         "fidelity = 'stiffened' (nonlinear and linear have them)")

    jacobian_numpy = output_jacobian_numpy = output_derivatives_numpy = _no_jacobian


@functools.lru_cache(maxsize=64)
def stiffened_plant_model(p: PlantParams) -> StiffenedPlantModel:
    """The (cached) :class:`StiffenedPlantModel` of a parameter record."""
    return StiffenedPlantModel(p)


def model_for(p: PlantParams, fidelity: str):
    """The model of ``plant.fidelity`` (``"nonlinear"``, ``"linear"`` or ``"stiffened"``)."""
    makers = {"nonlinear": plant_model, "linear": linear_plant_model,
              "stiffened": stiffened_plant_model}
    if fidelity not in makers:
        raise ValueError(f"fidelity = {fidelity!r} is not allowed here; allowed: "
                         f"{', '.join(makers)}")
    return makers[fidelity](p)


@functools.lru_cache(maxsize=64)
def linear_plant_model(p: PlantParams) -> LinearPlantModel:
    """The (cached) :class:`LinearPlantModel` of a parameter record."""
    return LinearPlantModel(p)


@functools.lru_cache(maxsize=64)
def plant_model(p: PlantParams) -> PlantModel:
    """The (cached) :class:`PlantModel` of a parameter record."""
    return PlantModel(p)


def rhs(t: float, x: np.ndarray, u: float, p: PlantParams) -> np.ndarray:
    """``dx/dt`` of the nonlinear plant with parameters ``p`` (see :meth:`PlantModel.rhs`)."""
    return plant_model(p).rhs(t, x, u)


def outputs(t: float, x: np.ndarray, u: float, p: PlantParams) -> dict:
    return plant_model(p).outputs(t, x, u)


def energy(x: np.ndarray, p: PlantParams) -> float:
    return plant_model(p).energy(x)


def linearize(p: PlantParams):
    return plant_model(p).linearize()


def state_space(p: PlantParams):
    return plant_model(p).state_space()
