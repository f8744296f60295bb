"""Sweeps: many fits over a grid of settings, each one a task on Dask, gathered in one table.

A sweep is described in TOML by two tables::

    [base]                      # fixed settings of every cell (any key below; defaults otherwise)
    system = "henon-heiles"
    num_samples = 20000
    burn_in = 10000
    num_chains = 2

    [sweep]
    name = "seeds-and-propagators"          # optional, shown in the progress bar
    cell_fn = "symplid.experiments.paper:run_cell"   # optional (this is the default)
    grid = { seed = [0, 1, 2], integrator = ["leapfrog", "rk2-midpoint"] }
    cells = [ {}, { dt = 0.1 }, { noise_std = 0.01 } ]

``grid`` is a Cartesian product (one list of values per key). ``cells`` is an explicit list of
partial settings. When both are given, **every entry of** ``cells`` **is combined with every point
of** ``grid``: the example above is 3 × (3 × 2) = 18 cells, the paper's setting and two variants,
each over three seeds and both propagators. Give only ``grid`` for a plain product, only ``cells``
for a plain list. A cell's settings are, in increasing priority: the defaults, ``[base]``, then
its grid point and its ``cells`` entry (a key may not be in both ``grid`` and ``cells``).

The keys of a cell (:data:`CELL_KEYS`; defaults are the paper's Hénon–Heiles experiment)::

    system            named reference system (symplid.SYSTEMS)           "henon-heiles"
    seed              seed of the data noise; also seeds the MAP starts and the sampler   0
    noise_std         observation-noise standard deviation of the data   the system's (0.05)
    num_obs           number of observations                             the system's (20)
    obs_interval      time between observations, first one at t = obs_interval   (5.0)
    integrator        learning propagator (symplid.INTEGRATORS)          "leapfrog"
    dt                learning step (eq. 14)                             0.25
    order             total order of the polynomial potential (eqs 17–18)   3
    sampler           "dram" or "nuts"                                   "dram"
    num_samples       iterations per chain, burn-in included             200000
    burn_in           iterations discarded                               100000
    num_chains        chains                                             4
    num_starts        MAP starts                                         4
    prediction_dt     step of the leapfrog predictions                   0.01
    prediction_t_end  end of the predictions (s)                         200.0
    horizon_tol       a prediction is valid while |q1 − q1_true| ≤ this  0.1

Any key of the run settings can be added in dotted form (``"model.process_noise_per" = "step"``,
``"sampler.gamma" = 0.02``, ``"map.seed" = 7``); it is checked by :mod:`~.settings` and
reaches the cell through :func:`cell_settings`. The keys above that map to run settings must be
given by their short name.

Every cell gets a **stable id**: the first 12 hex digits of the SHA-256 of its fully resolved
settings (defaults included, as sorted JSON). A rerun of the same spec into the same folder finds
its finished cells by id and skips them; cells that failed are run again.

The output folder::

    sweep.json          the spec, the cell function's name and the ids of the cells
    cells/<id>.json     one record per cell: settings, status ("ok" / "failed"), metrics,
                        error and traceback, the warnings raised, start and end times, the worker
    results.csv         one row per cell: id, settings, status, elapsed_s, metrics, error,
                        warnings
    results.parquet     the same table
    figures/<metric>.png  every cell's value of a metric, by setting and propagator

The cell function
-----------------
``cell_fn(cell: dict) -> dict`` takes the resolved settings of one cell (the keys above and any
dotted keys) and returns a flat dict of metrics (numbers or short strings; nested dicts are
flattened to ``"a.b"`` columns). The default is ``symplid.experiments.paper:run_cell``.
:func:`cell_data` and :func:`cell_settings` turn a cell into its data and its run settings so
that every cell function reads a cell the same way.

Workers
-------
By default a :class:`dask.distributed.LocalCluster` of processes is started, one worker per core
with one thread each. Each worker process runs JAX single-threaded (``XLA_FLAGS``, see
:func:`worker_environment`) and in float64 (the task imports :mod:`symplid`), so that N workers
use N cores and no more. With ``scheduler="tcp://host:8786"`` the cells go to an existing Dask
cluster instead; start its workers with ``--nthreads 1`` and the environment of
:func:`worker_environment` (the task also sets ``XLA_FLAGS`` itself when the worker has not used
JAX yet). Every worker turns on JAX's persistent compilation cache
(:mod:`symplid.runtime`: ``$SYMPLID_CACHE_DIR``, by default ``~/.cache/symplid/jax``;
``SYMPLID_CACHE_DIR=off`` disables it), so a program compiled for one cell is loaded, not
recompiled, by the next cells, the other workers and later runs.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import difflib
import hashlib
import importlib
import itertools
import json
import logging
import math
import numbers
import os
import socket
import time
import tomllib
import traceback
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from symplid.dynamics.integrators import INTEGRATORS, get_integrator
from symplid.dynamics.systems import SYSTEMS, System, get_system
from symplid.model.data import Observations
from symplid.model.simulate import simulate
from symplid.workflow.results import read_json, to_jsonable, write_json
from symplid.workflow.settings import (
    Settings,
    SettingsError,
    settings_from_dict,
    settings_to_dict,
)

__all__ = [
    "CELL_KEYS",
    "DEFAULT_CELL_FN",
    "XLA_SINGLE_THREAD",
    "Cell",
    "CellKey",
    "SweepError",
    "SweepSpec",
    "cell_data",
    "cell_id",
    "cell_settings",
    "load_results",
    "load_sweep_spec",
    "resolve_cell_fn",
    "run_sweep",
    "sweep_spec_from_dict",
    "worker_environment",
]

DEFAULT_CELL_FN = "symplid.experiments.paper:run_cell"

#: XLA flags that keep a JAX process on one CPU thread.
XLA_SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

CELLS_DIR = "cells"
FIGURES_DIR = "figures"
MANIFEST = "sweep.json"
RESULTS_CSV = "results.csv"
RESULTS_PARQUET = "results.parquet"
ID_LENGTH = 12
MAX_WARNINGS = 20  # distinct warning messages kept per cell


class SweepError(SettingsError):
    """A bad sweep spec or sweep folder; the message names the file and the key."""


# ----------------------------------------------------------------------------- cell keys
@dataclass(frozen=True)
class CellKey:
    """One setting of a cell: its type, default, range and the run setting it maps to."""

    type: type
    default: Any
    doc: str
    minimum: float | None = None
    strict: bool = False
    choices: tuple[str, ...] | None = None
    setting: str | None = None  # dotted key of symplid.workflow.settings.Settings, if any


_SETTINGS_DEFAULTS = settings_to_dict(Settings())


def _default(dotted: str) -> Any:
    table: Any = _SETTINGS_DEFAULTS
    for part in dotted.split("."):
        table = table[part]
    return table


def _mapped(tp: type, dotted: str, doc: str, **kw: Any) -> CellKey:
    return CellKey(tp, _default(dotted), doc, setting=dotted, **kw)


#: The short keys of a cell, in table-column order. ``None`` defaults come from the system.
CELL_KEYS: dict[str, CellKey] = {
    "system": CellKey(str, "henon-heiles", "named reference system", choices=tuple(SYSTEMS)),
    "seed": CellKey(
        int, 0, "seed of the data noise, the MAP starts and the sampler", minimum=0, setting="seed"
    ),
    "noise_std": CellKey(float, None, "observation-noise standard deviation", minimum=0.0),
    "num_obs": CellKey(int, None, "number of observations", minimum=1),
    "obs_interval": CellKey(float, None, "time between observations", minimum=0.0, strict=True),
    "integrator": _mapped(str, "model.integrator", "learning propagator"),
    "dt": _mapped(float, "model.dt", "learning step (eq. 14)", minimum=0.0, strict=True),
    "order": _mapped(int, "model.order", "order of the polynomial potential", minimum=1),
    "sampler": _mapped(str, "sampler.method", "MCMC method", choices=("dram", "nuts")),
    "num_samples": _mapped(int, "sampler.num_samples", "iterations per chain", minimum=1),
    "burn_in": _mapped(int, "sampler.burn_in", "iterations discarded", minimum=0),
    "num_chains": _mapped(int, "sampler.num_chains", "number of chains", minimum=1),
    "num_starts": _mapped(int, "map.num_starts", "number of MAP starts", minimum=1),
    "prediction_dt": _mapped(
        float, "prediction.dt", "step of the predictions", minimum=0.0, strict=True
    ),
    "prediction_t_end": _mapped(
        float, "prediction.t_end", "end of the predictions", minimum=0.0, strict=True
    ),
    "horizon_tol": CellKey(
        float, 0.1, "a prediction is valid while |q1 − q1_true| ≤ this", minimum=0.0, strict=True
    ),
}
_SYSTEM_DEFAULTS = {"noise_std": "noise_std", "num_obs": "num_obs", "obs_interval": "obs_interval"}
_MAPPED = {k.setting: name for name, k in CELL_KEYS.items() if k.setting}
_SECTIONS = {"base": "[base]", "sweep": "[sweep]"}
_SWEEP_KEYS = ("name", "cell_fn", "grid", "cells")


# ----------------------------------------------------------------------------- spec
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

    def to_dict(self) -> dict[str, Any]:
        """The spec as TOML-shaped data (``[base]`` and ``[sweep]``)."""
        sweep: dict[str, Any] = {"name": self.name}
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


def load_sweep_spec(path: str | os.PathLike) -> SweepSpec:
    """Read and validate a sweep spec from a TOML file.

    Raises
    ------
    SweepError
        Missing file, invalid TOML, or any problem :func:`sweep_spec_from_dict` finds; the
        message starts with the file name.
    """
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
    return sweep_spec_from_dict(data, source=source)


def sweep_spec_from_dict(data: Mapping[str, Any], source: str = "sweep spec") -> SweepSpec:
    """Validate a sweep spec given as nested data (e.g. parsed TOML) and resolve its cells.

    Parameters
    ----------
    data
        ``{"base": {...}, "sweep": {"grid": {...}, "cells": [...], "cell_fn": ..., "name": ...}}``.
    source
        Where the data came from (a file name); every error message starts with it.

    Raises
    ------
    SweepError
        An unknown key (with the closest valid key suggested), a value of the wrong type or out
        of range, an empty grid list, a key in both ``grid`` and ``cells``, two cells with the
        same resolved settings, num_samples ≤ burn_in, a bad dotted run setting, ...
    """
    if not isinstance(data, Mapping):
        raise SweepError(source, None, f"a sweep spec must be a table, got {type(data).__name__}")
    for key in data:
        if key not in _SECTIONS:
            raise SweepError(source, None, f"unknown table [{key}]" + _hint(key, list(_SECTIONS)))
    base = _table(data.get("base", {}), "[base]", source)
    sweep = _table(data.get("sweep", {}), "[sweep]", source)
    for key in sweep:
        if key not in _SWEEP_KEYS:
            raise SweepError(
                source, None, f"unknown key '{key}' in [sweep]" + _hint(key, list(_SWEEP_KEYS))
            )
    base = {k: _check_value(k, v, "[base]", source) for k, v in base.items()}

    grid_raw = _table(sweep.get("grid", {}), "sweep.grid", source)
    grid: dict[str, list[Any]] = {}
    for key, values in grid_raw.items():
        where = f"sweep.grid.{key}"
        if not isinstance(values, list):
            raise SweepError(
                source, where, f"must be a list of values (e.g. [{values!r}]), got {values!r}"
            )
        if not values:
            raise SweepError(source, where, "is an empty list: a grid axis needs ≥ 1 value")
        grid[key] = [_check_value(key, v, "sweep.grid", source) for v in values]

    entries_raw = sweep.get("cells", [{}])
    if not isinstance(entries_raw, list) or not entries_raw:
        raise SweepError(
            source, "sweep.cells", f"must be a non-empty list of tables, got {entries_raw!r}"
        )
    entries: list[dict[str, Any]] = []
    for i, entry in enumerate(entries_raw):
        where = f"sweep.cells[{i}]"
        entry = _table(entry, where, source)
        for key in entry:
            if key in grid:
                raise SweepError(
                    source,
                    f"{where}.{key}",
                    "is also a sweep.grid axis; give each key in grid or in cells, not both",
                )
        entries.append({k: _check_value(k, v, where, source) for k, v in entry.items()})

    cell_fn = sweep.get("cell_fn")
    if cell_fn is not None and (not isinstance(cell_fn, str) or ":" not in cell_fn):
        raise SweepError(
            source, "sweep.cell_fn", f"must be a 'module:function' string, got {cell_fn!r}"
        )
    name = sweep.get("name", "sweep")
    if not isinstance(name, str) or not name.strip():
        raise SweepError(source, "sweep.name", f"must be a non-empty string, got {name!r}")

    cells: list[Cell] = []
    seen: dict[str, str] = {}
    keys = list(grid)
    for i, entry in enumerate(entries):
        for point in itertools.product(*(grid[k] for k in keys)):
            overrides = {**base, **dict(zip(keys, point, strict=True)), **entry}
            where = _describe(i, dict(zip(keys, point, strict=True)), len(entries) > 1)
            settings = resolve_cell(overrides, source, where)
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
    return SweepSpec(base, grid, entries, cell_fn, name.strip(), source, tuple(cells))


def _describe(entry: int, point: dict[str, Any], show_entry: bool) -> str:
    parts = [f"sweep.cells[{entry}]"] if show_entry else []
    if point:
        parts.append("grid point {" + ", ".join(f"{k} = {v!r}" for k, v in point.items()) + "}")
    return "the cell at " + " and ".join(parts) if parts else "the cell"


def _table(value: Any, where: str, source: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise SweepError(source, where, f"must be a table, got {value!r}")
    return dict(value)


def _hint(key: str, valid: Sequence[str]) -> str:
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.6)
    if close:
        return f"; did you mean '{close[0]}'?"
    return f" (valid: {', '.join(valid)})"


def _check_value(key: str, value: Any, where: str, source: str) -> Any:
    """Check one cell key and its value; return the value normalised (canonical names)."""
    dotted = f"{where}.{key}" if where.startswith("sweep") else key
    if "." in key:
        if key in _MAPPED:
            raise SweepError(
                source, dotted, f"is set by the short key '{_MAPPED[key]}' in a sweep; use that"
            )
        if key == "initial_state.x0" or key.split(".", 1)[0] not in _SETTINGS_DEFAULTS:
            valid = [k for k in _dotted_keys(_SETTINGS_DEFAULTS) if k not in _MAPPED]
            raise SweepError(source, None, f"unknown key '{key}' in {where}" + _hint(key, valid))
        if not isinstance(value, bool | int | float | str | list):
            raise SweepError(source, dotted, f"must be a value, got {value!r}")
        return value
    if key not in CELL_KEYS:
        raise SweepError(source, None, f"unknown key '{key}' in {where}" + _hint(key, CELL_KEYS))
    spec = CELL_KEYS[key]
    label = f"{where} {key}" if where == "[base]" else dotted
    if spec.type is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SweepError(source, label, f"must be an integer, got {value!r}")
        out: Any = value
    elif spec.type is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SweepError(source, label, f"must be a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise SweepError(source, label, f"must be finite, got {value!r}")
    else:
        if not isinstance(value, str):
            raise SweepError(source, label, f"must be a string, got {value!r}")
        out = value.strip().lower().replace("_", "-")
        if key == "integrator":
            try:
                return get_integrator(out).name
            except ValueError:
                raise SweepError(
                    source,
                    label,
                    f"is {value!r}, not a known integrator{_hint(out, list(INTEGRATORS))}",
                ) from None
    if spec.choices and out not in spec.choices:
        close = difflib.get_close_matches(out, spec.choices, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise SweepError(
            source,
            label,
            f"must be one of {', '.join(map(repr, spec.choices))}, got {value!r}{hint}",
        )
    if spec.minimum is not None:
        ok = out > spec.minimum if spec.strict else out >= spec.minimum
        if not ok:
            sign = ">" if spec.strict else "≥"
            raise SweepError(source, label, f"must be {sign} {spec.minimum:g}, got {value!r}")
    return out


def _dotted_keys(table: Mapping[str, Any], prefix: str = "") -> list[str]:
    out = []
    for k, v in table.items():
        if isinstance(v, Mapping):
            out += _dotted_keys(v, f"{prefix}{k}.")
        else:
            out.append(f"{prefix}{k}")
    return out


def resolve_cell(
    overrides: Mapping[str, Any], source: str = "sweep spec", where: str = "the cell"
) -> dict[str, Any]:
    """Every setting of one cell: defaults (the system's where they depend on it), then overrides.

    ``overrides`` must already hold checked values (see :func:`sweep_spec_from_dict`); the
    checks that involve several keys are made here, and dotted keys are validated as run
    settings. Returns the short keys in :data:`CELL_KEYS` order, then the dotted keys sorted,
    with dotted values normalised by :mod:`symplid.workflow.settings`.
    """
    cell: dict[str, Any] = {}
    system = get_system(overrides.get("system", CELL_KEYS["system"].default))
    for key, spec in CELL_KEYS.items():
        if key in overrides:
            cell[key] = overrides[key]
        elif key in _SYSTEM_DEFAULTS:
            cell[key] = CELL_KEYS[key].type(getattr(system, _SYSTEM_DEFAULTS[key]))
        else:
            cell[key] = spec.default
    if cell["num_samples"] <= cell["burn_in"]:
        raise SweepError(
            source,
            None,
            f"{where}: num_samples ({cell['num_samples']}) must be greater than burn_in "
            f"({cell['burn_in']}); num_samples counts every iteration, burn-in included",
        )
    for key in sorted(k for k in overrides if "." in k):
        cell[key] = overrides[key]
    try:
        settings = cell_settings(cell, source=source)
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


# ----------------------------------------------------------------------------- cell helpers
def cell_settings(cell: Mapping[str, Any], source: str = "sweep cell") -> Settings:
    """The run settings of a cell (:class:`symplid.workflow.settings.Settings`), validated.

    Short keys map to their run settings (``dt`` → ``model.dt``, ``num_starts`` →
    ``map.num_starts``, ``seed`` → ``seed`` and so ``map.seed`` and ``sampler.seed``, ...);
    dotted keys are set as given; the initial state is the system's, known (the paper's
    experiment). Keys the run settings do not hold (``system``, ``noise_std``, ``num_obs``,
    ``obs_interval``, ``horizon_tol``) are the data's and the metrics' business.
    """
    system = get_system(cell.get("system", CELL_KEYS["system"].default))
    data: dict[str, Any] = {"initial_state": {"mode": "known", "x0": list(system.initial_state)}}
    for key, spec in CELL_KEYS.items():
        if spec.setting is None or key not in cell:
            continue
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


def cell_data(cell: Mapping[str, Any]) -> tuple[System, Observations]:
    """The system and the simulated data of a cell.

    Full-state observations at ``obs_interval``, 2·``obs_interval``, …, ``num_obs``·
    ``obs_interval`` with noise ``noise_std``, drawn with ``seed`` (see :func:`~.simulate`).
    """
    system = get_system(cell.get("system", CELL_KEYS["system"].default))
    interval = float(cell.get("obs_interval", system.obs_interval))
    num_obs = int(cell.get("num_obs", system.num_obs))
    times = interval * np.arange(1, num_obs + 1)
    noise = float(cell.get("noise_std", system.noise_std))
    return system, simulate(system, times=times, noise_std=noise, seed=int(cell.get("seed", 0)))


# ----------------------------------------------------------------------------- cell function
def resolve_cell_fn(cell_fn: str | Callable[[dict], Mapping[str, Any]]) -> Callable:
    """The callable behind ``cell_fn``: itself, or ``"package.module:function"`` imported.

    Raises
    ------
    ValueError
        A string that is not ``module:function``, a module that cannot be imported, or a name
        that is not a callable in it.
    """
    if callable(cell_fn):
        return cell_fn
    if not isinstance(cell_fn, str) or cell_fn.count(":") != 1:
        raise ValueError(
            f"cell_fn must be a callable or a 'module:function' string, got {cell_fn!r}"
        )
    module_name, _, attr = cell_fn.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ValueError(f"cell_fn {cell_fn!r}: cannot import {module_name!r} ({err})") from None
    fn = getattr(module, attr, None)
    if not callable(fn):
        raise ValueError(f"cell_fn {cell_fn!r}: {module_name!r} has no function {attr!r}")
    return fn


def _cell_fn_name(cell_fn: str | Callable) -> str:
    if isinstance(cell_fn, str):
        return cell_fn
    module = getattr(cell_fn, "__module__", None) or "?"
    return f"{module}:{getattr(cell_fn, '__qualname__', repr(cell_fn))}"


def worker_environment(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment of a sweep worker process: single-threaded XLA and BLAS, plus ``extra``.

    ``XLA_FLAGS`` keeps JAX on one thread (``--xla_cpu_multi_thread_eigen=false
    intra_op_parallelism_threads=1``); ``OMP/MKL/OPENBLAS_NUM_THREADS = 1`` do the same for
    NumPy and SciPy, so that one worker per core never oversubscribes the machine.
    """
    env = {
        "XLA_FLAGS": XLA_SINGLE_THREAD,
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
    }
    env.update({str(k): str(v) for k, v in (extra or {}).items()})
    return env


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds")


