"""BLAS on one thread: :func:`symplid.runtime.one_blas_thread` and
:func:`symplid.runtime.limit_blas_threads`.

Each check runs in a child process with a known environment (no thread variable unless the
test sets one), and reads every loaded OpenBLAS's thread count through the library's own C
function (not through threadpoolctl, which the code under test uses):

* inside the block every OpenBLAS runs one thread, after it the count it had (set to 2 first);
  the decorator form does the same for the call; of two blocks that overlap (the first to
  enter leaving first, as in two threads), the limit holds until the last one leaves;
* a count the user set in the environment is kept;
* the process-wide limit reaches a library loaded before it (NumPy's) and one loaded after it
  (SciPy's linear algebra), and is kept when the user set a count.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from symplid import runtime

SRC = str(Path(__file__).resolve().parents[1] / "src")

COUNTS = r"""
import ctypes, json
def counts():
    with open("/proc/self/maps") as maps:
        paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower()})
    out = {}
    for path in paths:
        lib = ctypes.CDLL(path)
        for name in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                     "openblas_get_num_threads64_", "openblas_get_num_threads"):
            getter = getattr(lib, name, None)
            if getter is not None:
                getter.restype = ctypes.c_int
                out[path] = int(getter())
                break
    return out
"""

BLOCK = COUNTS + r"""
import numpy, scipy.linalg
from threadpoolctl import threadpool_limits
from symplid import runtime
threadpool_limits(limits=2, user_api="blas")
before = counts()
with runtime.one_blas_thread():
    inside = counts()
after = counts()
called = runtime.one_blas_thread()(counts)()
first, second = runtime.one_blas_thread(), runtime.one_blas_thread()
first.__enter__()
second.__enter__()  # blocks that overlap (as in two threads) share the limit
first.__exit__(None, None, None)  # the first to enter leaves first
still = counts()  # the second still holds it
second.__exit__(None, None, None)
print(json.dumps([before, inside, after, called, still, counts()]))
"""

PROCESS = COUNTS + r"""
import os, numpy
from symplid import runtime
runtime.limit_blas_threads()
import scipy.linalg  # its own OpenBLAS, loaded after the limit
print(json.dumps([counts(), os.environ.get("OPENBLAS_NUM_THREADS")]))
"""


def _child(code: str, **variables: str) -> list:
    env = {k: v for k, v in os.environ.items() if k not in runtime.THREAD_VARIABLES}
    env.update(variables, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _openblas_or_skip(counts: dict) -> None:
    if not counts:
        pytest.skip("NumPy and SciPy load no OpenBLAS here")


def test_one_blas_thread_inside_the_block_and_the_count_restored_after():
    before, inside, after, called, still, last = _child(BLOCK)
    _openblas_or_skip(before)
    assert set(inside.values()) == {1} and set(called.values()) == {1}
    assert set(still.values()) == {1}
    assert after == before == last


def test_one_blas_thread_keeps_a_count_the_user_set():
    before, inside, after, called, still, last = _child(BLOCK, OPENBLAS_NUM_THREADS="2")
    _openblas_or_skip(before)
    assert inside == before == after == called == still == last


def test_limit_blas_threads_reaches_libraries_loaded_before_and_after():
    counts, variable = _child(PROCESS)
    _openblas_or_skip(counts)
    assert len(counts) >= 1 and set(counts.values()) == {1}
    assert variable == "1"


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: OpenBLAS runs one thread")
def test_limit_blas_threads_keeps_a_count_the_user_set():
    counts, variable = _child(PROCESS, OPENBLAS_NUM_THREADS="2")
    _openblas_or_skip(counts)
    assert set(counts.values()) == {2} and variable == "2"
