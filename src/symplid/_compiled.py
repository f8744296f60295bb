"""The one cache of compiled programs: stored on the object that owns them.

A model compiles its filter once per structure and data layout (kept on its Hamiltonian, so
that models of equal structure share it), a posterior its log density and gradient, a
sampler its chunk. Each keeps what it compiled **on the object that owns it**, under a key of
the static choices that shaped the program::

    fn = cached(self, ("filter", max_steps, uniform), lambda: jax.jit(build()))

or, for a function whose first argument is the owner and whose next ones are static,
:func:`jit_for`::

    energy = jit_for(potential, _energy)(coefficients, states, inv_mass)

so the compiled program lives exactly as long as its owner: there is no module-level
table that keeps user objects (and their data) alive, and nothing to clear by hand.
Works for frozen dataclasses too (the store is put in the instance ``__dict__``).

This module imports nothing from symplid: every layer may use it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

__all__ = [
    "cached",
    "cached_or_built",
    "clear",
    "jit_for",
]

F = TypeVar("F")

_STORE = "_symplid_compiled"


def cached(owner: Any, key: Hashable, build: Callable[[], F]) -> F:
    """The program cached on ``owner`` under ``key``, built by ``build()`` on first use."""
    store = _store(owner)
    if key not in store:
        store[key] = build()
    return store[key]


def cached_or_built(owner: Any, key: Hashable, build: Callable[[], F]) -> F:
    """:func:`cached` where ``owner`` can keep a store and ``key`` is hashable, else ``build()``.

    For functions that accept any object with a posterior's interface (some have no
    ``__dict__``) or settings that may not be hashable: the program is then built afresh.
    """
    try:
        hash(key)
        vars(owner)
    except TypeError:
        return build()
    return cached(owner, key, build)


def jit_for(owner: Any, fn: Callable[..., Any], *static: Hashable) -> Callable[..., Any]:
    """``jax.jit(partial(fn, owner, *static))``, compiled once per ``(fn, static)`` and kept on
    ``owner`` (a potential, a model) instead of in a module-level ``jax.jit`` whose cache
    would hold every owner it was ever called with."""
    import jax  # only when something is compiled: this module stays import-light

    key = (fn.__module__, fn.__qualname__, *static)
    return cached(owner, key, lambda: jax.jit(functools.partial(fn, owner, *static)))


def clear(owner: Any) -> None:
    """Forget everything compiled for ``owner`` (e.g. after changing a setting in place)."""
    _store(owner).clear()


def _store(owner: Any) -> dict[Hashable, Any]:
    try:
        namespace = vars(owner)
    except TypeError:
        raise TypeError(
            f"{type(owner).__name__} has no __dict__ to keep compiled programs in"
        ) from None
    return namespace.setdefault(_STORE, {})
