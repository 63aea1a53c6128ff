"""The package layering holds: no import cycles, and no module imports from a layer above it.

Function-level (deferred) imports count too: a deferred upward import is still an upward
dependency. The layers are the ones README.md states (Architecture).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Layer of every top-level module or package of gaintune (and api), lowest first.
LAYERS: dict[str, int] = {
    "gaintune.cache": 0, "gaintune.cma": 0, "gaintune.errors": 0, "gaintune.files": 0, "gaintune.fmt": 0, "gaintune.lti": 0, "gaintune.statespace": 0, "gaintune.provenance": 0, "gaintune.spec_design": 0,
    "gaintune.spec": 1, "gaintune.spec_doc": 2,
    "gaintune.plants": 2,
    "gaintune.controllers": 3,
    "gaintune.classical": 4,
    "gaintune.sim": 5,
    "gaintune.verify": 6,
    "gaintune.objective": 7,
    "gaintune.boundary": 8, "gaintune.search_box": 8, "gaintune.repair": 8,
    "gaintune.envs": 9, "gaintune.baselines": 9,
    "gaintune.search": 10,
    "gaintune.export": 11, "gaintune.report": 11, "gaintune.bench": 11,
    "gaintune.cli": 12, "gaintune_api": 12,
    "gaintune": 13, "gaintune.__main__": 13,
}


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
