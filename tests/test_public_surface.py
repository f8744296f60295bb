"""The public surface: what ``__all__`` says is public is what the API reference documents.

The surface is ``symplid.__all__`` (less ``__version__``) plus, for each namespace it names
(``symplid.priors``, ``symplid.samplers``, ...), that module's ``__all__`` under the
namespace's path. It is read here from those lists alone and compared with

* the entries the docs' generator writes (``docs/_ext/symplid_api.py``, parsed from its
  reStructuredText): the same dotted names, one section per namespace;
* the source: every public class and function has its own docstring, every public constant or
  registry a doc comment where it is assigned (what the reference shows for it);
* every module of the package: each has an ``__all__`` whose entries exist, and a name one
  module imports from another is in that other's ``__all__`` (so ``__all__`` is each module's
  real interface, and anything else is private to its module);
* the README, the docs and the examples: every ``symplid`` import path they show resolves.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

import symplid

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def _surface() -> dict[str, object]:
    """Dotted public path -> object, from ``symplid.__all__`` and its namespaces' ``__all__``."""
    out = {}
    for name in symplid.__all__:
        if name.startswith("__"):
            continue
        obj = getattr(symplid, name)
        if isinstance(obj, types.ModuleType):
            out.update({f"symplid.{name}.{n}": getattr(obj, n) for n in obj.__all__})
        else:
            out[f"symplid.{name}"] = obj
    return out


