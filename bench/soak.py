"""Soak of the pythonfmu FMUs in a C host (issue 16): 10,000 lifecycles per FMU (instantiate,
set up, initialise, 5 steps of 1 ms, read an output, terminate, free), the resident set size every
1,000. Target: a flat RSS (pythonfmu 0.7.0 alone leaked about 1-1.5 KB per instance).

    python bench/soak.py [--lifecycles 10000] [--every 1000]

The host is ``bench/fmi2_soak.c`` (compiled here with gcc), loading each FMU's linux64 binary
with dlopen(RTLD_LOCAL) in a bare environment; the FMU's loader finds the Python recorded at
build time. Writes ``bench/results/soak.json`` and ``soak.png`` (RSS against lifecycles); the
growth is measured from the first report at 1,000 lifecycles (the first instances import numpy,
scipy and the model).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from common import RESULTS, ROOT, product_fmus


def soak(fmu: str, lifecycles: int, every: int, exe: Path, tmp: Path) -> list:
    from fmpy import read_model_description

    d = tmp / Path(fmu).stem
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(d)
    md = read_model_description(str(d / "modelDescription.xml"))
    out = next(v for v in md.modelVariables if v.causality == "output")
    env = {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/"), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1",
           **{k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")}}
    model = md.coSimulation.modelIdentifier
    proc = subprocess.Popen([str(exe), str(d / "binaries" / "linux64" / f"{model}.so"),
                             (d / "resources").as_uri(), md.guid, str(lifecycles), str(every),
                             str(out.valueReference)], env=env, stdout=subprocess.PIPE, text=True)
    rows = []
    for line in proc.stdout:
        n, rss, sec = line.split()
        rows.append((int(n), int(rss), float(sec)))
        print(f"  {model}: {n:>6} lifecycles  RSS {int(rss) / 1024:8.1f} MiB  {float(sec):7.1f} s",
              flush=True)
    if proc.wait() != 0:
        raise SystemExit(f"{model}: the soak host exited with status {proc.returncode}")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lifecycles", type=int, default=10_000)
    ap.add_argument("--every", type=int, default=1_000)
    args = ap.parse_args(argv)
    fmus = product_fmus()
    RESULTS.mkdir(parents=True, exist_ok=True)
    report = {}
    with tempfile.TemporaryDirectory(prefix="flexpend_soak_") as tmp:
        exe = Path(tmp) / "fmi2_soak"
        subprocess.run(["gcc", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
                        str(ROOT / "bench" / "fmi2_soak.c"), "-ldl"], check=True)
        for role, fmu in fmus.items():
            rows = soak(str(fmu), args.lifecycles, args.every, exe, Path(tmp))
            base = next((r for r in rows if r[0] >= args.every), rows[0])
            last = rows[-1]
            per = (last[1] - base[1]) * 1024 / max(1, last[0] - base[0])
            report[Path(fmu).stem] = {"rows": rows, "growth_kib": last[1] - base[1],
                                      "bytes_per_lifecycle": per,
                                      "ms_per_lifecycle": 1e3 * last[2] / last[0]}
            print(f"{Path(fmu).stem}: RSS {base[1] / 1024:.1f} MiB at {base[0]} -> "
                  f"{last[1] / 1024:.1f} MiB at {last[0]} lifecycles: {per:.1f} bytes per "
                  f"lifecycle; {1e3 * last[2] / last[0]:.2f} ms per lifecycle")
    (RESULTS / "soak.json").write_text(json.dumps(report, indent=1))
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 4))
        for name, r in report.items():
            ax.plot([x[0] for x in r["rows"]], [x[1] / 1024 for x in r["rows"]], "o-", label=name)
        ax.set_xlabel("lifecycles")
        ax.set_ylabel("RSS, MiB")
        ax.set_title("Soak in a C host: instantiate .. free")
        ax.grid(True, alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(RESULTS / "soak.png", dpi=120)
    except ImportError:  # pragma: no cover
        pass
    print(f"written: {RESULTS / 'soak.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
