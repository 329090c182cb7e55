"""Per macro step of the closed loop in a C host, before and after the FMU's loader, against the
fmpy master (issue 16; target: the C host with the loader within 1.2x of the fmpy master).

    python bench/bench_c_host.py [--runs 5] [--steps 2000]

Three ways to run the same loop (the ``flexible_pd_lowpass`` scene with 1 ms steps, Gauss-Seidel,
inputs held: the coupling the C host implements):

* **fmpy master**: ``orchestration.cosim.master`` in this process (``RunStats.wall_time / steps``);
* **C host, before**: ``tests/c_host/fmi2_host.c`` on pythonfmu's own library
  (``binaries/linux64/<model>_pythonfmu.so``), with what it needs by hand: ``LD_PRELOAD`` of
  libpython, ``PYTHONHOME`` and ``PYTHONPATH`` (every call then creates and destroys a Python
  thread state; the host aborts at exit, which does not affect the timing);
* **C host, after**: the same host on the FMU's binary (the loader), in a bare environment.

The C host times its stepping loop only. Medians of ``runs`` rounds, each running the three in
turn, after one warm-up run each; BLAS threads limited to one. Writes ``bench/results/c_host.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

from common import RESULTS, ROOT, CoSim, alternating_medians, product_fmus


def host_env(before: bool) -> dict:
    env = {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/"), "OMP_NUM_THREADS": "1",
           **{k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")}}
    if before:
        sys.path.insert(0, str(ROOT / "fmu_common" / "loader"))
        from flexpend_loader import libpython
        env.update(LD_PRELOAD=libpython(), PYTHONHOME=sys.base_prefix,
                   PYTHONPATH=sysconfig.get_paths()["purelib"])
    return env


def c_host_time(cmd, env) -> float:
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    m = re.search(r"us_per_step=([0-9.]+)", proc.stderr)
    if not m:
        raise SystemExit(f"the C host failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return float(m.group(1)) * 1e-6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "tests" / "export"))
    from fmpy import extract
    from test_fmu_c_host import host_command, zoh_scene

    fmus = product_fmus()
    scene = zoh_scene(f"stop_time={args.steps * 1e-3!r}", "output_interval=0.001")
    cosim = CoSim(scene, fmus)

    def fmpy_run():
        _, stats = cosim.run()
        return stats.wall_time / stats.steps, None

    with tempfile.TemporaryDirectory(prefix="flexpend_bench_") as tmp:
        exe = Path(tmp) / "fmi2_host"
        subprocess.run(["gcc", "-O2", "-o", str(exe), str(ROOT / "tests" / "c_host" / "fmi2_host.c"),
                        "-ldl"], check=True)
        dirs = {"FlexiblePendulum": extract(str(fmus["plant"]), str(Path(tmp) / "p")),
                "PDLowPass": extract(str(fmus["controller"]), str(Path(tmp) / "c"))}
        after = host_command(exe, dirs, scene, args.steps, args.steps)
        before = host_command(exe, dirs, scene, args.steps, args.steps,
                              binary="{model}_pythonfmu.so")
        env_after, env_before = host_env(False), host_env(True)
        ways = {"fmpy master": fmpy_run,
                "C host, before (pythonfmu + LD_PRELOAD)":
                    lambda: (c_host_time(before, env_before), None),
                "C host, after (the loader)": lambda: (c_host_time(after, env_after), None)}
        results = {}
        for name, (med, all_) in alternating_medians(ways, args.runs).items():
            results[name] = {"median_us": med * 1e6, "runs_us": [t * 1e6 for t in all_]}
            print(f"{name:42s} {med * 1e6:8.1f} us per macro step", flush=True)
    base = results["fmpy master"]["median_us"]
    for name, r in results.items():
        r["ratio_to_fmpy"] = r["median_us"] / base
    print(f"after / fmpy master: {results['C host, after (the loader)']['ratio_to_fmpy']:.2f} "
          f"(target <= 1.2); before / fmpy master: "
          f"{results['C host, before (pythonfmu + LD_PRELOAD)']['ratio_to_fmpy']:.2f}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "c_host.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
