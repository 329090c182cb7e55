"""``flexpend check --plot``'s figure (:func:`orchestration.report.check.check_figure`): every
axis label carries a unit, the one the FMU's model description gives the signal."""
import re
import shutil
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

from orchestration.export.check import check_fmu, variable_units
from orchestration.export.places import ROOT
from orchestration.report.check import check_figure

REFERENCES = ROOT / "tests" / "reference"


def _units_in_xml(fmu) -> dict:
    """``{variable: unit}`` read from modelDescription.xml with ElementTree: a variable's own
    ``unit``, else its declared type's, else "1"."""
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    types = {t.get("name"): t[0].get("unit") for t in root.iter("SimpleType")}
    out = {}
    for v in root.iter("ScalarVariable"):
        kind = v[0]
        out[v.get("name")] = kind.get("unit") or types.get(kind.get("declaredType")) or "1"
    return out


def _labels(fig) -> list[tuple[str, str]]:
    return [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]


@pytest.mark.parametrize("model", ["FlexiblePendulum", "PDLowPass"])
def test_every_axis_of_the_check_figure_has_the_signals_unit(fmus, model):
    report = check_fmu(fmus[model], REFERENCES)
    expected = _units_in_xml(fmus[model])
    fig = check_figure(report)
    labels = _labels(fig)
    assert len(labels) == len(report.signals) >= 1
    for (xlabel, ylabel), name in zip(labels, report.signals):
        assert ylabel == f"{name} ({expected[name]})"
        assert xlabel in ("", "time (s)")
    assert labels[-1][0] == "time (s)"
    for xlabel, ylabel in labels:                            # every label that is drawn
        for text in (xlabel, ylabel):
            assert text == "" or re.fullmatch(r".+ \([^()]+\)", text), text


def test_units_come_from_the_declared_type_or_are_dimensionless(fmus, tmp_path):
    """A unit given only by the variable's declared type is found; none at all gives "1"."""
    source = Path(fmus["FlexiblePendulum"])
    fmu = tmp_path / source.name
    shutil.copy(source, fmu)
    with zipfile.ZipFile(source) as z:
        members = {n: z.read(n) for n in z.namelist()}
    root = ET.fromstring(members["modelDescription.xml"])
    types = ET.Element("TypeDefinitions")
    ET.SubElement(ET.SubElement(types, "SimpleType", name="Angle"), "Real", unit="rad")
    children = list(root)
    root.insert(children.index(root.find("UnitDefinitions")) + 1, types)
    for v in root.iter("ScalarVariable"):
        if v.get("name") == "phi_o":
            del v[0].attrib["unit"]
            v[0].set("declaredType", "Angle")
        if v.get("name") == "energy":
            del v[0].attrib["unit"]
    members["modelDescription.xml"] = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)

    units = variable_units(fmu)
    assert units == _units_in_xml(fmu)
    assert units["phi_o"] == "rad" and units["energy"] == "1" and units["x_o"] == "m"
