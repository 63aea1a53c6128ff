"""The package layering holds: no import cycles, and no module imports from a layer above it.

Function-level (deferred) imports count too: a deferred upward import is still an upward
dependency. The layers are the ones README.md and docs/architecture.md state. The package root
holds only the base utilities, and every import names a module that exists.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Layer of every top-level module or package of gaintune (and api), lowest first.
LAYERS: dict[str, int] = {
    "gaintune.cache": 0, "gaintune.errors": 0, "gaintune.files": 0, "gaintune.fmt": 0, "gaintune.provenance": 0,
    "gaintune.lti": 0,
    "gaintune.spec": 1,
    "gaintune.plants": 2,
    "gaintune.controllers": 3,
    "gaintune.classical": 4,
    "gaintune.sim": 5,
    "gaintune.verification": 6,
    "gaintune.evaluation": 7,
    "gaintune.envs": 8, "gaintune.baselines": 8,
    "gaintune.search": 9,
    "gaintune.export": 10,
    "gaintune.tuners": 11, "gaintune.report": 11,
    "gaintune.bench": 12, "gaintune.sweep": 12,
    "gaintune.cli": 13, "gaintune_api": 13,
    "gaintune": 14, "gaintune.__main__": 14,
}

#: The only modules at the gaintune/ root besides __init__ and __main__: base utilities every layer may use.
ROOT_MODULES = {"gaintune.cache", "gaintune.errors", "gaintune.files", "gaintune.fmt", "gaintune.provenance"}


def _unit(module: str) -> str:
    """The layer unit a module belongs to (its top-level package or module under gaintune)."""
    parts = module.split(".")
    if parts[0] == "gaintune_api":
        return "gaintune_api"
    return ".".join(parts[:2]) if len(parts) > 1 else "gaintune"


def _modules() -> dict[str, Path]:
    out = {}
    # the api/ folder installs as the package gaintune_api (pyproject: package-dir)
    for pkg, folder in (("gaintune", "gaintune"), ("gaintune_api", "api")):
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT / folder).with_suffix("")
            name = ".".join((pkg, *rel.parts))
            out[name.removesuffix(".__init__")] = path
    return out


def _imports(name: str, path: Path) -> set[str]:
    found = set()
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = name.split(".") if is_pkg else name.split(".")[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            # ``from gaintune import spec`` imports the module gaintune.spec, not the package facade
            found |= {f"{base}.{a.name}" for a in node.names} if base in ("gaintune", "gaintune_api") else {base}
    return {m for m in found if m.split(".")[0] in ("gaintune", "gaintune_api", "api")}


def test_every_unit_has_a_layer():
    units = {_unit(m) for m in _modules()}
    assert units <= set(LAYERS), f"give these a layer in LAYERS and README.md: {sorted(units - set(LAYERS))}"


def test_no_module_imports_from_a_layer_above():
    upward = []
    for name, path in _modules().items():
        mine = LAYERS[_unit(name)]
        for dep in _imports(name, path):
            if LAYERS.get(_unit(dep), -1) > mine and _unit(dep) != _unit(name):
                upward.append(f"{name} -> {dep}")
    assert not upward, "upward imports:\n" + "\n".join(sorted(upward))


def test_no_import_cycles_between_modules():
    mods = _modules()
    graph = {n: {d for d in _imports(n, p) if d in mods and not n.startswith(d + ".") and d != n} for n, p in mods.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
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
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_every_package_folder_is_installed():
    """pyproject lists the packages explicitly (api/ maps to gaintune_api): a new folder must be added."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {n for n, p in _modules().items() if p.name == "__init__.py"}
    assert found == listed, f"pyproject [tool.setuptools] packages differ: missing {sorted(found - listed)}, extra {sorted(listed - found)}"


def test_nothing_imports_the_api_folder_by_its_folder_name():
    bad = sorted(n for n, p in _modules().items() if any(m.split(".")[0] == "api" for m in _imports(n, p)))
    assert not bad, f"import gaintune_api, not api: {bad}"


def test_the_package_root_holds_only_base_utilities():
    """Everything else lives in a package (docs/architecture.md says which)."""
    root = {n for n, p in _modules().items() if p.parent == ROOT / "gaintune" and p.name not in ("__init__.py", "__main__.py")}
    assert root == ROOT_MODULES, f"move these into a package, or into ROOT_MODULES if a base utility: {sorted(root ^ ROOT_MODULES)}"


def _import_module_strings(path: Path) -> set[str]:
    """Module names given as text to ``importlib.import_module`` (deferred imports)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            found.add(node.args[0].value)
    return found


def test_every_import_of_gaintune_names_a_module_that_exists():
    """A module renamed or moved leaves no import of its old name behind (tests included), e.g. after a merge."""
    mods = _modules()
    public = {f"gaintune.{n}" for n in ast.literal_eval(_assigned(ROOT / "gaintune" / "__init__.py", "_EXPORTS"))}
    files = dict(mods)
    files |= {f"tests.{'.'.join(p.relative_to(ROOT / 'tests').with_suffix('').parts)}": p for p in (ROOT / "tests").rglob("*.py")}
    missing = []
    for name, path in files.items():
        for dep in _imports(name, path) | _import_module_strings(path):
            if dep.split(".")[0] in ("gaintune", "gaintune_api") and dep not in mods and dep not in public:
                missing.append(f"{path.relative_to(ROOT)} -> {dep}")
    assert not missing, "imports of modules that do not exist:\n" + "\n".join(sorted(missing))


def _assigned(path: Path, target: str) -> str:
    """The source text of the value assigned to ``target`` at the top level of ``path``."""
    text = path.read_text()
    for node in ast.parse(text).body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            names = [t.id for t in (node.targets if isinstance(node, ast.Assign) else [node.target]) if isinstance(t, ast.Name)]
            if target in names:
                return ast.get_source_segment(text, node.value)
    raise AssertionError(f"{target} is not assigned in {path}")
