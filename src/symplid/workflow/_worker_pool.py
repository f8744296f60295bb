"""Jobs in worker processes pinned to their own cores, each handing back a first part early.

A job (a picklable function of one argument) may :func:`post` one message as soon as it has
something the parent can use, then go on and return its result: ``symplid reproduce`` posts
an approach's draws and prediction paths as soon as its sampler ends, and the parent draws
the figures while the worker still summarises its draws and writes them to disk.

:class:`WorkerPool` starts the jobs in spawned processes with one-thread pools set before NumPy
or JAX load (:func:`symplid.runtime.worker_environment`), each pinned to its own core
(:func:`symplid.runtime.pin_worker`) and stopping on signals at its safe points
(:func:`~symplid.workflow._interrupts.stop_on_signals`). :meth:`WorkerPool.messages` yields the
posted messages as they arrive; :meth:`WorkerPool.results` waits for the return values
(:func:`~symplid.workflow._interrupts.results_or_stop`: a stop asked for meanwhile is passed on
to the workers, which keep what they finished, and then raised here). A job that fails
raises its error from either. With one worker the jobs run in this process, one after the
other, when :meth:`~WorkerPool.messages` is first read.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import queue as queue_module
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from symplid import _stopping as stopping
from symplid import runtime
from symplid.workflow._interrupts import results_or_stop, stop_on_signals

__all__ = ["WorkerPool", "post"]

_POLL_S = 0.1

# In a worker process: where post() sends (set by the pool's initializer). In any process:
# the job now running and whether it has posted; for jobs run in this process, the messages.
_channel: Any = None
_job: int | None = None
_has_posted = False
_posted: list[Any] | None = None


def post(message: Any) -> None:
    """Hand ``message`` to the parent now, from inside a job (at most once per job; outside a
    :class:`WorkerPool` job it is dropped)."""
    global _has_posted
    if _job is None:
        return
    _has_posted = True
    if _channel is not None:
        _channel.put((_job, True, message))
    elif _posted is not None:
        _posted.append(message)


def _run_job(fn: Callable[[Any], Any], index: int, arg: Any) -> Any:
    """A job as the pool runs it: its post is numbered; one that posted nothing says so (the
    parent then stops waiting for it)."""
    global _job, _has_posted
    _job, _has_posted = index, False
    try:
        return fn(arg)
    finally:
        if not _has_posted and _channel is not None:
            _channel.put((index, False, None))
        _job = None


def _start_worker(counter: Any, channel: Any) -> None:
    """A worker's initializer: its own core (before JAX starts), the signal policy, the channel."""
    global _channel
    runtime.pin_worker(counter)
    stop_on_signals()
    _channel = channel


class WorkerPool:
    """``fn(job)`` for each of ``jobs`` in ``workers`` pinned processes (see the module).

    Use as a context manager: the jobs start when the block is entered (so that the workers
    load while this process does other work), and the block's end waits for the processes.
    """

    def __init__(self, fn: Callable[[Any], Any], jobs: Sequence[Any], workers: int) -> None:
        self._fn, self._jobs = fn, list(jobs)
        self._workers = max(1, min(int(workers), len(self._jobs)))
        self._pool: ProcessPoolExecutor | None = None
        self._channel: Any = None
        self._futures: list[concurrent.futures.Future] = []
        self._serial: list[Any] | None = None

    def __enter__(self) -> WorkerPool:
        if self._workers > 1:
            context = multiprocessing.get_context("spawn")
            self._channel = context.Queue()
            counter = context.Value("i", 0)  # numbers the workers, each pinned to its own core
            with runtime.worker_environment():  # one-thread pools, set before NumPy/JAX load
                self._pool = ProcessPoolExecutor(
                    max_workers=self._workers, mp_context=context, initializer=_start_worker,
                    initargs=(counter, self._channel))
                self._futures = [self._pool.submit(_run_job, self._fn, k, job)
                                 for k, job in enumerate(self._jobs)]
        return self

    def __exit__(self, *exc: object) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        if self._channel is not None:
            self._channel.close()
            self._channel.join_thread()

    def messages(self) -> Iterator[Any]:
        """Each job's posted message, in the order they arrive (a job that posted nothing has
        none). A failed job's error, or a stop asked for meanwhile, is raised here once every
        job has ended."""
        if self._pool is None:
            yield from self._run_here()
            return
        waiting = set(range(len(self._jobs)))
        while waiting:
            failed = any(f.done() and f.exception() is not None for f in self._futures)
            if failed or stopping.requested() is not None:
                results_or_stop(self._futures)  # passes a stop on, waits, raises
            try:
                index, posted, message = self._channel.get(timeout=_POLL_S)
            except queue_module.Empty:
                continue
            waiting.discard(index)
            if posted:
                yield message
            elif self._futures[index].exception() is not None:  # it ended without posting
                results_or_stop(self._futures)
        if stopping.requested() is not None:  # asked for after the last message
            results_or_stop(self._futures)

    def results(self) -> list[Any]:
        """The jobs' return values, in the order of the jobs."""
        if self._pool is None:
            if self._serial is None:
                for _ in self._run_here():
                    pass
            return list(self._serial or ())
        return results_or_stop(self._futures)

    def _run_here(self) -> Iterator[Any]:
        global _posted
        self._serial = []
        for k, job in enumerate(self._jobs):
            _posted = []
            try:
                self._serial.append(_run_job(self._fn, k, job))
                posted = list(_posted)
            finally:
                _posted = None
            yield from posted
