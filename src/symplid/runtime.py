"""Process-wide settings for symplid's own processes (CLI, workers, tests), in one place.

Nothing here runs at import: each setting is turned on by a call.

**Compilation cache.** JAX's persistent compilation cache.

Compiling the filter's gradient and Hessian for a MAP fit takes tens of seconds; the same
model structure compiles to the same program, so the second run of a command reuses the
compiled code from disk. The library never turns this on at import (it is a global JAX
setting); the command line and the worker processes it starts do.

Every program is kept, however quick its compilation: a fit also runs a hundred small ones
(the bijectors, random draws, the start's array arithmetic) that compile in 0.02–0.2 s each,
about 6 s of a warm pendulum fit when compiled again in every process; they are read back
from disk instead.

The folder is ``$SYMPLID_CACHE_DIR``, else ``$XDG_CACHE_HOME/symplid/jax``, else
``~/.cache/symplid/jax``; ``SYMPLID_CACHE_DIR=off`` disables it.

**XLA flags.** :func:`configure_xla` is the one exception to "nothing at import": it runs
when :mod:`symplid` is imported, before JAX starts its backend, because XLA reads
``XLA_FLAGS`` once, when the backend starts. It asks XLA:CPU to compile small ``while`` loops
whole (``xla_cpu_small_while_loop_byte_threshold``): the filter's loops are just over XLA's
default threshold of 1 KiB, and compiled as one kernel the log-likelihood is about 3× and
its gradient about 7× faster on one core. Numbers do not change, only how the loop is run.
A user's own ``XLA_FLAGS`` are kept (merged, theirs win); ``SYMPLID_XLA_FLAGS=off`` turns
this off; a one-line :class:`XlaFlagsWarning` says when JAX had started already.

**The bare-token rule.** XLA stops reading ``XLA_FLAGS`` at the first token that does not
start with ``--`` (such as ``intra_op_parallelism_threads=1``): everything after it is
silently dropped. :func:`merge_xla_flags` therefore puts every ``--flag`` first and bare
tokens last; :func:`single_thread_xla_flags` is the one place that writes the flags of a
single-threaded worker process.

**Worker processes.** A process that runs one fit beside others (``reproduce``'s two
approaches, a sweep's cells) should use one core and one thread: XLA's and OpenBLAS's
thread pools of two workers on two cores otherwise spin against each other (measured: a
third more CPU per DRAM iteration). :func:`single_thread_environment` is the environment of
such a process (XLA, OpenBLAS, MKL and OpenMP on one thread), which must be in place before
NumPy or JAX load: :func:`worker_environment` puts it into ``os.environ`` while a pool
starts its processes (a spawned process inherits it), and :func:`pin_worker` is the pool's
initializer that binds worker *i* to core *i* mod the cores this process may use. XLA:CPU
has no flag for the size of its intra-op pool: it is the number of cores the process may
run on, so pinning (before the backend starts) is what makes it one.

**BLAS on one thread.** The MAP search (L-BFGS-B), its Hessians' eigendecompositions and the
evidence's inner searches call LAPACK on matrices of a few rows, thousands of times a fit.
OpenBLAS hands each call to its thread pool, and when the other core is busy the caller waits
for that thread's time slice: measured on two shared cores (load 8), a 7-parameter L-BFGS-B
search took 60–400 ms with OpenBLAS's two threads against 0.5 ms on one, and a warm fit of an
elastic pendulum spent 28 of its 77 s inside L-BFGS-B's own arithmetic. Nothing in a fit gains
from BLAS threads (its large arithmetic is XLA's, with its own pool), and the numbers do not
change: :func:`one_blas_thread` is the block (it decorates ``find_map``, whose evidence's
inner searches run inside it), :func:`limit_blas_threads` the whole process (the command
line).
Both leave a count the user set (``THREAD_VARIABLES``) as it is.

**Optional dependencies.** What only the sweeps need (Dask, pyarrow) is the ``sweeps`` extra;
:func:`require_extra` is the one check, which names the command that installs it.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import threading
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

__all__ = [
    "MissingExtraError",
    "XlaFlagsWarning",
    "blas_threads_chosen",
    "configure_xla",
    "cores_for_a_while",
    "default_cache_dir",
    "enable_compilation_cache",
    "limit_blas_threads",
    "limit_threads",
    "merge_xla_flags",
    "one_blas_thread",
    "one_line_warnings",
    "own_cores",
    "pin_worker",
    "require_extra",
    "single_thread_environment",
    "single_thread_xla_flags",
    "small_loop_flag",
    "worker_environment",
]


class MissingExtraError(ImportError):
    """An optional dependency that a feature needs is not installed; the message says how
    to install it (one line, shown as such by the command line)."""


def require_extra(extra: str, feature: str, *modules: str) -> None:
    """Import ``modules`` (third-party names only), or raise :class:`MissingExtraError`.

    ``require_extra("sweeps", "a sweep", "dask.distributed", "pyarrow")`` raises
    ``a sweep needs dask.distributed, pyarrow, which are not installed:
    pip install 'symplid[sweeps]'`` when neither imports.
    """
    missing = []
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        verb = "is" if len(missing) == 1 else "are"
        raise MissingExtraError(f"{feature} needs {', '.join(missing)}, which {verb} not "
                                f"installed: pip install 'symplid[{extra}]'")


def default_cache_dir() -> Path | None:
    """Where the cache lives, or None when disabled by ``SYMPLID_CACHE_DIR=off``."""
    explicit = os.environ.get("SYMPLID_CACHE_DIR")
    if explicit is not None:
        return None if explicit.strip().lower() in ("", "0", "off", "none") else Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "symplid" / "jax"


def enable_compilation_cache(path: str | Path | None = None) -> Path | None:
    """Turn on the persistent cache (every compilation kept); returns the folder used.

    Does nothing when a cache folder is already configured or the cache is disabled.
    """
    import jax  # not at module level: configure_xla must run before JAX is imported

    if jax.config.jax_compilation_cache_dir:
        return Path(jax.config.jax_compilation_cache_dir)
    folder = Path(path) if path is not None else default_cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None  # a read-only home: run without the cache
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def show_warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """Write a warning as one readable line (no source path): ``symplid: warning: ...``."""
    print(f"symplid: warning: {message}", file=sys.stderr if file is None else file)


def one_line_warnings() -> None:
    """Show every warning of this process as one line (the CLI and its worker processes)."""
    warnings.showwarning = show_warning_line


# ----------------------------------------------------------------------------- XLA flags

XLA_ENV = "XLA_FLAGS"
OPT_OUT_ENV = "SYMPLID_XLA_FLAGS"
EXTRA_OPTIONS_FLAG = "--xla_backend_extra_options"
SMALL_LOOP_OPTION = "xla_cpu_small_while_loop_byte_threshold"
#: Loops whose state is under this many bytes are compiled whole (XLA's default is 1 KiB).
SMALL_LOOP_BYTES = 100_000_000
SINGLE_THREAD_FLAGS = ("--xla_cpu_multi_thread_eigen=false", "intra_op_parallelism_threads=1")


class XlaFlagsWarning(UserWarning):
    """JAX's backend started before symplid could set its XLA flags (they have no effect)."""


