"""The Python half of the FMU's loader (shipped in the FMU as ``resources/flexpend_loader.py``).

It serves three callers, and needs nothing beyond the standard library:

* **the probe**: the C loader runs ``<python> -I flexpend_loader.py`` for each candidate
  interpreter, in a child process, before it loads anything into the host; the script prints
  ``version=``, ``executable=``, ``libpython=`` (the shared library to load) and ``missing=`` (what
  the FMU needs and this Python lacks: numpy, a recent enough version);
* **the C loader, in process** (the file is executed into a private namespace): :func:`missing`
  checks the interpreter the loader uses, :func:`before_instantiate` makes pythonfmu import this
  FMU's slave module (not another copy's), :func:`state_error` reads the verdict of the model's
  checks on a deserialised FMU state;
* **the slave module** (``resources/<model>.py``, which pythonfmu imports): :func:`load_slave`
  imports the FMU's own copy of its packages under a private name,
  ``_flexpend_<model>_<digest of the resources>``, so that

  - a host that imported other versions of ``plant_fmu``/``controller_fmu``/``pythonfmu`` (a
    checkout, as ``flexpend run`` and the tests do) still runs the code shipped in the FMU, and
    the FMU leaves the host's modules alone;
  - two different copies of one FMU in one process each run their own code, and identical copies
    share it.

  Absolute imports of the shipped packages in their source (``from plant_fmu.params import ...``)
  are rewritten, at import, to the private name; nothing is written to disk.
"""
import ast
import os
import sys

__all__ = ["missing", "missing_in_host", "libpython", "probe", "before_instantiate", "slave_module", "state_error",
           "load_slave"]

#: What the FMU's Python code needs (the import names, with the project's lower bounds). scipy is
#: not among them: the FMUs import it only for the plant's ``exponential`` integrator, which then
#: names it if it is missing.
REQUIRED = (("numpy", "numpy", "1.24"),)
MIN_PYTHON = (3, 10)


def missing(load: bool = True) -> str:
    """What this interpreter lacks to run the FMU ('' if nothing), as one line. With ``load``
    (the probe, in a child process) each package is imported; without (in the host process) only
    numpy is, and scipy is looked up but not loaded: the FMUs import it only for the plant's
    ``exponential`` integrator, and loading its own OpenBLAS into a host that never uses it is a
    cost and, with OpenBLAS's threads, an exit-time risk (see docs/fmus.md)."""
    import importlib
    import importlib.metadata
    import importlib.util

    problems = []
    if sys.version_info[:2] < MIN_PYTHON:
        problems.append(f"Python {sys.version.split()[0]} is older than "
                        f"{'.'.join(map(str, MIN_PYTHON))}")
    for dist, module, low in REQUIRED:
        try:
            if load or dist == "numpy":
                importlib.import_module(module)
                version = getattr(sys.modules[dist], "__version__", "0")
            else:
                if importlib.util.find_spec(dist) is None:
                    raise ModuleNotFoundError(f"No module named {dist!r}")
                version = importlib.metadata.version(dist)
        except Exception as exc:  # noqa: BLE001 - any failure to import is a missing package
            problems.append(f"{dist} cannot be imported ({type(exc).__name__}: {exc})")
            continue
        if _version_tuple(version) < _version_tuple(low):
            problems.append(f"{dist} {version} is older than {low}")
    return "; ".join(p.replace("\n", " ") for p in problems)


def missing_in_host() -> str:
    """:func:`missing` for the Python the loader is about to use, in the host process."""
    return missing(load=False)


def _version_tuple(v: str) -> tuple:
    out = []
    for part in v.split(".")[:3]:
        digits = "".join(ch for ch in part if ch.isdigit())
        out.append(int(digits) if digits else 0)
    return tuple(out)


def libpython() -> str:
    """The path of this interpreter's shared library ('' if it has none)."""
    import sysconfig

    if os.name == "nt":
        name = f"python{sys.version_info.major}{sys.version_info.minor}.dll"
        for d in (sys.base_prefix, os.path.dirname(getattr(sys, "_base_executable", "") or "")):
            if d and os.path.isfile(os.path.join(d, name)):
                return os.path.join(d, name)
        return ""
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    multiarch = sysconfig.get_config_var("MULTIARCH") or ""
    names = [sysconfig.get_config_var(k) for k in ("INSTSONAME", "LDLIBRARY")]
    names = [n for n in names if n and (".so" in n or n.endswith(".dylib"))]
    dirs = [libdir, os.path.join(libdir, multiarch) if multiarch else "",
            os.path.join(sys.base_prefix, "lib")]
    for d in dirs:
        for n in names:
            path = os.path.join(d, n)
            if d and os.path.isfile(path):
                return path
    return ""


def probe() -> None:
    """Print what the C loader needs to know of this interpreter."""
    print(f"version={sys.version.split()[0]}")
    print(f"executable={sys.executable}")
    print(f"libpython={libpython()}")
    print(f"missing={missing()}")


# ---------------------------------------------------------------------------- in the host
def before_instantiate(resources: str, model: str) -> str:
    """Before pythonfmu imports the slave module (named in ``slavemodule.txt``): if a module of
    that name from another copy of the FMU is loaded, drop it from ``sys.modules`` so that this
    copy's is imported. Returns a warning, or ''."""
    try:
        with open(os.path.join(resources, "slavemodule.txt"), encoding="utf-8") as f:
            name = f.read().strip()
    except OSError as exc:
        return f"cannot read slavemodule.txt: {exc}"
    mod = sys.modules.get(name)
    here = os.path.normcase(os.path.abspath(resources))
    if mod is not None:
        where = os.path.normcase(os.path.dirname(os.path.abspath(getattr(mod, "__file__", "") or "")))
        if where != here:
            del sys.modules[name]
    return ""


