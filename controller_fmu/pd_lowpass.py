"""PD on the tip sensors followed by a unit-DC-gain low-pass filter (docs/model.md section 5).

    e   = kp*phi_o + kd*omega_o + kx*x_o
    F_c = -H(s) e,   H = 1 (order 0),  wc/(s + wc) (order 1),  wc^2/(s^2 + 2 zf wc s + wc^2) (order 2)

optionally saturated at ``+-force_limit``. The filter's state-space form is the controllable
canonical one with the filter output as first state; it is discretised exactly over a step ``h``
with the input ``e`` held (zero-order hold), by the matrix exponential of the augmented matrix.
"""
from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass

import numpy as np

from fmu_common.checks import check_fields, choice, integer, real, replace_checked

__all__ = ["ControllerParams", "PDLowPassModel", "INPUT_NAMES", "NO_LIMIT", "DISCRETIZATIONS",
           "SAMPLED_FIELDS"]

#: "No limit" for the saturation: the largest double (1.7976931348623157e+308). No finite force
#: exceeds it, so it means what infinity means; ``inf`` is accepted too.
NO_LIMIT = sys.float_info.max

#: How the sampled controller's filter becomes a difference equation (docs/sampled.md):
#: ``tustin``, the bilinear map prewarped at the cutoff (the default: it keeps the cutoff and the
#: second-order filter's peak where the continuous design put them, and adds no lag of its own),
#: or ``zoh``, the filter's zero-order-hold equivalent (half a sample more lag).
DISCRETIZATIONS = ("tustin", "zoh")
#: The fields of the sampled controller (0: the continuous controller), after the others: in the
#: FMUs' variable table they come after every older variable, so no value reference moves.
SAMPLED_FIELDS = ("sample_period", "delay", "discretization")

#: Controller inputs, in the order of the columns of ``B`` and ``D``.
INPUT_NAMES = ("x_o", "phi_o", "omega_o")


@dataclass(frozen=True)
class ControllerParams:
    """Gains and filter of the controller. ``force_limit`` is the saturation; the default,
    ``NO_LIMIT`` (the largest double, which no finite force exceeds), and ``inf`` mean none.
    The default is finite so that every FMU checker reads the FMUs' start value (the FMI 2.0 VDM
    checker's static distribution cannot read ``INF``; libcosim's SSP reader neither).

    The defaults are the paper's PD (``kp = 500``, ``kd = 5``) and the robust second-order
    filter that ``flexpend design`` chooses for it (97.3 rad/s, damping 0.1; ``docs/spillover.md``).
    docs/model.md's acceptance table also uses 150 rad/s with damping 0.5.
    """

    kp: float = real(500.0, "proportional gain on phi_o", "N/rad", low=-1e12,
                     high=1e12)
    kd: float = real(5.0, "derivative gain (on omega_o)", "N.s/rad", low=-1e12,
                     high=1e12)
    kx: float = real(0.0, "gain on the cart position x_o (0: no cart feedback)",
                     "N/m", low=-1e12, high=1e12)
    filter_order: int = integer(2, "order of the unit-DC-gain low-pass filter: 0 (none), 1 or 2", low=0, high=2)
    cutoff: float = real(97.3, "filter cutoff frequency", "rad/s", low=0.0, high=1e9)
    filter_damping: float = real(0.1, "damping ratio of the 2nd-order filter", low=0.0,
                                 high=100.0)
    force_limit: float = real(NO_LIMIT, "saturation |F_c| <= force_limit (inf, or the largest "
                              "double: none)", "N", low=0.0, allow_inf=True)
    sample_period: float = real(0.0, "sample period T of the digital controller (0: the "
                                "continuous controller)", "s", low=0.0, low_open=False, high=1e3,
                                note="with the tustin filter, cutoff * sample_period < pi")
    delay: float = real(0.0, "computation delay: the force computed at a sample acts this much "
                        "later", "s", low=0.0, low_open=False, high=1e3,
                        note="at most controller.sample_period")
    discretization: str = choice("tustin", "how the sampled filter becomes a difference "
                                 "equation: tustin (prewarped at the cutoff) or zoh",
                                 DISCRETIZATIONS)

    def __post_init__(self):
        check_fields(self)
        if self.delay > self.sample_period:
            raise ValueError(f"delay = {self.delay!r} is out of range; allowed: at most "
                             f"controller.sample_period ({self.sample_period!r} s)")
        if (self.sampled and self.discretization == "tustin" and self.filter_order > 0
                and not self.cutoff * self.sample_period < math.pi):
            raise ValueError(f"sample_period = {self.sample_period!r} is out of range for the "
                             f"tustin filter prewarped at controller.cutoff = {self.cutoff!r} "
                             f"rad/s; allowed: below pi / cutoff = {math.pi / self.cutoff:.6g} s "
                             f"(or controller.discretization = zoh)")

    @property
    def sampled(self) -> bool:
        """Whether the controller is digital (``sample_period > 0``)."""
        return self.sample_period > 0.0

    @property
    def saturates(self) -> bool:
        """Whether ``force_limit`` limits the force (``NO_LIMIT`` and ``inf`` do not)."""
        return self.force_limit < NO_LIMIT

    def replace(self, **changes) -> "ControllerParams":
        """A copy with ``changes`` applied and validated; unknown names raise TypeError."""
        return replace_checked(self, "controller", changes)


