"""Sweep specs: validation of ``[base]`` and ``[sweep]``, the cells, their ids and settings.

A cell is the keys of its experiment (:class:`~symplid.workflow._experiment.Experiment`) plus
any dotted run setting; every value is checked by the one validator
(:mod:`symplid.workflow._validate`) against the experiment's key specs or, for dotted keys,
by building the cell's run settings. See :mod:`symplid.workflow._sweep` for the format.

The experiment is given as an object (``experiment=``) by the caller that knows it — the
command line, which registers the studies and resolves a spec's ``experiment = "..."``, or a
study that builds its own spec; only when none is given is the spec's name looked up in
:data:`~symplid.workflow._experiment.EXPERIMENTS`, which holds what has been registered there.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from symplid._registry import Registry
from symplid.workflow._experiment import EXPERIMENTS, Experiment
from symplid.workflow._results import to_jsonable
from symplid.workflow._settings import (
    Settings,
    SettingsError,
    settings_from_dict,
    settings_to_dict,
)
from symplid.workflow._settings_schema import RENAMED
from symplid.workflow._validate import check_value, suggest

__all__ = [
    "DEFAULT_EXPERIMENT",
    "Cell",
    "SweepError",
    "SweepSpec",
    "cell_id",
    "cell_settings",
    "get_experiment",
    "load_sweep_spec",
    "named_experiment",
    "read_sweep_file",
    "resolve_cell",
    "sweep_spec_from_dict",
]

DEFAULT_EXPERIMENT = "paper"
ID_LENGTH = 12
_SECTIONS = {"base": "[base]", "sweep": "[sweep]"}
_SWEEP_KEYS = ("name", "experiment", "cell_fn", "grid", "cells")
_SETTINGS_DEFAULTS = settings_to_dict(Settings())


class SweepError(SettingsError):
    """A bad sweep spec or sweep folder; the message names the file and the key."""


@dataclass(frozen=True)
class Cell:
    """One resolved cell: its stable id and its settings (every key, defaults included)."""

    id: str
    settings: dict[str, Any]


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: the fixed settings, the grid, the explicit cells, and the cells.

    Build it with :func:`load_sweep_spec` (a TOML file) or :func:`sweep_spec_from_dict`.
    ``cells`` are resolved and checked on construction, in the order: each ``cells`` entry, then
    each grid point (last grid key varying fastest).
    """

    base: dict[str, Any]
    grid: dict[str, list[Any]]
    entries: list[dict[str, Any]]
    cell_fn: str | None = None
    name: str = "sweep"
    source: str = "sweep spec"
    cells: tuple[Cell, ...] = ()
    experiment: str = DEFAULT_EXPERIMENT

    def to_dict(self) -> dict[str, Any]:
        """The spec as TOML-shaped data (``[base]`` and ``[sweep]``)."""
        sweep: dict[str, Any] = {"name": self.name, "experiment": self.experiment}
        if self.cell_fn:
            sweep["cell_fn"] = self.cell_fn
        if self.grid:
            sweep["grid"] = self.grid
        if self.entries != [{}]:
            sweep["cells"] = self.entries
        return {"base": self.base, "sweep": sweep}

    @property
    def ids(self) -> list[str]:
        return [c.id for c in self.cells]

    @property
    def setting_columns(self) -> list[str]:
        """The cells' keys (the experiment's, then the dotted ones), as table columns."""
        return list(dict.fromkeys(k for c in self.cells for k in c.settings))


def get_experiment(
    name: str | Experiment,
    source: str = "sweep spec",
    registry: Mapping[str, Experiment] = EXPERIMENTS,
) -> Experiment:
    """The experiment registered as ``name`` in ``registry``, or the one given."""
    if isinstance(name, Experiment):
        return name
    if not registry:
        raise SweepError(source, "sweep.experiment", f"is {name!r}, but no experiment is "
                         "registered (the studies' are registered by "
                         "symplid.studies.register_studies(); or pass the experiment itself)")
    try:
        return registry[name]
    except KeyError:
        message = (registry.unknown_message(name) if isinstance(registry, Registry)
                   else f"unknown experiment {name!r}")
        raise SweepError(source, "sweep.experiment", f"is {name!r}: {message}") from None