def slave_module(resources: str):
    """The slave module imported from this FMU's resources folder, or None."""
    try:
        with open(os.path.join(resources, "slavemodule.txt"), encoding="utf-8") as f:
            name = f.read().strip()
    except OSError:
        return None
    mod = sys.modules.get(name)
    if mod is None:
        return None
    where = os.path.normcase(os.path.dirname(os.path.abspath(getattr(mod, "__file__", "") or "")))
    return mod if where == os.path.normcase(os.path.abspath(resources)) else None


def state_error(state) -> str:
    """The reason why a deserialised FMU state was rejected by the model's checks, or ''."""
    if isinstance(state, dict) and "invalid" in state:
        return str(state["invalid"])
    return ""


# ---------------------------------------------------------------------------- private import
def _digest(resources: str) -> str:
    """A BLAKE2b digest of every file under the resources folder (caches left out). CPython's own
    BLAKE2, not hashlib: hashlib loads OpenSSL, which the FMUs keep out of a host's process."""
    try:
        from _blake2 import blake2b
    except ImportError:  # pragma: no cover - a Python without the built-in module
        from hashlib import blake2b
    h = blake2b(digest_size=32)
    for root, dirs, files in os.walk(resources):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            path = os.path.join(root, name)
            h.update(os.path.relpath(path, resources).replace(os.sep, "/").encode() + b"\0")
            with open(path, "rb") as f:
                h.update(f.read() + b"\0")
    return h.hexdigest()


def load_slave(resources: str, module: str, name: str, packages) -> type:
    """The class ``name`` of ``module``, imported from the FMU's own packages under a private
    top-level name (one per distinct content of the resources folder)."""
    import importlib
    import types

    prefix = f"_flexpend_{name}_{_digest(resources)[:16]}"
    if prefix not in sys.modules:
        root = types.ModuleType(prefix, f"the packages of the FMU {name}, from {resources}")
        root.__path__ = []
        root.__file__ = None
        sys.modules[prefix] = root
        sys.meta_path.insert(0, _PrivateFinder(prefix, resources, tuple(packages)))
    mod = importlib.import_module(f"{prefix}.{module}")
    return getattr(mod, name)


class _PrivateFinder:
    """Finds ``<prefix>.<package>...`` in the FMU's resources folder."""

    def __init__(self, prefix, resources, packages):
        self.prefix, self.resources, self.packages = prefix, resources, packages

    def find_spec(self, fullname, path=None, target=None):
        import importlib.util

        if not fullname.startswith(self.prefix + "."):
            return None
        parts = fullname[len(self.prefix) + 1:].split(".")
        if parts[0] not in self.packages:
            return None
        base = os.path.join(self.resources, *parts)
        init = os.path.join(base, "__init__.py")
        if os.path.isfile(init):
            return importlib.util.spec_from_file_location(
                fullname, init, loader=_RewritingLoader(self, init),
                submodule_search_locations=[base])
        if os.path.isfile(base + ".py"):
            return importlib.util.spec_from_file_location(
                fullname, base + ".py", loader=_RewritingLoader(self, base + ".py"))
        return None

    def invalidate_caches(self):
        pass


class _RewritingLoader:
    """Executes a source file with its absolute imports of the shipped packages moved under the
    private prefix (``from plant_fmu.x import y`` -> ``from <prefix>.plant_fmu.x import y``)."""

    def __init__(self, finder, path):
        self.finder, self.path = finder, path

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        with open(self.path, "rb") as f:
            tree = ast.parse(f.read(), self.path)
        tree = ast.fix_missing_locations(_Rewrite(self.finder.prefix,
                                                  self.finder.packages).visit(tree))
        exec(compile(tree, self.path, "exec"), module.__dict__)

    def get_filename(self, fullname=None):
        return self.path

    def get_source(self, fullname=None):
        with open(self.path, encoding="utf-8") as f:
            return f.read()


class _Rewrite(ast.NodeTransformer):
    """Moves absolute imports of the shipped packages under the private prefix."""

    def __init__(self, prefix, packages):
        self.prefix, self.packages = prefix, packages

    def _ours(self, dotted):
        return dotted.split(".")[0] in self.packages

    def visit_ImportFrom(self, node):
        if node.level == 0 and node.module and self._ours(node.module):
            node.module = f"{self.prefix}.{node.module}"
        return node

    def visit_Import(self, node):
        out = []
        for alias in node.names:
            if not self._ours(alias.name):
                out.append(ast.Import(names=[alias]))
            elif alias.asname:        # import a.b as c
                out.append(ast.Import(names=[ast.alias(f"{self.prefix}.{alias.name}",
                                                       alias.asname)]))
            else:                     # import a.b  (binds a)
                top = alias.name.split(".")[0]
                out.append(ast.Import(names=[ast.alias(f"{self.prefix}.{alias.name}")]))
                out.append(ast.ImportFrom(module=self.prefix, names=[ast.alias(top)], level=0))
        return [ast.copy_location(n, node) for n in out]


if __name__ == "__main__":
    probe()
