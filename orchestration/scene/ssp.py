"""A scene as an SSP 1.0 package (System Structure and Parameterization), and back.

    export_scene(scene, flavour="python", out=None)   -> ExportResult (writes <out>.ssp)
    write_ssp(scene, fmus, path)                      the archive of a scene whose model is chosen
    read_ssp(path, overrides=())                      -> SspSystem (scene + the archive's FMUs)
    validate_ssd(xml)                                 -> schema problems (SSP 1.0, fmpy's copy)
    fmpy_parameter_set(path)                          the bindings as fmpy.ssp.simulate_ssp takes them

The archive is ``SystemStructure.ssd`` plus both FMUs under ``resources/`` (and the companion
run's plant FMU, which no component names: :func:`write_ssp`). The SSD holds:

* one ``Component`` per FMU (``plant``, ``controller``), with every input and output as a
  connector and every parameter the scene sets as a ``parameter`` connector;
* a ``ParameterBinding`` per component with the parameter values inline (an SSV
  ``ParameterSet`` inside ``ParameterValues``): libcosim, FMPy and OMSimulator all read inline
  values (libcosim reads them only on components, not on the system);
* the scene's connections;
* a ``DefaultExperiment`` (start 0, the scene's stop time) with two annotations: libcosim's
  ``osp:FixedStepAlgorithm`` (``com.opensimulationplatform``, the step libcosim takes), and ours,
  ``org.flexpend.scene``: every scene key the standard has no place for (``output_interval``,
  ``master.*``, ``fidelity.*``), as TOML values, and where ``"auto"`` chose the model, which model and why.

SSP 1.0 has no step size of its own (``SimulationInformation`` is not in the 1.0 schema), hence the
annotations. The prefixes ``ssd``, ``ssc``, ``ssv``, ``osp`` are the ones libcosim's parser
expects literally.

Reading (``flexpend run FILE.ssp``) takes our own exports and a plain SSP 1.0 from another tool:
two FMU components, recognised by their variables (the plant has the input ``F_c`` and the
outputs ``x_o``, ``phi_o``, ``omega_o``; the controller the reverse), connections between them,
parameter values inline or in ``.ssv`` files of the archive. Every scene key the file does not
give takes the scene default; without our annotation, libcosim's step is the master's step.
Anything else (a missing FMU, a connection to an unknown connector, malformed XML, nested
systems, parameter mappings, transformations, a start time other than 0) is an
:class:`SspError` naming it: one line, exit 2 on the command line.
"""
from __future__ import annotations

import math
import re
import shutil
import tempfile
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from controller_fmu import interface as controller_interface
from plant_fmu import interface as plant_interface

from ..files import atomic_path
from . import archive
from .fmu import FmuError, model_description
from .keys import ConfigError, parse_value, toml_value
from .records import OutputSettings
from .schema import OverrideError, scene_from_config, start_values

__all__ = ["SspError", "SspSystem", "write_ssp", "read_ssp",
           "validate_ssd", "fmpy_parameter_set", "ssd_of", "SSD_NAME", "NS", "SCENE_ANNOTATION",
           "OSP_ANNOTATION", "PLANT_SIGNALS"]

SSD_NAME = "SystemStructure.ssd"
NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
    "fp": "urn:flexpend:ssp:1",
}
#: Annotation types: libcosim's (its parser reads only this one) and ours.
OSP_ANNOTATION = "com.opensimulationplatform"
SCENE_ANNOTATION = "org.flexpend.scene"
FMU_TYPE = "application/x-fmu-sharedlibrary"
#: The variables that make a component the plant (inputs, outputs); the controller has them the
#: other way round.
PLANT_SIGNALS = (("F_c",), ("x_o", "phi_o", "omega_o"))
#: Scene keys the SSD carries in its own elements (the rest goes into our annotation).
#: the keys the SSD carries in its own places (the FMUs' parameter bindings, the experiment);
#: every other key goes into the scene annotation (the fidelity.* keys included: a run of the
#: archive needs them, fidelity.max_modes against plant.n_elements and fidelity.companion)
_CARRIED = ("plant.", "controller.", "initial.")
_CARRIED_KEYS = ("connections", "stop_time", "description")


