"""The package's shape: layers, module size, no hidden imports (README "Architecture")."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "src" / "roadcollab"

#: What each package may import from the rest of roadcollab (errors and _validation are open to all).
ALLOWED = {
    "lti": set(),
    "models": {"lti"},
    "estimation": {"lti", "models"},
    "detection": {"lti", "models"},
    "wire": {"lti"},
    "privacy": {"lti", "models", "estimation", "wire"},
    "collaboration": {"lti", "models", "estimation", "wire", "privacy"},
    "io": {"lti", "models"},
    "geo": {"lti", "models", "io"},
    "store": {"lti", "models", "io", "geo"},
    "experiments": {"lti", "models", "estimation", "detection", "wire", "privacy", "collaboration", "io", "geo",
                    "store"},
    "network": {"lti", "models", "estimation", "detection", "wire", "privacy", "collaboration", "io", "geo", "store",
                "experiments"},
    "reporting": {"lti", "models", "estimation", "detection", "wire", "privacy", "collaboration", "io", "experiments",
                  "geo", "store", "network"},
    "cli": {"lti", "models", "estimation", "detection", "wire", "privacy", "collaboration", "io", "experiments",
            "reporting", "geo", "store", "network"},
}
BASE = {"errors", "_validation", "__version__"}
#: Inside experiments/: the studies (one subpackage each) that a study may import, besides the shared
#: modules at the top of experiments/ (config, seeds, runner, pipeline), which import no study ("" below).
STUDIES_ALLOWED = {
    "": set(),
    "drives": set(),
    "bench": set(),
    "anomalies": set(),
    "reproduction": {"drives"},
    "security": {"anomalies", "drives"},
    "sweep": {"reproduction"},
}
#: Imports allowed inside functions: optional or heavy third-party modules only.
LAZY_OK = {"control", "slycot", "numba", "dask", "matplotlib", "phe", "cryptography", "rich", "tomllib", "tomli", "gmpy2",
           "psycopg", "paho", "amqtt", "pwdlib"}
#: Heavy submodules of a core dependency that may be imported inside functions (SciPy's ``signal`` and
#: ``stats`` packages take about 1 s to import, ``interpolate`` with ``optimize`` 0.1-0.13 s; the functions
#: that use them import them when first called, so ``reproduce`` and ``bench`` import none of them).
LAZY_OK_SUBMODULES = {"scipy.signal", "scipy.stats", "scipy.interpolate", "scipy.optimize"}
#: Packages whose functions may import roadcollab modules (relative imports, still subject to the layers):
#: the command-line entry point imports a command's study and report modules when that command runs, so
#: ``roadcollab --help`` and small commands load only what they use.
LAZY_LOCAL_OK = {"cli"}
MAX_MODULE_LINES = 450


def _modules():
    return sorted(p for p in ROOT.rglob("*.py"))


def _package(path: Path) -> str:
    parts = path.relative_to(ROOT).parts
    return parts[0] if len(parts) > 1 else path.stem


def _imported_packages(path: Path):
    depth = len(path.relative_to(ROOT).parts) - 1
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            if node.level == depth + 1:
                head = (node.module or "").split(".")[0]
                yield from ([head] if head else [a.name for a in node.names])
            elif node.level > depth + 1:
                raise AssertionError(f"{path}: relative import beyond the package")


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_layers(path):
    pkg = _package(path)
    if pkg not in ALLOWED:
        return
    bad = {m for m in _imported_packages(path) if m not in ALLOWED[pkg] | BASE | {pkg}}
    assert not bad, f"{path.relative_to(ROOT)} ({pkg}) imports {sorted(bad)}; allowed {sorted(ALLOWED[pkg])}"


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_module_size(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_MODULE_LINES, f"{path.relative_to(ROOT)} has {n} lines"


def _lazy_import_ok(name: str, package: str) -> bool:
    """May a function of ``package`` import ``name`` (``"."`` for a relative import)?"""
    if name == ".":
        return package in LAZY_LOCAL_OK
    return name.split(".")[0] in LAZY_OK or any(name == m or name.startswith(m + ".") for m in LAZY_OK_SUBMODULES)


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_hidden_imports(path):
    tree = ast.parse(path.read_text())
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = ["." if node.level else (node.module or "")]
            else:
                continue
            for n in names:
                assert _lazy_import_ok(n, _package(path)), \
                    f"{path.relative_to(ROOT)}:{node.lineno} imports {n!r} inside {fn.name}()"


@pytest.mark.parametrize("name, package, ok", [
    ("matplotlib.pyplot", "reporting", True), ("scipy.signal", "models", True), ("scipy.stats", "privacy", True),
    ("scipy.linalg", "models", False), ("numpy", "cli", False), (".", "cli", True), (".", "experiments", False)])
def test_lazy_import_rule(name, package, ok):
    assert _lazy_import_ok(name, package) is ok



EXPERIMENTS = ROOT / "experiments"


def _study(path: Path) -> str:
    """The study subpackage of experiments/ that ``path`` is in ("" for the shared modules at its top)."""
    parts = path.relative_to(EXPERIMENTS).parts
    return parts[0] if len(parts) > 1 else ""


def _study_import_ok(study: str, imported: str) -> bool:
    """May a module of ``study`` import a module of study ``imported`` ("" the shared modules)?"""
    return imported in ("", study) or imported in STUDIES_ALLOWED[study]


def test_studies_are_listed():
    subpackages = {p.name for p in EXPERIMENTS.iterdir() if (p / "__init__.py").exists()}
    assert subpackages == set(STUDIES_ALLOWED) - {""}


@pytest.mark.parametrize("path", sorted(EXPERIMENTS.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_study_layers(path):
    study = _study(path)
    pkg = _module_name(path) if path.name == "__init__.py" else _module_name(path).rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if not (isinstance(node, ast.ImportFrom) and node.level):
            continue
        base = pkg.split(".")
        mod = ".".join(base[:len(base) - (node.level - 1)] + ([node.module] if node.module else []))
        parts = mod.split(".")
        if parts[:2] != ["roadcollab", "experiments"]:
            continue
        names = [parts[2]] if len(parts) > 2 else [a.name for a in node.names]
        for name in names:
            imported = name if name in STUDIES_ALLOWED else ""
            assert _study_import_ok(study, imported), \
                f"{path.relative_to(ROOT)} ({study or 'shared'}) imports the {imported} study; " \
                f"allowed {sorted(STUDIES_ALLOWED[study])}"


@pytest.mark.parametrize("study, imported, ok", [
    ("security", "anomalies", True), ("anomalies", "security", False), ("", "drives", False),
    ("sweep", "", True), ("sweep", "sweep", True), ("reproduction", "sweep", False)])
def test_study_import_rule(study, imported, ok):
    assert _study_import_ok(study, imported) is ok

MAX_FUNCTION_LINES = 80


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_function_length(path):
    """Functions (docstring included) stay under 80 lines unless a ``# Long:`` comment says why."""
    lines = path.read_text().splitlines()
    for fn in ast.walk(ast.parse("\n".join(lines))):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = fn.end_lineno - fn.lineno + 1
            body = lines[fn.lineno - 1:fn.end_lineno]
            assert n <= MAX_FUNCTION_LINES or any("# Long:" in b for b in body), \
                f"{path.relative_to(ROOT)}:{fn.lineno} {fn.name}() has {n} lines"


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = [p for p in rel.parts if p != "__init__"]
    return ".".join(["roadcollab", *parts])


def _module_level_imports(path: Path) -> set[str]:
    """Modules of roadcollab imported at module level (not under ``if TYPE_CHECKING``)."""
    name = _module_name(path)
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom) and node.level:
            base = pkg.split(".")
            base = base[:len(base) - (node.level - 1)]
            mod = ".".join(base + ([node.module] if node.module else []))
            if node.module:
                out.add(mod)
            for a in node.names:  # ``from . import x`` may name a submodule
                out.add(f"{mod}.{a.name}")
    return out


def test_no_import_cycles():
    modules = {_module_name(p): p for p in _modules()}
    graph = {m: {d for d in _module_level_imports(p) if d in modules and d != m} for m, p in modules.items()}
    # A package's __init__ re-exporting its modules is not a cycle of its modules.
    graph = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in graph.items()}
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in graph[m]:
            if state.get(d) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(d):] + [d]))
            if d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
