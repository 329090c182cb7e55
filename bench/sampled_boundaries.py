"""The sampled controller's stability boundaries, predicted and run: for each paper scene, with no
delay and with a full period's delay, every boundary of the stable intervals of the sample period
(:func:`orchestration.studies.sampled.stable_intervals`), and runs of the native pair just either
side of it (5 %, or less where another boundary is nearer). Each row gives the run's verdict, and
the growth rate of the mode that crosses: predicted (the s-plane equivalent of the sampled loop's
pole) and fitted in the run's ``phi_o`` (matrix pencil within 30 % of its frequency). The runs:
``initial.phi = 0.01``, 10 s, the master at T / 12, no companion run.

    python3 bench/sampled_boundaries.py

``tests/cosim/test_sampled_runs.py`` asserts the same agreement. Results: docs/sampled.md.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from orchestration.export import build_fmus, fmu_pair  # noqa: E402
from orchestration.job import run_scene  # noqa: E402
from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.fit import fit_mode  # noqa: E402
from orchestration.studies.sampled import boundaries, sampled_poles  # noqa: E402

SCENES = ("rigid_pd", "flexible_pd", "flexible_pd_lowpass")


def main() -> int:
    pair = fmu_pair(build_fmus(flavour="native"))
    print(f"{'scene':<21}{'delay':>7}{'boundary':>11}{'T':>11}  {'verdict':<10}"
          f"{'mode':>10}{'predicted':>11}{'run':>10}")
    for scene in SCENES:
        for fraction in (0.0, 1.0):
            for edge, below, delta in boundaries(scene, fraction):
                for T in ((1 - delta) * edge, (1 + delta) * edge):
                    tau = fraction * T
                    sets = {"initial.phi": 0.01, "fidelity.companion": "false",
                            "controller.sample_period": T, "controller.delay": tau,
                            "master.step": T / 12, "output_interval": T,
                            "stop_time": round(10.0 / T) * T}
                    run = run_scene(load_scene(scene, [f"{k}={v}" for k, v in sets.items()]),
                                    pair, progress=False)
                    s = sampled_poles(scene, T, tau).s
                    s = s[np.isfinite(s) & (s.imag > 1.0)]
                    crossing = s[np.argmax(s.real)]
                    f = fit_mode(run.result["time"], run.result["phi_o"],
                                 (0.7 * crossing.imag, 1.3 * crossing.imag), near=crossing.imag)
                    fitted = f"{f.rate:+.4f}" if f is not None else "-"
                    print(f"{scene:<21}{'T' if fraction else '0':>7}{1e3 * edge:>9.4g}ms"
                          f"{1e3 * T:>9.4g}ms  {run.summary['verdict']:<10}"
                          f"{crossing.imag:>7.1f}r/s{crossing.real:>+11.4f}{fitted:>10}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
