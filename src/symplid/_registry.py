"""Registries: the one place where each kind of choice is listed.

Every list of choices in symplid (integrators, named systems, prior families, likelihood
backends, samplers, experiments) is a :class:`Registry`. Settings validation, the command
line's help and the sweep keys read the registry, so a new entry — registered from any
module, a test file or a notebook — is usable everywhere at once::

    from symplid.dynamics._integrators import INTEGRATORS, Integrator

    INTEGRATORS.register("my-method", Integrator("my-method", 2, False, my_step))

How built-in entries are registered (one pattern for every registry):

* **In the registry's own module.** The module that creates a registry ends with the
  ``register`` calls of its built-in entries, one per entry, importing what they are built
  from (its own layer or below). Whoever can read the registry has imported that module, so
  the built-ins are always there, and the list of them is read in one place.
* **A higher layer registers its own entries by an explicit call.** Entries built from a
  layer above the registry (the studies' experiments, which the workflow's sweep runs) are
  registered by a ``register_*()`` function of that layer, called at its entry point: the
  command line calls :func:`symplid.studies.register_studies` before it reads a sweep spec.
* **Never by name, never as an import's side effect.** A registry imports nothing by name,
  and no module is imported only so that it registers something; ``replace=True`` is for a
  user who means to replace an entry, not for wiring. ``tests/test_layers.py`` holds this.

This module imports nothing from symplid: every layer may use it.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator, Mapping
from typing import Generic, TypeVar, overload

__all__ = ["Registry"]

T = TypeVar("T")


def normalise(name: str) -> str:
    """The lookup form of a name: lower case, ``_`` and spaces as ``-``."""
    return str(name).strip().lower().replace("_", "-").replace(" ", "-")


class Registry(Mapping[str, T], Generic[T]):
    """Named entries of one kind, in registration order, with aliases and helpful errors.

    A read-only :class:`~collections.abc.Mapping` from canonical names to entries; names are
    matched after :func:`~symplid._registry.normalise` and through aliases.

    Parameters
    ----------
    kind
        What an entry is, for messages (``"integrator"``, ``"prior family"``).
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, T] = {}
        self._aliases: dict[str, str] = {}

    @overload
    def register(self, name: str, entry: T, *, aliases: tuple[str, ...] = (),
                 replace: bool = False) -> T: ...

    @overload
    def register(self, name: str, entry: None = None, *, aliases: tuple[str, ...] = (),
                 replace: bool = False) -> Callable[[T], T]: ...

    def register(self, name, entry=None, *, aliases=(), replace=False):
        """Add ``entry`` under ``name`` (and ``aliases``); without ``entry``, a decorator.

        Registering a name that exists is an error unless ``replace=True``.
        """

        def add(obj: T) -> T:
            key = normalise(name)
            if not key:
                raise ValueError(f"a {self.kind} needs a non-empty name")
            taken = key in self._entries or key in self._aliases
            if taken and not replace:
                raise ValueError(f"a {self.kind} named {name!r} is registered already "
                                 "(pass replace=True to replace it)")
            self._aliases.pop(key, None)
            self._entries[key] = obj
            for alias in aliases:
                self._aliases[normalise(alias)] = key
            return obj

        return add if entry is None else add(entry)

    def unregister(self, name: str) -> T:
        """Remove an entry and its aliases (tests that register a toy entry clean up)."""
        key = self.canonical(name)
        self._aliases = {a: k for a, k in self._aliases.items() if k != key}
        return self._entries.pop(key)

    def canonical(self, name: str) -> str:
        """The registered name that ``name`` (or an alias) stands for; ``ValueError`` if none."""
        key = normalise(name)
        key = self._aliases.get(key, key)
        if key not in self._entries:
            raise ValueError(self.unknown_message(name))
        return key

    def unknown_message(self, name: object) -> str:
        """``unknown integrator 'lepfrog' (did you mean 'leapfrog'?); choose one of ...``."""
        close = difflib.get_close_matches(normalise(str(name)), list(self._entries), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return f"unknown {self.kind} {name!r}{hint}; choose one of {', '.join(self.names())}"

    def get_entry(self, name: str) -> T:
        """The entry registered as ``name`` (or an alias); ``ValueError`` listing the choices."""
        return self._entries[self.canonical(name)]

    def names(self) -> tuple[str, ...]:
        """The canonical names, in registration order (built-in entries first)."""
        return tuple(self._entries)

    def __getitem__(self, name: str) -> T:
        try:
            return self.get_entry(name)
        except ValueError:
            raise KeyError(name) from None

    def __contains__(self, name: object) -> bool:
        if not isinstance(name, str):
            return False
        key = normalise(name)
        return self._aliases.get(key, key) in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}: {', '.join(self._entries)})"
