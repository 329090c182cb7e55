"""One sign convention for rates in the figures: a rate is sigma = Re(lambda), 1/s, negative
decays, positive grows, in the title and in every legend alike (as the text summary prints it)."""
import re

import numpy as np
import pytest

import orchestration
from orchestration import simulate

SIGNED = re.compile(r"σ = (?:Re\(λ\) = )?([+-]\d[\d.e+-]*) 1/s")


def _dominant(scene) -> float:
    """Re of the linearised loop's dominant root, the cart's drift roots at 0 left aside."""
    eig = np.asarray(orchestration.analyze(scene).eigenvalues)
    return float(max(z.real for z in eig if abs(z) > 1e-6))


def _texts(fig):
    import matplotlib.pyplot as plt

    title = fig._suptitle.get_text()
    legends = [t.get_text() for ax in fig.axes if ax.get_legend() is not None
               for t in ax.get_legend().get_texts()]
    plt.close(fig)
    return title, legends


@pytest.mark.parametrize("scene", ["flexible_pd_lowpass", "flexible_pd"])
def test_title_and_legends_carry_the_sign_of_re_lambda(scene, fmus):
    dominant = _dominant(scene)
    run = simulate(scene)
    title, legends = _texts(run.plot())
    loop_line = next(ln for ln in title.splitlines() if ln.startswith("linearised loop"))
    assert f"{dominant:+.3g}" in loop_line                   # the dominant root, signed
    if dominant < 0:
        assert "stable" in loop_line and "UNSTABLE" not in loop_line
        assert SIGNED.search(loop_line).group(1) == f"{dominant:+.3g}"
    else:
        assert "UNSTABLE" in loop_line and "grow" in loop_line
    # every fitted rate in a legend: signed as the dominant root in these scenes (the slow fit
    # decays at the slow root's rate in the stable one; the bending fit grows in the other)
    rates = [float(m.group(1)) for text in legends for m in SIGNED.finditer(text)]
    assert rates, legends
    assert all(np.sign(r) == np.sign(dominant) for r in rates), (dominant, legends)
    # and no rate is written without its sign
    for text in (title, *legends):
        for m in re.finditer(r"(\S+) 1/s", text):
            assert m.group(1)[0] in "+-", text
