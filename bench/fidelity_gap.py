"""The fidelity gap: every rung of the ladder against a refined exact beam, at three angles and
under both damping laws (and none), on the paper's filtered scene, monolithic (no co-simulation).

    python3 bench/fidelity_gap.py [--stop 3] [--laws none,modal,kelvin-voigt]

The reference is the geometrically exact beam (:mod:`plant_fmu.exact`) with the controller in the
loop, stepped as one system by Radau IIA at 48 elements and 0.125 ms
(:mod:`orchestration.studies.exact_loop`; within 1.3e-5 rad of a second method, generalized alpha
at 32 elements and 6.25 us: ``bench/exact_convergence.py --cross-check``), under the scene's law:
``none`` (``plant.zeta = 0``: the two laws are one), ``modal`` (0.1 % in every mode: the floating
frame's cantilever modes, the exact beam's clamped modes in its root tangent's frame) or
``kelvin-voigt`` (material damping, 0.1 % in the first mode). The rungs, monolithic
(:func:`orchestration.studies.reference.simulate_reference`, DOP853 at 1e-12), under the same law:
linear, nonlinear (the default), nonlinear with ``plant.gravity_preload``, stiffened at 4 and 8
modes; and the exact rung itself at its defaults (24 elements, 1 ms), monolithic. Each cell is the
largest ``|phi_o|`` difference from the reference over the run, rad. References are cached in
``bench/results/exact_refs`` (ignored by git). Results: docs/exact.md, "Every rung against the
reference".
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.reference import simulate_reference  # noqa: E402
from orchestration.studies.exact_loop import exact_run  # noqa: E402

ANGLES = (0.05, 0.2, math.pi / 6)
LAWS = {"none": {"plant.zeta": 0.0}, "modal": {"plant.damping": "modal"},
        "kelvin-voigt": {"plant.damping": "kelvin-voigt"}}
CACHE = ROOT / "bench" / "results" / "exact_refs"


def scene_for(phi0: float, stop: float, law: str, **keys):
    return load_scene("flexible_pd_lowpass", {"initial.phi": phi0, "stop_time": stop,
                                              **LAWS[law], **keys})


def reference(phi0: float, stop: float, law: str, ne: int = 48, h: float = 1.25e-4):
    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"gap_{law}_{phi0:.6f}_{ne}_{h:g}_{stop:g}.npy"
    if path.exists():
        return np.load(path)
    out = exact_run(scene_for(phi0, stop, law, **{"plant.fidelity": "exact"}), ne, h,
                    kernel=True)
    np.save(path, out)
    return out


RUNGS = (("linear", {"plant.fidelity": "linear"}),
         ("nonlinear", {}),
         ("+ preload", {"plant.gravity_preload": True}),
         ("stiffened 4", {"plant.fidelity": "stiffened"}),
         ("stiffened 8", {"plant.fidelity": "stiffened", "plant.n_modes": 8}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stop", type=float, default=3.0)
    ap.add_argument("--laws", default="none,modal,kelvin-voigt")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    head = "  ".join(f"{name:>11s}" for name, _ in RUNGS)
    for law in args.laws.split(","):
        print(f"damping: {law}")
        print(f"  phi0    {head}  exact (24 el, 1 ms)")
        for phi0 in ANGLES:
            ref = reference(phi0, args.stop, law)
            cells = []
            for _, keys in RUNGS:
                run = simulate_reference(scene_for(phi0, args.stop, law, **keys))["phi_o"]
                cells.append(np.max(np.abs(run - ref)))
            own = exact_run(scene_for(phi0, args.stop, law, **{"plant.fidelity": "exact"}),
                            24, 1e-3, kernel=True)
            print(f"  {phi0:6.4f}  " + "  ".join(f"{c:11.2e}" for c in cells)
                  + f"  {np.max(np.abs(own - ref)):11.2e}", flush=True)
    print(f"({time.perf_counter() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
