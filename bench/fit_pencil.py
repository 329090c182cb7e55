"""The summary's mode fits on Monte Carlo runs: what they cost, and how far they move when the
matrix pencil's parameter moves within the range Hua & Sarkar recommend (``N/3`` to ``N/2``)
against the uncertainty each fit states.

    python bench/fit_pencil.py [--runs 200] [--pencils 0.25,0.4,0.5] [--reps 3]

Runs ``--runs`` design samples of the 10 s filtered scene (``flexpend sweep flexible_pd_lowpass
--sample design``, seed 0) through the sweep's per-run function, records the signals each
``fit_mode`` call of the summary gets (two a run: the slow and the bending oscillation), then
fits them again, with BLAS on one thread:

* **cost**: the two fits of a run, ms, median over ``--reps`` passes after a warm-up pass, at
  the product's pencil parameter (``fit.PENCIL``) and at each of ``--pencils``;
* **moves**: for each band and each of ``--pencils``, the largest move of the rate and of the
  frequency in units of the product's stated uncertainty (``rate_uncertainty``,
  ``frequency_uncertainty`` of the fit at ``fit.PENCIL``), and how many fits move by more than
  one uncertainty;
* **coverage**: for each band and pencil parameter, how many fits are further from the
  linearised loop's root nearest in frequency (the run's ``linear_modes``, what the fits of the
  linear range estimate) than their own stated uncertainty, in rate or frequency, and the
  largest such distance in uncertainties.

Prints a table and one JSON object (``--json`` writes it to a file too). The product's fit is
not changed: the pencil parameter is set on the module for the comparison and restored.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sweep_run_profile import design_tasks  # noqa: E402

BANDS = ("slow", "bending")


def recorded_calls(runs: int):
    """``[(args, kwargs), ...]`` of the summary's ``fit_mode`` calls on ``runs`` design
    samples, in order (slow, bending per run), and each run's linearised loop's roots."""
    import orchestration.studies.summary as summary
    import orchestration.sweeps.engine as engine

    calls, roots, real = [], [], summary.fit_mode

    def recording(*a, **k):
        calls.append((a, k))
        return real(*a, **k)

    tasks = design_tasks(runs)
    summary.fit_mode = recording
    try:
        for i, task in enumerate(tasks):
            row = engine.run_task(task)
            roots.append(summary.linear_modes(task[0]))
            if row["status"] not in ("ok", "failed"):
                raise SystemExit(f"fit_pencil: run {i} ended {row['status']}: "
                                 f"{row.get('message')}")
            print(f"\rrun {i + 1}/{runs}", end="", file=sys.stderr, flush=True)
    finally:
        summary.fit_mode = real
        print(file=sys.stderr)
    if len(calls) != 2 * runs:
        raise SystemExit(f"fit_pencil: {len(calls)} fits for {runs} runs; expected two a run")
    return calls, roots


def fits_at(calls, pencil: float, reps: int):
    """The fits of ``calls`` with the pencil parameter ``pencil``, and the median time of the
    two fits of a run (ms) over ``reps`` passes after a warm-up pass."""
    from orchestration.studies import fit

    saved = fit.PENCIL
    fit.PENCIL = pencil
    try:
        out = [fit.fit_mode(*a, **k) for a, k in calls]
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            for a, k in calls:
                fit.fit_mode(*a, **k)
            times.append(time.perf_counter() - t0)
    finally:
        fit.PENCIL = saved
    return out, statistics.median(times) / (len(calls) / 2) * 1e3


def moves(base, other) -> dict:
    """Per band: the largest move of rate and frequency over the stated uncertainty of
    ``base``, and the count of fits moving by more than one uncertainty (fits with an
    uncertainty in both)."""
    out = {}
    for b, band in enumerate(BANDS):
        worst_r = worst_w = 0.0
        outside = compared = 0
        for f0, f1 in list(zip(base, other))[b::2]:
            if f0 is None or f1 is None or not f0.rate_uncertainty or \
                    not f0.frequency_uncertainty:
                continue
            compared += 1
            r = abs(f1.rate - f0.rate) / f0.rate_uncertainty
            w = abs(f1.frequency - f0.frequency) / f0.frequency_uncertainty
            worst_r, worst_w = max(worst_r, r), max(worst_w, w)
            outside += r > 1 or w > 1
        out[band] = {"compared": compared, "outside": outside,
                     "rate_moves_max": worst_r, "frequency_moves_max": worst_w}
    return out


def coverage(fits, roots) -> dict:
    """Per band: how many of ``fits`` (slow, bending per run) are further from their run's
    linear root nearest in frequency than their stated uncertainty (rate or frequency), of how
    many, and the largest distance in uncertainties."""
    out = {}
    for b, band in enumerate(BANDS):
        outside = compared = 0
        worst = 0.0
        for f, lam in zip(fits[b::2], roots):
            if f is None or not f.rate_uncertainty or not f.frequency_uncertainty or \
                    not len(lam):
                continue
            near = lam[abs(abs(lam.imag) - f.frequency).argmin()]
            d = max(abs(f.rate - near.real) / f.rate_uncertainty,
                    abs(f.frequency - abs(near.imag)) / f.frequency_uncertainty)
            compared += 1
            outside += d > 1
            worst = max(worst, d)
        out[band] = {"compared": compared, "outside": outside, "largest": worst}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--pencils", default="0.25,0.4,0.5",
                    help="pencil parameters to compare, fractions of N in (0, 1)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--json", help="also write the JSON object to this file")
    args = ap.parse_args(argv)
    try:
        pencils = [float(v) for v in args.pencils.split(",")]
    except ValueError:
        print(f"fit_pencil: --pencils {args.pencils!r}: not numbers; allowed: e.g. 0.25,0.5",
              file=sys.stderr)
        return 2
    if args.runs < 1 or args.reps < 1 or not all(0 < p < 1 for p in pencils):
        print("fit_pencil: allowed: --runs >= 1, --reps >= 1, pencils in (0, 1)",
              file=sys.stderr)
        return 2
    from threadpoolctl import threadpool_limits

    from orchestration.studies import fit

    with threadpool_limits(limits=1, user_api="blas"):
        calls, roots = recorded_calls(args.runs)
        base, base_ms = fits_at(calls, fit.PENCIL, args.reps)
        cov = coverage(base, roots)
        result = {"runs": args.runs, "pencil": fit.PENCIL, "ms_per_run": base_ms,
                  "coverage": cov, "compared": {}}

        def show(c):
            return ", ".join(f"{band} {c[band]['outside']}/{c[band]['compared']} (largest "
                             f"{c[band]['largest']:.2f})" for band in BANDS)

        print(f"pencil {fit.PENCIL:.3g} (the product's): {base_ms:.2f} ms for a run's two fits;"
              f" fits further from the linear root than their uncertainty: {show(cov)}")
        for p in pencils:
            other, ms = fits_at(calls, p, args.reps)
            m, c = moves(base, other), coverage(other, roots)
            result["compared"][f"{p:g}"] = {"ms_per_run": ms, "coverage": c, **m}
            print(f"pencil {p:.3g}: {ms:.2f} ms; fits further from the linear root than their "
                  f"uncertainty: {show(c)}; moves in the product's fits' uncertainties "
                  f"(largest rate, frequency; fits outside one):")
            for band in BANDS:
                v = m[band]
                print(f"  {band:8s} {v['rate_moves_max']:6.2f} {v['frequency_moves_max']:6.2f}"
                      f"   {v['outside']}/{v['compared']}")
    text = json.dumps(result, indent=2)
    print(text)
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