def _run_cell_task(settings: dict[str, Any], cell_fn: str | Callable) -> dict[str, Any]:
    """Run one cell in a worker; never raises: a failure becomes a record with its traceback.

    The worker uses JAX's persistent compilation cache (:mod:`symplid.runtime`), so
    a program compiled for one cell is loaded from disk by the next cells, the other workers
    and later runs.
    """
    os.environ.setdefault("XLA_FLAGS", XLA_SINGLE_THREAD)  # if this worker has not used JAX yet
    import jax  # symplid is imported with this module, so float64 is on

    from symplid import runtime

    runtime.enable_compilation_cache()

    started = _now()
    t0 = time.perf_counter()
    record: dict[str, Any] = {"status": "ok", "metrics": None, "error": None, "traceback": None}
    with warnings.catch_warnings(record=True) as caught:  # kept in the record, not printed
        warnings.simplefilter("always")
        try:
            fn = resolve_cell_fn(cell_fn)
            metrics = fn(dict(settings))
            if not isinstance(metrics, Mapping):
                raise TypeError(
                    f"the cell function returned {type(metrics).__name__}, "
                    "expected a dict of metrics"
                )
            record["metrics"] = to_jsonable({str(k): v for k, v in metrics.items()})
        except Exception as err:
            record.update(
                status="failed",
                error=f"{type(err).__name__}: {err}",
                traceback=traceback.format_exc(),
            )
    messages = [f"{w.category.__name__}: {w.message}" for w in caught]
    record["warnings"] = list(dict.fromkeys(messages))[:MAX_WARNINGS]
    record.update(
        started=started,
        finished=_now(),
        elapsed_s=time.perf_counter() - t0,
        worker={
            "host": socket.gethostname(),
            "pid": os.getpid(),
            "x64": bool(jax.config.jax_enable_x64),
            "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "jax_cache": jax.config.jax_compilation_cache_dir,
        },
    )
    return record