def merge_xla_flags(existing: str | None, *added: str) -> str:
    """``existing`` XLA flags with ``added`` ones merged in, every bare token last.

    A ``--name=value`` already in ``existing`` wins over an added one of the same name;
    ``--xla_backend_extra_options`` lists (``key=value,key=value``) are merged key by key,
    again the existing value winning. Bare tokens (not starting with ``--``) end XLA's flag
    parsing, so they are moved to the end, in their order, without duplicates.
    """
    flags: dict[str, str] = {}  # name -> token, in order
    bare: list[str] = []
    for token in [*(existing or "").split(), *added]:
        if not token.startswith("--"):
            if token not in bare:
                bare.append(token)
            continue
        name, _, value = token.partition("=")
        if name == EXTRA_OPTIONS_FLAG and name in flags:
            old = _extra_options(flags[name].partition("=")[2])
            new = _extra_options(value)
            merged = {**old, **{k: v for k, v in new.items() if k not in old}}  # user's wins
            flags[name] = f"{name}=" + ",".join(
                key if val is None else f"{key}={val}" for key, val in merged.items()
            )
        elif name not in flags:
            flags[name] = token
    return " ".join([*flags.values(), *bare])


def _extra_options(text: str) -> dict[str, str | None]:
    out: dict[str, str | None] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, sep, value = item.partition("=")
        out[key] = value if sep else None
    return out


