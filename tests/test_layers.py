"""The package's layers hold: no module imports from a higher layer, and no imports in a circle.

Imports are read from the source (every ``import``, function-local ones too), so the test
needs nothing but the standard library. The layers are those of
``docs/explanation/architecture.md``.

A module can also reach another by name, without an ``import`` statement:
``importlib.import_module("symplid.x")``, a lazy table (``"Name": "symplid.x"``), or a
``"symplid.x:function"`` reference that a sweep resolves on its workers. Every string
constant of the source that names a symplid module (with or without ``:function``) counts as
a reference to it and is held to the same layer order; the top-level package (its lazy
table) and the command line are the top and may name anything. The explicit wiring of the
registries (``symplid._registry``) is checked here too: no loading by name, every built-in
entry registered in its registry's own module, no ``replace=True`` and no import kept only
for its side effect.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"

#: Layer of each top-level part of the package, bottom (0) to top.
LAYERS = {
    "_registry": 0,
    "_compiled": 0,
    "_jsonfloat": 0,
    "_moved": 0,  # the old paths of the private modules (an import hook)
    "_namespace": 0,  # the lazy tables of the public namespaces
    "_kernel_region": 0,
    "runtime": 0,
    "_stopping": 0,
    "_saved_programs": 0,
    "dynamics": 1,
    "filters": 2,
    "model": 3,
    "inference": 4,
    "sampling": 5,  # the sampling runner: chunks, restarts, stopping rules, progress
    "io": 6,
    "plotting": 6,
    "workflow": 7,
    "studies": 8,  # the research studies, beside the library: only cli and the top use them
    "cli": 9,  # the command line: the only package that imports click
    "": 10,  # symplid/__init__.py: the public facade over everything
}


def _namespaces() -> tuple[str, ...]:
    """``symplid._NAMESPACES``, read from the source: the public namespaces."""
    tree = ast.parse((SRC / "symplid" / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "_NAMESPACES":
            return ast.literal_eval(node.value)
    return ()


#: A public namespace without a layer of its own (``symplid/priors.py``, re-exporting from the
#: layers) is part of the facade.
LAYERS |= {name: 10 for name in _namespaces() if name not in LAYERS}


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


TREES = {module: ast.parse(path.read_text(encoding="utf-8")) for module, path in MODULES.items()}
#: A string that names a symplid module, optionally with ``:attribute``.
BY_NAME = re.compile(r"symplid(\.[A-Za-z_]\w*)*(:[A-Za-z_]\w*)?")


def _by_name(module: str) -> set[str]:
    """The symplid modules that ``module`` names in a string constant (not docstrings)."""
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(TREES[module])
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    found: set[str] = set()
    for node in ast.walk(TREES[module]):
        if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                and id(node) not in docstrings and BY_NAME.fullmatch(node.value)):
            target = _resolve(node.value.partition(":")[0])
            if target and target != module and not module.startswith(target + "."):
                found.add(target)
    return found


def _imports(module: str) -> set[str]:
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(TREES[module]):
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


IMPORTS = {module: _imports(module) for module in MODULES}
NAMED = {module: _by_name(module) for module in MODULES}
GRAPH = {module: IMPORTS[module] | NAMED[module] for module in MODULES}


def test_every_part_of_the_package_has_a_layer():
    parts = {m.split(".")[1] for m in MODULES if "." in m}
    assert parts <= set(LAYERS), f"give these a layer: {sorted(parts - set(LAYERS))}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_imports_from_a_higher_layer(module):
    upward = sorted(t for t in IMPORTS[module] if _layer(t) > _layer(module))
    assert not upward, f"{module} (layer {_layer(module)}) imports from above: {upward}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if NAMED[m]))
def test_no_module_names_a_higher_layer(module):
    """``import_module("symplid.x")``, lazy tables, ``"symplid.x:fn"``: by name is no way up."""
    upward = sorted(t for t in NAMED[module] if _layer(t) > _layer(module))
    assert not upward, f"{module} (layer {_layer(module)}) names modules above: {upward}"


def test_the_by_name_scan_sees_the_references_it_must():
    """The scan is not blind: the top-level lazy table and a study's cell function (by
    ``"module:function"`` in its tests' specs, and by import) are found."""
    assert "symplid.dynamics._integrators" in NAMED["symplid"]
    assert "symplid.sampling" in NAMED["symplid"]
    assert BY_NAME.fullmatch("symplid.studies._paper_cells:run_cell")
    assert not BY_NAME.fullmatch("see symplid.studies.register_studies()")


