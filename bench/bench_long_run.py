"""The cost of a run against its length (issue 25): the filtered scene from 10 s to 2000 s.

    python bench/bench_long_run.py [--runs 5] [--quick] [--json bench/results/long_run.json]

``flexible_pd_lowpass`` (the 2 ms communication step of the scene, a row every 10 ms as in the
issue's ``flexpend run flexible_pd_lowpass --set stop_time=1000 --set output_interval=0.01``) is
stepped for ``stop_time`` = 10, 20, 50, 100, 200, 500, 1000 and 2000 s by the master over the
native FMUs (the compiled loop). Per length: the median wall time of the run (the master's
``RunStats.wall_time``: initialisation and stepping, FMU loading excluded), the same per macro
step and per simulated second, the loop that ran (``compiled`` throughout, or the run falls
off it), and the process's CPU time of the run beside the wall time (the machine is shared:
wall time carries its load, CPU time much less). The lengths are timed in turn, round after
round, after one warm-up each, so that the load falls on all of them alike.

The claim it checks: the cost grows linearly with ``stop_time``, the cost per simulated second
("x 1st": against the shortest run's) bounded at every length. Before issue 25 a run left the
compiled loop after 256,003 steps (512 s here) and every later step cost about 18 times more.
Then one run of the longest length with a progress callback: the bar's estimate of the total time
(elapsed / fraction) from 10 % on against the time it took, and the cost per step in each tenth
of the run. The scene decays (its slowest mode at -0.64/s): from about 350 s on, products of its
small state in the FMUs' equations are subnormal numbers, whose arithmetic is slower on x86 (a
step cost 1.7 times more before the plant kernel's steppers flushed them to zero, issue 39); the
control runs the scene from phi0 = 1e-100, where they are from the start, to price that.

``--quick``: 10, 100 and 1000 s. Writes ``--json`` and a figure beside it (``.png``), both into
``bench/results/`` by default (git-ignored).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import RESULTS, CoSim, load_scene, product_fmus  # noqa: E402

SCENE = "flexible_pd_lowpass"
OUTPUT_INTERVAL = 0.01
STOP_TIMES = (10, 20, 50, 100, 200, 500, 1000, 2000)
QUICK = (10, 100, 1000)


def timed(cosim: CoSim) -> dict:
    """One run: wall time (the master's), CPU time of the call, steps, the loop."""
    cpu = time.process_time()
    res, stats = cosim.run()
    cpu = time.process_time() - cpu
    return {"wall": stats.wall_time, "cpu": cpu, "steps": stats.steps, "loop": stats.loop,
            "rows": len(res)}


def measure(stop_times, runs: int, fmus, log) -> list:
    sims = {T: CoSim(load_scene(SCENE, [f"stop_time={T}", f"output_interval={OUTPUT_INTERVAL}"]),
                     fmus) for T in stop_times}
    for T, sim in sims.items():                  # warm-up (FMUs unpacked, caches, pages)
        timed(sim)
    per = {T: [] for T in stop_times}
    for r in range(runs):
        for T, sim in sims.items():
            per[T].append(timed(sim))
        log(f"  round {r + 1} of {runs} done")
    points = []
    for T in stop_times:
        wall = statistics.median(x["wall"] for x in per[T])
        cpu = statistics.median(x["cpu"] for x in per[T])
        steps, loops = per[T][0]["steps"], sorted({x["loop"] for x in per[T]})
        points.append({"stop_time": T, "steps": steps, "loop": ", ".join(loops),
                       "wall_s": wall, "cpu_s": cpu, "us_per_step": wall / steps * 1e6,
                       "ms_per_simulated_s": wall / T * 1e3,
                       "all_wall_s": [x["wall"] for x in per[T]],
                       "all_cpu_s": [x["cpu"] for x in per[T]]})
    return points


def along_the_run(fmus, stop_time: float) -> dict:
    """One run with a progress callback, as ``flexpend run``'s bar gets it: the bar's estimate of
    the total time (elapsed / fraction: elapsed + left) from 10 % on, against the total; and the
    wall and CPU time per macro step in each tenth of the run."""
    sim = CoSim(load_scene(SCENE, [f"stop_time={stop_time}",
                                   f"output_interval={OUTPUT_INTERVAL}"]), fmus)
    seen = []
    start = (time.perf_counter(), time.process_time())   # instantiation first, as in a run
    _, stats = sim.run(progress=lambda f: seen.append((time.perf_counter(), time.process_time(),
                                                       f)))
    total = seen[-1][0] - start[0]
    est = [(now - start[0]) / f for now, _, f in seen if f >= 0.1]
    marks = [start + (0.0,)] + seen
    tenths = []
    for q in range(1, 11):
        a = marks[0] if q == 1 else tenths[-1]["_end"]
        b = min((m for m in marks if m[2] >= q / 10 - 1e-12), key=lambda m: m[2])
        steps = (b[2] - a[2]) * stats.steps
        tenths.append({"from_s": a[2] * stop_time, "to_s": b[2] * stop_time,
                       "wall_us_per_step": (b[0] - a[0]) / steps * 1e6,
                       "cpu_us_per_step": (b[1] - a[1]) / steps * 1e6, "_end": b})
    for t in tenths:
        del t["_end"]
    return {"stop_time": stop_time, "loop": stats.loop, "total_s": total,
            "estimate_min_s": min(est), "estimate_max_s": max(est), "reports": len(seen),
            "tenths": tenths}


def subnormal_control(fmus, runs: int, stop_time: float = 100.0) -> dict:
    """The FMUs' own cost per step with the state near zero: the scene from phi0 = pi/6 and from
    phi0 = 1e-100 (products of the small state in the plant's equations are subnormal numbers
    from the start, whose arithmetic is slow on x86), median CPU time per macro step."""
    out = {}
    for label, phi in (("phi0 = pi/6", "0.5235987755982988"), ("phi0 = 1e-100", "1e-100")):
        sim = CoSim(load_scene(SCENE, [f"stop_time={stop_time}", f"initial.phi={phi}",
                                       f"output_interval={OUTPUT_INTERVAL}"]), fmus)
        timed(sim)
        per = [timed(sim) for _ in range(runs)]
        out[label] = statistics.median(x["cpu"] / x["steps"] * 1e6 for x in per)
    return out


def plot(points, along, control, path: Path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = np.array([p["stop_time"] for p in points], float)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    ax = axes[0]
    ax.loglog(T, [p["wall_s"] for p in points], "o-", label="wall time (median)")
    ax.loglog(T, [p["cpu_s"] for p in points], "s--", label="CPU time (median)")
    ax.loglog(T, points[0]["wall_s"] * T / T[0], ":", color="grey", label="linear from the first")
    ax.set_xlabel("stop_time, s")
    ax.set_ylabel("run, s")
    ax.set_title("cost against stop_time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[1]
    mid = [(t["from_s"] + t["to_s"]) / 2 for t in along["tenths"]]
    ax.plot(mid, [t["wall_us_per_step"] for t in along["tenths"]], "o-", label="wall")
    ax.plot(mid, [t["cpu_us_per_step"] for t in along["tenths"]], "s--", label="CPU")
    for (label, v), style in zip(control.items(), (":", "-.")):
        ax.axhline(v, color="grey", ls=style, label=f"CPU, 100 s from {label}")
    ax.set_ylim(0, None)
    ax.set_xlabel("simulated time, s")
    ax.set_ylabel("per macro step, us")
    ax.set_title(f"along one {along['stop_time']:g} s run")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle(f"{SCENE}: 2 ms steps on the compiled loop")
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="10, 100 and 1000 s only")
    ap.add_argument("--json", type=Path, default=RESULTS / "long_run.json")
    args = ap.parse_args(argv)
    if args.runs < 1:
        print(f"bench_long_run: --runs = {args.runs}; allowed: >= 1", file=sys.stderr)
        return 2

    def log(msg):
        print(msg, flush=True)

    fmus = product_fmus("native")
    stop_times = QUICK if args.quick else STOP_TIMES
    log(f"{SCENE}, output every {OUTPUT_INTERVAL} s: medians of {args.runs} runs after a "
        f"warm-up, lengths {', '.join(map(str, stop_times))} s in turn")
    points = measure(stop_times, args.runs, fmus, log)
    log(f"{'stop_time':>9} {'steps':>9} {'wall s':>8} {'CPU s':>8} {'wall us':>8} {'CPU us':>7} "
        f"{'wall ms':>8} {'x 1st':>6}  loop")
    log(f"{'s':>9} {'':>9} {'':>8} {'':>8} {'per step':>8} {'/step':>7} {'per s':>8} {'':>6}")
    for p in points:
        p["cpu_us_per_step"] = p["cpu_s"] / p["steps"] * 1e6
        p["per_s_to_first"] = p["ms_per_simulated_s"] / points[0]["ms_per_simulated_s"]
        log(f"{p['stop_time']:>9} {p['steps']:>9} {p['wall_s']:8.4f} {p['cpu_s']:8.4f} "
            f"{p['us_per_step']:8.3f} {p['cpu_us_per_step']:7.3f} {p['ms_per_simulated_s']:8.3f} "
            f"{p['per_s_to_first']:6.2f}  {p['loop']}")
    longest = max(stop_times)
    prog = along_the_run(fmus, longest)
    log(f"one {longest} s run with progress ({prog['loop']} loop): the bar's estimate of the total "
        f"{prog['estimate_min_s']:.3f} to {prog['estimate_max_s']:.3f} s from 10 % on, took "
        f"{prog['total_s']:.3f} s; per macro step along it (us, wall / CPU):")
    log("  " + ", ".join(f"{t['from_s']:.0f}-{t['to_s']:.0f} s {t['wall_us_per_step']:.2f} / "
                         f"{t['cpu_us_per_step']:.2f}" for t in prog["tenths"]))
    control = subnormal_control(fmus, args.runs)
    log("the FMUs near zero, 100 s, CPU per macro step: " + ", ".join(
        f"{k} {v:.3f} us" for k, v in control.items()))
    off = [p for p in points if p["loop"] != "compiled"]
    if off:
        log(f"NOT on the compiled loop throughout: {', '.join(str(p['stop_time']) for p in off)} s")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.json.with_suffix(".tmp")
    tmp.write_text(json.dumps({"scene": SCENE, "output_interval": OUTPUT_INTERVAL,
                               "runs": args.runs, "points": points,
                               "along_the_run": prog, "subnormal_control_cpu_us_per_step": control},
                              indent=1))
    tmp.replace(args.json)
    png = args.json.with_suffix(".png")
    plot(points, prog, control, png)
    log(f"wrote {args.json}, {png}")
    return 1 if off else 0


if __name__ == "__main__":
    sys.exit(main())
