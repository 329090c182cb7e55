"""The manual (``docs/``, ``mkdocs.yml``) builds with ``mkdocs build --strict``: no broken link,
no missing anchor, no warning of mkdocstrings; every page is in the nav; every public name of the
API (``orchestration.__all__``, and the public methods and properties of the result classes) has
a docstring and a place on the built API page; the README is a front page (at most 300 lines of
at most 100 characters) that links into the manual; no page a user reads cites the design folder's
``MODEL.md``, which is not in the repository (``docs/model.md`` is)."""
import inspect
import os
import re
import subprocess
import sys
from functools import cached_property
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

#: The classes whose public methods and properties a user calls on what the API returns.
RESULT_CLASSES = ("Run", "Scene", "Analysis", "DesignReport", "Sweep", "KeySpec", "ConfigError")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The manual built with ``mkdocs build --strict`` into a temporary folder; its output.
    Skipped only when the manual's tools are not installed (they are in the ``test`` and ``docs``
    extras, so CI has them)."""
    for tool in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
        pytest.importorskip(tool, reason=f"{tool} is not installed: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                           str(ROOT / "mkdocs.yml"), "-d", str(out)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    return out, proc


def test_the_manual_builds_strict_without_a_warning(site):
    out, proc = site
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-5000:]
    assert not re.search(r"^(WARNING|ERROR)\b", log, re.M), log[-5000:]
    assert (out / "index.html").is_file() and (out / "api" / "index.html").is_file()


def nav_pages(nav) -> list:
    """Every page file the nav of ``mkdocs.yml`` names, in order."""
    out = []
    for item in nav:
        value = next(iter(item.values())) if isinstance(item, dict) else item
        out += nav_pages(value) if isinstance(value, list) else [value]
    return out


def test_every_page_is_in_the_nav_once():
    import yaml

    class Loader(yaml.SafeLoader):
        pass
    # mkdocs.yml may hold python-specific tags (!!python/name:...): read them as plain strings
    Loader.add_multi_constructor("", lambda loader, suffix, node: None)
    config = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=Loader)
    pages = nav_pages(config["nav"])
    assert len(pages) == len(set(pages)), pages
    on_disk = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    assert sorted(pages) == on_disk
    assert pages[0] == "index.md" and "model.md" in pages and "api.md" in pages


def public_members(cls) -> list:
    """``(name, object)`` of the public methods and properties ``cls`` defines itself."""
    out = []
    for name, value in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(value, (property, cached_property)) or inspect.isfunction(value):
            out.append((name, value))
    return out


def doc_of(value) -> str:
    if isinstance(value, property):
        value = value.fget
    if isinstance(value, cached_property):
        value = value.func
    return inspect.getdoc(value) or ""


def test_every_public_name_has_a_docstring_and_is_on_the_api_page(site):
    import orchestration

    out, proc = site
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    page = (out / "api" / "index.html").read_text()
    ids = set(re.findall(r'id="([A-Za-z_][\w.]*)"', page))
    names = [n for n in orchestration.__all__ if n != "__version__"]
    assert names and set(RESULT_CLASSES) <= set(names)
    missing_doc, missing_page = [], []
    for name in names:
        obj = getattr(orchestration, name)
        where = f"{obj.__module__}.{obj.__qualname__}"
        if not (inspect.getdoc(obj) or "").strip():
            missing_doc.append(name)
        if where not in ids:
            missing_page.append(where)
        if name in RESULT_CLASSES:
            for member, value in public_members(obj):
                if not doc_of(value).strip():
                    missing_doc.append(f"{name}.{member}")
                if f"{where}.{member}" not in ids:
                    missing_page.append(f"{where}.{member}")
    assert not missing_doc, f"public names without a docstring: {missing_doc}"
    assert not missing_page, f"public names not on the built API page: {missing_page}"


def test_the_readme_is_a_front_page_that_links_into_the_manual():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 300, len(lines)
    long = [i + 1 for i, line in enumerate(lines) if len(line) > 100]
    assert not long, f"README lines over 100 characters: {long}"
    text = "\n".join(lines)
    linked = set(re.findall(r"\]\((docs/[\w/]+\.md)(?:#[\w-]+)?\)", text))
    assert linked, "the README links to no manual page"
    for target in linked:
        assert (ROOT / target).is_file(), target
    assert {"docs/model.md", "docs/api.md"} <= linked


def test_no_page_a_user_reads_cites_the_missing_model_md():
    """The specification is ``docs/model.md``; ``MODEL.md`` of the design folder is not shipped."""
    user_facing = [ROOT / "README.md", *DOCS.rglob("*.md")]
    for package in ("orchestration", "plant_fmu", "controller_fmu", "fmu_common", "bench"):
        user_facing += (ROOT / package).rglob("*.py")
        user_facing += (ROOT / package).rglob("*.[ch]")
    cited = [str(p.relative_to(ROOT)) for p in user_facing
             if re.search(r"(?<![\w/])MODEL\.md", p.read_text(errors="replace"))]
    assert not cited, f"files citing MODEL.md (the manual's page is docs/model.md): {cited}"


#: The packages whose docstrings, comments and messages a user reads.
PRODUCT = ("orchestration", "plant_fmu", "controller_fmu", "fmu_common")


def product_sources():
    for package in PRODUCT:
        yield from sorted((ROOT / package).rglob("*.py"))
        yield from sorted((ROOT / package).rglob("*.[ch]"))


def test_every_section_of_the_model_the_code_cites_exists():
    """The docstrings cite the model by number ("docs/model.md section 4", "sections 6 and 7"):
    each number is a heading ``## N. ...`` of ``docs/model.md``, so renumbering the page breaks
    this test, not the citations."""
    headings = set(re.findall(r"^## (\d+)\. \S", (DOCS / "model.md").read_text(), re.M))
    assert headings == {str(n) for n in range(1, len(headings) + 1)}, sorted(headings)
    cited = {}
    for path in [*product_sources(), *DOCS.rglob("*.md")]:
        text = re.sub(r"\s+", " ", path.read_text(errors="replace"))
        for numbers in re.findall(r"model\.md\)?'?s? sections? (\d+(?:(?:, | and )\d+)*)", text):
            for n in re.findall(r"\d+", numbers):
                cited.setdefault(n, []).append(str(path.relative_to(ROOT)))
    assert cited, "no citation found: the pattern no longer matches how the code cites the model"
    missing = {n: where for n, where in cited.items() if n not in headings}
    assert not missing, f"cited sections that docs/model.md does not have: {missing}"


def test_the_model_page_renders_its_formulas(site):
    """``docs/model.md`` writes its equations in TeX (``$...$``, ``$$...$$``): arithmatex wraps
    every one for MathJax, whose script the page loads; no dollar sign is left in the text."""
    out, proc = site
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    page = (out / "model" / "index.html").read_text()
    assert re.search(r'<script src="[^"]*mathjax[^"]*"', page, re.I), "MathJax is not loaded"
    math = re.findall(r'class="arithmatex"', page)
    source = (DOCS / "model.md").read_text()
    prose = re.sub(r"^```.*?^```", "", source, flags=re.M | re.S)
    expected = len(re.findall(r"\$\$.*?\$\$", prose, re.S))
    expected += len(re.findall(r"(?<!\$)\$(?!\$)[^$\n]+?(?<!\$)\$(?!\$)", re.sub(
        r"\$\$.*?\$\$", "", prose, flags=re.S)))
    assert expected > 50 and len(math) == expected, (len(math), expected)
    body = re.sub(r'<(span|div) class="arithmatex">.*?</\1>', "", page, flags=re.S)
    body = re.sub(r"<script.*?</script>", "", body, flags=re.S)
    assert "$" not in body, body[body.index("$") - 200: body.index("$") + 200]


def test_the_code_cites_the_manual_not_the_readme():
    """The README is a front page: the code's docstrings, comments and messages point to the
    manual's pages (``docs/...``), where the README's former sections now live."""
    cited = [str(p.relative_to(ROOT)) for p in product_sources()
             if re.search(r"\bREADME\b", p.read_text(errors="replace"))]
    assert not cited, f"files citing the README (cite a page of docs/ instead): {cited}"