def test_only_the_command_line_and_the_top_use_the_studies():
    users = sorted(m for m, targets in GRAPH.items() if _layer(m) < LAYERS["studies"]
                   and any(_layer(t) == LAYERS["studies"] for t in targets))
    assert not users, f"the core reaches symplid.studies from {users}"
    assert any(t.startswith("symplid.studies") for t in GRAPH["symplid.cli._study_commands"])


def test_only_the_command_line_imports_click():
    """click is the command line's: the layers below (the workflow too) are usable without it."""
    users = sorted(
        module for module in MODULES if not module.startswith("symplid.cli")
        for node in ast.walk(TREES[module])
        if (isinstance(node, ast.Import) and any(a.name.split(".")[0] == "click"
                                                 for a in node.names))
        or (isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "click"
            and not node.level)
    )
    assert not users, f"click imported outside symplid.cli: {sorted(set(users))}"
    assert any(isinstance(node, ast.Import) and node.names[0].name == "click"
               for node in ast.walk(TREES["symplid.cli._errors"]))


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


# ----------------------------------------------------------------------------- registries
def _calls(tree: ast.AST):
    return (node for node in ast.walk(tree) if isinstance(node, ast.Call))


def _registries() -> dict[str, str]:
    """Registry variable name -> the module that creates it (``NAME = Registry(...)``)."""
    found = {}
    for module, tree in TREES.items():
        for node in tree.body:
            value = node.value if isinstance(node, ast.Assign | ast.AnnAssign) else None
            if (isinstance(value, ast.Call) and isinstance(value.func, ast.Name)
                    and value.func.id == "Registry"):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for target in targets:
                    assert target.id not in found, f"two registries named {target.id}"
                    found[target.id] = module
    return found


REGISTRIES = _registries()


def test_every_registry_is_found():
    assert {"INTEGRATORS", "LIKELIHOOD_BACKENDS", "EXPERIMENTS", "SAMPLERS",
            "PRIOR_FAMILIES", "SYSTEMS"} <= set(REGISTRIES)
    assert REGISTRIES["LIKELIHOOD_BACKENDS"] == "symplid.model._backends"


def test_no_registry_loads_anything_by_name():
    for module, tree in TREES.items():
        for call in _calls(tree):
            if isinstance(call.func, ast.Name) and call.func.id == "Registry":
                assert [k.arg for k in call.keywords] == [], (
                    f"{module}: Registry({ast.unparse(call)[9:-1]}) takes its kind only")


def test_built_in_entries_are_registered_in_their_registrys_module():
    """``X.register(...)`` for a registry X appears in X's own module only: its list of
    built-ins is read in one place, and no other module registers as a side effect."""
    elsewhere = sorted(
        f"{module}: {ast.unparse(call.func)}"
        for module, tree in TREES.items()
        for call in _calls(tree)
        if isinstance(call.func, ast.Attribute) and call.func.attr == "register"
        and isinstance(call.func.value, ast.Name) and call.func.value.id in REGISTRIES
        and REGISTRIES[call.func.value.id] != module
    )
    assert not elsewhere, elsewhere


def test_nothing_registers_with_replace_or_is_imported_for_its_side_effect():
    replacing = sorted(module for module, tree in TREES.items() for call in _calls(tree)
                       if isinstance(call.func, ast.Attribute) and call.func.attr == "register"
                       and any(k.arg == "replace" for k in call.keywords))
    assert not replacing, f"register(..., replace=True) in {replacing}"
    kept = sorted(f"{module}:{n}" for module, path in MODULES.items()
                  for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
                  if "import" in line and "noqa" in line and "F401" in line)
    assert not kept, f"imports kept for a side effect: {kept}"


def test_the_core_registers_no_experiment_and_loads_no_study():
    """In a fresh interpreter, every module of the core imported: the experiments' registry
    is empty and no module of symplid.studies was loaded."""
    import subprocess
    import sys

    core = sorted(m for m in MODULES if 0 < _layer(m) < LAYERS["studies"])
    code = (f"import importlib, sys\nfor m in {core!r}:\n    importlib.import_module(m)\n"
            "from symplid.workflow._experiment import EXPERIMENTS\n"
            "print(len(EXPERIMENTS), sorted(m for m in sys.modules if "
            "m.startswith('symplid.studies')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["0", "[]"]
