"""Long runs at a flat cost: the plant kernel's steppers flush subnormal numbers to zero (a
decayed state's products below 2.2e-308 cost x86 cores about 100 cycles an operation). The
results are those of the linear loop scaled, to rounding, and the host's floating-point mode is
left as it was."""
import sys

import numpy as np
import pytest

from orchestration import simulate

COLUMNS = ("x", "phi_o", "F_c")


def _run(phi):
    return simulate("flexible_pd_lowpass", {"initial.phi": phi, "stop_time": 2.0}).result


@pytest.mark.parametrize("tiny,rel", [(1e-160, 1e-9), (1e-300, 1e-4)])
def test_a_decayed_loop_is_the_small_loop_scaled(tiny, rel):
    """From phi0 = tiny the loop is linear to 1e-140 relative, so its run is the run from 1e-10
    scaled by tiny / 1e-10 (whose nonlinear terms are 1e-20 of it). At 1e-160 the flushed
    products (squares, 1e-320) change nothing beyond rounding. At 1e-300 the loop's own
    smallest terms (the state times factors below 1e-8, 1e-309) are subnormal and flushed: a
    change of 1e-305 rad, 1e-5 of the state."""
    small, decayed = _run(1e-10), _run(tiny)
    for col in COLUMNS:
        want = small[col] * (tiny / 1e-10)
        scale = np.abs(want).max()
        assert scale > 0
        assert np.abs(decayed[col] - want).max() <= rel * scale, col


def test_the_hosts_floating_point_mode_is_kept():
    """The FMU flushes subnormals only inside its steps: this process still computes them."""
    _run(1e-300)
    x = np.float64(sys.float_info.min)
    assert x / 4 > 0 and (x / 4) * 2 == x / 2           # subnormal results are not flushed
    assert np.float64(5e-324) * 2 == np.float64(1e-323)  # nor are subnormal operands