class SspError(ConfigError):
    """An SSP that flexpend cannot read or run (the message is one line naming the problem)."""


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


# ---------------------------------------------------------------------- values
def _xml_real(value) -> str:
    value = float(value)
    if math.isnan(value):
        raise ValueError("NaN is not a parameter value")
    if math.isinf(value):
        return "INF" if value > 0 else "-INF"
    return repr(value)


def _ssv_value(var_type: str, value) -> str:
    """A scene value as the ``value`` attribute of an SSV parameter of the FMU's type."""
    if var_type == "Real":
        return _xml_real(value)
    if var_type in ("Integer", "Enumeration"):
        if isinstance(value, bool) or int(value) != value:
            raise ValueError(f"{value!r} is not an integer")
        return str(int(value))
    if var_type == "Boolean":
        if not isinstance(value, bool):
            raise ValueError(f"{value!r} is not a boolean")
        return "true" if value else "false"
    return str(value)


def _parse_ssv_value(kind: str, text: str):
    if kind == "Real":
        return float(text)                   # also INF, -INF
    if kind in ("Integer", "Enumeration"):
        return int(text)
    if kind == "Boolean":
        if text in ("true", "1"):
            return True
        if text in ("false", "0"):
            return False
        raise ValueError(f"{text!r} is not a boolean")
    return text


# ---------------------------------------------------------------------- schema
def _schema():
    import fmpy.ssp
    from lxml import etree

    xsd = Path(fmpy.ssp.__file__).parent / "schema" / "SystemStructureDescription.xsd"
    return etree.XMLSchema(file=str(xsd))


def validate_ssd(xml) -> list[str]:
    """Problems of an SSD (bytes or an lxml element) against the SSP 1.0 schema that fmpy ships
    (``fmpy/ssp/schema``); an empty list when it is valid."""
    from lxml import etree

    root = etree.fromstring(xml, _parser()) if isinstance(xml, (bytes, str)) else xml
    schema = _schema()
    if schema.validate(root):
        return []
    return [f"line {e.line}: {e.message}" for e in schema.error_log]


def _parser():
    from lxml import etree

    return etree.XMLParser(resolve_entities=False, no_network=True, remove_blank_text=True)


def _component_parameters(scene) -> dict:
    """component -> {FMU parameter: value}: what the master sets on each FMU."""
    return {"plant": start_values(scene, plant_interface.VARIABLES),
            "controller": start_values(scene, controller_interface.VARIABLES)}


def _scene_settings(cfg: dict) -> dict:
    return {k: v for k, v in cfg.items()
            if not k.startswith(_CARRIED) and k not in _CARRIED_KEYS}


