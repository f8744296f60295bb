"""A namespace's public names imported when first used (PEP 562), from one table.

The top level (``symplid``) and the public namespaces beside it (``symplid.priors``,
``symplid.samplers``, ...) each hold a table ``_PUBLIC``: public name -> the module that
defines it. Their ``__all__`` is the table's keys, so a public name is written down once, and
importing a namespace imports nothing until one of its names is asked for (``import
symplid`` does not start JAX).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_attributes"]


def lazy_attributes(
    namespace: dict[str, Any],
    table: Mapping[str, str],
    modules: Mapping[str, str] | None = None,
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for the module whose globals are ``namespace``.

    A name of ``table`` is read from the module the table names for it; a name of
    ``modules`` is that module itself. Each value is kept in ``namespace`` once found, so
    later look-ups are plain attribute reads. Any other name is an ``AttributeError``.
    """
    owner = namespace["__name__"]
    modules = dict(modules or {})

    def __getattr__(name: str) -> Any:
        if name in table:
            value = getattr(importlib.import_module(table[name]), name)
        elif name in modules:
            value = importlib.import_module(modules[name])
        else:
            raise AttributeError(f"module {owner!r} has no attribute {name!r}")
        namespace[name] = value
        return value

    def __dir__() -> list[str]:  # the public names (and the module's dunders), not its helpers
        dunders = {name for name in namespace if name.startswith("__")}
        return sorted(dunders | set(table) | set(modules))

    return __getattr__, __dir__