def small_loop_flag(threshold: int = SMALL_LOOP_BYTES) -> str:
    """The flag that makes XLA:CPU compile loops of up to ``threshold`` bytes as one kernel."""
    return f"{EXTRA_OPTIONS_FLAG}={SMALL_LOOP_OPTION}={int(threshold)}"


def single_thread_xla_flags(existing: str | None = None) -> str:
    """``XLA_FLAGS`` for a one-thread worker process: single-threaded, small loops whole.

    ``existing`` (e.g. the parent's ``XLA_FLAGS``) is kept and merged by
    :func:`merge_xla_flags`, so no flag is lost behind a bare token.
    """
    added = [SINGLE_THREAD_FLAGS[0]]
    if not _opted_out():
        added.append(small_loop_flag())
    return merge_xla_flags(existing, *added, *SINGLE_THREAD_FLAGS[1:])


def limit_threads() -> None:
    """Make this process's JAX single-threaded (a worker: the parallelism is across processes).

    Only effective before JAX's backend starts; it merges with ``XLA_FLAGS`` already set.
    """
    os.environ[XLA_ENV] = single_thread_xla_flags(os.environ.get(XLA_ENV))


def _opted_out() -> bool:
    return os.environ.get(OPT_OUT_ENV, "").strip().lower() in ("off", "0", "false", "no")


def backend_started() -> bool:
    """Whether JAX has started a backend in this process (XLA flags are read then, once)."""
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - a JAX without this module
        return False
    return bool(xla_bridge.backends_are_initialized())


def configure_xla() -> str | None:
    """Put symplid's XLA flags into ``XLA_FLAGS`` before JAX starts; returns the value set.

    Called by ``import symplid``. Merged with a user's ``XLA_FLAGS`` (theirs win); nothing
    is done when ``SYMPLID_XLA_FLAGS=off`` (returns None). When JAX's backend has already
    started without the flag, the flag cannot take effect: one :class:`XlaFlagsWarning`
    says so (import symplid before using JAX, or set ``XLA_FLAGS`` yourself).
    """
    if _opted_out():
        return None
    existing = os.environ.get(XLA_ENV)
    if backend_started():
        if SMALL_LOOP_OPTION not in (existing or ""):
            warnings.warn(
                "JAX started before symplid was imported, so XLA compiles the filter's loops "
                "step by step (slower, same numbers); import symplid first or set "
                f"XLA_FLAGS='{small_loop_flag()}' (SYMPLID_XLA_FLAGS=off silences this)",
                XlaFlagsWarning,
                stacklevel=3,
            )
        return existing
    merged = merge_xla_flags(existing, small_loop_flag())
    os.environ[XLA_ENV] = merged
    return merged


# ----------------------------------------------------------------------------- workers

