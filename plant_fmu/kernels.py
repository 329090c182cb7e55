"""Compiled right-hand side of the nonlinear plant (numba), the hot path of every integrator.

It computes exactly what :meth:`plant_fmu.dynamics.PlantModel.accelerations` computes (the
readable numpy version, which stays the specification); a test checks the two against each other
at random states. Without numba the numpy version is used, ~15 times slower.
"""
from __future__ import annotations

import math

try:
    import numba
except ImportError:  # pragma: no cover - numba is a declared dependency
    numba = None

__all__ = ["rhs_kernel", "erk_steps_kernel", "energy_kernel", "tip_kernel", "HAVE_NUMBA"]

HAVE_NUMBA = numba is not None


def _rhs(x, u, consts, I3, I5, Kd, Dd, Kg, out):
    """Fill ``out`` with dx/dt; ``consts = [I0, I1, I2, g, I3.I3, I3.I5, I5.I5, preload]``."""
    n = I3.size
    nq = n + 2
    I0, I1, I2, g = consts[0], consts[1], consts[2], consts[3]
    I3I3, I3I5, I5I5, preload = consts[4], consts[5], consts[6], consts[7]
    phi = x[1]
    phid = x[nq + 1]
    c = math.cos(phi)
    s = math.sin(phi)
    I3eta = 0.0
    I3etad = 0.0
    ee = 0.0
    eed = 0.0
    for j in range(n):
        e = x[2 + j]
        ed = x[nq + 2 + j]
        I3eta += I3[j] * e
        I3etad += I3[j] * ed
        ee += e * e
        eed += e * ed
    f0 = u - (I1 * s + I3eta * c) * phid * phid - 2.0 * phid * s * I3etad
    f1 = -2.0 * phid * eed + g * (I1 * s + I3eta * c)
    I3fe = 0.0
    I5fe = 0.0
    for j in range(n):
        e = x[2 + j]
        fe = phid * phid * e + g * s * I3[j] - Kd[j] * e - Dd[j] * x[nq + 2 + j]
        if preload != 0.0:
            kge = 0.0
            for k in range(n):
                kge += Kg[j, k] * x[2 + k]
            fe += c * kge
            f1 -= 0.5 * s * e * kge
        out[nq + 2 + j] = fe
        I3fe += I3[j] * fe
        I5fe += I5[j] * fe
    # Schur complement of the identity block of the modes (see PlantModel.accelerations)
    a00 = I0 - c * c * I3I3
    a01 = -I1 * c + s * I3eta + c * I3I5
    a11 = I2 + ee - I5I5
    r0 = f0 + c * I3fe
    r1 = f1 - I5fe
    det = a00 * a11 - a01 * a01
    xdd = (a11 * r0 - a01 * r1) / det
    phidd = (a00 * r1 - a01 * r0) / det
    for i in range(nq):
        out[i] = x[nq + i]
    out[nq] = xdd
    out[nq + 1] = phidd
    for j in range(n):
        out[nq + 2 + j] += c * xdd * I3[j] - phidd * I5[j]
    return out


def _energy(x, consts, I3, I5, Kd, Kg):
    """Total energy ``T + V``: what :meth:`PlantModel.energy_numpy` computes."""
    n = I3.size
    nq = n + 2
    I0, I1, I2, g, preload = consts[0], consts[1], consts[2], consts[3], consts[7]
    phi, xd, phid = x[1], x[nq], x[nq + 1]
    c = math.cos(phi)
    s = math.sin(phi)
    I3eta = 0.0
    I3etad = 0.0
    ee = 0.0
    I5etad = 0.0
    etadetad = 0.0
    strain = 0.0
    for j in range(n):
        e = x[2 + j]
        ed = x[nq + 2 + j]
        I3eta += I3[j] * e
        I3etad += I3[j] * ed
        ee += e * e
        I5etad += I5[j] * ed
        etadetad += ed * ed
        strain += Kd[j] * e * e
    T = (0.5 * I0 * xd * xd + xd * (-(I1 * phid + I3etad) * c + phid * s * I3eta)
         + 0.5 * phid * phid * (I2 + ee) + phid * I5etad + 0.5 * etadetad)
    V = g * (I1 * c - s * I3eta) + 0.5 * strain
    if preload != 0.0:
        ekge = 0.0
        for j in range(n):
            for k in range(n):
                ekge += x[2 + j] * Kg[j, k] * x[2 + k]
        V -= 0.5 * c * ekge
    return T + V


def _tip(x, slope):
    """``(phi_o, omega_o)``: what :meth:`PlantModel.tip_angle` computes."""
    n = slope.size
    nq = n + 2
    sl = 0.0
    sld = 0.0
    for j in range(n):
        sl += slope[j] * x[2 + j]
        sld += slope[j] * x[nq + 2 + j]
    return x[1] + math.atan(sl), x[nq + 1] + sld / (1.0 + sl * sl)


def _erk_steps(y, u0, du, d2u, s0, h, n_steps, A, B, C, consts, I3, I5, Kd, Dd, Kg, K, ys):
    """``n_steps`` substeps of length ``h`` of the explicit Runge-Kutta tableau ``(A, B, C)`` on
    the plant, in place on ``y``, with the input ``u0 + du s + d2u s^2 / 2``, ``s = s0`` at the
    start (``du = d2u = 0``: held); ``K`` (stages x states) and ``ys`` are work arrays. Stops
    after a substep whose state is not finite (``y`` keeps the last finite state) and returns
    the number of substeps taken. The arithmetic is that of
    :meth:`plant_fmu.integrators.rk.ExplicitRungeKutta._rk_step`."""
    s = B.size
    nx = y.size
    for k in range(n_steps):
        for i in range(s):
            for m in range(nx):
                acc = 0.0
                for j in range(i):
                    acc += (h * A[i, j]) * K[j, m]
                ys[m] = y[m] + acc
            st = s0 + k * h + C[i] * h
            u = u0 + st * (du + 0.5 * st * d2u)
            _rhs_c(ys, u, consts, I3, I5, Kd, Dd, Kg, K[i])
        norm2 = 0.0
        for m in range(nx):
            acc = 0.0
            for i in range(s):
                acc += (h * B[i]) * K[i, m]
            ys[m] = y[m] + acc
            norm2 += ys[m] * ys[m]
        if not norm2 < math.inf:            # overflow or NaN: fail if an entry is not finite
            for m in range(nx):
                if not abs(ys[m]) < math.inf:
                    return k
        for m in range(nx):
            y[m] = ys[m]
    return n_steps


if HAVE_NUMBA:
    rhs_kernel = _rhs_c = numba.njit(cache=True)(_rhs)
    energy_kernel = numba.njit(cache=True)(_energy)
    tip_kernel = numba.njit(cache=True)(_tip)
    erk_steps_kernel = numba.njit(cache=True)(_erk_steps)
else:  # pragma: no cover - numba is a declared dependency
    rhs_kernel = _rhs_c = _rhs
    energy_kernel = _energy
    tip_kernel = _tip
    erk_steps_kernel = _erk_steps
