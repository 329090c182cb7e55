"""The compiled right-hand side against the readable numpy one (two implementations)."""
import numpy as np
import pytest

from plant_fmu.dynamics import plant_model
from plant_fmu.kernels import HAVE_NUMBA
from plant_fmu.params import PlantParams


def test_numba_is_in_use():
    assert HAVE_NUMBA


@pytest.mark.parametrize("n,preload", [(0, False), (1, False), (4, False), (4, True), (8, True)],
                         ids=["rigid", "n1", "n4", "n4-preload", "n8-preload"])
def test_kernel_equals_numpy_rhs(n, preload):
    m = plant_model(PlantParams(n_modes=n, gravity_preload=preload))
    rng = np.random.default_rng(n)
    for _ in range(20):
        x = rng.standard_normal(m.nx) * np.r_[1, 2, 0.02 * np.ones(n), 1, 3, 5 * np.ones(n)]
        u = rng.standard_normal() * 100
        a, b = m.rhs(0.0, x, u), m.rhs_numpy(0.0, x, u)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())