class PDLowPassModel:
    """The controller as a linear system ``xc' = A xc + B y``, ``F_c = C xc + D y`` (then saturated).

    ``y = [x_o, phi_o, omega_o]``. The filter state has ``filter_order`` entries.
    """

    def __init__(self, p: ControllerParams):
        self.params = p
        gains = np.array([[p.kx, p.kp, p.kd]])                 # e = gains @ y
        wc, zf = p.cutoff, p.filter_damping
        if p.filter_order == 0:
            Af, Bf, Cf, Df = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))
        elif p.filter_order == 1:
            Af, Bf, Cf, Df = np.array([[-wc]]), np.array([[wc]]), np.ones((1, 1)), np.zeros((1, 1))
        else:
            Af = np.array([[0.0, 1.0], [-wc * wc, -2.0 * zf * wc]])
            Bf = np.array([[0.0], [wc * wc]])
            Cf, Df = np.array([[1.0, 0.0]]), np.zeros((1, 1))
        self.Af, self.Bf, self.Cf, self.Df = Af, Bf, Cf, Df
        self.gains = gains
        self.A = Af
        self.B = Bf @ gains
        self.C = -Cf
        self.D = -Df @ gains
        self.nx = p.filter_order

    def state_space(self):
        return self.A, self.B, self.C, self.D

    def transfer_function(self, s: complex) -> complex:
        """The filter ``H(s)`` (unit DC gain)."""
        p = self.params
        if p.filter_order == 0:
            return 1.0 + 0j
        if p.filter_order == 1:
            return p.cutoff / (s + p.cutoff)
        wc = p.cutoff
        return wc * wc / (s * s + 2 * p.filter_damping * wc * s + wc * wc)

    def initial_state(self) -> np.ndarray:
        return np.zeros(self.nx)

    def error_signal(self, y) -> float:
        p = self.params
        return p.kx * y[0] + p.kp * y[1] + p.kd * y[2]

    def output(self, xc: np.ndarray, y) -> float:
        """``F_c`` for filter state ``xc`` and sensors ``y = [x_o, phi_o, omega_o]``."""
        if self.nx == 0:
            F = -self.error_signal(y)
        else:
            F = -xc[0]
        lim = self.params.force_limit
        return min(max(F, -lim), lim)

    @functools.lru_cache(maxsize=8)
    def discretize(self, h: float):
        """``(Ad, Bd)`` with ``xc[k+1] = Ad xc[k] + Bd e[k]``: exact for ``e`` held over ``h``."""
        n = self.nx
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n] = self.Af * h
        aug[:n, n:] = self.Bf * h
        E = _expm(aug)
        return E[:n, :n].copy(), E[:n, n].copy()

    @functools.lru_cache(maxsize=8)
    def discretize_polynomial(self, h: float):
        """``(Ad, G)`` with ``xc(t + h) = Ad xc(t) + G @ [e0, e1, e2]``: exact for the error
        signal ``e(t + s) = e0 + e1 s + e2 s^2 / 2`` over ``[0, h]`` (``G[:, 0]`` is the
        zero-order-hold ``Bd``). From one matrix exponential of the filter driven by a chain of
        three integrators."""
        n = self.nx
        aug = np.zeros((n + 3, n + 3))
        aug[:n, :n] = self.Af * h
        aug[:n, n] = self.Bf[:, 0] * h
        aug[n, n + 1] = aug[n + 1, n + 2] = h        # e' = e1 + e2 s, e'' = e2
        E = _expm(aug)
        return E[:n, :n].copy(), E[:n, n:].copy()

    def step(self, xc: np.ndarray, y, h: float) -> np.ndarray:
        """Advance the filter state over ``h`` with the sensors ``y`` held."""
        if self.nx == 0:
            return xc
        Ad, Bd = self.discretize(float(h))
        return Ad @ xc + Bd * self.error_signal(y)


def _expm(M):
    """scipy's matrix exponential (imported on first use: an FMU's start does not need it)."""
    import scipy.linalg

    return scipy.linalg.expm(M)
