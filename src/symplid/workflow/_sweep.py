"""Sweeps: many fits over a grid of settings, each one a task on Dask, gathered in one table.

A sweep is described in TOML by two tables::

    [base]                      # fixed settings of every cell (any key below; defaults otherwise)
    system = "henon-heiles"
    num_iterations = 20000
    burn_in = 10000
    num_chains = 2

    [sweep]
    name = "seeds-and-propagators"          # optional, shown in the progress bar
    experiment = "paper"                    # optional (the default): keys, cell function, figures
    grid = { seed = [0, 1, 2], integrator = ["leapfrog", "rk2-midpoint"] }
    cells = [ {}, { dt = 0.1 }, { noise_std = 0.01 } ]

``grid`` is a Cartesian product (one list of values per key). ``cells`` is an explicit list of
partial settings. When both are given, **every entry of** ``cells`` **is combined with every point
of** ``grid``: the example above is 3 × (3 × 2) = 18 cells, the paper's setting and two variants,
each over three seeds and both propagators. Give only ``grid`` for a plain product, only ``cells``
for a plain list. A cell's settings are, in increasing priority: the defaults, ``[base]``, then
its grid point and its ``cells`` entry (a key may not be in both ``grid`` and ``cells``).

The keys of a cell are those its **experiment** declares (an
:class:`~symplid.workflow._experiment.Experiment`, given to :func:`run_sweep` as an object or
named by the spec and registered in :data:`~symplid.workflow._experiment.EXPERIMENTS`; the
default name is the paper's, whose keys are listed in :mod:`symplid.studies._paper` and which
the ``symplid sweep`` command registers with the other studies), each with
its type, default, range and the run setting it stands for, plus any key of the run settings in
dotted form (``"model.process_noise_per" = "step"``, ``"sampler.gamma" = 0.02``, ``"map.seed" =
7``). Every value is checked by the one validator (:mod:`symplid.workflow._validate`): an
experiment key against its spec, a dotted key by building the cell's run settings
(:func:`cell_settings`). A run setting that the experiment has a key for must be given by that
key. The old key ``num_samples`` (and ``sampler.num_samples``) is read as ``num_iterations``
with a ``FutureWarning``.

Every cell gets a **stable id**: the first 12 hex digits of the SHA-256 of its fully resolved
settings (defaults included, as sorted JSON). A rerun of the same spec into the same folder finds
its finished cells by id and skips them; cells that failed are run again.

The output folder::

    sweep.json          the spec, the experiment, the cell function's name and the cell ids
    cells/<id>.json     one record per cell: settings, status ("ok" / "failed"), metrics,
                        error and traceback, the warnings raised, start and end times, the worker
    results.csv         one row per cell: id, settings, status, elapsed_s, metrics, error,
                        warnings
    results.parquet     the same table
    figures/<metric>.png  every cell's value of a metric, by setting (the experiment's figures)

The cell function
-----------------
``cell_fn(cell: dict) -> dict`` takes the resolved settings of one cell (the experiment's keys
and any dotted keys) and returns a flat dict of metrics (numbers or short strings; nested dicts
are flattened to ``"a.b"`` columns). The default is the experiment's ``run_cell``; ``cell_fn =
"module:function"`` in ``[sweep]`` (or the ``cell_fn`` argument) runs another function on the
experiment's cells. :func:`cell_settings` turns a cell into its run settings so that every cell
function reads a cell the same way.

Workers
-------
Sweeps need Dask and pyarrow, the ``sweeps`` extra (``pip install 'symplid[sweeps]'``); without
them :func:`run_sweep` raises :class:`symplid.runtime.MissingExtraError`, which says so. By
default a :class:`dask.distributed.LocalCluster` of processes is started, one worker per core
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

import numbers
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from symplid.plotting._sweep import plot_sweep
from symplid.workflow._experiment import EXPERIMENTS, Experiment
from symplid.workflow._results import read_json, write_json
from symplid.workflow._sweep_results import CELLS_DIR, MANIFEST, load_results, write_table
from symplid.workflow._sweep_spec import (
    DEFAULT_EXPERIMENT,
    Cell,
    SweepError,
    SweepSpec,
    cell_id,
    cell_settings,
    get_experiment,
    load_sweep_spec,
    resolve_cell,
    sweep_spec_from_dict,
)
from symplid.workflow._sweep_tasks import (
    XLA_SINGLE_THREAD,
    cell_fn_name,
    dask_client,
    execute_cells,
    require_sweep_modules,
    resolve_cell_fn,
    same_cell_fn,
    worker_environment,
)

__all__ = [
    "DEFAULT_EXPERIMENT",
    "EXPERIMENTS",
    "XLA_SINGLE_THREAD",
    "Cell",
    "Experiment",
    "SweepError",
    "SweepSpec",
    "cell_id",
    "cell_settings",
    "get_experiment",
    "load_results",
    "load_sweep_spec",
    "resolve_cell",
    "resolve_cell_fn",
    "run_sweep",
    "sweep_spec_from_dict",
    "worker_environment",
]

FIGURES_DIR = "figures"


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
    experiment: Experiment | None = None,
) -> Any:
    """Run every unfinished cell of a sweep on Dask and gather the results table.

    (Its length is the documentation of its parameters; the body is a list of steps, each a
    function of its own.)

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
        the workers. Default: the spec's ``cell_fn``, else the experiment's ``run_cell``.
    progress
        Show a progress bar that moves once per finished cell.
    worker_env
        Extra environment variables for the local workers (see :func:`worker_environment`).
    figures
        Draw the experiment's figures into ``out_dir/figures`` (its ``figures`` function, or
        :func:`symplid.plotting._sweep.plot_sweep` of its metrics).
    experiment
        The experiment whose cells the spec holds (its keys, cell function and figures); the
        spec's ``experiment``, if it names one, must be its name. ``None``: the one the spec
        names, looked up in :data:`~symplid.workflow._experiment.EXPERIMENTS`.

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
    symplid.runtime.MissingExtraError
        Dask or pyarrow is not installed (``pip install 'symplid[sweeps]'``).
    ValueError
        A cell function that cannot be resolved, ``workers`` < 1 or given with ``scheduler``, an
        unreachable scheduler.
    """
    _check_workers(workers, scheduler)
    require_sweep_modules()
    spec = _as_spec(spec, experiment)
    if experiment is not None and spec.experiment != experiment.name:
        raise SweepError(spec.source, "sweep.experiment", f"is {spec.experiment!r}, but the "
                         f"sweep was given the experiment {experiment.name!r}")
    experiment = experiment or get_experiment(spec.experiment, spec.source)
    fn = cell_fn if cell_fn is not None else (spec.cell_fn or experiment.run_cell)
    fn_name = cell_fn_name(fn)
    resolve_cell_fn(fn)  # fail fast, in the client, on a name that does not resolve

    out = Path(out_dir)
    cells_dir = out / CELLS_DIR
    cells_dir.mkdir(parents=True, exist_ok=True)
    _write_manifest(out, spec, fn_name)

    done = {c.id for c in spec.cells if _is_finished(cells_dir / f"{c.id}.json")}
    todo = [c for c in spec.cells if c.id not in done]
    t_start = time.perf_counter()
    num_failed = (_run_cells(spec, todo, len(done), (fn, fn_name), cells_dir,
                             (scheduler, workers, worker_env), progress) if todo else 0)
    table = load_results(out, spec)
    write_table(table, out)
    if figures:
        draw_figures(experiment, table, out / FIGURES_DIR, spec.setting_columns)
    table.attrs["sweep"] = {
        "cells": len(spec.cells), "skipped": len(done), "ran": len(todo),
        "failed_now": num_failed, "failed": int((table["status"] == "failed").sum()),
        "wall_time_s": time.perf_counter() - t_start,
    }
    return table


def _check_workers(workers: Any, scheduler: Any) -> None:
    """``workers``: a positive integer, and only for the local cluster (no ``scheduler``)."""
    if workers is not None and (
        isinstance(workers, bool) or not isinstance(workers, numbers.Integral) or workers < 1
    ):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if workers is not None and scheduler is not None:
        raise ValueError(
            "workers sets the size of the local cluster; do not give it with scheduler"
        )


def _run_cells(spec: SweepSpec, todo: list, num_done: int, cell: tuple[Any, str],
               cells_dir: Path, cluster: tuple[Any, int | None, Mapping[str, str] | None],
               progress: bool) -> int:
    """Run the cells ``todo`` on Dask (``cluster``: scheduler, local workers, their
    environment) with a bar that moves once per finished cell; returns how many failed."""
    from tqdm.auto import tqdm

    scheduler, workers, worker_env = cluster
    bar = tqdm(total=len(spec.cells), initial=num_done, desc=spec.name, unit="cell",
               disable=not progress, dynamic_ncols=True)
    try:
        with dask_client(scheduler, workers, len(todo), worker_env) as client:
            return execute_cells(client, todo, *cell, cells_dir, bar)
    finally:
        bar.close()


def _as_spec(
    spec: SweepSpec | Mapping[str, Any] | str | os.PathLike, experiment: Experiment | None
) -> SweepSpec:
    if isinstance(spec, SweepSpec):
        return spec
    if isinstance(spec, Mapping):
        return sweep_spec_from_dict(spec, experiment=experiment)
    return load_sweep_spec(spec, experiment)


def draw_figures(
    experiment: Experiment, table: Any, folder: Path, settings: list[str]
) -> Mapping[str, Path]:
    """The experiment's figures of a results table (by default one per metric)."""
    if experiment.figures is not None:
        return experiment.figures(table, folder, settings)
    return plot_sweep(table, folder, settings=settings, metrics=experiment.metrics or None)


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
        previous = old.get("cell_fn") if isinstance(old, dict) else None
        if previous is not None and not same_cell_fn(previous, fn_name):
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
            "experiment": spec.experiment,
            "cell_fn": fn_name,
            "spec": spec.to_dict(),
            "cells": [{"id": c.id, "settings": c.settings} for c in spec.cells],
        },
        path,
    )
