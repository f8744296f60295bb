"""The prior tables of a settings file: ``prior = ...`` in every one of them.

A ``[priors.GROUP]`` table names its family by ``prior``, as a ``[model.parameters]`` entry
does (:mod:`symplid.workflow._user_parameters`): a family of
:data:`~symplid.model._priors.PRIOR_FAMILIES` with the parameters its class takes as keys, or
text such as ``"normal(0, 2)"`` alone. The old key ``family`` (in a file, a ``--config`` file
or ``--set priors.GROUP.family=...``) is read with one FutureWarning line; both keys at once
are refused.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from typing import Any

from symplid.model._priors import PRIOR_FAMILIES, Prior, as_prior
from symplid.workflow._settings_schema import PRIOR_DEFAULTS, PRIOR_SPECS, PRIOR_SYNONYMS
from symplid.workflow._validate import SettingsError, Spec, check_value

__all__ = ["build_prior", "upgrade_prior_keys", "upgrade_prior_overrides"]


def _warn_renamed(old: str, new: str, source: str) -> None:
    warnings.warn(f"{source}: {old} is deprecated; use {new}", FutureWarning, stacklevel=5)


def upgrade_prior_keys(data: dict[str, Any], source: str) -> dict[str, Any]:
    """``data`` whose ``[priors.GROUP]`` tables name their family by ``prior``, the key of
    every prior table (as in ``[model.parameters]``): the old key ``family`` is read with a
    FutureWarning; both at once are refused."""
    priors = data.get("priors")
    if not isinstance(priors, Mapping):
        return data
    fixed = dict(priors)
    for group, table in priors.items():
        if isinstance(table, Mapping) and "family" in table:
            key = f"priors.{group}"
            if "prior" in table:  # refused before any warning: one line
                raise SettingsError(source, f"{key}.family", f"and {key}.prior are the same "
                                    f"setting; give only {key}.prior")
            _warn_renamed(f"{key}.family", f"{key}.prior", source)
            fixed[group] = {("prior" if k == "family" else k): v for k, v in table.items()}
    return {**data, "priors": fixed}


def upgrade_prior_overrides(overrides: dict[str, Any], source: str) -> dict[str, Any]:
    """Dotted overrides with ``priors.GROUP.family`` read as ``priors.GROUP.prior`` (one
    FutureWarning line each; both keys at once are refused)."""
    overrides = dict(overrides)
    for key in [k for k in overrides if k.startswith("priors.") and k.endswith(".family")]:
        new = key[: -len("family")] + "prior"
        if new in overrides:  # refused before any warning: one line
            raise SettingsError(source, key, f"and {new} are the same setting; give only {new}")
        _warn_renamed(key, new, source)
        overrides[new] = overrides.pop(key)
    return overrides


def build_prior(data: Mapping[str, Any], prefix: str, source: str) -> Prior:
    """A prior group: ``prior``, a family of :data:`PRIOR_FAMILIES` with the parameters its
    class takes as keys, or text such as ``"normal(0, 2)"`` alone."""
    raw = data.get("prior", "normal")
    if isinstance(raw, str) and "(" in raw:
        others = [k for k in data if k != "prior"]
        if others:
            raise SettingsError(source, f"{prefix}prior", f"gives its parameters in {raw!r}; "
                                f"drop {', '.join(others)}")
        try:
            return as_prior(raw, "prior")
        except ValueError as err:
            raise SettingsError(source, f"{prefix}prior", str(err)) from None
    family_spec = Spec(str, "normal", choices=PRIOR_FAMILIES)
    family = check_value(raw, str, family_spec, f"{prefix}prior", source)
    cls = PRIOR_FAMILIES[family]
    used = [f.name for f in dataclasses.fields(cls)]
    synonyms = PRIOR_SYNONYMS.get(family, {})
    kwargs: dict[str, float] = {}
    for key, value in data.items():
        if key == "prior":
            continue
        name = synonyms.get(key, key)
        if name not in used:
            raise SettingsError(
                source,
                f"{prefix}{key}",
                f"is not used by the {family!r} prior (it takes: {', '.join(used)})",
            )
        spec = PRIOR_SPECS.get(name, Spec(float))
        kwargs[name] = check_value(value, float, spec, f"{prefix}{key}", source)
    for name in used:
        if name not in kwargs and name in PRIOR_DEFAULTS:
            kwargs[name] = PRIOR_DEFAULTS[name]
    if family == "uniform" and not kwargs["low"] < kwargs["high"]:
        raise SettingsError(
            source,
            f"{prefix}low",
            f"({kwargs['low']:g}) must be less than {prefix}high ({kwargs['high']:g})",
        )
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise SettingsError(source, f"{prefix}prior", f"{family!r}: {err}") from None
