"""The ``symplid-settings`` directive: the settings reference, generated from the schema.

Every key of :class:`symplid.workflow._settings_schema.Settings` with its type, default,
allowed values and meaning. The meaning is the ``doc`` of the key's
:func:`~symplid.workflow._validate.setting` (or the attribute docstring written under the
field); choices that come from a registry are listed as the registry holds them at build time.
Nothing here is typed by hand: a new key appears, a changed default changes the page.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.pycode import ModuleAnalyzer
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles


def _toml(value: Any) -> str:
    import tomli_w

    if hasattr(value, "to_dict"):  # a prior: its family and the parameters it uses
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.to_dict().items()) + " }"
    if isinstance(value, tuple):
        value = list(value)
    return tomli_w.dumps({"x": value}).strip()[4:]


def _type(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _allowed(spec: Any) -> str:
    parts = []
    if spec is None:
        from symplid.model._priors import PRIOR_FAMILIES

        names = ", ".join(f'``"{n}"``' for n in PRIOR_FAMILIES.names())
        return (f"a table ``{{ prior = ..., <its parameters> }}`` (or "
                f"``prior = \"normal(0, 1)\"``; the old key ``family`` is deprecated); "
                f"prior: {names}")
    names = spec.names()
    if names:
        parts.append(", ".join(f'``"{n}"``' for n in names))
    if spec.minimum is not None:
        parts.append(("> " if spec.strict else "≥ ") + f"{spec.minimum:g}")
    if spec.words:
        parts.append("or " + ", ".join(f'``"{w}"``' for w in spec.words))
    return "; ".join(parts)


def _cell(text: str) -> str:
    return " ".join(text.split()) or " "


def settings_rst() -> list[str]:
    """A section per settings table, a row per key."""
    from symplid.workflow import _settings_schema as schema

    attr_docs = ModuleAnalyzer.for_module(schema.__name__).find_attr_docs()
    lines: list[str] = []
    top = [f for f in dataclasses.fields(schema.Settings) if f.metadata.get("spec")]
    sections = [f for f in dataclasses.fields(schema.Settings) if not f.metadata.get("spec")]
    groups = [("Top level", schema.Settings, "", top)]
    for f in sections:
        cls = f.default_factory
        groups.append((f"[{f.name}]", cls, f"{f.name}.", list(dataclasses.fields(cls))))
    for title, cls, prefix, fields in groups:
        lines += [title, "-" * len(title), ""]
        if prefix:
            lines += [inspect.getdoc(cls) or "", ""]
        lines += [".. list-table::", "   :header-rows: 1", "   :widths: 22 18 25 35", "",
                  "   * - key", "     - default", "     - allowed", "     - meaning"]
        defaults = cls()
        for f in fields:
            spec = f.metadata.get("spec")
            doc = (spec.doc if spec is not None else "") or " ".join(
                attr_docs.get((cls.__name__, f.name), []))
            allowed = "; ".join(x for x in (_type(f.type), _allowed(spec)) if x)
            lines += [f"   * - ``{prefix}{f.name}``",
                      f"     - ``{_toml(getattr(defaults, f.name))}``",
                      f"     - {_cell(allowed)}",
                      f"     - {_cell(doc)}"]
        lines.append("")
    return lines


class SymplidSettings(SphinxDirective):
    """``.. symplid-settings::`` -- every settings key with its default and meaning."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        node = nodes.section()
        node.document = self.state.document
        text = StringList(settings_rst(), source="symplid-settings")
        nested_parse_with_titles(self.state, text, node)
        return node.children


def setup(app: Any) -> dict[str, Any]:
    app.add_directive("symplid-settings", SymplidSettings)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