# ----------------------------------------------------------------------------- running
def run_sweep(
    spec: SweepSpec | Mapping[str, Any] | str | os.PathLike,
    out_dir: str | os.PathLike,
    scheduler: str | Any | None = None,
    workers: int | None = None,
    cell_fn: str | Callable[[dict], Mapping[str, Any]] | None = None,
    *,
    progress: bool = True,
    worker_env: Mapping[str, str] | None = None,
    figures: bool = True,
) -> Any:
    """Run every unfinished cell of a sweep on Dask and gather the results table.

    Parameters
    ----------
    spec
        A :class:`SweepSpec`, a TOML file path, or the spec as a mapping.
    out_dir
        The sweep folder (created). Finished cells already in it are skipped; failed ones rerun.
    scheduler
        ``None``: start a local cluster of processes (one worker per core, or ``workers``),
        single-threaded each. An address (``"tcp://host:8786"``): run on that Dask cluster. A
        :class:`dask.distributed.Client`: use it (it is left open).
    workers
        Number of local worker processes (default: the cores this process may use); never more
        than the cells to run. Only for the local cluster.
    cell_fn
        ``cell_fn(settings: dict) -> dict`` of metrics, or ``"module:function"`` importable on
        the workers. Default: the spec's ``cell_fn``, else :data:`DEFAULT_CELL_FN`.
    progress
        Show a progress bar that moves once per finished cell.
    worker_env
        Extra environment variables for the local workers (see :func:`worker_environment`).
    figures
        Draw one figure per metric into ``out_dir/figures`` (:func:`~.paper_study.plot_sweep`).

    Returns
    -------
    pandas.DataFrame
        The results table, also written to ``results.csv`` and ``results.parquet``: one row per
        cell of the spec with ``cell_id``, the settings, ``status``, ``elapsed_s`` (the task's
        wall time), the metrics, ``error``, ``warnings`` (the distinct warnings the cell raised,
        joined by " | "), ``started``, ``finished``. The table's
        ``attrs["sweep"]`` holds the counts and this call's wall time.

    Raises
    ------
    SweepError
        A bad spec, or an out_dir holding a sweep made with another cell function.
    ValueError
        A cell function that cannot be resolved, ``workers`` < 1 or given with ``scheduler``, an
        unreachable scheduler.
    """
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1
    ):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if workers is not None and scheduler is not None:
        raise ValueError(
            "workers sets the size of the local cluster; do not give it with scheduler"
        )

    spec = _as_spec(spec)
    fn = cell_fn if cell_fn is not None else (spec.cell_fn or DEFAULT_CELL_FN)
    fn_name = _cell_fn_name(fn)
    resolve_cell_fn(fn)  # fail fast, in the client, on a name that does not resolve

    out = Path(out_dir)
    cells_dir = out / CELLS_DIR
    cells_dir.mkdir(parents=True, exist_ok=True)
    _write_manifest(out, spec, fn_name)

    done = {c.id for c in spec.cells if _is_finished(cells_dir / f"{c.id}.json")}
    todo = [c for c in spec.cells if c.id not in done]
    t_start = time.perf_counter()
    num_failed = 0
    if todo:
        from tqdm.auto import tqdm

        bar = tqdm(
            total=len(spec.cells),
            initial=len(done),
            desc=spec.name,
            unit="cell",
            disable=not progress,
            dynamic_ncols=True,
        )
        try:
            with _client(scheduler, workers, len(todo), worker_env) as client:
                num_failed = _execute(client, todo, fn, fn_name, cells_dir, bar)
        finally:
            bar.close()
    table = load_results(out, spec)
    _write_table(table, out)
    if figures:
        from symplid.experiments.paper_study import (
            plot_sweep,  # the study module builds on this one
        )

        plot_sweep(table, out / FIGURES_DIR)
    table.attrs["sweep"] = {
        "cells": len(spec.cells),
        "skipped": len(done),
        "ran": len(todo),
        "failed_now": num_failed,
        "failed": int((table["status"] == "failed").sum()),
        "wall_time_s": time.perf_counter() - t_start,
    }
    return table


