"""A request to stop, set by a signal and obeyed at safe points.

A signal handler that raises (as Python's default SIGINT handler does) can land anywhere: in a
library's callback (JAX's memory callback, which swallows it), inside SciPy's optimiser or in
the middle of a compilation, where it was seen to be lost, printed twice or to end in a
segmentation fault. Symplid's command line therefore installs handlers that only **record**
the signal here (:func:`request`, from :mod:`symplid.workflow._interrupts`); the long loops ask
at points where stopping is safe and cheap:

* the sampler between two compiled chunks (:func:`symplid.sampling._run.run_chains`
  ends the run there and keeps every finished chunk);
* the optimisers at each evaluation of their objective (the MAP's L-BFGS-B starts, the neural
  fit's Adam and L-BFGS steps), which :func:`check` turns into :class:`StopRequested`;
* the workflow between its phases (MAP, sampling, saving) and between the cells of a sweep.

The request is process-wide and sticky until :func:`clear`. Outside the command line nothing
sets it, and Python's own Ctrl-C (``KeyboardInterrupt``) behaves as before.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

_T = TypeVar("_T")

__all__ = ["POLL", "StopRequested", "abandoned", "check", "clear", "first_call_waits",
           "request", "requested", "waiting"]


class StopRequested(KeyboardInterrupt):
    """Raised at a safe point after a stop was requested (a ``KeyboardInterrupt``, so that
    code which keeps its work on Ctrl-C keeps it on this too).

    Attributes
    ----------
    signum
        The number of the signal that asked for the stop.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(f"stop requested by signal {signum}")
        self.signum = signum


_LOCK = threading.Lock()
_RECEIVED: list[int] = []


def request(signum: int) -> None:
    """Record a request to stop by signal ``signum`` (called by a signal handler: it only
    records the number, once)."""
    if int(signum) not in _RECEIVED:
        _RECEIVED.append(int(signum))


def requested() -> int | None:
    """The signal number of the first request since the last :func:`clear`, or None."""
    return _RECEIVED[0] if _RECEIVED else None


def check() -> None:
    """Raise :class:`StopRequested` if a stop was requested; a safe point calls this."""
    signum = requested()
    if signum is not None:
        raise StopRequested(signum)


def clear() -> None:
    """Forget every request (a new command starts)."""
    with _LOCK:
        _RECEIVED.clear()


#: How often :func:`waiting` looks for a stop request (seconds).
POLL = 0.05


def waiting(fn: Callable[..., _T], *args: Any) -> _T:
    """``fn(*args)`` run in a worker thread while this one waits, looking for a stop request
    every :data:`POLL` seconds; a request raises :class:`StopRequested` at once.

    For a call that cannot be cut short and may be long, a compilation above all (XLA compiles
    in one C call, for seconds to minutes): the caller stops within a fraction of a second,
    the call goes on in its (daemon) thread and its result is dropped. The process must then
    end without waiting for it (:func:`abandoned` says whether one is still running). An
    exception of ``fn`` is raised here.
    """
    done: dict[str, Any] = {}

    def run() -> None:
        try:
            done["value"] = fn(*args)
        except BaseException as err:  # handed over to the waiting thread
            done["error"] = err

    worker = threading.Thread(target=run, daemon=True, name="symplid-compile")
    worker.start()
    while worker.is_alive():
        worker.join(POLL)
        signum = requested()
        if signum is not None and worker.is_alive():
            _ABANDONED.append(worker)
            raise StopRequested(signum)
    if "error" in done:
        raise done["error"]
    return done["value"]


_ABANDONED: list[threading.Thread] = []


def abandoned() -> bool:
    """True while a call that :func:`waiting` gave up on is still running (a compilation): the
    process should end with :func:`os._exit`, its files written, rather than tear the
    interpreter down under it."""
    return any(thread.is_alive() for thread in _ABANDONED)


def first_call_waits(fn: Callable[..., _T]) -> Callable[..., _T]:
    """``fn`` whose first call runs through :func:`waiting` (a jitted function's first call
    compiles it: a stop asked for meanwhile is obeyed at once) and later calls directly."""
    compiled: list[bool] = []

    def call(*args: Any) -> _T:
        if compiled:
            return fn(*args)
        value = waiting(fn, *args)
        compiled.append(True)
        return value

    return call

