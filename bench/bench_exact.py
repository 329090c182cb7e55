"""The exact rung's cost and its error against the element count.

Cost, per simulated second, side by side in one run (median of ``--repeat`` timed repetitions
after one untimed warm-up, one core):

* **plant alone**, the force held over each 1 ms communication step as an FMU's doStep holds it
  (zero, from the undeformed beam at pi/6: the pendulum falls freely over the timed span): the
  floating-frame kernel (the default rung: 4 modes, RK4 at 4 substeps per ms, ``fp_fixed_steps``),
  the stiffened rung's the same way (``plant.fidelity = "stiffened"``),
  the exact rung's C kernel (``fp_exact_steps``, 10 generalized-alpha substeps of 0.1 ms per ms)
  and its numpy specification (``GeneralizedAlpha.step``) on the same mesh;
* **closed loop**, the paper's filtered scene (``flexible_pd_lowpass``) monolithic
  (``orchestration.studies.exact_loop``: the controller's filter in numpy each step, the force law
  inside the step's Newton), C kernel and numpy, at h = 0.1 ms;
* **flexpend run**, the three paper scenes through the product (the master) at the default, the
  stiffened and the exact rungs (native FMUs; the exact rung under its own damping law,
  ``plant.damping = "kelvin-voigt"``, the others under the scenes' modal law), and at the default
  and the stiffened rungs with the pythonfmu plant (``--run-span``).

Error against the element count: the filtered scene, 3 s from pi/6 (the paper's, with its
``zeta = 0.1 %`` as the Kelvin-Voigt law, ``plant.damping = "kelvin-voigt"``), by the C kernel
at h = 0.1 ms: the largest ``|phi_o|`` difference on the output grid of 8, 16 and 32 elements
from 64, and the step's own share (16 elements at h against h / 2).

Measured (one loaded 2-core machine, helpers running beside it; ``python3 bench/bench_exact.py``,
about 2 min):

    plant alone, held force, s of wall time per simulated s (median of 3, 0.2 s spans):
      floating frame, 4 modes, RK4 h = 0.25 ms (kernel)    0.0024
      stiffened frame, 4 modes, RK4 h = 0.25 ms (kernel)   0.033     (a later run, below)
      exact, 8 elements, h = 0.1 ms, C kernel              0.27
      exact, 8 elements, h = 0.1 ms, numpy                 6.6
      exact, 16 elements, h = 0.1 ms, C kernel             0.6
    closed loop, filtered scene:
      exact, 8 elements, C kernel                          0.47
      exact, 8 elements, numpy                             4.9
    error of phi_o against 64 elements (3 s from pi/6, h = 0.1 ms), rad:
      8 elements  1.2e-05
      16 elements  7.4e-07
      32 elements  4.3e-08
      (order 4.1; step: 16 elements at 0.1 ms against 0.05 ms: 3.2e-06)

The product, ``flexpend run`` at ``plant.fidelity = "exact"`` (the native FMUs through the master,
24 elements, generalized alpha at each scene's ``plant.step``), beside the default rung, master's
wall time per simulated second (median of 3, 1 s runs; ``--skip-error``, 15 s):

      rigid_pd, nonlinear                                  0.00096
      rigid_pd, exact                                      0.32      (h = 0.25 ms)
      flexible_pd, nonlinear                               0.0029
      flexible_pd, exact                                   0.53      (h = 0.125 ms)
      flexible_pd_lowpass, nonlinear                       0.0014
      flexible_pd_lowpass, exact                           0.27      (h = 0.25 ms)

The stiffened rung beside them (one later run, a busier machine: the default rung 0.0024, exact
at 8 elements 0.35; ``--skip-error``): 0.033 s per simulated s on the plant alone (2.6 us a
right-hand side against the default rung's 1.0, 4.0 against 1.0 at 8 modes), a tenth of the exact
rung's; through the product, pythonfmu plant: 0.048 / 0.52 / 0.10 s on rigid_pd / flexible_pd /
flexible_pd_lowpass, against 0.03 / 0.35 / 0.078 for the default rung with the same plant and
0.33 / 0.71 / 0.54 for the exact rung (native) in that run. With the native plant (a later run,
every row in one: the plant alone 0.013 against 0.0024 and 0.18 for the exact rung): 0.0037 /
0.029 / 0.015 s, against 0.0011 / 0.003 / 0.0013 for the default rung and 0.36 / 0.57 / 0.28 for
the exact one; the pythonfmu plant in that run 0.031 / 0.25 / 0.057 against 0.033 / 0.25 / 0.033.

The C kernel is ~25 times faster than the numpy specification on the plant alone (27 us a
0.1 ms step at 8 elements: about two Newton iterations, one tangent), and ~110 times slower than
the floating frame (RK4 at 4 modes: 4000 right-hand sides of well under a microsecond per
simulated second). In the closed loop the Python around each step (the filter, the force law,
the sensors) costs about as much as the kernel, so the ratio to numpy falls to ~10. The tip
angle's mesh error falls at fourth order in the element count (cubic Hermite elements; the
nodal slope superconverges) and at 16 elements is already below the step's share at 0.1 ms.

    python3 bench/bench_exact.py [--repeat 3] [--span 0.2] [--stop 3] [--skip-error] [--run-span 1]
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller_fmu.pd_lowpass import PDLowPassModel  # noqa: E402
from orchestration.scene.schema import load_scene  # noqa: E402
from orchestration.studies.exact_loop import ExactLoop, exact_run  # noqa: E402
from plant_fmu.dynamics import model_for  # noqa: E402
from plant_fmu.exact import ExactPlant, GeneralizedAlpha  # noqa: E402
from plant_fmu.kernel import ExactKernel  # noqa: E402

H_COMM = 1e-3           # the communication step
H_EXACT = 1e-4          # the exact rung's substep
H_RK4 = 2.5e-4          # the floating frame's default substep (plant_fmu.interface.FMU_SETTINGS)
PHI0 = math.pi / 6
RK4 = dict(A=[[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]],
           B=[1 / 6, 1 / 3, 1 / 3, 1 / 6], C=[0, 0.5, 0.5, 1])


def median_cost(run, span: float, repeat: int) -> float:
    """Seconds of wall time per simulated second: ``run(span)`` once untimed, then ``repeat``
    timed, the median."""
    run(span)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        run(span)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) / span


def floating_frame(params, fidelity: str = "nonlinear"):
    model = model_for(params, fidelity)
    kernel = model.kernel
    tab = kernel.tableau(**RK4)
    x0 = model.initial_state(phi=PHI0)
    per = int(round(H_COMM / H_RK4))

    def run(span):
        y = x0
        for k in range(int(round(span / H_COMM))):
            y, done, rc = kernel.fixed_steps("rk4", tab, y, (0.0, 0.0, 0.0, 0.0), k * H_COMM,
                                             H_RK4, per)
            assert rc == 0
    return run


def exact_plant_alone(params, ne: int, kernel: bool):
    plant = ExactPlant(params.replace(n_elements=ne))
    x0 = plant.initial_state(phi=PHI0)
    per = int(round(H_COMM / H_EXACT))
    nq = plant.nq

    if kernel:
        k = ExactKernel(plant, H_EXACT)

        def run(span):
            s = k.start(x0[:nq], x0[nq:], 0.0)
            for _ in range(int(round(span / H_COMM))):
                s = k.steps(s, 0.0, per)
    else:
        ga = GeneralizedAlpha(plant.system, H_EXACT)

        def run(span):
            s = ga.start(x0[:nq], x0[nq:], 0.0)
            for _ in range(int(round(span / H_COMM)) * per):
                s = ga.step(s, 0.0)
    return run


def exact_closed_loop(scene, ne: int, kernel: bool):
    plant = ExactPlant(scene.plant.params.replace(n_elements=ne))
    x0 = plant.initial_state(phi=PHI0)

    def run(span):
        loop = ExactLoop(plant, PDLowPassModel(scene.controller), H_EXACT, kernel=kernel)
        loop.run(x0, span, scene.output.output_interval)
    return run


def product_cost(name: str, fidelity: str, span: float, repeat: int,
                 fmus: str = "native") -> float:
    """The master's wall time per simulated second of ``flexpend run name`` at ``fidelity`` over
    ``span`` s (the scene's own master, plant step and 24 elements; the ``fmus`` flavour): one
    untimed run, then the median of ``repeat``."""
    from orchestration import simulate

    def run():
        keys = {"plant.fidelity": fidelity, "stop_time": span, "master.fmus": fmus}
        if fidelity == "exact":                   # its own damping law, the scene's zeta
            keys["plant.damping"] = "kelvin-voigt"
        r = simulate(name, keys)
        assert r.completed
        return r.stats.wall_time / span
    run()
    return statistics.median(run() for _ in range(repeat))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--span", type=float, default=0.2, help="simulated seconds per timed run")
    ap.add_argument("--stop", type=float, default=3.0, help="the error study's duration")
    ap.add_argument("--skip-error", action="store_true")
    ap.add_argument("--run-span", type=float, default=1.0,
                    help="simulated seconds of each flexpend run timed (0: skip)")
    args = ap.parse_args(argv)
    scene = load_scene("flexible_pd_lowpass", {"initial.phi": PHI0, "stop_time": args.stop,
                                               "plant.damping": "kelvin-voigt"})
    params = scene.plant.params
    span, rep = args.span, args.repeat
    print("plant alone, held force, s of wall time per simulated s "
          f"(median of {rep}, {span:g} s spans):", flush=True)
    rows = [(f"floating frame, {params.n_modes} modes, RK4 h = {H_RK4 * 1e3:g} ms (kernel)",
             floating_frame(params)),
            (f"stiffened frame, {params.n_modes} modes, RK4 h = {H_RK4 * 1e3:g} ms (kernel)",
             floating_frame(params, "stiffened")),
            (f"exact, 8 elements, h = {H_EXACT * 1e3:g} ms, C kernel",
             exact_plant_alone(params, 8, True)),
            (f"exact, 8 elements, h = {H_EXACT * 1e3:g} ms, numpy",
             exact_plant_alone(params, 8, False)),
            (f"exact, 16 elements, h = {H_EXACT * 1e3:g} ms, C kernel",
             exact_plant_alone(params, 16, True))]
    for name, run in rows:
        print(f"  {name:52s} {median_cost(run, span, rep):.2g}", flush=True)
    print("closed loop, filtered scene:")
    for name, run in (("exact, 8 elements, C kernel", exact_closed_loop(scene, 8, True)),
                      ("exact, 8 elements, numpy", exact_closed_loop(scene, 8, False))):
        print(f"  {name:52s} {median_cost(run, span, rep):.2g}", flush=True)
    if args.run_span > 0:
        print(f"flexpend run (the scene's master and plant step, 24 elements), the master's "
              f"wall time per simulated s (median of {rep}, {args.run_span:g} s):")
        for name in ("rigid_pd", "flexible_pd", "flexible_pd_lowpass"):
            for fid, fmus in (("nonlinear", "native"), ("stiffened", "native"),
                              ("exact", "native"), ("nonlinear", "python"),
                              ("stiffened", "python")):
                cost = product_cost(name, fid, args.run_span, rep, fmus)
                print(f"  {name + ', ' + fid + ' (' + fmus + ')':52s} {cost:.2g}", flush=True)
    if args.skip_error:
        return
    print(f"error of phi_o against 64 elements ({args.stop:g} s from pi/6, "
          f"h = {H_EXACT * 1e3:g} ms), rad:", flush=True)
    ref = exact_run(scene, 64, H_EXACT, kernel=True)
    errs = {}
    for ne in (8, 16, 32):
        phi = exact_run(scene, ne, H_EXACT, kernel=True)
        errs[ne] = np.max(np.abs(phi - ref))
        print(f"  {ne} elements  {errs[ne]:.1e}", flush=True)
    order = math.log2(errs[16] / errs[32])
    half = exact_run(scene, 16, H_EXACT / 2, kernel=True)
    step = np.max(np.abs(half - exact_run(scene, 16, H_EXACT, kernel=True)))
    print(f"  (order {order:.1f}; step: 16 elements at {H_EXACT * 1e3:g} ms against "
          f"{H_EXACT * 5e2:g} ms: {step:.1e})")


if __name__ == "__main__":
    main()
