"""A scene as an SSP archive with its FMUs (``flexpend export``): the model chosen first, the FMUs
built, the archive written by :func:`orchestration.scene.ssp.write_ssp`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..files import output_error
from ..scene.ssp import write_ssp
from ..studies.fidelity import select_model
from . import flavour_fmus, pair_for, plant_role

__all__ = ["ExportResult", "export_scene"]


@dataclass
class ExportResult:
    path: Path
    scene: object                 # the scene written (its model chosen)
    model: dict | None = None     # the report of the choice, where "auto" chose the model
    fmus: dict = field(default_factory=dict)


def _archived(scene, fmus: dict) -> dict:
    """The FMUs the archive of ``scene`` carries: the pair of its rung (:func:`pair_for`), and
    the companion run's plant FMU where it is another (the stiffened rung's, for a run on a
    floating-frame rung that states its error figure), which flexpend's run of the archive
    takes from it."""
    out = pair_for(fmus, scene.plant.fidelity, scene.controller)
    if scene.plant.fidelity in ("nonlinear", "linear") and scene.fidelity.companion:
        role = plant_role(fmus, "stiffened")
        if role != "plant":
            out[role] = fmus[role]
    return out


def export_scene(scene, flavour: str = "native", out=None, progress=None) -> ExportResult:
    """Write ``scene`` as an SSP archive with the FMUs of ``flavour`` (``"native"`` or
    ``"python"``); ``plant.n_modes``/``plant.fidelity``
    ``"auto"`` are chosen first (:func:`orchestration.studies.fidelity.select_model`; the fidelity
    ladder climbed on the scene's monolithic runs), and the chosen model is written.
    ``progress(fraction, label)``: told as the FMUs are built and the model chosen
    (:mod:`orchestration.report.progress`)."""
    def share(start, end, label):           # a part of the whole: from start to end
        if progress is None:
            return None
        progress(start, label)
        return lambda f, now=None: progress(start + (end - start) * f, now or label)
    split = 1.0 if scene.resolved else 0.25          # the FMUs, then the model's choice
    fmus = flavour_fmus(flavour, portable=True,
                        progress=share(0.0, split, f"{scene.name}: the {flavour} FMUs"))
    model = None
    if not scene.resolved:
        scene, model = select_model(scene, share(split, 1.0, f"{scene.name}: choosing the "
                                                             "model"), monolithic=True)
    path = Path(out) if out is not None else Path("out") / f"{scene.name}.ssp"
    try:
        fmus = _archived(scene, fmus)
        write_ssp(scene, fmus, path, model=model)       # complete or absent
    except OSError as exc:                              # a full disk: an OutputError naming it
        raise output_error(path, exc) from None
    if progress is not None:
        progress(1.0, f"{scene.name}: archive written")
    return ExportResult(path, scene, model, fmus)

