"""The one validator of settings: run settings (TOML, ``--set``) and sweep cells share it.

Each setting is described once by a :class:`Spec` (type, default, range, choices, doc, and
for a sweep cell key the run setting it stands for); :func:`check_value` checks one value
against it and returns it normalised. Choices are either a fixed tuple (``("gap", "step")``)
or a :class:`~symplid._registry.Registry` (integrators, samplers, prior families, systems),
so that a name registered anywhere is accepted everywhere and every error lists the
registry's names.

Why not pydantic v2: the messages are the product here (one line, ``"<source>: <dotted key>
must be > 0, got -0.25"``, the closest valid key suggested), and pydantic's errors would have
to be translated back into them type by type; the settings are also plain frozen
dataclasses that the rest of the library builds and ``dataclasses.replace``-s. A ~150-line
validator over dataclass field metadata, shared by the settings and the sweep, removes the
second validator without a new dependency or a translation layer.
"""

from __future__ import annotations

import difflib
import math
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from symplid._registry import Registry

__all__ = ["SettingsError", "Spec", "check_value", "setting", "suggest"]


class SettingsError(ValueError):
    """A bad setting. The message names the source (file or "command line") and the key."""

    def __init__(self, source: str, key: str | None, message: str) -> None:
        self.source = source
        self.key = key
        text = f"{source}: {key} {message}" if key else f"{source}: {message}"
        super().__init__(text)


@dataclass(frozen=True)
class Spec:
    """How one setting is checked: its type, default, range and choices.

    Parameters
    ----------
    type
        ``int``, ``float``, ``str``, ``bool`` or ``tuple`` (a list of numbers).
    default
        The value when the setting is not given (``None``: decided elsewhere, e.g. by a system).
    doc
        One line for help texts and tables of keys.
    minimum, strict
        Lower bound, and whether it is excluded (``dt > 0``) or included (``order ≥ 1``).
    choices
        Allowed strings: a tuple, or a :class:`Registry` whose names (and aliases) are accepted
        and normalised to the canonical name.
    setting
        For a sweep cell key: the dotted run setting it stands for (``"model.dt"``).
    words
        For a number: words accepted in its place (``initial_state.t0 = "first"``).
    other
        For a string with choices: a test of text accepted as written besides the choices
        (``model.potential``: a user's expression or ``file:PATH:NAME``).
    """

    type: Any
    default: Any = None
    doc: str = ""
    minimum: float | None = None
    strict: bool = False
    choices: tuple[str, ...] | Registry | None = None
    setting: str | None = None
    words: tuple[str, ...] = ()
    other: Any = None

    def names(self) -> tuple[str, ...]:
        """The allowed strings (a registry's names at the time of the call)."""
        if isinstance(self.choices, Registry):
            return self.choices.names()
        return tuple(self.choices or ())


def setting(default: Any, **kw: Any) -> Any:
    """A dataclass field carrying its :class:`Spec` (the type is the field's annotation)."""
    return field(default=default, metadata={"spec": Spec(None, default, **kw)})


def suggest(key: str, valid: Sequence[str], fallback: str = " (valid: {})") -> str:
    """``"; did you mean 'x'?"`` for the closest of ``valid``, else ``fallback`` listing them."""
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.6)
    if close:
        return f"; did you mean '{close[0]}'?"
    return fallback.format(", ".join(valid)) if fallback else ""


def check_value(
    value: Any,
    tp: Any,
    spec: Spec,
    key: str,
    source: str,
    error: type[SettingsError] = SettingsError,
) -> Any:
    """Check one value's type, choices and range; return it normalised.

    Integers stay integers, numbers become finite floats, strings are stripped and lower
    case (a registry's alias becomes its canonical name), lists of numbers become tuples of
    floats. ``key`` is how the value is named in the message (``"model.dt"``, ``"[base] dt"``).

    Raises
    ------
    SettingsError
        (or ``error``, a subclass) with a one-line message naming ``source`` and ``key``.
    """
    if spec.words and isinstance(value, str):
        word = value.strip().lower()
        if word not in spec.words:
            allowed = " or ".join(repr(w) for w in spec.words)
            raise error(source, key, f"must be a number or {allowed}, got {value!r}")
        return word
    if isinstance(tp, types.UnionType):  # a number or a word
        tp = float if float in typing.get_args(tp) else int
    if tp is bool:
        if not isinstance(value, bool):
            raise error(source, key, f"must be true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise error(source, key, f"must be an integer, got {value!r}")
        out: Any = value
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise error(source, key, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise error(source, key, f"must be finite, got {value!r}")
    elif tp is str:
        if not isinstance(value, str):
            raise error(source, key, f"must be a string, got {value!r}")
        if spec.other is not None and spec.other(value):
            return value.strip()
        out = _choose(value.strip().lower(), value, spec, key, source, error)
    elif typing.get_args(tp) == (str, Ellipsis):  # a list of texts, kept as written
        if not isinstance(value, list | tuple) or not all(isinstance(x, str) for x in value):
            raise error(source, key, f"must be a list of strings, got {value!r}")
        return tuple(x.strip() for x in value)
    else:  # tuple[float, ...]
        if not isinstance(value, list | tuple) or any(
            isinstance(x, bool) or not isinstance(x, int | float) for x in value
        ):
            raise error(source, key, f"must be a list of numbers, got {value!r}")
        out = tuple(float(x) for x in value)
        if not all(math.isfinite(x) for x in out):
            raise error(source, key, f"must hold finite numbers, got {value!r}")
        return out
    if spec.minimum is not None:
        ok = out > spec.minimum if spec.strict else out >= spec.minimum
        if not ok:
            sign = ">" if spec.strict else "≥"
            raise error(source, key, f"must be {sign} {spec.minimum:g}, got {value!r}")
    return out


def _choose(
    name: str, value: Any, spec: Spec, key: str, source: str, error: type[SettingsError]
) -> str:
    """A string checked against the spec's choices (a registry's alias → its canonical name)."""
    if spec.choices is None:
        return name
    registry = spec.choices if isinstance(spec.choices, Registry) else None
    if registry is not None and name in registry:
        return registry.canonical(name)
    if registry is None and name in spec.choices:
        return name
    names = spec.names()
    close = difflib.get_close_matches(name, list(names), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    unknown = f": not a known {registry.kind}" if registry is not None else ""
    raise error(
        source, key, f"must be one of {', '.join(map(repr, names))}, got {value!r}{unknown}{hint}"
    )