def named_experiment(data: Mapping[str, Any], source: str = "sweep spec") -> str:
    """The experiment a spec's data names (``[sweep] experiment``; default
    :data:`DEFAULT_EXPERIMENT`), read without checking the rest of the spec."""
    sweep = data.get("sweep", {}) if isinstance(data, Mapping) else {}
    return _string(sweep, "experiment", DEFAULT_EXPERIMENT, source) if isinstance(
        sweep, Mapping) else DEFAULT_EXPERIMENT


def load_sweep_spec(path: str | os.PathLike, experiment: Experiment | None = None) -> SweepSpec:
    """Read and validate a sweep spec from a TOML file (``experiment``: see
    :func:`sweep_spec_from_dict`).

    Raises
    ------
    SweepError
        Missing file, invalid TOML, or any problem :func:`sweep_spec_from_dict` finds; the
        message starts with the file name.
    """
    return sweep_spec_from_dict(read_sweep_file(path), str(path), experiment)


def read_sweep_file(path: str | os.PathLike) -> dict[str, Any]:
    """The TOML of a sweep spec file, not yet checked; :class:`SweepError` if unreadable."""
    path = Path(path)
    source = str(path)
    if not path.exists():
        raise SweepError(source, None, "no such sweep spec file")
    if path.is_dir():
        raise SweepError(source, None, "is a directory, not a sweep spec file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SweepError(source, None, "not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as err:
        raise SweepError(source, None, f"not valid TOML: {err}") from None
    return data


def sweep_spec_from_dict(
    data: Mapping[str, Any],
    source: str = "sweep spec",
    experiment: Experiment | None = None,
) -> SweepSpec:
    """Validate a sweep spec given as nested data (e.g. parsed TOML) and resolve its cells.

    Parameters
    ----------
    data
        ``{"base": {...}, "sweep": {"grid": {...}, "cells": [...], "experiment": ...,
        "cell_fn": ..., "name": ...}}``.
    source
        Where the data came from (a file name); every error message starts with it.
    experiment
        The experiment whose cells these are; the spec's ``experiment``, if it names one, must
        be its name. ``None``: the experiment the spec names, looked up in
        :data:`~symplid.workflow._experiment.EXPERIMENTS`.

    Raises
    ------
    SweepError
        An unknown key (with the closest valid key suggested), a value of the wrong type or out
        of range, an empty grid list, a key in both ``grid`` and ``cells``, two cells with the
        same resolved settings, num_iterations ≤ burn_in, a bad dotted run setting, ...
    """
    if not isinstance(data, Mapping):
        raise SweepError(source, None, f"a sweep spec must be a table, got {type(data).__name__}")
    for key in data:
        if key not in _SECTIONS:
            raise SweepError(source, None, f"unknown table [{key}]" + suggest(key, list(_SECTIONS)))
    sweep = _table(data.get("sweep", {}), "[sweep]", source)
    for key in sweep:
        if key not in _SWEEP_KEYS:
            raise SweepError(
                source, None, f"unknown key '{key}' in [sweep]" + suggest(key, _SWEEP_KEYS)
            )
    exp = _spec_experiment(sweep, source, experiment)
    check = _Checker(exp, source)
    base = check.table(_table(data.get("base", {}), "[base]", source), "[base]")
    grid = _grid(_table(sweep.get("grid", {}), "sweep.grid", source), check, source)
    entries = _entries(sweep.get("cells", [{}]), grid, check, source)
    cell_fn = sweep.get("cell_fn")
    if cell_fn is not None and (not isinstance(cell_fn, str) or ":" not in cell_fn):
        raise SweepError(
            source, "sweep.cell_fn", f"must be a 'module:function' string, got {cell_fn!r}"
        )
    name = _string(sweep, "name", "sweep", source)
    cells: list[Cell] = []
    seen: dict[str, str] = {}
    keys = list(grid)
    for i, entry in enumerate(entries):
        for values in itertools.product(*(grid[k] for k in keys)):
            point = dict(zip(keys, values, strict=True))
            where = _describe(i, point, len(entries) > 1)
            settings = resolve_cell({**base, **point, **entry}, source, where, exp)
            cid = cell_id(settings)
            if cid in seen:
                raise SweepError(
                    source,
                    None,
                    f"{where} has the same resolved settings as {seen[cid]}; "
                    "each cell must differ (remove the duplicate value)",
                )
            seen[cid] = where
            cells.append(Cell(cid, settings))
    return SweepSpec(base, grid, entries, cell_fn, name, source, tuple(cells), exp.name)


def _spec_experiment(
    sweep: Mapping[str, Any], source: str, experiment: Experiment | None
) -> Experiment:
    """The experiment of a spec's ``[sweep]``: the one given (checked against the name the
    spec gives, if any), else the one the spec names."""
    if experiment is None:
        return get_experiment(_string(sweep, "experiment", DEFAULT_EXPERIMENT, source), source)
    named = _string(sweep, "experiment", experiment.name, source)
    if named != experiment.name:
        raise SweepError(source, "sweep.experiment", f"is {named!r}, but the sweep was given "
                         f"the experiment {experiment.name!r}")
    return experiment


def _string(sweep: Mapping[str, Any], key: str, default: str, source: str) -> str:
    value = sweep.get(key, default)
    if not isinstance(value, str) or not value.strip():
        raise SweepError(source, f"sweep.{key}", f"must be a non-empty string, got {value!r}")
    return value.strip()


def _grid(raw: dict[str, Any], check: _Checker, source: str) -> dict[str, list[Any]]:
    grid: dict[str, list[Any]] = {}
    for key, values in raw.items():
        where = f"sweep.grid.{key}"
        if not isinstance(values, list):
            raise SweepError(
                source, where, f"must be a list of values (e.g. [{values!r}]), got {values!r}"
            )
        if not values:
            raise SweepError(source, where, "is an empty list: a grid axis needs ≥ 1 value")
        checked = [check.value(key, v, "sweep.grid") for v in values]
        grid[checked[0][0]] = [v for _, v in checked]
    return grid


def _entries(raw: Any, grid: dict[str, Any], check: _Checker, source: str) -> list[dict]:
    if not isinstance(raw, list) or not raw:
        raise SweepError(source, "sweep.cells", f"must be a non-empty list of tables, got {raw!r}")
    entries = []
    for i, entry in enumerate(raw):
        where = f"sweep.cells[{i}]"
        entry = check.table(_table(entry, where, source), where)
        for key in entry:
            if key in grid:
                raise SweepError(
                    source,
                    f"{where}.{key}",
                    "is also a sweep.grid axis; give each key in grid or in cells, not both",
                )
        entries.append(entry)
    return entries


def _describe(entry: int, point: dict[str, Any], show_entry: bool) -> str:
    parts = [f"sweep.cells[{entry}]"] if show_entry else []
    if point:
        parts.append("grid point {" + ", ".join(f"{k} = {v!r}" for k, v in point.items()) + "}")
    return "the cell at " + " and ".join(parts) if parts else "the cell"


def _table(value: Any, where: str, source: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise SweepError(source, where, f"must be a table, got {value!r}")
    return dict(value)


class _Checker:
    """Checks the keys and values of a cell against an experiment and the run settings."""

    def __init__(self, experiment: Experiment, source: str) -> None:
        self.exp = experiment
        self.source = source
        self.mapped = experiment.mapped

    def table(self, table: Mapping[str, Any], where: str) -> dict[str, Any]:
        for key in table:  # an old and a new name together: refused before any warning
            new = self.exp.renamed.get(key) or RENAMED.get(key)
            if new is not None and self.mapped.get(new, new) in table:
                new = self.mapped.get(new, new)
                raise SweepError(self.source, None, f"{key} and {new} in {where} are the same "
                                 f"setting; give only {new}")
        return dict(self.value(k, v, where) for k, v in table.items())

    def value(self, key: str, value: Any, where: str) -> tuple[str, Any]:
        """``(key, value)`` checked and normalised (renamed keys get their new name)."""
        key = self._rename(key, where)
        dotted = f"{where}.{key}" if where.startswith("sweep") else key
        source = self.source
        if "." in key:
            if key in self.mapped:
                raise SweepError(
                    source, dotted, f"is set by the short key '{self.mapped[key]}' in a sweep; "
                    "use that"
                )
            if key == "initial_state.x0" or key.split(".", 1)[0] not in _SETTINGS_DEFAULTS:
                valid = [k for k in _dotted_keys(_SETTINGS_DEFAULTS) if k not in self.mapped]
                raise SweepError(source, None, f"unknown key '{key}' in {where}"
                                 + suggest(key, valid))
            if not isinstance(value, bool | int | float | str | list):
                raise SweepError(source, dotted, f"must be a value, got {value!r}")
            return key, value
        if key not in self.exp.keys:
            raise SweepError(
                source, None, f"unknown key '{key}' in {where}" + suggest(key, list(self.exp.keys))
            )
        spec = self.exp.keys[key]
        label = f"{where} {key}" if where == "[base]" else dotted
        return key, check_value(value, spec.type, spec, label, source, SweepError)

    def _rename(self, key: str, where: str) -> str:
        new = self.exp.renamed.get(key) or RENAMED.get(key)
        if new is None:
            return key
        new = self.mapped.get(new, new)
        warnings.warn(
            f"{self.source}: {key} in {where} is deprecated; use {new}", FutureWarning,
            stacklevel=5,
        )
        return new


def _dotted_keys(table: Mapping[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k, v in table.items():
        if isinstance(v, Mapping):
            out += _dotted_keys(v, f"{prefix}{k}.")
        else:
            out.append(f"{prefix}{k}")
    return out


def resolve_cell(
    overrides: Mapping[str, Any],
    source: str = "sweep spec",
    where: str = "the cell",
    experiment: str | Experiment = DEFAULT_EXPERIMENT,
) -> dict[str, Any]:
    """Every setting of one cell: the experiment's defaults, then ``overrides``.

    ``overrides`` must already hold checked values (see :func:`sweep_spec_from_dict`); the
    checks that involve several keys are made by building the cell's run settings. Returns the
    experiment's keys in their order, then the dotted keys sorted, with dotted values
    normalised by :mod:`symplid.workflow._settings`.
    """
    exp = get_experiment(experiment, source)
    derived = dict(exp.defaults(overrides)) if exp.defaults else {}
    cell: dict[str, Any] = {}
    for key, spec in exp.keys.items():
        if key in overrides:
            cell[key] = overrides[key]
        elif spec.default is None and key in derived:
            cell[key] = spec.type(derived[key])
        else:
            cell[key] = spec.default
    for key in sorted(k for k in overrides if "." in k):
        cell[key] = overrides[key]
    try:
        settings = cell_settings(cell, source=source, experiment=exp)
    except SettingsError as err:
        raise SweepError(source, None, f"{where}: {_strip_source(str(err), source)}") from None
    resolved = settings_to_dict(settings)
    for key in cell:
        if "." in key:
            cell[key] = _lookup(resolved, key)
    return cell


def _strip_source(message: str, source: str) -> str:
    prefix = f"{source}: "
    return message[len(prefix) :] if message.startswith(prefix) else message


def _lookup(table: Mapping[str, Any], dotted: str) -> Any:
    value: Any = table
    for part in dotted.split("."):
        value = value[part]
    return value


def cell_id(settings: Mapping[str, Any]) -> str:
    """Stable id of a cell: the first 12 hex digits of SHA-256 of its settings as sorted JSON.

    The same resolved settings give the same id in any process, on any machine, in any key
    order; floats are written by ``json`` (shortest round-trip repr), so ``0.25`` is always
    ``"0.25"``.
    """
    text = json.dumps(to_jsonable(dict(settings)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:ID_LENGTH]


def cell_settings(
    cell: Mapping[str, Any],
    source: str = "sweep cell",
    experiment: str | Experiment = DEFAULT_EXPERIMENT,
) -> Settings:
    """The run settings of a cell (:class:`~symplid.workflow._settings.Settings`), validated.

    They start from the experiment's ``base_settings(cell)``; each key with a ``setting``
    sets that run setting (``dt`` → ``model.dt``, ``seed`` → ``seed`` and so ``map.seed`` and
    ``sampler.seed``, ...), and dotted keys are set as given. Keys without a ``setting`` are
    the cell function's business.
    """
    exp = get_experiment(experiment, source)
    data: dict[str, Any] = exp.base_settings(cell) if exp.base_settings else {}
    for key, spec in exp.keys.items():
        if spec.setting is not None and key in cell:
            _put(data, spec.setting, cell[key])
    for key, value in cell.items():
        if "." in key:
            _put(data, key, value)
    return settings_from_dict(data, source=source)


def _put(data: dict[str, Any], dotted: str, value: Any) -> None:
    *parents, leaf = dotted.split(".")
    table = data
    for part in parents:
        table = table.setdefault(part, {})
    table[leaf] = value

