"""The ``flexpend`` command line.

    flexpend analyze [--set key=value ...] [--json]     linear loop analysis

Every error in the user's input (an unknown key, a bad value) is printed as one line naming it,
and the exit code is 2.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from .config import (CONTROLLER_KEYS, ConfigError, apply_overrides, controller_params,
                     default_config, fidelity, plant_params)

__all__ = ["main"]

EXIT_USAGE = 2


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(message)


def _json_safe(obj):
    if isinstance(obj, float):
        if math.isnan(obj):
            return None
        if math.isinf(obj):
            return "inf" if obj > 0 else "-inf"
        return obj
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def _fmt(v, spec=".4g"):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return format(v, spec)


def cmd_analyze(args) -> int:
    from .analysis import analyze

    cfg = apply_overrides(default_config(), args.set)
    fidelity(cfg)
    p, c = plant_params(cfg), controller_params(cfg)
    a = analyze(p, c)
    if args.json:
        out = {"plant": {k[6:]: v for k, v in cfg.items() if k.startswith("plant.")},
               "controller": {k: getattr(c, k) for k in CONTROLLER_KEYS}, **a.to_json()}
        print(json.dumps(_json_safe(out), indent=2))
        return 0
    filt = {0: "none", 1: f"1st order, wc = {c.cutoff:g} rad/s",
            2: f"2nd order, wc = {c.cutoff:g} rad/s, zf = {c.filter_damping:g}"}[c.filter_order]
    print(f"plant: n_modes = {p.n_modes}, zeta = {p.zeta:g}, gravity_preload = "
          f"{str(p.gravity_preload).lower()}  (linearised at the upright rest state)")
    print(f"controller: kp = {c.kp:g}, kd = {c.kd:g}, kx = {c.kx:g}, filter: {filt}")
    if a.cantilever_frequencies:
        print("cantilever frequencies (rad/s): "
              + ", ".join(f"{w:.2f}" for w in a.cantilever_frequencies))
    print()
    print(f"{'closed-loop eigenvalue':>30}  {'|lambda| rad/s':>14}  {'damping ratio':>13}")
    for re, im, wn, zeta in a.modes():
        lam = f"{re:+.4f} {'+-' if im > 0 else '  '} {im:.4f}j" if im > 0 else f"{re:+.4f}"
        print(f"{lam:>30}  {wn:14.3f}  {_fmt(zeta, '13.4f'):>13}")
    print()
    verdict = "STABLE" if a.stable else "UNSTABLE"
    note = " (cart drift roots at 0 left aside)" if c.kx == 0 else ""
    print(f"max real part{note}: {a.max_real_part:+.4f}  ->  {verdict}")
    m = a.margins
    if m["nominal_stable"]:
        print(f"gain margin: x{_fmt(m['gain_margin_upper'])} upward (at "
              f"{_fmt(m['gain_margin_upper_freq'])} rad/s), x{_fmt(m['gain_margin_lower'])} "
              f"downward (at {_fmt(m['gain_margin_lower_freq'])} rad/s)")
    print(f"phase margin: {_fmt(m['phase_margin_deg'])} deg at {_fmt(m['phase_margin_freq'])} "
          "rad/s (smallest of all gain crossovers)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="flexpend", description="Flexible inverted pendulum: analysis and "
                                                  "co-simulation of the FMUs.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    pa = sub.add_parser("analyze", help="linear analysis of the closed loop",
                        description="Eigenvalues, stability and margins of the linearised loop.")
    pa.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a parameter, e.g. plant.n_modes=4 or controller.cutoff=150")
    pa.add_argument("--json", action="store_true", help="print the result as JSON")
    pa.set_defaults(func=cmd_analyze)
    return parser


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except (UsageError, ConfigError) as exc:
        print(f"flexpend: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. piped into head
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
