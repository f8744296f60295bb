"""The ``symplid-api`` directive: the API reference of exactly the public surface.

The public surface is ``symplid.__all__``; a name there that is a module is a namespace
(``symplid.priors``, ``symplid.samplers``, ...) whose own ``__all__`` is public too. The
directive writes one section for the top level (grouped by kind) and one per namespace, with
one entry per name under its public path (``symplid.Posterior``, not the module that defines
it), so a name added to an ``__all__`` appears without editing a page. An object public at two
paths (``symplid.Laplace`` and ``symplid.priors.Laplace``) is documented at the first and
listed at the second as the same object. :func:`public_names` is what
``docs/check_reference.py`` compares the built inventory against.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import types
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.pycode import ModuleAnalyzer
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

_KINDS = (
    ("Models and potentials", "class"),
    ("Functions", "function"),
    ("Exceptions and warnings", "exception"),
    ("Registries and constants", "data"),
)
_ROLE = {"class": "class", "exception": "exc", "function": "func", "data": "data"}


def _kind(obj: Any) -> str:
    if isinstance(obj, types.ModuleType):
        return "module"
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if callable(obj) and (inspect.isfunction(obj) or inspect.isbuiltin(obj)
                          or hasattr(obj, "__wrapped__")):
        return "function"
    return "data"


def namespace_names(package: str = "symplid") -> dict[str, list[str]]:
    """``{namespace: [public names]}``: the top level and every module named in its ``__all__``."""
    top = importlib.import_module(package)
    out = {package: [n for n in top.__all__ if not n.startswith("__")
                     and not isinstance(getattr(top, n), types.ModuleType)]}
    for name in top.__all__:
        obj = getattr(top, name)
        if isinstance(obj, types.ModuleType):
            out[f"{package}.{name}"] = [n for n in getattr(obj, "__all__", [])
                                        if not n.startswith("_")]
    return out


def public_names(package: str = "symplid") -> list[str]:
    """Every documented dotted name: ``symplid.X``, ``symplid.<namespace>`` and its ``Y``."""
    spaces = namespace_names(package)
    out = [f"{package}.{n}" for n in spaces.pop(package)]
    for space, names in spaces.items():
        out += [space, *(f"{space}.{n}" for n in names)]
    return out


def attribute_doc(obj: Any, name: str, package: str = "symplid") -> list[str]:
    """The doc comment (``#:``) or docstring of the module-level assignment that defines
    ``name`` (found in the loaded modules of ``package`` that hold ``obj`` under that name)."""
    for modname in sorted(sys.modules):
        module = sys.modules[modname]
        if not modname.startswith(package) or getattr(module, name, None) is not obj:
            continue
        doc = ModuleAnalyzer.for_module(modname).find_attr_docs().get(("", name))
        if doc:
            return [line for line in doc if line is not None]
    return []


def _plain(kind: str, path: str, text: list[str]) -> list[str]:
    """A Python-domain entry written out (no autodoc): ``name`` with its ``:module:``."""
    module, _, name = path.rpartition(".")
    return [f".. py:{kind}:: {name}", f"   :module: {module}", "", *(f"   {t}" for t in text), ""]


def _entry(path: str, obj: Any, first: dict[int, str]) -> list[str]:
    kind = _kind(obj)
    if id(obj) in first:  # public at an earlier path too: one entry, one link
        return _plain(kind, path, [f"The same object as :{_ROLE[kind]}:`{first[id(obj)]}`."])
    first[id(obj)] = path
    if kind == "class":
        return [f".. autoclass:: {path}", "   :members:", ""]
    if kind == "exception":
        return [f".. autoexception:: {path}", ""]
    if kind == "function":
        return [f".. autofunction:: {path}", ""]
    return _plain("data", path, attribute_doc(obj, path.rsplit(".", 1)[1]))


def _section(title: str, lines: list[str], level: str) -> list[str]:
    return [title, level * len(title), "", *lines]


def api_rst(package: str = "symplid") -> list[str]:
    """The reStructuredText of the whole reference: the top level by kind, then one section
    per namespace."""
    spaces = namespace_names(package)
    top = importlib.import_module(package)
    first: dict[int, str] = {}
    by_kind: dict[str, list[str]] = {k: [] for _, k in _KINDS}
    for name in spaces.pop(package):
        obj = getattr(top, name)
        by_kind[_kind(obj)] += _entry(f"{package}.{name}", obj, first)
    body = [".. py:module:: " + package, "   :no-index:", ""]
    for title, kind in _KINDS:
        if by_kind[kind]:
            body += _section(title, by_kind[kind], "~")
    lines = _section(f"``{package}``", body, "-")
    for space, names in spaces.items():
        module = getattr(top, space.rsplit(".", 1)[1])
        doc = (inspect.getdoc(module) or "").split("\n\n")[0]
        body = [f".. py:module:: {space}", "", doc, ""]
        for name in names:
            body += _entry(f"{space}.{name}", getattr(module, name), first)
        lines += _section(f"``{space}``", body, "-")
    return lines


class SymplidApi(SphinxDirective):
    """``.. symplid-api::`` -- the generated reference of the public surface."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(api_rst(), source="symplid-api"), node)
        return node.children


def setup(app: Any) -> dict[str, Any]:
    app.add_directive("symplid-api", SymplidApi)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