def _as_spec(spec: SweepSpec | Mapping[str, Any] | str | os.PathLike) -> SweepSpec:
    if isinstance(spec, SweepSpec):
        return spec
    if isinstance(spec, Mapping):
        return sweep_spec_from_dict(spec)
    return load_sweep_spec(spec)


def _execute(
    client: Any,
    todo: list[Cell],
    fn: Any,
    fn_name: str,
    cells_dir: Path,
    bar: Any,
) -> int:
    """Submit one task per cell; write each record as it completes. Returns the failures."""
    import uuid

    from dask.distributed import as_completed

    tag = uuid.uuid4().hex[:8]  # keys unique per call: a shared cluster never reuses a result
    futures = {
        client.submit(
            _run_cell_task,
            c.settings,
            fn,
            key=f"symplid-cell-{c.id}-{tag}",
            pure=False,
        ): c
        for c in todo
    }
    failed = 0
    try:
        for future in as_completed(futures):
            cell = futures[future]
            try:
                record = future.result()
            except Exception as err:  # the worker died, the task was cancelled, ...
                record = _lost_record(err)
            record = {"id": cell.id, "settings": cell.settings, "cell_fn": fn_name, **record}
            write_json(record, cells_dir / f"{cell.id}.json")
            failed += record["status"] != "ok"
            bar.update(1)
            if failed:
                bar.set_postfix(failed=failed)
            future.release()
    except BaseException:
        client.cancel(list(futures))
        raise
    return failed


