"""The ``symplid-api`` directive: the API reference of exactly the public surface.

The public surface is ``symplid.__all__``; a name there that is a module is a namespace
(``symplid.samplers``, ``symplid.predict``, ...) whose own ``__all__`` is public too. The
directive writes one autodoc entry per name under its public path (``symplid.Posterior``, not
the module that defines it), grouped by kind, so a name added to ``__all__`` appears without
editing a page. :func:`public_names` is what ``docs/check_reference.py`` compares the built
inventory against.
"""

from __future__ import annotations

import importlib
import inspect
import types
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

_KINDS = (
    ("Models and potentials", "class"),
    ("Functions", "function"),
    ("Exceptions and warnings", "exception"),
    ("Registries and constants", "data"),
)


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
    out = {package: [n for n in top.__all__ if not n.startswith("__")]}
    for name in top.__all__:
        obj = getattr(top, name)
        if isinstance(obj, types.ModuleType):
            out[f"{package}.{name}"] = [n for n in getattr(obj, "__all__", [])
                                        if not n.startswith("_")]
    return out


def public_names(package: str = "symplid") -> list[str]:
    """Every documented dotted name: ``symplid.X`` and ``symplid.<namespace>.Y``."""
    return [f"{ns}.{n}" for ns, names in namespace_names(package).items() for n in names]


def _entry(path: str, obj: Any) -> list[str]:
    kind = _kind(obj)
    if kind == "class":
        return [f".. autoclass:: {path}", "   :members:", ""]
    if kind == "exception":
        return [f".. autoexception:: {path}", ""]
    if kind == "function":
        return [f".. autofunction:: {path}", ""]
    return [f".. autodata:: {path}", "   :no-value:", ""]


def _section(title: str, lines: list[str], level: str) -> list[str]:
    return [title, level * len(title), "", *lines]


def api_rst(package: str = "symplid") -> list[str]:
    """The reStructuredText of the whole reference (one section per kind and namespace)."""
    spaces = namespace_names(package)
    top = importlib.import_module(package)
    lines = [f".. py:module:: {package}", "   :no-index:", ""]
    by_kind: dict[str, list[str]] = {k: [] for _, k in _KINDS}
    for name in spaces.pop(package):
        obj = getattr(top, name)
        if _kind(obj) != "module":
            by_kind[_kind(obj)] += _entry(f"{package}.{name}", obj)
    for title, kind in _KINDS:
        if by_kind[kind]:
            lines += _section(title, by_kind[kind], "-")
    for space, names in spaces.items():
        module = getattr(top, space.rsplit(".", 1)[1])
        doc = (inspect.getdoc(module) or "").split("\n\n")[0]
        body = [f".. py:module:: {space}", "", doc, ""]
        for name in names:
            body += _entry(f"{space}.{name}", getattr(module, name))
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