def ssd_of(scene, fmus: dict, sources: dict, model: dict | None = None):
    """The SSD (an lxml element) of a scene whose model is chosen; ``fmus``: component -> FMU
    path (read for its variables), ``sources``: component -> path inside the archive."""
    from lxml import etree

    cfg = scene.config
    if not scene.resolved:
        raise ValueError(f"{scene.name}: choose the model before writing it (plant.n_modes and "
                         "plant.fidelity must not be 'auto')")
    E = etree.Element
    root = E(_q("ssd", "SystemStructureDescription"), nsmap={k: NS[k] for k in ("ssd", "ssc", "ssv", "osp")},
             version="1.0", name=scene.name, generationTool=_tool())
    system = etree.SubElement(root, _q("ssd", "System"), name=scene.name)
    if cfg["description"]:
        system.set("description", cfg["description"])
    elements = etree.SubElement(system, _q("ssd", "Elements"))
    params = _component_parameters(scene)
    conns = scene.connections
    # inputs left unconnected are not connectors: fmpy.ssp (0.3.32) wires an unconnected input
    # connector to the source of the input before it
    wired = {comp: {c.dst_var for c in conns if c.dst == comp} for comp in ("plant", "controller")}
    for comp in ("plant", "controller"):
        md = model_description(fmus[comp])
        variables = {v.name: v for v in md.modelVariables}
        el = etree.SubElement(elements, _q("ssd", "Component"), name=comp, type=FMU_TYPE,
                              source=sources[comp])
        connectors = etree.SubElement(el, _q("ssd", "Connectors"))
        for v in md.modelVariables:
            if v.causality == "output" or (v.causality == "input" and v.name in wired[comp]):
                _connector(connectors, v.name, v.causality, v.type)
        for name in list(params[comp]):
            v = variables.get(name)
            if v is None or v.causality != "parameter":
                raise ValueError(f"{scene.name}: the {comp} FMU ({Path(fmus[comp]).name}) has no "
                                 f"parameter {name!r}")
            if _infinite_default(v, params[comp][name]):
                del params[comp][name]
                continue
            _connector(connectors, name, "parameter", v.type)
        bindings = etree.SubElement(el, _q("ssd", "ParameterBindings"))
        binding = etree.SubElement(bindings, _q("ssd", "ParameterBinding"))
        values = etree.SubElement(binding, _q("ssd", "ParameterValues"))
        pset = etree.SubElement(values, _q("ssv", "ParameterSet"), version="1.0",
                                name=f"{scene.name}.{comp}")
        plist = etree.SubElement(pset, _q("ssv", "Parameters"))
        for name, value in params[comp].items():
            v = variables[name]
            p = etree.SubElement(plist, _q("ssv", "Parameter"), name=name)
            try:
                text = _ssv_value(v.type, value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{scene.name}: {comp}.{name}: {exc}") from None
            etree.SubElement(p, _q("ssv", "Enumeration" if v.type == "Enumeration" else v.type),
                             value=text)
    connections = etree.SubElement(system, _q("ssd", "Connections"))
    for c in conns:
        etree.SubElement(connections, _q("ssd", "Connection"), startElement=c.src,
                         startConnector=c.src_var, endElement=c.dst, endConnector=c.dst_var)
    exp = etree.SubElement(root, _q("ssd", "DefaultExperiment"), startTime="0.0",
                           stopTime=repr(float(cfg["stop_time"])))
    notes = etree.SubElement(exp, _q("ssd", "Annotations"))
    osp = etree.SubElement(notes, _q("ssc", "Annotation"), type=OSP_ANNOTATION)
    alg = etree.SubElement(osp, _q("osp", "Algorithm"))
    # the step a run takes (at the exact rung plant.exact_step: Scene.run_master)
    etree.SubElement(alg, _q("osp", "FixedStepAlgorithm"),
                     baseStepSize=repr(float(scene.run_master.step)))
    ours = etree.SubElement(notes, _q("ssc", "Annotation"), type=SCENE_ANNOTATION)
    sc = etree.SubElement(ours, _q("fp", "Scene"), nsmap={"fp": NS["fp"]}, name=scene.name)
    for key, value in _scene_settings(cfg).items():
        etree.SubElement(sc, _q("fp", "Setting"), key=key).text = toml_value(value)
    if model is not None:
        m = etree.SubElement(sc, _q("fp", "ModelChoice"), n_modes=str(model["n_modes"]),
                             fidelity=model["fidelity"])
        m.text = model.get("reason", "")
    return root


def _infinite_default(variable, value) -> bool:
    """True for an infinite Real value equal to the FMU's own start value. Such a value is left
    out of the binding: libcosim's parser cannot read ``INF`` (xs:double's spelling of infinity;
    it fails the whole archive) and the FMU has the value already."""
    if variable.type != "Real" or not isinstance(value, (int, float)) or not math.isinf(value):
        return False
    try:
        return float(variable.start) == value
    except (TypeError, ValueError):
        return False


def _connector(parent, name, kind, var_type):
    from lxml import etree

    c = etree.SubElement(parent, _q("ssd", "Connector"), name=name, kind=kind)
    etree.SubElement(c, _q("ssc", var_type if var_type in ("Real", "Integer", "Boolean", "String")
                           else "Enumeration"))


def _tool() -> str:
    try:
        from importlib.metadata import version
        return f"flexpend {version('flexpend')}"
    except Exception:  # noqa: BLE001 - not installed as a distribution
        return "flexpend"


def write_ssp(scene, fmus: dict, path, model: dict | None = None) -> Path:
    """Write the archive of ``scene`` (its model chosen) with ``fmus`` (``{"plant": path,
    "controller": path}``) to ``path``, atomically; the SSD is validated against the SSP 1.0
    schema first (a ``ValueError`` lists the problems). Another entry of ``fmus``, named by a
    native plant FMU of another rung family (``FlexiblePendulumStiffened``: the companion run's
    plant), rides along under ``resources/`` with no component naming it: an SSP importer
    ignores it, and flexpend's run of the archive runs that rung on it (:func:`read_ssp`)."""
    from lxml import etree

    path = Path(path)
    sources = {c: f"resources/{Path(fmus[c]).name}" for c in ("plant", "controller")}
    if sources["plant"] == sources["controller"]:
        raise ValueError("the plant and the controller FMU have the same file name")
    riders = {f"resources/{name}.fmu": fmus[name] for name in plant_interface.PLANT_FMUS
              if name in fmus}
    riders = {m: f for m, f in riders.items() if m not in sources.values()}
    root = ssd_of(scene, fmus, sources, model)
    problems = validate_ssd(root)
    if problems:
        raise ValueError(f"{scene.name}: the SSD written does not follow the SSP 1.0 schema: "
                         + "; ".join(problems[:3]))
    xml = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as part, zipfile.ZipFile(part, "w") as zf:     # complete or absent
        # fixed time stamps: the same scene and FMUs give the same bytes
        zf.writestr(zipfile.ZipInfo(SSD_NAME, (1980, 1, 1, 0, 0, 0)), xml,
                    compress_type=zipfile.ZIP_DEFLATED)
        for member, fmu in [*((sources[c], fmus[c]) for c in ("plant", "controller")),
                            *riders.items()]:
            zf.writestr(zipfile.ZipInfo(member, (1980, 1, 1, 0, 0, 0)),
                        Path(fmu).read_bytes(), compress_type=zipfile.ZIP_STORED)
    return path


# ---------------------------------------------------------------------- reading
@dataclass
class SspSystem:
    """A scene read from an SSP archive, with its FMUs unpacked into a temporary folder (removed
    by :meth:`close` or on leaving the ``with`` block)."""

    path: Path
    scene: object
    fmus: dict                    # {"plant": path, "controller": path}
    components: dict              # {"plant": SSD component name, "controller": ...}
    tmpdir: str | None = None

    def close(self):
        if self.tmpdir is not None:
            shutil.rmtree(self.tmpdir, ignore_errors=True)
            self.tmpdir = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _scene_name(root, path: Path) -> str:
    name = root.get("name") or ""
    return name if re.fullmatch(r"[A-Za-z0-9_.-]{1,100}", name) else path.stem


def read_ssp(path, overrides=()) -> SspSystem:
    """Read an SSP archive into a scene and the paths of its FMUs (unpacked into a temporary
    folder); ``overrides``: ``--set`` items applied on top. :class:`SspError` (or
    :class:`~orchestration.scene.keys.ConfigError` for a bad value) names any problem."""
    path = Path(path)
    label = path.name
    if not path.is_file():
        raise SspError(f"{label}: not a regular file" if path.exists() else f"{label}: no such file")
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise SspError(f"{label}: not an SSP archive (a zip file): {exc}") from None
    with zf, _as_ssp_error():
        names = {i.filename for i in archive.members(zf, label)}    # the limits, before reading
        if SSD_NAME not in names:
            raise SspError(f"{label}: the archive has no {SSD_NAME}")
        root = _parse_xml(label, SSD_NAME, archive.read_member(zf, SSD_NAME, label))
        version = root.get("version") or ""
        if not re.fullmatch(r"1\.[0-9]+(-.*)?", version):
            raise SspError(f"{label}: SSD version {version!r}: flexpend reads SSP 1.x")
        problems = validate_ssd(root)
        if problems:
            raise SspError(f"{label}: {SSD_NAME} does not follow the SSP 1.0 schema: {problems[0]}")
        system = root.find(_q("ssd", "System"))
        if system.find(f"{_q('ssd', 'Elements')}/{_q('ssd', 'System')}") is not None:
            raise SspError(f"{label}: nested systems are not supported (flexpend runs one plant "
                           "and one controller)")
        comps = system.findall(f"{_q('ssd', 'Elements')}/{_q('ssd', 'Component')}")
        if len(comps) != 2:
            raise SspError(f"{label}: the system has {len(comps)} components; flexpend runs "
                           "exactly two, a plant and a controller")
        tmpdir = tempfile.mkdtemp(prefix="flexpend_ssp_")
        try:
            return _read_system(path, label, zf, names, root, system, comps, tmpdir, overrides)
        except BaseException:
            shutil.rmtree(tmpdir, ignore_errors=True)
            raise


@contextmanager
def _as_ssp_error():
    """An archive beyond its limits or with an unsafe member (:mod:`.archive`), or an FMU of it
    that is not loaded (:mod:`.fmu`), as an :class:`SspError`."""
    try:
        yield
    except (archive.ArchiveError, FmuError) as exc:
        raise SspError(str(exc)) from None


def _parse_xml(label, member, data):
    from lxml import etree

    try:
        return etree.fromstring(data, _parser())
    except etree.XMLSyntaxError as exc:
        raise SspError(f"{label}: {member} is not well-formed XML: {exc}") from None


def _read_system(path, label, zf, names, root, system, comps, tmpdir, overrides):
    info = {}                      # component name -> (FMU path, {variable: ModelVariable})
    for comp in comps:
        name = comp.get("name")
        source = comp.get("source")
        kind = comp.get("type", FMU_TYPE)
        if kind != FMU_TYPE:
            raise SspError(f"{label}: component {name!r} is of type {kind!r}; flexpend runs FMUs "
                           f"({FMU_TYPE})")
        member = source[2:] if source.startswith("./") else source
        if member not in names:
            raise SspError(f"{label}: component {name!r} names the FMU {source!r}, which the "
                           "archive does not contain")
        dest = archive.copy_member(zf, member, Path(tmpdir) / f"{len(info)}_{Path(member).name}",
                                   label)
        try:
            md = model_description(dest, f"{label}: component {name!r}: {source}")
        except ConfigError:
            raise
        except Exception as exc:  # noqa: BLE001 - any reason the FMU cannot be read
            raise SspError(f"{label}: component {name!r}: {source} is not a readable FMU: "
                           f"{exc}") from None
        if md.coSimulation is None:
            raise SspError(f"{label}: component {name!r}: {source} is not a co-simulation FMU")
        info[name] = (dest, {v.name: v for v in md.modelVariables})

    role = {}                      # SSD component name -> "plant" / "controller"
    ins, outs = PLANT_SIGNALS
    for name, (_, variables) in info.items():
        def has(names_, causality):
            return all(variables.get(n) is not None and variables[n].causality == causality
                       for n in names_)
        if has(ins, "input") and has(outs, "output"):
            role[name] = "plant"
        elif has(ins, "output") and has(outs, "input"):
            role[name] = "controller"
    if sorted(role.values()) != ["controller", "plant"]:
        raise SspError(f"{label}: flexpend runs a plant (input {', '.join(ins)}; outputs "
                       f"{', '.join(outs)}) and a controller (the reverse); the components "
                       f"{', '.join(repr(n) for n in info)} are not one of each")

    values = {}
    # connections
    conns = []
    for c in system.findall(f"{_q('ssd', 'Connections')}/{_q('ssd', 'Connection')}"):
        a, av, b, bv = (c.get(k) for k in ("startElement", "startConnector", "endElement",
                                            "endConnector"))
        text = f"{a}.{av} -> {b}.{bv}" if a and b else \
            f"{a or '(system)'}.{av} -> {b or '(system)'}.{bv}"
        if a is None or b is None:
            raise SspError(f"{label}: connection {text}: connections to the system's own "
                           "connectors are not supported")
        for el, var, causality in ((a, av, "output"), (b, bv, "input")):
            if el not in info:
                raise SspError(f"{label}: connection {text}: no component named {el!r}")
            v = info[el][1].get(var)
            if v is None or v.causality != causality:
                raise SspError(f"{label}: connection {text}: {el} has no {causality} {var!r}")
        if len(c):
            tags = {_local(x.tag) for x in c}
            if tags - {"ConnectionGeometry", "Annotations"}:
                raise SspError(f"{label}: connection {text}: transformations "
                               f"({', '.join(sorted(tags))}) are not supported")
        conns.append(f"{role[a]}.{av} -> {role[b]}.{bv}")
    if not conns:
        raise SspError(f"{label}: the system has no connections")
    values["connections"] = conns

    # parameters: on each component, and on the system with names "<component>.<parameter>"
    scene_keys = _scene_keys()

    def bind(comp_name, pname, kind, text, where):
        v = info[comp_name][1].get(pname)
        if v is None or v.causality != "parameter":
            raise SspError(f"{label}: {where}: {comp_name} has no parameter {pname!r}")
        key = scene_keys[role[comp_name]].get(pname)
        if key is None:
            raise SspError(f"{label}: {where}: {comp_name}.{pname} is not a parameter flexpend "
                           "sets (no scene key)")
        try:
            values[key] = _parse_ssv_value(kind, text)
        except ValueError as exc:
            raise SspError(f"{label}: {where}: {comp_name}.{pname}: {exc}") from None

    for comp in comps:
        for pname, kind, text, where in _bindings(label, zf, names, comp):
            bind(comp.get("name"), pname, kind, text, where)
    for pname, kind, text, where in _bindings(label, zf, names, system):
        comp_name, dot, rest = pname.partition(".")
        if not dot or comp_name not in info:
            raise SspError(f"{label}: {where}: parameter {pname!r} names no component")
        bind(comp_name, rest, kind, text, where)

    # experiment and settings
    exp = root.find(_q("ssd", "DefaultExperiment"))
    osp_step = None
    settings = {}
    if exp is not None:
        start = float(exp.get("startTime", "0"))
        if start != 0.0:
            raise SspError(f"{label}: startTime = {start:g}: flexpend runs from 0")
        if exp.get("stopTime") is not None:
            values["stop_time"] = float(exp.get("stopTime"))
        for note in exp.findall(f"{_q('ssd', 'Annotations')}/{_q('ssc', 'Annotation')}"):
            if note.get("type") == OSP_ANNOTATION:
                fs = note.find(f"{_q('osp', 'Algorithm')}/{_q('osp', 'FixedStepAlgorithm')}")
                if fs is not None and fs.get("baseStepSize") is not None:
                    osp_step = _positive(label, "osp:FixedStepAlgorithm baseStepSize",
                                         fs.get("baseStepSize"))
            elif note.get("type") == SCENE_ANNOTATION:
                sc = note.find(_q("fp", "Scene"))
                if sc is not None:
                    for s in sc.findall(_q("fp", "Setting")):
                        settings[s.get("key")] = parse_value(s.text or "")
    if settings:
        values.update(settings)
    elif osp_step is not None:
        values["master.step"] = osp_step
        dt = OutputSettings().output_interval
        ratio = dt / osp_step
        if not math.isfinite(ratio) or abs(ratio - round(ratio)) > 1e-9 * ratio \
                or round(ratio) < 1:
            values["output_interval"] = osp_step
    description = system.get("description") or root.get("description")
    if description:
        values["description"] = description
    name = _scene_name(root, path)
    try:
        scene = scene_from_config(name, values, overrides)
    except OverrideError:
        raise
    except ConfigError as exc:
        raise exc.prefixed(f"{label}: ", cls=SspError) from None
    fmus = {role[n]: p for n, (p, _) in info.items()}
    sources = {Path(p).name.partition("_")[2] for p in fmus.values()}
    for rung_fmu in plant_interface.PLANT_FMUS:     # another family's plant riding along
        member = f"resources/{rung_fmu}.fmu"
        if member in names and f"{rung_fmu}.fmu" not in sources:
            dest = archive.copy_member(zf, member, Path(tmpdir) / f"{rung_fmu}.fmu", label)
            model_description(dest, f"{label}: {member}")
            fmus[rung_fmu] = str(dest)
    components = {role[n]: n for n in info}
    return SspSystem(path, scene, fmus, components, tmpdir)


def _positive(label, what, text) -> float:
    """``text`` as a positive finite number (an annotation's value: no schema checks it)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise SspError(f"{label}: {what} = {text!r}: allowed: a positive number")
    return value


def _scene_keys() -> dict:
    """role -> {FMU parameter: scene key}, from the FMUs' variable tables."""
    return {role: {v.name: v.scene_key for v in table
                   if v.causality == "parameter" and v.scene_key}
            for role, table in (("plant", plant_interface.VARIABLES),
                                ("controller", controller_interface.VARIABLES))}


def _local(tag) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _bindings(label, zf, names, element):
    """``(parameter, SSV type, value text, where)`` of every parameter bound on ``element``."""
    out = []
    for b in element.findall(f"{_q('ssd', 'ParameterBindings')}/{_q('ssd', 'ParameterBinding')}"):
        where = f"parameter binding of {element.get('name')!r}"
        if b.find(_q("ssd", "ParameterMapping")) is not None:
            raise SspError(f"{label}: {where}: parameter mappings are not supported")
        prefix = b.get("prefix", "")
        sets = []
        source = b.get("source")
        if source is not None:
            member = source[2:] if source.startswith("./") else source
            if b.get("sourceBase", "SSD") != "SSD" or member not in names:
                raise SspError(f"{label}: {where}: the parameter file {source!r} is not in the "
                               "archive")
            ssv = _parse_xml(label, member, archive.read_member(zf, member, label))
            sets.append((ssv, f"{where} ({member})"))
        for pset in b.findall(f"{_q('ssd', 'ParameterValues')}/{_q('ssv', 'ParameterSet')}"):
            sets.append((pset, where))
        for pset, w in sets:
            if _local(pset.tag) != "ParameterSet":
                raise SspError(f"{label}: {w}: not an SSV ParameterSet")
            for p in pset.findall(f"{_q('ssv', 'Parameters')}/{_q('ssv', 'Parameter')}"):
                pname = p.get("name", "")
                if prefix and pname.startswith(prefix):
                    pname = pname[len(prefix):]
                typed = [x for x in p if _local(x.tag) in
                         ("Real", "Integer", "Boolean", "String", "Enumeration")]
                if not typed or typed[0].get("value") is None:
                    raise SspError(f"{label}: {w}: parameter {pname!r} has no value of a "
                                   "supported type (Real, Integer, Boolean, String)")
                out.append((pname, _local(typed[0].tag), typed[0].get("value"), w))
    return out


# ---------------------------------------------------------------------- FMPy
def fmpy_parameter_set(path):
    """The archive's parameter values as ``fmpy.ssp.simulate_ssp(parameter_set=...)`` takes them.

    FMPy 0.3.32 reads an SSD's parameter bindings but ``simulate_ssp`` does not apply them; it
    applies a ``ParameterSet`` passed in, with names ``<component>.<parameter>``. It sets Real
    and Integer values, raises on String ones and sets every Boolean to true (it compares the
    text with 0.0). So String and Boolean values equal to the FMU's own start value are left out
    (the FMU has them already); any other String or Boolean value raises ``ValueError``: FMPy
    cannot run that archive as written."""
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    label = Path(path).name
    with archive.checked_archive(path):              # the limits, before fmpy reads it
        pass
    ssd = read_ssd(str(path))
    out = ParameterSet(name="flexpend")
    with archive.checked_archive(path) as (zf, _), tempfile.TemporaryDirectory() as tmp:
        for comp in ssd.system.elements:
            embedded = archive.copy_member(zf, comp.source, Path(tmp) / Path(comp.source).name,
                                           label)
            starts = {v.name: v.start for v in
                      model_description(embedded, f"{label}: {comp.source}").modelVariables}
            for binding in comp.parameterBindings:
                for pset in binding.parameterValues:
                    for p in pset.parameters:
                        if p.type in ("String", "Boolean"):
                            start = starts.get(p.name)
                            same = (str(start).lower() == p.value.lower() if p.type == "Boolean"
                                    else start == p.value)
                            if same:
                                continue
                            raise ValueError(f"{comp.name}.{p.name} = {p.value!r}: fmpy.ssp "
                                             f"cannot set a {p.type} parameter")
                        out.parameters.append(Parameter(name=f"{comp.name}.{p.name}",
                                                        type=p.type, value=p.value))
    return out
