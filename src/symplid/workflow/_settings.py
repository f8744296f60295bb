"""Run settings: nested frozen dataclasses with the paper's defaults, read from and written to TOML.

A settings file has one table per section (``[model]``, ``[initial_state]``, ``[priors]``,
``[map]``, ``[sampler]``, ``[prediction]``, ``[plots]``); every key is optional. The keys, their
defaults (the paper's Hénon–Heiles experiment, Section IV, unless a key says otherwise) and
their meanings are written once, in the schema (:mod:`symplid.workflow._settings_schema`,
``setting(..., doc=...)``), from which the docs' settings reference is generated; a run folder's
``settings.toml`` writes every value out.

Every prior table names its family by ``prior``, as ``[model.parameters]`` does (the old key
``family`` of a ``[priors.GROUP]`` table, or of ``--set priors.GROUP.family=...``, is read with a
FutureWarning; files are written with ``prior``); ``prior = "normal(0, 2)"`` gives the family
and its parameters at once. Prior families are those of
:data:`symplid.model._priors.PRIOR_FAMILIES` and their keys are the fields of the family's
class: ``laplace`` and ``normal`` (``loc``, ``scale``),
``half-normal`` (``scale``), ``uniform`` (``low``, ``high``), ``log-normal`` (``mu``, ``sigma``
of log x; ``loc`` and ``scale`` are read as synonyms). A key that a family does not use is an
error, so that what is written is what is used. Each group's value in :class:`PriorSettings` is
a :class:`~symplid.model._priors.Prior`; :meth:`PriorSettings.prior_spec` turns the groups into
the :class:`~symplid.model._prior_spec.PriorSpec` the posterior takes.

The key ``sampler.num_samples`` of older files (and ``--set sampler.num_samples=...``) is read
as ``sampler.num_iterations`` with a ``FutureWarning``; files are written with the new key.

Values are checked by the one validator of :mod:`symplid.workflow._validate`, which the sweeps
use too.

Every problem raises :class:`SettingsError` with a one-line message ``"<source>: <key> ..."``
naming the file (or "command line") and the dotted key; a misspelt key gets the closest valid
key as a suggestion.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
import typing
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from symplid.io._files import write_text
from symplid.model._priors import PRIOR_FAMILIES, Prior
from symplid.workflow._model_builder import family_prior, model_family, with_family_prior
from symplid.workflow._plan import resolve_for_data
from symplid.workflow._prior_tables import build_prior, upgrade_prior_keys, upgrade_prior_overrides
from symplid.workflow._settings_data import MAX_SUBSTEPS_PER_GAP
from symplid.workflow._settings_schema import (
    PRIOR_SYNONYMS,
    RENAMED,
    InitialStateSettings,
    MapSettings,
    ModelSettings,
    PlotSettings,
    PredictionSettings,
    PriorSettings,
    SamplerSettings,
    Settings,
)
from symplid.workflow._user_parameters import parameters_from_table, with_model_paths
from symplid.workflow._validate import SettingsError, check_value, suggest

__all__ = [
    "MAX_SUBSTEPS_PER_GAP",
    "InitialStateSettings",
    "MapSettings",
    "ModelSettings",
    "PlotSettings",
    "PredictionSettings",
    "PriorSettings",
    "SamplerSettings",
    "Settings",
    "SettingsError",
    "dump_settings",
    "load_settings",
    "merge_overrides",
    "parse_override",
    "resolve_for_data",
    "settings_from_dict",
    "settings_to_dict",
    "upgrade_prior_keys",
]


_SEEDED_SECTIONS = ("map", "sampler")


# ----------------------------------------------------------------------------- dict <-> settings
def settings_to_dict(settings: Settings) -> dict[str, Any]:
    """Nested plain dict (tuples as lists); each prior lists only the keys its family uses."""
    return _to_dict(settings)


def _to_dict(obj: Any) -> dict[str, Any]:
    if isinstance(obj, Prior):  # the family under ``prior``, as in every prior table
        return {("prior" if k == "family" else k): v for k, v in obj.to_dict().items()}
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value) or isinstance(value, Prior):
            out[f.name] = _to_dict(value)
        elif f.name == "parameters" and isinstance(obj, ModelSettings):
            out[f.name] = {p.name: p.to_dict() for p in value}
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def _all_keys(cls: type, prefix: str = "") -> list[str]:
    keys = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hints[f.name]):
            keys += _all_keys(hints[f.name], name + ".")
        else:
            keys.append(name)
    return keys


_VALID_KEYS = _all_keys(Settings)


def _suggest(key: str, section_keys: list[str]) -> str:
    """'; did you mean X?' using difflib, first within the section, then anywhere."""
    leaf = key.rsplit(".", 1)[-1]
    prefix = key.rsplit(".", 1)[0] + "." if "." in key else ""
    close = suggest(leaf, section_keys, fallback="")
    if close:
        return close.replace("'", f"'{prefix}", 1)
    close = suggest(key, _VALID_KEYS, fallback="")
    if not close:
        same = [k for k in _VALID_KEYS if k.rsplit(".", 1)[-1] == leaf][:1]
        close = f"; did you mean '{same[0]}'?" if same else ""
    return close or f" (valid keys here: {', '.join(section_keys)})"


def _upgrade(data: dict[str, Any], source: str) -> dict[str, Any]:
    """Rename the keys of :data:`RENAMED` in nested ``data``, each with a FutureWarning, and
    the old ``family`` key of a prior table (:func:`upgrade_prior_keys`)."""
    data = upgrade_prior_keys(data, source)
    for old, new in RENAMED.items():
        section, old_key = old.split(".")
        table = data.get(section)
        if not isinstance(table, Mapping) or old_key not in table:
            continue
        new_key = new.split(".")[1]
        if new_key in table:  # refused before any warning: one line
            raise SettingsError(source, old, f"and {new} are the same setting; give only {new}")
        _warn_renamed(old, new, source)
        table = dict(table)
        table[new_key] = table.pop(old_key)
        data[section] = table
    return data


def _warn_renamed(old: str, new: str, source: str) -> None:
    warnings.warn(f"{source}: {old} is deprecated; use {new}", FutureWarning, stacklevel=4)


def settings_from_dict(data: Mapping[str, Any], source: str = "settings") -> Settings:
    """Build validated :class:`Settings` from a nested mapping (e.g. parsed TOML).

    Missing keys take the paper's defaults. ``map.seed`` and ``sampler.seed`` default to the
    top-level ``seed`` when it is given and they are not. ``source`` (a file name, or
    "command line") starts every error message. ``sampler.num_samples`` (the old name) is read
    as ``sampler.num_iterations`` with a ``FutureWarning``.

    Raises
    ------
    SettingsError
        For an unknown (e.g. misspelt) key, with the closest valid key suggested; a value of the
        wrong type; a value out of range (dt ≤ 0, order < 1, a negative scale, ...); a name
        that its registry does not hold (integrator, sampler, prior family); num_iterations ≤
        burn_in; a prior key its family does not use; ...
    """
    if not isinstance(data, Mapping):
        raise SettingsError(source, None, f"settings must be a table, got {type(data).__name__}")
    data = _upgrade(dict(data), source)
    if "seed" in data:
        for section in _SEEDED_SECTIONS:
            table = data.get(section, {})
            if isinstance(table, Mapping) and "seed" not in table:
                data[section] = {**table, "seed": data["seed"]}
    data = with_model_paths(with_family_prior(data))
    settings = _build(Settings, data, "", source)
    _check_cross(settings, source)
    return settings


def _build(cls: type, data: Mapping[str, Any], prefix: str, source: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key not in fields:
            dotted = f"{prefix}{key}"
            raise SettingsError(
                source, None, f"unknown key '{dotted}'" + _suggest(dotted, list(fields))
            )
    kwargs = {}
    for name in fields:
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], fields[name], prefix + name, source)
    return cls(**kwargs)


def _convert(value: Any, tp: Any, f: dataclasses.Field, key: str, source: str) -> Any:
    """One value against its field: a section, a prior, or a value with a :class:`Spec`."""
    if dataclasses.is_dataclass(tp) or tp is Prior:
        if not isinstance(value, Mapping):
            raise SettingsError(source, key, f"must be a table ([{key}]), got {value!r}")
        if tp is Prior:
            return build_prior(value, key + ".", source)
        return _build(tp, value, key + ".", source)
    if key == "model.parameters":
        return parameters_from_table(value, key, source)
    return check_value(value, tp, f.metadata["spec"], key, source)


def _check_cross(s: Settings, source: str) -> None:
    """Checks that involve more than one key."""
    _check_sampler(s.sampler, source)
    family = model_family(s.model)
    if family.neural and s.sampler.method == "dram":
        raise SettingsError(
            source,
            "sampler.method",
            f'"dram" cannot explore the weights of the {family.name!r} family (random-walk '
            'proposals in hundreds of dimensions); use sampler.method = "nuts" (--method nuts)',
        )
    if any(m <= 0 for m in s.model.mass):
        raise SettingsError(
            source, "model.mass", f"must hold positive numbers, got {list(s.model.mass)}"
        )
    if not s.initial_state.at_first_observation and s.prediction.t_end <= s.initial_state.t0:
        raise SettingsError(
            source,
            "prediction.t_end",
            f"({s.prediction.t_end:g}) must be after initial_state.t0 ({s.initial_state.t0:g})",
        )
    variances = s.priors.variances
    low, high = variances.support
    if low < 0 or high <= 0:
        raise SettingsError(
            source,
            "priors.variances.prior",
            f"must have positive support (half-normal, log-normal, or uniform with low ≥ 0), "
            f"got {variances.family!r}",
        )
    if s.priors.initial_state.support != (-math.inf, math.inf):
        raise SettingsError(
            source,
            "priors.initial_state.prior",
            f"must allow any real value (normal or laplace), got {s.priors.initial_state.family!r}",
        )
    if s.initial_state.x0 and len(s.initial_state.x0) % 2:
        raise SettingsError(
            source,
            "initial_state.x0",
            f"has {len(s.initial_state.x0)} numbers; it must be a full state (q1..qd, p1..pd)",
        )


def _check_sampler(sampler: SamplerSettings, source: str) -> None:
    burn_in = sampler.resolved_burn_in
    if not sampler.fixed:
        if burn_in is not None and burn_in >= sampler.max_iterations:
            raise SettingsError(
                source, "sampler.max_iterations",
                f"({sampler.max_iterations}) must be greater than sampler.burn_in ({burn_in}); "
                "it caps every iteration, burn-in included")
        return
    if sampler.num_iterations <= burn_in:
        raise SettingsError(
            source,
            "sampler.num_iterations",
            f"({sampler.num_iterations}) must be greater than sampler.burn_in "
            f"({burn_in}); num_iterations counts every iteration, burn-in included",
        )
    if sampler.thin > sampler.num_iterations - burn_in:
        raise SettingsError(
            source,
            "sampler.thin",
            f"({sampler.thin}) is larger than the {sampler.num_iterations - burn_in} "
            "draws kept after burn-in",
        )


# ----------------------------------------------------------------------------- files
def load_settings(path: str | os.PathLike) -> Settings:
    """Read and validate a TOML settings file; missing keys take the paper's defaults."""
    path = Path(path)
    if not path.exists():
        raise SettingsError(str(path), None, "no such settings file")
    if path.is_dir():
        raise SettingsError(str(path), None, "is a directory, not a settings file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SettingsError(str(path), None, "not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as err:
        raise SettingsError(str(path), None, f"not valid TOML: {err}") from None
    return settings_from_dict(with_model_paths(data, path.parent), source=str(path))


_HEADER = (
    "# symplid run settings: every value written out, so the run can be repeated exactly.\n"
    "# Read with symplid.workflow._settings.load_settings (or `symplid fit --config`).\n\n"
)


def dump_settings(settings: Settings, path: str | os.PathLike) -> Path:
    """Write every setting (defaults included) as TOML, atomically; returns the path."""
    return write_text(path, _HEADER + tomli_w.dumps(settings_to_dict(settings)))


# ----------------------------------------------------------------------------- overrides
def parse_override(text: str, source: str = "command line") -> tuple[str, Any]:
    """Parse ``"model.dt=0.1"`` into ``("model.dt", 0.1)``.

    The value is read as a TOML value (numbers, booleans, ``[0.2, -0.25]``, quoted strings),
    falling back to the bare text as a string (``model.integrator=rk4``).
    """
    key, sep, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not sep or not key:
        raise SettingsError(source, None, f"expected KEY=VALUE (e.g. model.dt=0.1), got {text!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def merge_overrides(
    settings: Settings, overrides: Mapping[str, Any], source: str = "command line"
) -> Settings:
    """Return ``settings`` with dotted keys replaced, e.g. ``{"model.dt": 0.1}``, re-validated.

    ``None`` values are skipped (an option the user did not give); ``sampler.num_samples`` is
    read as ``sampler.num_iterations`` with a ``FutureWarning``. Overriding the top-level
    ``seed`` also reseeds ``map.seed`` and ``sampler.seed`` unless they are overridden too.
    """
    data = settings_to_dict(settings)
    overrides = {k: v for k, v in overrides.items() if v is not None}
    for old, new in RENAMED.items():
        if old in overrides:
            if new in overrides:  # refused before any warning: one line
                raise SettingsError(source, old, f"and {new} are the same setting; give only {new}")
            _warn_renamed(old, new, source)
            overrides[new] = overrides.pop(old)
    overrides = upgrade_prior_overrides(overrides, source)
    if "seed" in overrides:
        for section in _SEEDED_SECTIONS:
            overrides.setdefault(f"{section}.seed", overrides["seed"])
    new_family = {"model.potential", "model.hamiltonian"} & set(overrides)
    if (new_family and not any(k.startswith("priors.coefficients") for k in overrides)
            and settings.priors.coefficients == family_prior(settings.model)):
        del data["priors"]["coefficients"]  # the old family's default: take the new one's
    for key, value in overrides.items():
        parts = key.split(".")
        table = data
        for depth, part in enumerate(parts):
            if not isinstance(table, dict) or (part not in table and not _is_prior_key(
                    parts, depth) and parts[:2] != ["model", "parameters"]):
                section = list(table) if isinstance(table, dict) else []
                raise SettingsError(source, None, f"unknown key '{key}'" + _suggest(key, section))
            if depth == len(parts) - 1:
                if isinstance(table.get(part), dict):
                    raise SettingsError(source, key, "is a section; give one of its keys")
                table[part] = list(value) if isinstance(value, tuple) else value
            else:
                table = table[part]
        if len(parts) == 3 and parts[0] == "priors" and parts[2] == "prior":
            # a new family: drop the old family's parameters so defaults apply
            group = data["priors"][parts[1]]
            for k in list(group):
                if k != "prior" and f"priors.{parts[1]}.{k}" not in overrides:
                    del group[k]
    return settings_from_dict(data, source=source)


def _is_prior_key(parts: list[str], depth: int) -> bool:
    """Prior groups list only their family's keys; any family's key is still valid to set."""
    return len(parts) == 3 and depth == 2 and parts[0] == "priors" and parts[2] in _prior_keys()


def _prior_keys() -> set[str]:
    keys = {key for synonyms in PRIOR_SYNONYMS.values() for key in synonyms}
    for cls in PRIOR_FAMILIES.values():
        keys |= {f.name for f in dataclasses.fields(cls)}
    return keys
