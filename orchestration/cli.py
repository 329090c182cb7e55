"""The ``flexpend`` command line.

    flexpend run [SCENE ...] [--set key=value ...] [--out DIR] [--json] [--reference]
    flexpend analyze [--set key=value ...] [--json]     linear loop analysis
    flexpend build [--force] [--out DIR]                build the two FMUs
    flexpend scenes                                     list the scenes

Every error in the user's input (an unknown key, a bad value) is printed as one line naming it,
and the exit code is 2.
"""
from __future__ import annotations

import argparse
import dataclasses
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

    from .scenes import known_keys

    # every scene key is accepted; those that do not change the linear loop are ignored
    cfg = apply_overrides(default_config(), args.set, known=known_keys())
    fidelity(cfg)
    p, c = plant_params(cfg), controller_params(cfg)
    a = analyze(p, c)
    if args.json:
        out = {"plant": {f.name: getattr(p, f.name) for f in dataclasses.fields(p)},
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


def _print_summary(name, s, out_dir):
    def osc(o):
        return "-" if o is None else f"rate {o['rate']:+.3f} 1/s at {o['frequency']:.2f} rad/s"
    verdict = "stable" if s["stable"] else "UNSTABLE"
    print(f"{name}: {verdict}")
    if s.get("failure"):
        print(f"  stopped: {s['failure']}")
    print(f"  slow (rigid) oscillation: {osc(s.get('slow'))}")
    print(f"  bending oscillation:      {osc(s.get('bending'))}")
    if s.get("max_abs_F_c") is not None:
        print(f"  max |F_c|: {s['max_abs_F_c']:.4g}")
    if "wall_time" in s:
        print(f"  wall time: {s['wall_time']:.2f} s ({s['steps']} communication steps, "
              f"{s['rejected_steps']} rejected)")
    if "max_error_phi_o" in s:
        print(f"  max error against the monolithic reference: phi_o {s['max_error_phi_o']:.3e} rad, "
              f"eta_1 {s['max_error_eta_1']:.3e}")
    if out_dir is not None:
        print(f"  wrote {out_dir / (name + '.csv')}, {out_dir / (name + '.png')}, "
              f"{out_dir / (name + '_shapes.png')}")


def cmd_run(args) -> int:
    from pathlib import Path

    from fmpy.util import write_csv

    from .scenes import PAPER_SCENES, load_scene

    names = args.scenes or list(PAPER_SCENES)
    scenes = [load_scene(n, args.set) for n in names]          # validate all before running

    from . import plots
    from .fmu_build import build_fmus
    from .run import run_scene
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = build_fmus()
    fmus = {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"]}
    summaries, results = {}, {}
    for scene in scenes:
        r = run_scene(scene, fmus, reference=args.reference, progress=True,
                      connections_out=sys.stderr if args.connections else None)
        write_csv(str(out_dir / f"{scene.name}.csv"), r.result)
        title = f"{scene.name}: {scene['description']}" if scene["description"] else scene.name
        plots.plot_time_histories(r.result, title, out_dir / f"{scene.name}.png", r.reference)
        if r.frames:
            plots.plot_snapshots(scene_beam(scene), r.frames, f"{scene.name}: beam shapes",
                                 out_dir / f"{scene.name}_shapes.png")
        summaries[scene.name] = r.summary
        results[scene.name] = r.result
        if not args.json:
            _print_summary(scene.name, r.summary, out_dir)
    if not args.scenes:
        plots.plot_paper_overview(results, out_dir / "paper_overview.png")
        if not args.json:
            print(f"paper overview: {out_dir / 'paper_overview.png'}")
    (out_dir / "summary.json").write_text(json.dumps(_json_safe(summaries), indent=2))
    if args.json:
        print(json.dumps(_json_safe(summaries), indent=2))
    return 0


def scene_beam(scene):
    from plant_fmu.beam import beam_model
    return beam_model(scene.plant)


def cmd_build(args) -> int:
    from pathlib import Path

    from .fmu_build import build_fmus
    paths = build_fmus(force=args.force) if args.out is None else \
        build_fmus(out_dir=Path(args.out), force=args.force)
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def cmd_scenes(args) -> int:
    from .scenes import list_scenes, load_scene
    for name in list_scenes():
        print(f"{name:24s} {load_scene(name)['description']}")
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

    pr = sub.add_parser("run", help="co-simulate scenes (default: the paper's three)",
                        description="Co-simulate the plant and controller FMUs for each scene; "
                                    "write <out>/<scene>.csv and PNG plots, print a summary.")
    pr.add_argument("scenes", nargs="*", metavar="SCENE",
                    help="scene names (see 'flexpend scenes') or paths to .toml files")
    pr.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene key, e.g. master.step=5e-4")
    pr.add_argument("--out", default="out", help="output folder (default: out)")
    pr.add_argument("--json", action="store_true", help="print the summary as JSON")
    pr.add_argument("--connections", action="store_true",
                    help="print each scene's connection table (wiring by variable name)")
    pr.add_argument("--reference", action="store_true",
                    help="also solve the monolithic reference and report the error against it")
    pr.set_defaults(func=cmd_run)

    pb = sub.add_parser("build", help="build the two FMUs (only when their sources changed)")
    pb.add_argument("--force", action="store_true", help="rebuild even if up to date")
    pb.add_argument("--out", default=None, help="output folder (default: build/fmus)")
    pb.set_defaults(func=cmd_build)

    ps = sub.add_parser("scenes", help="list the scenes")
    ps.set_defaults(func=cmd_scenes)
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
