"""How the FMUs and systems are made and checked.

    build_fmus(flavour="native" | "python", fmi_version=2) -> {"FlexiblePendulum": path, ...}
    flavour_fmus("native") -> {"plant": path, "controller": path, "FlexiblePendulumExact": path, ...}
    pair_for(fmus, fidelity) -> {"plant": the plant FMU of that rung, "controller": path}

:mod:`.python_fmus` builds the pythonfmu FMUs (FMI 2.0; only when their sources changed) into
``build/fmus/``; :mod:`.native_fmus` the native ones (C, FMI 2.0 and 3.0, linux64 and win64) into
``build/fmus/native/fmi2/`` and ``build/fmus/native/fmi3/``;
:func:`flavour_fmus` gives the FMUs of a flavour by name (``python``, ``native``), for a run
(the native FMUs need only the host's binaries) or an archive (every platform): the pair, and for
the native flavour the plant of every rung family (one native plant FMU per family,
:data:`plant_fmu.interface.PLANT_FMUS`; :func:`pair_for` picks a rung's);
:mod:`.ssp` writes a scene as an SSP 1.0 archive and reads one back (``flexpend export``,
``flexpend run FILE.ssp``);
:mod:`.check` regresses an FMU against reference results in the FMI cross-check layout and writes
them (``flexpend check``; the project's own references in ``tests/reference/``).
``build/build_fmus.py`` and ``flexpend build`` are thin front ends of this package.
"""
import argparse
import sys
from pathlib import Path

from controller_fmu.interface import CONTROLLER_FMUS, controller_fmu_name
from plant_fmu.interface import PLANT_FMUS, plant_fmu_name

from ..scene.keys import FMU_FLAVOURS
from . import places
from .check import write_references
from .native_fmus import NativeBuildError, build_native_fmus
from .python_fmus import SPECS, BuildError, is_stale
from .python_fmus import build_fmus as build_python

__all__ = ["build_fmus", "BuildError", "FMU_FLAVOURS", "fmu_pair", "flavour_fmus", "plant_role",
           "controller_role", "pair_for", "with_families", "main"]


def build_fmus(out_dir=None, names=None, force: bool = False, *, flavour: str = "python",
               fmi_version: int = 2, platforms=None, progress=None) -> dict:
    """Build (if stale) the FMUs of a flavour and return ``{model name: path}``.

    ``flavour``: ``"python"`` (pythonfmu, FMI 2.0 only; ``out_dir`` default ``build/fmus``) or
    ``"native"`` (C; ``fmi_version`` 2 or 3; ``out_dir`` default ``build/fmus/native``, the FMUs in
    its ``fmi2``/``fmi3`` folder). ``platforms`` (native): the binaries each FMU must have (default:
    every platform this machine builds; :func:`.native_fmus.build_native_fmus`).
    ``progress(fraction, label)``: told each step of each FMU built, the label naming the FMU,
    its flavour and FMI version, and the step (:mod:`orchestration.report.progress`). Raises
    :class:`BuildError` when a build fails and ValueError on a bad argument."""
    if flavour not in FMU_FLAVOURS:
        raise ValueError(f"flavour = {flavour!r}; allowed: {', '.join(FMU_FLAVOURS)}")
    if fmi_version not in (2, 3) or (flavour == "python" and fmi_version != 2):
        raise ValueError(f"fmi_version = {fmi_version!r}; allowed: 2 (both flavours), 3 (native)")
    with places.build_lock():
        if flavour == "python":
            return build_python(Path(out_dir) if out_dir else None, names, force, progress)
        try:
            return build_native_fmus(Path(out_dir) if out_dir else None, names, force,
                                     fmi_version, platforms, progress)
        except NativeBuildError as exc:
            raise BuildError(str(exc)) from None


def fmu_pair(paths: dict) -> dict:
    """The master's names from :func:`build_fmus`' result: ``{"plant": ..., "controller": ...}``,
    and the native plant of each other rung family built (``FlexiblePendulumStiffened``,
    ``FlexiblePendulumExact``) under its own name (:func:`pair_for` picks a rung's plant)."""
    return {"plant": paths["FlexiblePendulum"], "controller": paths["PDLowPass"],
            **{n: p for n, p in paths.items() if n in PLANT_FMUS and n != "FlexiblePendulum"},
            **{n: p for n, p in paths.items() if n in CONTROLLER_FMUS and n != "PDLowPass"}}


