"""The sweep's workers: the task that runs one cell, its environment, and the Dask client.

Each worker process runs JAX single-threaded (:data:`XLA_SINGLE_THREAD`) and in float64 (the
task imports :mod:`symplid`), so that N workers use N cores and no more; a failing cell
becomes a record with its traceback, never an exception in the client.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import importlib
import logging
import math
import os
import signal
import socket
import time
import traceback
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from symplid import runtime
from symplid._stopping import check as check_stop
from symplid.workflow._results import to_jsonable, write_json
from symplid.workflow._sweep_spec import Cell

__all__ = [
    "SWEEP_MODULES",
    "XLA_SINGLE_THREAD",
    "cell_fn_name",
    "dask_client",
    "execute_cells",
    "require_sweep_modules",
    "resolve_cell_fn",
    "same_cell_fn",
    "worker_environment",
]

#: XLA flags that keep a JAX process on one CPU thread.
XLA_SINGLE_THREAD = runtime.single_thread_xla_flags()  # bare token last (see runtime)
MAX_WARNINGS = 20  # distinct warning messages kept per cell
#: What a sweep needs beyond the core: its workers (Dask) and its table's Parquet file
#: (pyarrow), both the ``sweeps`` extra.
SWEEP_MODULES = ("dask.distributed", "pyarrow")


def require_sweep_modules() -> None:
    """:class:`symplid.runtime.MissingExtraError` (``pip install 'symplid[sweeps]'``) unless
    Dask and pyarrow are installed."""
    runtime.require_extra("sweeps", "a sweep", *SWEEP_MODULES)


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


def same_cell_fn(a: str, b: str) -> bool:
    """Whether two ``"module:function"`` names are one cell function: equal, or one names
    its module by the path it had before the package's modules became private
    (``symplid.studies.paper:run_cell`` for ``symplid.studies._paper:run_cell``), as a sweep
    folder written by the previous version does."""
    def public(name: str) -> str:
        module, _, function = name.partition(":")
        return ".".join(part.removeprefix("_") for part in module.split(".")) + ":" + function
    return a == b or public(a) == public(b)


def cell_fn_name(cell_fn: str | Callable) -> str:
    if isinstance(cell_fn, str):
        return cell_fn
    module = getattr(cell_fn, "__module__", None) or "?"
    return f"{module}:{getattr(cell_fn, '__qualname__', repr(cell_fn))}"


def worker_environment(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment of a sweep worker process: single-threaded XLA and BLAS, plus ``extra``.

    ``XLA_FLAGS`` keeps JAX on one thread (``--xla_cpu_multi_thread_eigen=false
    intra_op_parallelism_threads=1``); ``OMP/MKL/OPENBLAS_NUM_THREADS = 1`` do the same for
    NumPy and SciPy (:func:`symplid.runtime.single_thread_environment`), so that one worker
    per core never oversubscribes the machine.
    """
    env = runtime.single_thread_environment(XLA_SINGLE_THREAD)
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
    runtime.limit_threads()  # if this worker has not used JAX yet
    import jax  # symplid is imported with this module, so float64 is on

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


def execute_cells(
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
        for future in _completed(as_completed(futures)):
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


def _completed(pending: Any) -> Iterator[Any]:
    """The futures of a Dask ``as_completed`` as they finish, with a stop requested by a
    signal (:mod:`symplid._stopping`) obeyed between them within a tenth of a second."""
    while not pending.is_empty():
        check_stop()
        if pending.has_ready():
            yield from pending.next_batch(block=False)
        else:
            time.sleep(0.1)


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
def dask_client(
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
        try:
            yield client
        except BaseException:  # Ctrl-C above all: the cells still running are not waited for
            _end_local_workers(client)
            raise


def _end_local_workers(client: Any) -> None:
    """End the worker processes of the local cluster at once, by their ids.

    Closing the cluster waits for the cells that are running, which on Ctrl-C took 5–10 s;
    their results would be lost anyway (a rerun runs unfinished cells again), and the
    workers write nothing themselves. Nothing is done when the workers cannot be asked.
    """
    try:
        pids = list(client.run(os.getpid).values())
    except Exception:  # a worker already gone, the scheduler closing: the plain close follows
        return
    for pid in pids:  # worker processes of their own (processes=True above)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, getattr(signal, "SIGKILL", signal.SIGTERM))


def _num_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