def _module_names() -> list[str]:
    """Every module of the package, from its files."""
    out = []
    for path in sorted((SRC / "symplid").rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        out.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return out


def test_the_namespaces_are_the_modules_named_in_all():
    modules = {n for n in symplid.__all__ if isinstance(getattr(symplid, n), types.ModuleType)}
    assert modules == set(symplid._NAMESPACES)
    for name in modules:
        namespace = importlib.import_module(f"symplid.{name}")  # a real module, not an alias
        assert namespace is getattr(symplid, name)
        inner = [n for n in namespace.__all__
                 if isinstance(getattr(namespace, n), types.ModuleType)]
        assert not inner, f"symplid.{name}.__all__ names modules: {inner}"


def test_import_symplid_starts_no_jax():
    code = "import sys, symplid; dir(symplid); print('jax' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_the_surface_has_no_private_and_no_repeated_names():
    surface = _surface()
    print(f"\npublic surface: {len(surface)} names ({len(symplid._NAMESPACES)} namespaces)")
    assert not [p for p in surface if p.rpartition(".")[2].startswith("_")]
    for name in [*symplid.__all__, *(n for m in symplid._NAMESPACES
                                      for n in getattr(symplid, m).__all__)]:
        assert isinstance(name, str)
    assert len(symplid.__all__) == len(set(symplid.__all__))


def _entries(rst: list[str]) -> list[str]:
    """The dotted names the generated reference has an entry for (modules apart): an autodoc
    entry names its full path, a written-out one its name and a ``:module:`` option."""
    out = []
    for line, after in zip(rst, [*rst[1:], ""], strict=True):
        found = re.fullmatch(r"\.\. (?:auto|py:)(\w+):: (\S+)", line)
        if not found or found.group(1) == "module":
            continue
        module = re.fullmatch(r"   :module: (\S+)", after)
        out.append(f"{module.group(1)}.{found.group(2)}" if module else found.group(2))
    return out


def test_the_api_reference_documents_exactly_the_surface():
    pytest.importorskip("sphinx")
    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    from symplid_api import api_rst, public_names

    rst = api_rst()
    entries = _entries(rst)
    surface = _surface()
    assert len(entries) == len(set(entries)) == len(surface)
    assert set(entries) == set(surface)
    sections = [rst[i - 1] for i, line in enumerate(rst) if set(line) == {"-"}]
    assert sections == ["``symplid``", *(f"``symplid.{n}``" for n in symplid.__all__
                                         if n in symplid._NAMESPACES)]
    namespaces = {f"symplid.{n}" for n in symplid._NAMESPACES}
    assert set(public_names()) == set(surface) | namespaces  # what check_reference.py reads
    # a constant's entry carries its doc comment (autodoc would show its type's docstring)
    for i, line in enumerate(rst):
        if line.startswith(".. py:data:: "):
            assert rst[i + 3].strip(), f"{line}: no text"


def _has_attribute_doc(module: types.ModuleType, name: str) -> bool:
    """Whether ``module`` assigns ``name`` at its top level with a ``#:`` comment before it or
    a string right after it (the two forms Sphinx reads as the attribute's doc)."""
    source = inspect.getsource(module)
    lines = source.splitlines()
    body = ast.parse(source).body
    for i, node in enumerate(body):
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if not isinstance(node, ast.Assign | ast.AnnAssign):
            continue
        if not any(isinstance(t, ast.Name) and t.id == name for t in targets):
            continue
        after = body[i + 1] if i + 1 < len(body) else None
        if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(
            after.value.value, str
        ):
            return True
        if node.lineno >= 2 and lines[node.lineno - 2].lstrip().startswith("#:"):
            return True
    return False


def _is_own_docstring(obj: object) -> bool:
    """A docstring that the object's author wrote (not a dataclass's or NamedTuple's
    generated ``Name(field, ...)`` line, not one inherited)."""
    doc = (obj.__doc__ or "").strip()
    generated = "\n" not in doc and doc.startswith(f"{obj.__name__}(") and doc.endswith(")")
    return bool(doc) and not generated


@pytest.mark.parametrize("path", sorted(_surface()))
def test_every_public_name_has_a_docstring(path):
    obj = _surface()[path]
    if inspect.isclass(obj) or (callable(obj) and hasattr(obj, "__name__")):
        assert _is_own_docstring(obj), f"{path}: no docstring"
        return
    name = path.rpartition(".")[2]
    holders = [m for n, m in sorted(sys.modules.items())
               if n.startswith("symplid") and getattr(m, name, None) is obj]
    assert any(_has_attribute_doc(m, name) for m in holders), f"{path}: no doc comment"


@pytest.mark.parametrize("name", _module_names())
def test_every_module_has_an_all_whose_names_exist(name):
    module = importlib.import_module(name)
    assert "__all__" in vars(module), f"{name} has no __all__"
    names = module.__all__
    assert len(names) == len(set(names)), f"{name}.__all__ repeats a name"
    assert not [n for n in names if not hasattr(module, n)], f"{name}.__all__: missing names"
    assert not [n for n in names if n.startswith("_") and n != "__version__"]


def _all_of(module: str) -> set[str] | None:
    path = SRC / Path(*module.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "__all__":
            try:
                return set(ast.literal_eval(node.value))
            except ValueError:  # built from other names (symplid/__init__.py)
                return set(importlib.import_module(module).__all__)
    return None


def _imported_names(path: Path) -> list[tuple[str, str]]:
    """(module, name) for every ``from symplid.x import name`` that is not a submodule, and
    every ``alias.name`` read from a module imported under an alias."""
    modules = set(_module_names())
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out, aliases = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("symplid"):
            for alias in node.names:
                if f"{node.module}.{alias.name}" in modules:
                    aliases[alias.asname or alias.name] = f"{node.module}.{alias.name}"
                else:
                    out.append((node.module, alias.name))
        elif isinstance(node, ast.Import):
            aliases |= {a.asname: a.name for a in node.names if a.asname and a.name in modules}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            module = aliases.get(node.value.id)
            if module and f"{module}.{node.attr}" not in modules:
                out.append((module, node.attr))
    return out


def test_names_one_module_imports_from_another_are_in_its_all():
    wrong = []
    for path in sorted((SRC / "symplid").rglob("*.py")):
        for module, name in _imported_names(path):
            public = _all_of(module)
            if public is None or name not in public:
                wrong.append(f"{path.relative_to(SRC)}: {module}.{name}")
    assert not wrong, "imported but not in that module's __all__:\n" + "\n".join(wrong)


def _shown_paths() -> set[str]:
    """Every ``symplid`` import or dotted path in the README, the docs' pages and examples."""
    files = [ROOT / "README.md", *sorted((ROOT / "examples").glob("*.py"))]
    files += [p for p in sorted((ROOT / "docs").rglob("*.md")) if "_build" not in p.parts]
    out = set()
    for path in files:
        text = path.read_text(encoding="utf-8")
        imports = re.findall(r"from (symplid[\w.]*) import (?:\(([^)]*)\)|([\w ,]+))", text)
        for base, grouped, inline in imports:
            names = (grouped or inline).replace("\n", ",").split(",")
            out |= {f"{base}.{n.split(' as ')[0].strip()}" for n in names if n.strip()}
        out |= set(re.findall(r"\bsymplid(?:\.[A-Za-z_]\w*)+", text))
    return {p for p in out if not any(part.startswith("_") for part in p.split("."))}


def _resolve(path: str) -> bool:
    """Whether a shown path resolves as a user's import would: each part an attribute of the
    last (a public namespace's name) or else a submodule of it, from the top down (so a
    name a namespace exports wins over an old module path of the same spelling)."""
    parts = path.split(".")
    obj = importlib.import_module(parts[0])
    for i, attr in enumerate(parts[1:], start=1):
        if hasattr(obj, attr):
            obj = getattr(obj, attr)
            continue
        try:
            obj = importlib.import_module(".".join(parts[:i + 1]))
        except ImportError:
            return False
    return True


def test_import_paths_shown_to_users_still_work():
    shown = _shown_paths()
    assert "symplid.predict.posterior_predictive" in shown  # the README's own
    missing = sorted(p for p in shown if not _resolve(p))
    assert not missing, f"paths in the README, docs or examples that do not resolve: {missing}"