def with_families(fmus: dict) -> dict:
    """``fmus`` with the native plant FMU of each other rung family found beside its plant: a
    pair whose plant is a native ``FlexiblePendulum.fmu`` in a folder that also holds
    ``FlexiblePendulumStiffened.fmu`` and ``FlexiblePendulumExact.fmu`` (what ``flexpend build``
    writes) runs every rung, the companion's included, on its family's FMU (:func:`plant_role`).
    Anything else is returned as it is."""
    plant = fmus.get("plant")
    if plant is None or Path(plant).name != "FlexiblePendulum.fmu":
        return fmus
    out = dict(fmus)
    for name in PLANT_FMUS:
        sibling = Path(plant).with_name(f"{name}.fmu")
        if name not in out and name != "FlexiblePendulum" and sibling.is_file():
            out[name] = str(sibling) if isinstance(plant, str) else sibling
    controller = fmus.get("controller")
    if controller is not None and Path(controller).name == "PDLowPass.fmu":
        for name in CONTROLLER_FMUS:
            sibling = Path(controller).with_name(f"{name}.fmu")
            if name not in out and name != "PDLowPass" and sibling.is_file():
                out[name] = str(sibling) if isinstance(controller, str) else sibling
    return out


def controller_role(fmus: dict, params) -> str:
    """The key of ``fmus`` whose controller runs the ControllerParams ``params``: the native
    ``PDLowPassSampled`` for a sampled controller when ``fmus`` holds it, else
    ``"controller"`` (an FMU that does not run it refuses it, naming the one that does)."""
    name = controller_fmu_name(params)
    return name if name in fmus and name != "PDLowPass" else "controller"


def plant_role(fmus: dict, fidelity: str) -> str:
    """The key of ``fmus`` whose plant runs rung ``fidelity`` (resolved): the native plant FMU of
    that rung's family when ``fmus`` holds it (:func:`fmu_pair`), else ``"plant"`` (the pythonfmu
    plant runs each of its rungs; a pair of one's own is used as it is, and its plant refuses a
    rung it does not run, naming the FMU that does)."""
    name = plant_fmu_name(fidelity)
    return name if name in fmus else "plant"


def pair_for(fmus: dict, fidelity: str, controller=None) -> dict:
    """``{"plant": path, "controller": path}``: the pair of ``fmus`` a run on rung ``fidelity``
    with the ControllerParams ``controller`` (None: the continuous one) uses
    (:func:`plant_role`, :func:`controller_role`)."""
    role = "controller" if controller is None else controller_role(fmus, controller)
    return {"plant": fmus[plant_role(fmus, fidelity)], "controller": fmus[role]}


def flavour_fmus(flavour: str, *, portable: bool = False, progress=None) -> dict:
    """The FMUs a scene of ``master.fmus = flavour`` runs on, built if missing or stale:
    ``{"plant": path, "controller": path}`` (FMI 2.0), and for the native flavour the plant of
    every other rung family under its FMU's name (:func:`fmu_pair`; a run's companion and its
    climb of the fidelity ladder change rung). A run needs the native FMUs' binaries for this
    machine alone: they are all that is built for it (an FMU that has them is up to date);
    ``portable`` (an archive to hand on): those of every platform this machine builds.
    ``progress``: as :func:`build_fmus`'."""
    from fmu_common.kernels import host_platform

    platforms = None if portable or flavour != "native" else [host_platform()]
    told = {} if progress is None else {"progress": progress}
    return fmu_pair(build_fmus(flavour=flavour, platforms=platforms, **told))


# ---------------------------------------------------------------------- command line
def main(argv=None) -> int:
    """``python build/build_fmus.py``: build the pythonfmu FMUs, and with ``--references``
    regenerate the reference results under ``tests/reference/``."""

    ap = argparse.ArgumentParser(
        prog="build_fmus.py", description="Build the FlexiblePendulum and PDLowPass FMUs "
        "(pythonfmu) into build/fmus/, only those whose sources changed.")
    ap.add_argument("names", nargs="*", help=f"FMUs to build (default: all of {', '.join(SPECS)})")
    ap.add_argument("--out", default=str(places.fmu_dir()),
                    help="output folder (default: build/fmus in a checkout)")
    ap.add_argument("--force", action="store_true", help="rebuild even if up to date")
    ap.add_argument("--references", action="store_true",
                    help="also regenerate the reference results under tests/reference/")
    args = ap.parse_args(argv)
    unknown = sorted(set(args.names) - set(SPECS))
    if unknown:
        print(f"error: unknown FMU(s) {', '.join(unknown)}; known: {', '.join(SPECS)}",
              file=sys.stderr)
        return 2
    try:
        stale = {n: is_stale(n, args.out) for n in (args.names or SPECS)}
        fmus = build_python(args.out, args.names or None, force=args.force)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for n, p in fmus.items():
        state = "built" if args.force or stale[n] else "up to date"
        print(f"{n}: {p} ({state})")
    if args.references:
        if set(fmus) != set(SPECS):
            fmus = build_python(args.out)
        for n, files in write_references(fmus).items():
            print(f"{n}: reference written to {files['ref'].parent}")
    return 0
