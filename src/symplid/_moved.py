"""The old import paths of the modules made private (``symplid.model.priors`` is now
``symplid.model._priors``): still importable for one version, with a ``DeprecationWarning``.

One finder, at the end of ``sys.meta_path`` (installed by ``import symplid``), so it is asked
only about a ``symplid`` module that no file provides: when its package holds ``_name.py``
for the missing ``name``, the import gives that module, under both names. The public paths
are the namespaces of ``symplid.__all__``; these old ones go in the next version.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

__all__ = ["MovedModuleWarning", "install"]


class MovedModuleWarning(DeprecationWarning):
    """An internal module imported by its old, public-looking path (``symplid.model.priors``)."""


def _private_path(fullname: str) -> str | None:
    """``symplid.a._b`` for ``symplid.a.b`` when no file provides the latter and ``_b.py`` is in
    package ``symplid.a`` (already imported: Python imports a parent before its child)."""
    package, _, name = fullname.rpartition(".")
    if not package.startswith("symplid") or name.startswith("_") or package not in sys.modules:
        return None
    for folder in getattr(sys.modules[package], "__path__", None) or ():
        base = Path(folder)
        if (base / f"{name}.py").exists() or (base / name).is_dir():
            return None
        if (base / f"_{name}.py").exists():
            return f"{package}._{name}"
    return None


class _OldPaths(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname: str, path: Sequence[str] | None = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if _private_path(fullname) is None:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> None:
        return None  # the default module, replaced by the real one in exec_module

    def exec_module(self, module: ModuleType) -> None:
        old = module.__name__
        new = _private_path(old)
        warnings.warn(f"{old} is internal and now {new}; import from symplid or its public "
                      "namespaces (the old path goes in the next version)",
                      MovedModuleWarning, stacklevel=2)
        # the import system returns what sys.modules holds once this returns: the real module
        sys.modules[old] = importlib.import_module(new)


def install() -> None:
    """Add the finder to ``sys.meta_path`` (once)."""
    if not any(isinstance(finder, _OldPaths) for finder in sys.meta_path):
        sys.meta_path.append(_OldPaths())