def _lost_record(err: BaseException) -> dict[str, Any]:
    now = _now()
    return {
        "status": "failed",
        "metrics": None,
        "error": f"{type(err).__name__}: {err} (the task did not return; its worker may have died)",
        "traceback": "".join(traceback.format_exception(err)),
        "warnings": [],
        "started": None,
        "finished": now,
        "elapsed_s": math.nan,
        "worker": None,
    }


@contextlib.contextmanager
def _client(
    scheduler: Any, workers: int | None, num_tasks: int, worker_env: Mapping[str, str] | None
) -> Iterator[Any]:
    from dask.distributed import Client, LocalCluster

    if isinstance(scheduler, Client):
        yield scheduler
        return
    if scheduler is not None:
        try:
            client = Client(str(scheduler), timeout="20s")
        except (OSError, TimeoutError) as err:
            raise ValueError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = min(int(workers) if workers is not None else _num_cores(), num_tasks)
    with (
        LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            env=worker_environment(worker_env),
            dashboard_address="127.0.0.1:0",  # a free port: no clash with other clusters
            silence_logs=logging.ERROR,
            memory_limit=0,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _num_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _is_finished(path: Path) -> bool:
    if not path.exists():
        return False
    try:
        return read_json(path).get("status") == "ok"
    except Exception:  # a damaged record: run the cell again
        return False


def _write_manifest(out: Path, spec: SweepSpec, fn_name: str) -> None:
    path = out / MANIFEST
    if path.exists():
        try:
            old = read_json(path)
        except Exception:
            old = {}
        if isinstance(old, dict) and old.get("cell_fn") not in (None, fn_name):
            raise SweepError(
                str(path),
                None,
                f"this folder holds a sweep run with cell_fn {old['cell_fn']!r}, not {fn_name!r}; "
                "use another output folder",
            )
    write_json(
        {
            "name": spec.name,
            "source": spec.source,
            "cell_fn": fn_name,
            "spec": spec.to_dict(),
            "cells": [{"id": c.id, "settings": c.settings} for c in spec.cells],
        },
        path,
    )


# ----------------------------------------------------------------------------- the table
_BOOKKEEPING = ("cell_id", "status", "elapsed_s", "error", "warnings", "started", "finished")


def load_results(out_dir: str | os.PathLike, spec: SweepSpec | None = None) -> Any:
    """The results table of a sweep folder, from its cell records (pandas DataFrame).

    One row per cell of ``spec`` (default: the cells listed in the folder's ``sweep.json``), in
    the spec's order; a cell without a record has status ``"pending"``. Metric columns that
    would clash with a settings or bookkeeping column are prefixed ``metric_``.
    """
    import pandas as pd

    out = Path(out_dir)
    if spec is not None:
        cells = [(c.id, c.settings) for c in spec.cells]
    else:
        manifest = out / MANIFEST
        if not manifest.exists():
            raise SweepError(str(out), None, f"not a sweep folder (no {MANIFEST})")
        cells = [(c["id"], c["settings"]) for c in read_json(manifest)["cells"]]
    rows = []
    setting_cols: list[str] = []
    metric_cols: list[str] = []
    for cid, settings in cells:
        for k in settings:
            if k not in setting_cols:
                setting_cols.append(k)
        path = out / CELLS_DIR / f"{cid}.json"
        record = read_json(path) if path.exists() else {"status": "pending"}
        row = {"cell_id": cid, **settings}
        row["status"] = record.get("status", "pending")
        for key in ("elapsed_s", "error", "started", "finished"):
            row[key] = record.get(key)
        row["warnings"] = " | ".join(record.get("warnings") or []) or None
        for k, v in _flatten(record.get("metrics") or {}).items():
            name = f"metric_{k}" if k in settings or k in _BOOKKEEPING else k
            if name not in metric_cols:
                metric_cols.append(name)
            row[name] = v
        rows.append(row)
    columns = ["cell_id", *setting_cols, "status", "elapsed_s", *metric_cols, "error", "warnings"]
    columns += ["started", "finished"]
    table = pd.DataFrame(rows, columns=columns)
    return _tidy_types(table)


def _flatten(metrics: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in metrics.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        elif isinstance(v, list):
            out[f"{prefix}{k}"] = json.dumps(v)
        else:
            out[f"{prefix}{k}"] = v
    return out


def _tidy_types(table: Any) -> Any:
    """Object columns of numbers become float; mixed ones become strings (Parquet-safe)."""
    import pandas as pd

    for col in table.columns:
        if table[col].dtype != object:
            continue
        values = table[col].dropna()
        if values.empty:
            continue
        if all(isinstance(v, bool) for v in values):
            continue
        if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            table[col] = pd.to_numeric(table[col], errors="coerce").astype(float)
        elif not all(isinstance(v, str) for v in values):
            table[col] = table[col].map(lambda v: None if v is None else str(v))
    return table


def _write_table(table: Any, out: Path) -> None:
    for name, write in (
        (RESULTS_CSV, lambda p: table.to_csv(p, index=False)),
        (RESULTS_PARQUET, lambda p: table.to_parquet(p, index=False)),
    ):
        path = out / name
        tmp = path.with_name(f".{name}.tmp")
        write(tmp)
        os.replace(tmp, path)
