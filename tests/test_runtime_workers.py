"""Worker processes: one core and one-thread pools, set before NumPy and JAX load.

* A process started inside :func:`symplid.runtime.worker_environment` with
  :func:`symplid.runtime.pin_worker` as its pool's initializer starts with the one-thread
  variables in its environment before it has imported NumPy or JAX, runs on one core (worker
  *i* on core *i*), and OpenBLAS inside NumPy reports one thread (asked through its own C
  function, not through the variable we set).
* Importing the paper's experiment does no JAX work: JAX's backend has not started, so a
  worker can still choose its threads after the import; nor does it load matplotlib (the
  workers draw no figure).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from symplid import runtime

SRC = str(Path(__file__).resolve().parents[1] / "src")
OPENBLAS_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                    "openblas_get_num_threads64_", "openblas_get_num_threads")

_SEEN_AT_START: dict[str, object] = {}


def _initializer(counter) -> None:
    # what the process had loaded and in its environment before anything else ran
    _SEEN_AT_START["modules"] = sorted(m for m in ("numpy", "jax") if m in sys.modules)
    _SEEN_AT_START["env"] = {name: os.environ.get(name) for name in
                             (*runtime.THREAD_VARIABLES, "XLA_FLAGS")}
    _SEEN_AT_START["core"] = runtime.pin_worker(counter)


def _openblas_threads() -> int | None:
    import numpy  # noqa: F401  (loads OpenBLAS)

    with open("/proc/self/maps") as maps:
        paths = {line.split()[-1] for line in maps if "openblas" in line.lower()}
    for path in paths:
        lib = ctypes.CDLL(path)
        for name in OPENBLAS_GETTERS:
            getter = getattr(lib, name, None)
            if getter is not None:
                getter.restype = ctypes.c_int
                return int(getter())
    return None


def _report(_: int) -> dict[str, object]:
    import jax

    from symplid.runtime import backend_started

    started_before = backend_started()
    jax.numpy.zeros(1).block_until_ready()  # start the backend here, pinned
    return {**_SEEN_AT_START, "openblas": _openblas_threads(),
            "affinity": sorted(os.sched_getaffinity(0)), "started_before": started_before,
            "pid": os.getpid()}


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinity here")
def test_spawned_workers_are_pinned_and_single_threaded_before_imports():
    cores = sorted(os.sched_getaffinity(0))
    context = multiprocessing.get_context("spawn")
    counter = context.Value("i", 0)
    before = dict(os.environ)
    with runtime.worker_environment() as env, ProcessPoolExecutor(
        2, mp_context=context, initializer=_initializer, initargs=(counter,)
    ) as pool:
        reports = list(pool.map(_report, range(2)))
    assert dict(os.environ) == before  # this process's environment is restored
    assert len({r["pid"] for r in reports}) == 2
    for r in reports:
        assert r["modules"] == []  # nothing numerical loaded before the initializer
        assert r["env"] == env and r["env"]["OPENBLAS_NUM_THREADS"] == "1"
        assert "--xla_cpu_multi_thread_eigen=false" in r["env"]["XLA_FLAGS"].split()
        assert r["started_before"] is False
        assert len(r["affinity"]) == 1 and r["affinity"] == [r["core"]]
        if r["openblas"] is not None:
            assert r["openblas"] == 1
    assert sorted(r["core"] for r in reports) == sorted(cores[i % len(cores)] for i in range(2))


def test_pin_worker_by_index_wraps_around_the_allowed_cores():
    cores = sorted(os.sched_getaffinity(0))
    code = ("import os; from symplid import runtime; "
            f"print(runtime.pin_worker(index={len(cores) + 1}), sorted(os.sched_getaffinity(0)))")
    out = _python(code).split()
    expected = cores[(len(cores) + 1) % len(cores)]
    assert out[0] == str(expected) and out[1] == f"[{expected}]"


def test_cores_for_a_while_moves_this_process_and_back():
    """In a child process (this one's affinity stays untouched): inside the block it runs on
    the last allowed core only, after it on all of them again; None changes nothing."""
    code = ("import os; from symplid import runtime; before = runtime.own_cores(); "
            "cm = runtime.cores_for_a_while(before[-1:])\n"
            "with cm: inside = sorted(os.sched_getaffinity(0))\n"
            "with runtime.cores_for_a_while(None): untouched = runtime.own_cores()\n"
            "print(before, inside, runtime.own_cores(), untouched, sep='|')")
    before, inside, after, untouched = _python(code).strip().split("|")
    cores = sorted(os.sched_getaffinity(0))
    assert before == after == untouched == str(cores)
    assert inside == str(cores[-1:])


def test_worker_environment_keeps_the_users_xla_flags(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/x")
    env = runtime.single_thread_environment()
    tokens = env["XLA_FLAGS"].split()
    assert "--xla_dump_to=/x" in tokens and "--xla_cpu_multi_thread_eigen=false" in tokens
    assert all(env[name] == "1" for name in runtime.THREAD_VARIABLES)


def test_importing_the_paper_experiment_starts_no_jax_backend_and_no_matplotlib():
    code = ("import symplid.studies._paper, symplid.workflow._fit, sys; "
            "from symplid.runtime import backend_started; "
            "assert 'jax' in sys.modules; "
            "print(backend_started(), 'matplotlib' in sys.modules)")
    assert _python(code).split() == ["False", "False"]


def _python(code: str) -> str:
    environ = dict(os.environ)
    environ["PYTHONPATH"] = SRC + os.pathsep + environ.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True,
                          text=True, check=True).stdout
