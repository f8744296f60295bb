"""The package's layers hold: no module imports from a higher layer, and no imports in a circle.

Imports are read from the source (every ``import``, function-local ones too), so the test
needs nothing but the standard library. The layers are those of
``docs/explanation/architecture.md``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

#: Layer of each top-level part of the package, bottom (0) to top.
LAYERS = {
    "registry": 0,
    "compiled": 0,
    "runtime": 0,
    "stopping": 0,
    "dynamics": 1,
    "filters": 2,
    "model": 3,
    "inference": 4,
    "io": 5,
    "plotting": 5,
    "workflow": 6,
    "experiments": 7,
    "cli": 8,
    "": 9,  # symplid/__init__.py: the public facade over everything
}


def _modules() -> dict[str, Path]:
    out = {}
    for path in (SRC / "symplid").rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str) -> set[str]:
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, base] if base else up)
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        for name in names:
            target = _resolve(name) if name.startswith("symplid") else None
            if target and target != module and not module.startswith(target + "."):
                found.add(target)
    return found


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS[parts[1] if len(parts) > 1 else ""]


GRAPH = {module: _imports(module) for module in MODULES}


def test_every_part_of_the_package_has_a_layer():
    parts = {m.split(".")[1] for m in MODULES if "." in m}
    assert parts <= set(LAYERS), f"give these a layer: {sorted(parts - set(LAYERS))}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_imports_from_a_higher_layer(module):
    upward = sorted(t for t in GRAPH[module] if _layer(t) > _layer(module))
    assert not upward, f"{module} (layer {_layer(module)}) imports from above: {upward}"


def test_no_import_cycles():
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in GRAPH:
        if module not in index:
            visit(module)
    assert not cycles, f"import cycles: {cycles}"


def test_a_registry_loads_its_builtin_entries_on_first_lookup(tmp_path, monkeypatch):
    """``Registry(load=...)``: a lower layer finds entries a higher one registers on import."""
    import sys

    from symplid.registry import Registry

    plugins = Registry("plugin", load=("symplid_test_builtin_plugins",))
    (tmp_path / "symplid_test_builtin_plugins.py").write_text(
        "from test_layers_registry import REGISTRY\nREGISTRY.register('builtin', 42)\n"
    )
    holder = type(sys)("test_layers_registry")
    holder.REGISTRY = plugins
    monkeypatch.setitem(sys.modules, "test_layers_registry", holder)
    monkeypatch.syspath_prepend(str(tmp_path))
    assert "symplid_test_builtin_plugins" not in sys.modules
    assert plugins.get_entry("builtin") == 42
    assert "builtin" in plugins and plugins.names() == ("builtin",)
    with pytest.raises(ValueError, match="unknown plugin 'other'"):
        plugins.get_entry("other")
