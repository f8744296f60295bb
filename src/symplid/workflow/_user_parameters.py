"""The parameters of a user's own model: the ``[model.parameters]`` table of the settings.

Each parameter of an expression or a file model (:mod:`symplid.dynamics._user_models`) is
declared with its prior, and optionally bounds and a starting value:

.. code-block:: toml

    [model.parameters]
    GM = { prior = "half-normal", scale = 1e-3 }             # bounded below by 0: log scale
    k  = { prior = "normal", loc = 1.0, scale = 0.5, lower = 0, initial = 0.8 }

``prior`` is a family of :data:`symplid.model._priors.PRIOR_FAMILIES` with the keys its class
takes (``loc``, ``scale``, ``mu``, ``sigma``, ``low``, ``high``), or text such as
``"normal(1, 0.5)"``. ``lower``/``upper`` restrict the prior to those bounds, renormalised
(:class:`~symplid.model._truncated.Truncated`); ``initial`` is the first start of the MAP search.
The parameters form θ's coefficient block in the order written; a parameter whose bounds are
(0, ∞) (a half-normal or log-normal prior, or ``lower = 0``) is moved on a log scale by the
samplers and the MAP search (:mod:`symplid.model._params`).
"""

from __future__ import annotations

import keyword
import math
import re
import unicodedata
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from symplid.dynamics._user_models import CONSTANTS, FUNCTIONS
from symplid.model._priors import Prior, as_prior
from symplid.model._truncated import bounded
from symplid.workflow._validate import SettingsError

__all__ = ["UserParameter", "initial_values", "parameter_priors", "parameters_from_table",
           "with_model_paths"]

_EXTRA = ("lower", "upper", "initial")
_COORDINATE = re.compile(r"^[qp][1-9][0-9]*$")


@dataclass(frozen=True)
class UserParameter:
    """One declared parameter: its name, prior, bounds and optional MAP start."""

    name: str
    prior: Prior
    lower: float = -math.inf
    upper: float = math.inf
    initial: float | None = None

    @property
    def bounded_prior(self) -> Prior:
        """The prior within ``[lower, upper]`` (the prior itself when they do not cut it)."""
        return bounded(self.prior, self.lower, self.upper)

    def to_dict(self) -> dict[str, Any]:
        """The table written to a run's settings (finite bounds and a start only)."""
        out = self.prior.to_dict()
        out["prior"] = out.pop("family")
        for key in _EXTRA:
            value = getattr(self, key)
            if value is not None and math.isfinite(value):
                out[key] = float(value)
        return out


def _number(value: Any, key: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SettingsError(source, key, f"must be a number, got {value!r}")
    return float(value)


def _one(name: str, table: Any, key: str, source: str) -> UserParameter:
    folded = unicodedata.normalize("NFKC", name)
    if folded != name:
        raise SettingsError(source, key, f"is not a usable parameter name: it is read as "
                            f"{folded!r} (a character that looks like another); type {folded!r}")
    if (not name.isidentifier() or keyword.iskeyword(name) or _COORDINATE.match(name)
            or name in FUNCTIONS or name in CONSTANTS or name.startswith("_")):
        raise SettingsError(source, key, "is not a usable parameter name (a letter, then letters,"
                            " digits or _; not q1.., p1.., a function or pi)")
    if not isinstance(table, Mapping):
        raise SettingsError(source, key, f"must be a table such as {{ prior = \"normal\", "
                            f"loc = 0, scale = 1 }}, got {table!r}")
    if "family" in table and "prior" not in table:  # the old key of the [priors.*] tables
        warnings.warn(f"{source}: {key}.family is deprecated; use {key}.prior", FutureWarning,
                      stacklevel=4)
        table = {("prior" if k == "family" else k): v for k, v in table.items()}
    if "prior" not in table:
        raise SettingsError(source, key, "has no prior: give one, e.g. { prior = \"normal\", "
                            "loc = 0, scale = 1 } (families: laplace, normal, half-normal, "
                            "uniform, log-normal)")
    extra = {k: _number(table[k], f"{key}.{k}", source) for k in _EXTRA if k in table}
    spec = {k: v for k, v in table.items() if k not in _EXTRA and k != "prior"}
    raw = table["prior"]
    try:
        if not isinstance(raw, str):
            raise ValueError(f"must be a family name or text such as 'normal(0, 1)', got {raw!r}")
        if "(" in raw:
            if spec:
                raise ValueError(f"gives its parameters in {raw!r}; drop {', '.join(spec)}")
            prior = as_prior(raw, "prior")
        else:
            prior = as_prior({"family": raw.strip().lower(), **spec}, "prior")
        param = UserParameter(name, prior, extra.get("lower", -math.inf),
                              extra.get("upper", math.inf), extra.get("initial"))
        checked = param.bounded_prior
    except (ValueError, KeyError) as err:
        raise SettingsError(source, key, str(err).strip("'\"")) from None
    if param.initial is not None and not (checked.support[0] < param.initial
                                          < checked.support[1]):
        raise SettingsError(source, f"{key}.initial", f"({param.initial:g}) must lie strictly "
                            f"inside the bounds {list(checked.support)}")
    return param


def parameters_from_table(value: Any, key: str, source: str) -> tuple[UserParameter, ...]:
    """The ``[model.parameters]`` table (name → table), checked, in the order written."""
    if isinstance(value, list | tuple) and all(isinstance(v, UserParameter) for v in value):
        return tuple(value)
    if not isinstance(value, Mapping):
        raise SettingsError(source, key, f"must be a table name = {{ prior = ... }}, got "
                            f"{value!r}")
    return tuple(_one(str(name), table, f"{key}.{name}", source) for name, table in value.items())


def with_model_paths(data: Any, base: Path | None = None) -> Any:
    """Settings ``data`` whose ``file:PATH:NAME`` models name absolute paths: a relative PATH is
    taken from ``base`` (a settings file's folder; None: the current directory), so that the
    run folder's copy of the settings still finds the file."""
    model = data.get("model") if isinstance(data, Mapping) else None
    if not isinstance(model, Mapping):
        return data
    fixed = dict(model)
    for key in ("potential", "hamiltonian", "kinetic"):
        text = fixed.get(key)
        if isinstance(text, str) and text.strip().startswith("file:"):
            path, sep, name = text.strip()[5:].rpartition(":")
            if sep and path:
                full = Path(path).expanduser()
                full = full if full.is_absolute() else (base or Path.cwd()) / full
                fixed[key] = f"file:{full.resolve()}:{name}"
    return {**data, "model": fixed}


def parameter_priors(parameters: Sequence[UserParameter]) -> dict[str, Prior]:
    """``{name: prior within its bounds}``: the per-name priors of θ's coefficient block."""
    return {p.name: p.bounded_prior for p in parameters}


def initial_values(parameters: Sequence[UserParameter]) -> dict[str, float]:
    """``{name: initial}`` of the parameters that declare a MAP start."""
    return {p.name: float(p.initial) for p in parameters if p.initial is not None}

