"""Every row of docs/model.md section 6's acceptance table, computed by the project.

The table's numbers come from two independent linear models outside this project; eigenvalues
are checked to 1 %.
"""
import numpy as np
import pytest

from controller_fmu.pd_lowpass import ControllerParams
from orchestration.studies.analysis import analyze, closed_loop_matrix
from plant_fmu.dynamics import plant_model
from plant_fmu.params import PlantParams

PD = ControllerParams(filter_order=0)


def _upper(eigs):
    return sorted((z for z in eigs if z.imag > 1e-9), key=lambda z: z.imag)


def _near(eigs, target):
    """The eigenvalue closest to ``target``, asserted within 1 % of |target|."""
    z = min(eigs, key=lambda e: abs(e - target))
    assert abs(z - target) <= 0.01 * abs(target), (z, target)
    return z


def test_cantilever_frequencies():
    a = analyze(PlantParams(n_modes=4), PD)
    np.testing.assert_allclose(a.cantilever_frequencies, [26.33, 165.02, 462.07, 905.47],
                               rtol=1e-3)


@pytest.mark.parametrize("n", range(0, 7))
def test_open_loop_unstable_root(n):
    A = plant_model(PlantParams(n_modes=n)).state_space()[0]
    assert np.linalg.eigvals(A).real.max() == pytest.approx(7.065, abs=0.006)


def test_rigid_pd():
    a = analyze(PlantParams(n_modes=0), PD)
    _near(a.eigenvalues, -0.765 + 10.13j)
    # the double root at zero (cart drift)
    assert np.sum(np.abs(a.eigenvalues) < 1e-9) == 2
    assert a.stable and a.max_real_part == pytest.approx(-0.765, rel=0.01)


def test_one_mode_pd_looks_stable():
    a = analyze(PlantParams(n_modes=1), PD)
    _near(a.eigenvalues, -0.05 + 226.7j)
    assert a.stable


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_two_or_more_modes_pd_is_unstable_near_151(n):
    a = analyze(PlantParams(n_modes=n), PD)
    z = _near(a.eigenvalues, 1.64 + 151.3j)
    assert not a.stable and z.real > 0


@pytest.mark.parametrize("n", range(0, 7))
def test_first_order_130_is_stable(n):
    a = analyze(PlantParams(n_modes=n), ControllerParams(filter_order=1, cutoff=130))
    assert a.stable
    if n >= 2:
        assert a.max_real_part == pytest.approx(-0.18, abs=0.01)


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_first_order_200_is_unstable(n):
    assert not analyze(PlantParams(n_modes=n), ControllerParams(filter_order=1, cutoff=200)).stable


SECOND = ControllerParams(filter_order=2, cutoff=150, filter_damping=0.5)


@pytest.mark.parametrize("n", range(0, 9))
def test_second_order_filter_is_stable(n):
    a = analyze(PlantParams(n_modes=n), SECOND)
    assert a.stable
    if n == 0:
        _near(a.eigenvalues, -0.255 + 10.21j)
    else:
        _near(a.eigenvalues, -0.263 + 10.30j) if n >= 2 else None
    if n >= 2:
        _near(a.eigenvalues, -1.89 + 150.5j)
    if n >= 3:
        _near(a.eigenvalues, -1.30 + 426.4j)


def test_second_order_filter_needs_structural_damping():
    """docs/model.md: with no structural damping the filtered loop's 2nd bending mode is
    unstable."""
    Acl = closed_loop_matrix(PlantParams(n_modes=4, zeta=0.0), SECOND)
    eigs = np.linalg.eigvals(Acl)
    z = min(_upper(eigs), key=lambda e: abs(e.imag - 426.4))
    assert z.real > 0


def _bending(a):
    return min(_upper(a.eigenvalues), key=lambda z: abs(z.imag - 151.3))


@pytest.mark.parametrize("n", [4, 6, 8])
def test_flexible_pd_bending_growth_under_both_damping_laws(n):
    """docs/model.md sections 6 and 7: ``flexible_pd`` (PD only) has its bending root growing at
    +1.64/s under the modal law (checked to 1 %, as the table) and at about +1.20/s under the
    Kelvin-Voigt law, which damps the higher cantilever modes more (``about``: checked to 2 %;
    the model gives 1.213 .. 1.216). The second check of the Kelvin-Voigt figure is the
    geometrically exact beam's own linearisation (:meth:`plant_fmu.exact.ExactPlant.state_space`,
    its material damping in the continuum, with the self-weight's stiffness;
    docs/model.md: "a refined exact beam agrees"): the floating frame with the preload agrees
    with it to 1 %."""
    from plant_fmu.exact import ExactPlant
    from controller_fmu.pd_lowpass import PDLowPassModel
    from orchestration.studies.analysis import assemble_closed_loop

    modal = _bending(analyze(PlantParams(n_modes=n), PD))
    kv = PlantParams(n_modes=n, damping="kelvin-voigt")
    kelvin = _bending(analyze(kv, PD))
    assert modal.real == pytest.approx(1.64, rel=0.01)
    assert kelvin.real == pytest.approx(1.20, rel=0.02)
    assert abs(kelvin.imag - modal.imag) < 0.01 * modal.imag     # the same mode
    A, B, C = ExactPlant(PlantParams(n_elements=8, damping="kelvin-voigt")).state_space()
    exact = min(_upper(np.linalg.eigvals(assemble_closed_loop(
        A, B, C, PDLowPassModel(PD).state_space()))), key=lambda z: abs(z.imag - 151.3))
    preloaded = _bending(analyze(kv.replace(gravity_preload=True), PD))
    assert preloaded.real == pytest.approx(exact.real, rel=0.01)
    assert preloaded.imag == pytest.approx(exact.imag, rel=1e-3)
