"""controller_fmu.spec: the controller's model of a parameter record, as the plant's
``model_for`` gives the plant's."""
import dataclasses

import numpy as np
import pytest

from controller_fmu import pd_lowpass
from controller_fmu.pd_lowpass import ControllerParams
from controller_fmu.spec import LAWS, model_classes, model_for


def test_every_law_is_a_record_and_a_model_class():
    assert model_classes() == tuple(LAWS.values())
    for record, law in LAWS.items():
        assert dataclasses.is_dataclass(record)
        assert law(record()).params == record()


@pytest.mark.parametrize("order", [0, 1, 2])
def test_model_for_gives_the_pd_lowpass_law_of_its_record(order):
    """The model of a ControllerParams is the PD + low-pass law of that record: its transfer
    function from the sensors to the force is ``-H(s) [kx, kp, kd]`` with ``H`` the filter of
    the record's order, in closed form, at a few frequencies."""
    c = ControllerParams(kp=400.0, kd=4.0, kx=-3.0, filter_order=order, cutoff=120.0,
                         filter_damping=0.3)
    m = model_for(c)
    assert type(m) is pd_lowpass.PDLowPassModel and m.params is c and m.nx == order
    A, B, C, D = m.state_space()
    wc, zf = c.cutoff, c.filter_damping
    for s in (0.0, 7j, 80j, 2.0 + 300j):
        H = {0: 1.0, 1: wc / (s + wc), 2: wc * wc / (s * s + 2 * zf * wc * s + wc * wc)}[order]
        G = C @ np.linalg.solve(s * np.eye(order) - A, B) + D if order else D
        assert G == pytest.approx(-H * np.array([[c.kx, c.kp, c.kd]]), rel=1e-12, abs=1e-9)


def test_model_for_refuses_another_record():
    with pytest.raises(TypeError, match=r"^controller parameters of type dict are not allowed; "
                                        r"allowed: ControllerParams$"):
        model_for({"kp": 500.0})
