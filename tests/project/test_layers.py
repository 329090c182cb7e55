"""The house's rules: no import circle among the product's modules (imports inside functions
count), and imports go only from a higher layer to a lower one (or within one room).

The layers, top to bottom, as ``orchestration/__init__.py`` states them: the command line, the
front door, sweeps, the job, the FMU factory, reports, studies, the co-simulation engine, scenes,
the output files, the models, what every FMU shares. Two rooms of one layer (the plant and the
controller) import nothing from each other."""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("fmu_common", "plant_fmu", "controller_fmu", "orchestration")
#: (module prefix, layer), the most specific prefix first; a higher number is a higher layer
LAYERS = [
    ("orchestration.cli", 11),
    ("orchestration.api", 9),
    ("orchestration.sweeps", 8),
    ("orchestration.job", 7),
    ("orchestration.export", 6),
    ("orchestration.report", 5),
    ("orchestration.studies", 4),
    ("orchestration.cosim", 3),
    ("orchestration.scene", 2),
    ("orchestration.files", 1.5),  # output files, complete or absent: below all that write
    ("orchestration.notes", 1.5),  # what a command says on stderr, silenced by --quiet
    ("orchestration", 10),         # the front door (its __init__), on the api
    ("plant_fmu", 1),
    ("controller_fmu", 1),
    ("fmu_common", 0),
]


def modules(root: Path) -> dict:
    """dotted module name -> file, for every module of the product packages under ``root``."""
    out = {}
    for pkg in PACKAGES:
        for f in (root / pkg).rglob("*.py"):
            if "__pycache__" in f.parts or not all(
                    (d / "__init__.py").is_file() for d in f.parents
                    if d.is_relative_to(root / pkg)):
                continue          # a folder that is not a package (fmu_common/loader)
            name = ".".join(f.relative_to(root).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = f
    return out


def imports(root: Path) -> dict:
    """module -> {(imported module, line)} of every import statement, at any depth."""
    mods = modules(root)
    graph = {m: set() for m in mods}
    for mod, path in mods.items():
        tree = ast.parse(path.read_text())
        base = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    stem = ".".join(base[:len(base) - node.level + 1]
                                    + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                names = [stem] + [f"{stem}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for n in names:
                while n and n not in mods:
                    n = n.rpartition(".")[0]
                if n and n != mod and not mod.startswith(n + "."):
                    graph[mod].add((n, node.lineno))
    return graph


def circles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    edges = {m: {t for t, _ in v} for m, v in graph.items()}
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def room(mod: str) -> tuple:
    """``(prefix, layer)`` of the most specific layer entry that ``mod`` belongs to."""
    for prefix, layer in LAYERS:
        if mod == prefix or mod.startswith(prefix + "."):
            return prefix, layer
    raise AssertionError(f"{mod} belongs to no layer: add it to LAYERS")


def violations(graph: dict) -> list:
    out = []
    for mod, targets in graph.items():
        here, layer = room(mod)
        for target, line in sorted(targets):
            there, tlayer = room(target)
            if there != here and tlayer >= layer:
                out.append(f"{mod}:{line} imports {target} (layer {tlayer} >= {layer})")
    return out


def test_no_import_circle():
    assert circles(imports(ROOT)) == []


def test_imports_go_down_the_layers_only():
    assert violations(imports(ROOT)) == []


def test_the_rules_catch_a_circle_and_an_upward_import(tmp_path):
    """The checker itself: a planted circle (scene <-> cosim, through an import inside a
    function) and a planted upward import (the plant importing the host) are found."""
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
    for sub in ("scene", "cosim"):
        (tmp_path / "orchestration" / sub).mkdir()
        (tmp_path / "orchestration" / sub / "__init__.py").write_text("")
    (tmp_path / "orchestration" / "scene" / "a.py").write_text(
        "def f():\n    from ..cosim import b\n")
    (tmp_path / "orchestration" / "cosim" / "b.py").write_text("from ..scene.a import f\n")
    (tmp_path / "plant_fmu" / "m.py").write_text("import orchestration.cosim.b\n")
    graph = imports(tmp_path)
    assert circles(graph) == [["orchestration.cosim.b", "orchestration.scene.a"]]
    found = violations(graph)
    assert any(v.startswith("orchestration.scene.a:2 imports orchestration.cosim.b")
               for v in found), found
    assert any(v.startswith("plant_fmu.m:1 imports orchestration.cosim.b") for v in found)


@pytest.mark.parametrize("model,other", [("plant_fmu", "controller_fmu"),
                                         ("controller_fmu", "plant_fmu")])
def test_a_model_imports_nothing_of_the_other_nor_of_the_host(model, other):
    graph = imports(ROOT)
    bad = [(m, t) for m, ts in graph.items() if m.startswith(model)
           for t, _ in ts if t.startswith((other, "orchestration"))]
    assert bad == []


#: (importer, imported): rooms that the layers would allow to meet but that must not. The FMU
#: factory writes its files with :mod:`orchestration.files`, not through the reports; the reports
#: format what the job computed (the summary, its facts, the design's curves) and call no study.
APART = [("orchestration.export", "orchestration.report"),
         ("orchestration.report", "orchestration.studies")]


def within(mod: str, prefix: str) -> bool:
    return mod == prefix or mod.startswith(prefix + ".")


@pytest.mark.parametrize("importer,imported", APART)
def test_rooms_kept_apart(importer, imported):
    bad = [f"{m}:{line} imports {t}" for m, ts in imports(ROOT).items() if within(m, importer)
           for t, line in sorted(ts) if within(t, imported)]
    assert bad == []


def model_class_names() -> set:
    """The names of every model class of the controller's laws
    (:func:`controller_fmu.spec.model_classes`) and of the plant's rungs (the classes of what
    :func:`plant_fmu.dynamics.model_for` and :func:`plant_fmu.exact.exact_plant` return for each
    of :data:`plant_fmu.interface.FIDELITIES`), with their base classes within the models."""
    from controller_fmu.spec import model_classes
    from plant_fmu.dynamics import model_for
    from plant_fmu.exact import exact_plant
    from plant_fmu.interface import FIDELITIES
    from plant_fmu.params import PlantParams

    p = PlantParams()
    classes = list(model_classes()) + [type(exact_plant(p) if f == "exact" else model_for(p, f))
                                       for f in FIDELITIES]
    return {c.__name__ for cls in classes for c in cls.__mro__
            if c.__module__.startswith(("plant_fmu", "controller_fmu"))}


def test_the_host_names_no_model_class():
    """The host obtains the models from their specifications (``model_for``), so a new
    controller law or plant rung touches no module of ``orchestration`` by name: no file there
    names a model class, not even in a docstring."""
    import re

    names = model_class_names()
    assert {"PDLowPassModel", "PlantModel", "StiffenedPlantModel", "LinearPlantModel",
            "ExactPlant"} <= names
    word = re.compile(r"\b(" + "|".join(sorted(names)) + r")\b")
    found = [f"{f.relative_to(ROOT)}:{i}: {m.group(0)}"
             for f in sorted((ROOT / "orchestration").rglob("*.py"))
             for i, line in enumerate(f.read_text().splitlines(), 1)
             for m in [word.search(line)] if m]
    assert found == []
