"""Cross-references in docstrings: a link where the target is documented, text where it is not.

The docstrings name internal functions and classes (``:func:`symplid.runtime.configure_xla```)
and outside ones (``:class:`numpy.ndarray```) that the reference does not document: the
reference shows the public surface only. With ``nitpicky = True`` each of those would be a
warning. This handler resolves such a reference by importing what it names:

* an object documented under another (public) path -> a link to that entry
  (``symplid.model._posterior.Posterior`` -> ``symplid.Posterior``);
* an object that exists but is not documented -> its name as code, no link;
* a name that does not exist -> left alone, so Sphinx reports it (a broken reference fails
  the build under ``-W``).
"""

from __future__ import annotations

import builtins
import importlib
import sys
from typing import Any

_MISSING = object()
_ALIASES = {"np": "numpy", "jnp": "jax.numpy", "npt": "numpy.typing"}


def _import(path: str) -> Any:
    """The object at a dotted path, or ``_MISSING``."""
    parts = path.split(".")
    if parts[0] in _ALIASES:
        parts = _ALIASES[parts[0]].split(".") + parts[1:]
    if len(parts) == 1 and hasattr(builtins, parts[0]):
        return getattr(builtins, parts[0])
    for cut in range(len(parts), 0, -1):
        modname = ".".join(parts[:cut])
        try:
            obj = importlib.import_module(modname)
        except Exception:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr, _MISSING)
            if obj is _MISSING:
                break
        if obj is not _MISSING:
            return obj
    return _MISSING


def _candidates(target: str, module: str | None, cls: str | None, source: str) -> list[str]:
    """Where ``target`` may live: relative to the defining object of the docstring that names
    it (read from the node's source, ``"...:docstring of symplid.model._posterior.Posterior"``),
    to the page's current module and class, under any symplid module (a leading dot), or as
    it is."""
    target = target.lstrip("~")
    out = []
    if "docstring of " in source:
        parts = source.rsplit("docstring of ", 1)[1].split(":")[0].split(".")
        out += [".".join([*parts[:i], target.lstrip(".")]) for i in range(len(parts), 0, -1)]
    if target.startswith("."):
        target = target.lstrip(".")
        names = [m for m in list(sys.modules) if m.startswith("symplid")]
        out += [f"{m}.{target}" for m in sorted(names)]
    if module and cls:
        out.append(f"{module}.{cls}.{target}")
    if module:
        parts = module.split(".")
        out += [".".join([*parts[:i], target]) for i in range(len(parts), 0, -1)]
    out.append(target)
    return out


def _documented(env: Any) -> dict[int, tuple[str, str]]:
    cache = getattr(env, "_symplid_documented", None)
    if cache is None:
        cache = {}
        for name, entry in env.get_domain("py").objects.items():
            obj = _import(name)
            if obj is not _MISSING and not isinstance(obj, (int, float, str, bool)):
                cache.setdefault(id(obj), (name, entry.objtype))
        env._symplid_documented = cache
    return cache


def missing_reference(app: Any, env: Any, node: Any, contnode: Any) -> Any:
    """Resolve a py reference that Sphinx did not find (see the module docstring)."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"]
    source = node.source or ""
    for path in _candidates(target, node.get("py:module"), node.get("py:class"), source):
        obj = _import(path)
        if obj is _MISSING:
            continue
        hit = _documented(env).get(id(obj))
        if hit is not None:
            py = env.get_domain("py")
            ref = py.resolve_xref(env, node["refdoc"], app.builder, "obj", hit[0], node,
                                  contnode)
            if ref is not None:
                return ref
        return contnode
    root = target.lstrip("~.").split(".")[0]
    if root not in ("", "symplid") and _import(root) is not _MISSING and "." in target:
        return contnode  # a name inside an outside package (jax's private module paths)
    return None


def setup(app: Any) -> dict[str, Any]:
    app.connect("missing-reference", missing_reference)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