#: Thread-count variables of the numerical libraries below NumPy and SciPy.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def blas_threads_chosen() -> bool:
    """Whether a thread count of the numerical libraries is set in the environment (one of
    ``THREAD_VARIABLES``): then symplid keeps it."""
    return any(os.environ.get(name, "").strip() for name in THREAD_VARIABLES)


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS and LAPACK on one thread inside the block, as they were after it (module
    docstring, "BLAS on one thread"); nothing when :func:`blas_threads_chosen`. Also a
    decorator: ``@one_blas_thread()``.

    The limit is the process's (the libraries keep one count), so blocks that overlap, in
    one thread or several (MAP searches run from threads), share it: the first to enter sets
    it, the last to leave restores the counts."""
    if blas_threads_chosen():
        yield
        return
    from threadpoolctl import threadpool_limits

    with _BLAS_LOCK:
        if _BLAS["depth"] == 0:
            _BLAS["limiter"] = threadpool_limits(limits=1, user_api="blas")
        _BLAS["depth"] += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS["depth"] -= 1
            if _BLAS["depth"] == 0:  # the last block to leave restores the counts
                _BLAS.pop("limiter").restore_original_limits()


_BLAS_LOCK = threading.Lock()
_BLAS: dict = {"depth": 0}  # the blocks inside, and the first one's limiter while any is


def limit_blas_threads() -> None:
    """BLAS, LAPACK and OpenMP on one thread for the rest of this process (the command line):
    the libraries loaded already by :mod:`threadpoolctl`, those loaded later by
    ``THREAD_VARIABLES`` (also inherited by child processes). Nothing when
    :func:`blas_threads_chosen`."""
    if blas_threads_chosen():
        return
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")  # not restored: for the process's lifetime


def single_thread_environment(xla_flags: str | None = None) -> dict[str, str]:
    """The environment variables of a one-thread worker process.

    ``XLA_FLAGS`` is :func:`single_thread_xla_flags` of ``xla_flags`` (default: this
    process's), so the user's flags and symplid's small-loop flag are kept; the BLAS and
    OpenMP variables are 1. They take effect only in a process that has not yet loaded
    NumPy or started JAX's backend: a child process (see :func:`worker_environment`).
    """
    flags = os.environ.get(XLA_ENV) if xla_flags is None else xla_flags
    return {XLA_ENV: single_thread_xla_flags(flags), **dict.fromkeys(THREAD_VARIABLES, "1")}


@contextlib.contextmanager
def worker_environment() -> Iterator[dict[str, str]]:
    """``os.environ`` with :func:`single_thread_environment` while the block starts processes.

    A spawned process copies the environment when it starts, before it imports anything, so
    NumPy and JAX load one-threaded there; this process's own libraries, loaded already, are
    not affected, and its environment is restored when the block ends.
    """
    added = single_thread_environment()
    saved = {name: os.environ.get(name) for name in added}
    os.environ.update(added)
    try:
        yield added
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def own_cores() -> list[int] | None:
    """The cores this process may run on (None where the system cannot say)."""
    if not hasattr(os, "sched_getaffinity"):
        return None
    return sorted(os.sched_getaffinity(0))


@contextlib.contextmanager
def cores_for_a_while(cores: Iterable[int] | None) -> Iterator[None]:
    """Run this process on ``cores`` only inside the block, then on the cores it had.

    For a parent whose work would otherwise take time from a pinned worker that is still
    busy: it moves to the core of one that is done. Nothing happens where the system cannot
    pin or refuses, or when ``cores`` is None.
    """
    before = own_cores()
    moved = False
    if cores is not None and before is not None:
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, set(cores))
            moved = True
    try:
        yield
    finally:
        if moved:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, set(before))


def pin_worker(counter: object | None = None, index: int | None = None) -> int | None:
    """Bind this process to one core: core ``index`` mod the cores it may use.

    The initializer of a worker pool: ``counter`` (a ``multiprocessing.Value("i")`` shared by
    the pool) numbers the workers 0, 1, ... as they start. Call it before JAX's backend
    starts (XLA sizes its thread pool by the cores the process may run on). Returns the core,
    or None where the system cannot pin (no ``os.sched_setaffinity``) or refuses.
    """
    if index is None and counter is not None:
        with counter.get_lock():  # type: ignore[attr-defined]
            index = counter.value  # type: ignore[attr-defined]
            counter.value += 1  # type: ignore[attr-defined]
    cores = own_cores()
    if index is None or cores is None or not hasattr(os, "sched_setaffinity"):
        return None
    core = cores[index % len(cores)]
    try:
        os.sched_setaffinity(0, {core})
    except OSError:
        return None
    return core
