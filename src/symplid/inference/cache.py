"""Compiled programs of inference kept on their owner, by :func:`symplid.compiled.cached`.

The MAP search and the samplers accept any object with a posterior's interface; some cannot
keep a store (no ``__dict__``), and some keys (a sampler's settings) may not be hashable. For
those the program is built afresh on each call instead of failing.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any, TypeVar

from symplid.compiled import cached

F = TypeVar("F")


def cached_or_built(owner: Any, key: Hashable, build: Callable[[], F]) -> F:
    """``cached(owner, key, build)`` when ``owner`` can keep it and ``key`` is hashable."""
    try:
        hash(key)
        vars(owner)
    except TypeError:
        return build()
    return cached(owner, key, build)


__all__ = ["cached_or_built"]
