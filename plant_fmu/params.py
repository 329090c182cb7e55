"""The plant's parameter record: Table 1 of Tang & Ren, validated in one place.

The defaults are the paper's dimensionless sample (docs/model.md section 1). The paper gives EA and
EI but not the cross-section; with ``E = 2.1e11`` the area is ``A = EA/E = 2e-3`` and the beam's mass
per unit length is ``rhoA = rho*A = 15.6``.
"""
from __future__ import annotations

from dataclasses import dataclass

from fmu_common.checks import (boolean, check_fields, choice, integer, real,
                                replace_checked)

__all__ = ["PlantParams", "MAX_ELEMENTS", "POSITIVE_MIN", "DAMPING_LAWS",
           "damping_text"]

#: The beam's damping laws (docs/model.md section 7), ``plant.damping``:
#:
#: * ``"modal"``: the same ratio ``zeta`` in every cantilever mode, ``D = diag(2 zeta omega_j)``
#:   (the paper's "zeta = 0.1 %" read as this law; the default);
#: * ``"kelvin-voigt"``: material damping ``beta EI w''''_t`` with ``beta = 2 zeta / omega_1``
#:   (``omega_1`` the first cantilever frequency of the same mesh), which in the mass-normalised
#:   cantilever modes is ``D = beta K = diag(2 zeta omega_j^2 / omega_1)``: mode ``j`` has the
#:   ratio ``zeta omega_j / omega_1``. It acts on the material stiffness only, not on the
#:   geometric stiffness of the self-weight (``gravity_preload``, the stiffened rung).
#:
#: The two agree on the first cantilever mode and differ above it.
DAMPING_LAWS = ("modal", "kelvin-voigt")

#: The finest mesh the beam model accepts (the eigenproblem is dense).
MAX_ELEMENTS = 400


#: The smallest value of a positive physical parameter (m, L, rho, EA, EI, E). The beam's
#: invariants are products and quotients of up to about four of them: within [1e-15, 1e15] none
#: underflows to zero (a subnormal L or rho once gave "float division by zero" deep in the model,
#: naming no parameter).
POSITIVE_MIN = 1e-15


@dataclass(frozen=True)
class PlantParams:
    """Physical and discretisation parameters of the cart with a flexible beam.

    Attributes
    ----------
    m : cart mass.
    L : beam length.
    rho : beam density.
    EA : axial stiffness (with ``E`` it fixes the cross-section area ``A = EA/E``).
    EI : bending stiffness.
    E : Young's modulus, used only to read the area off ``EA``.
    zeta : structural damping ratio, ``0 <= zeta < 1``: of every cantilever mode (``damping =
        "modal"``), or of the first (``"kelvin-voigt"``).
    damping : the damping law, one of :data:`DAMPING_LAWS`.
    g : gravity.
    n_modes : number of cantilever modes kept; 0 is the rigid pendulum.
    n_elements : number of cubic Hermite beam elements of the finite-element mesh.
    gravity_preload : add the geometric stiffness of the beam's self-weight compression.
    """

    m: float = real(1.0, "cart mass", "kg", low=POSITIVE_MIN, low_open=False, high=1e15)
    L: float = real(1.0, "beam length", "m", low=POSITIVE_MIN, low_open=False, high=1e15)
    rho: float = real(7.8e3, "beam density", "kg/m3", low=POSITIVE_MIN, low_open=False,
                      high=1e15)
    EA: float = real(4.2e8, "axial stiffness", "N", low=POSITIVE_MIN, low_open=False, high=1e15)
    EI: float = real(8.75e2, "bending stiffness", "N.m2", low=POSITIVE_MIN, low_open=False,
                     high=1e15)
    E: float = real(2.1e11, "Young's modulus (cross-section area = EA/E)", "Pa",
                    low=POSITIVE_MIN, low_open=False, high=1e15)
    zeta: float = real(0.001, "damping ratio: of every cantilever mode (damping = modal), of "
                       "the first (kelvin-voigt)", low=0.0, high=1.0, low_open=False,
                       high_open=True)
    damping: str = choice("modal", "damping law: modal (zeta in every cantilever mode) or "
                          "kelvin-voigt (material damping, zeta in mode 1)", DAMPING_LAWS)
    g: float = real(9.81, "gravity", "m/s2", low=0.0, high=1e3, low_open=False)
    n_modes: int = integer(4, "cantilever modes kept (0: rigid pendulum)", low=0,
                           high_field="n_elements")
    n_elements: int = integer(24, "finite elements of the beam mesh", low=1, high=MAX_ELEMENTS,
                              note="at least plant.n_modes and fidelity.max_modes")
    gravity_preload: bool = boolean(False, "geometric stiffness of the beam's self-weight")

    def __post_init__(self):
        check_fields(self)

    @property
    def area(self) -> float:
        return self.EA / self.E

    @property
    def rhoA(self) -> float:
        """Mass per unit length of the beam."""
        return self.rho * self.EA / self.E

    def replace(self, **changes) -> "PlantParams":
        """A copy with ``changes`` applied and validated; unknown names raise TypeError."""
        return replace_checked(self, "plant", changes)


def damping_text(p: PlantParams) -> str:
    """The structural damping of ``p`` in words, its law named (every report that states a
    damping-dependent number says it): ``"modal damping 0.1 %"`` (every cantilever mode),
    ``"Kelvin-Voigt damping, 0.1 % in mode 1"``, or ``"no structural damping"``."""
    if p.zeta == 0.0:
        return "no structural damping"
    pct = f"{100 * p.zeta:.4g} %"
    return f"modal damping {pct}" if p.damping == "modal" else \
        f"Kelvin-Voigt damping, {pct} in mode 1"


# ------------------------------------------------------------------ the exact rung's damping law


