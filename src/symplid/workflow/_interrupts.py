"""Signals during a command: SIGINT, SIGTERM and SIGHUP stop it alike, at a safe point.

One policy for every long command (``fit``, ``reproduce``, ``predict``, ``report``,
``compare``, ``sweep``, the studies): :func:`supervised` installs handlers that only **record**
the signal (:func:`symplid._stopping.request`) and return. Nothing is raised inside a handler,
so a signal can no longer land inside a library's callback (JAX's memory callback swallowed
it), inside SciPy's optimiser or a compilation (where it ended in a segmentation fault), or
between two compiled sampling blocks (where it lost the draws). The code asks at safe points
(:mod:`symplid._stopping`): the sampler before each compiled chunk, the optimisers at each
evaluation, the workflow between phases and between a sweep's cells. There it stops, keeps
what is finished (every finished chunk of draws is already on disk), marks the run and exits
with 128 + the signal's number (130, 143, 129) after one line on stderr.

A compilation or a long C call cannot be cut short: the stop comes at the next safe point. A
second signal while stopping changes nothing (still one line, the draws kept); a **third** of
the same kind ends the process at once (one line; the finished chunks are on disk and
``symplid fit --resume`` continues from them). A signal ignored when the block starts
(``nohup`` ignores SIGHUP; a background job SIGINT) stays ignored.

:func:`deferred_interrupts` holds the same signals while a run's files are written, for the
library used without the command line (where Python's own Ctrl-C raises anywhere); inside
:func:`supervised` it has nothing to do. Signal handlers can be set only in the main thread;
elsewhere (a sweep worker thread) both context managers do nothing.

Worker processes (``symplid reproduce`` fits its two approaches in two) follow the same policy:
:func:`stop_on_signals` is their initializer, and the parent waits for them with
:func:`results_or_stop`, which passes a stop on to them (a terminal's Ctrl-C reaches them
anyway; a SIGTERM or SIGHUP only the parent), lets them keep what they finished and then
stops itself.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import signal
import threading
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from symplid import _stopping as stopping

__all__ = ["FORCE_AFTER", "deferred_interrupts", "results_or_stop", "stop_on_signals",
           "supervised"]

_HELD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

#: Signals of one kind after which a supervised command ends at once.
FORCE_AFTER = 3

_FORCED_LINE = (b"symplid: interrupted three times: stopped at once (the finished chunks of "
                b"draws are kept; continue with 'symplid fit --resume')\n")

_active = threading.Event()


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _install(handler) -> dict[int, object]:
    return {sig: signal.signal(sig, handler) for sig in _HELD
            if signal.getsignal(sig) is not signal.SIG_IGN}


def _restore(old: dict[int, object]) -> None:
    for sig, previous in old.items():
        signal.signal(sig, previous)


@contextmanager
def supervised() -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP only request a stop
    (:mod:`symplid._stopping`), obeyed at the next safe point; the third signal of one kind
    ends the process at once with 128 + its number.

    Requests are forgotten on entry and on exit: inside the block,
    :func:`symplid._stopping.requested` tells whether (and by which signal) a stop was asked.
    A block inside another (the command line supervises the whole process from its start,
    each command its own body) changes nothing: a signal recorded before it is kept.
    """
    if _active.is_set() and _main_thread():  # nested: the outer block holds the signals
        yield
        return
    stopping.clear()
    if not _main_thread():
        yield
        return
    watcher = _Watcher()

    def handler(signum: int, frame: object) -> None:
        stopping.request(signum)  # the watcher has counted it (or, without one, count here)
        if not watcher.running:
            watcher.count(signum)

    old = _install(handler)
    watcher.start()
    _active.set()
    try:
        yield
    finally:
        _active.clear()
        watcher.stop()
        _restore(old)
        stopping.clear()  # the process may go on (a test runner, a notebook): no stale stop


class _Watcher:
    """Counts the signals the moment they arrive, from the bytes CPython writes to its wakeup
    file descriptor (:func:`signal.set_wakeup_fd`), in a thread of its own.

    A Python-level handler runs only when the main thread next runs Python code, which a long
    C call (a compilation, a summary of millions of draws) can put off for minutes; the
    watcher requests the stop and ends the process on the third signal of one kind at once.
    Without a wakeup descriptor of its own (another library set one) it does nothing and the
    handler counts.
    """

    def __init__(self) -> None:
        self.counts: Counter[int] = Counter()
        self.running = False
        self._fds: tuple[int, int] | None = None
        self._old_fd = -1
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        self._old_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        if self._old_fd != -1:  # someone else's: give it back, count in the handler
            signal.set_wakeup_fd(self._old_fd)
            os.close(read_fd)
            os.close(write_fd)
            return
        self._fds, self.running = (read_fd, write_fd), True
        self._thread = threading.Thread(target=self._run, args=(read_fd,), daemon=True,
                                        name="symplid-signals")
        self._thread.start()

    def _run(self, read_fd: int) -> None:
        held = {int(sig) for sig in _HELD}
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:  # the write end was closed: the block is over
                return
            for signum in data:
                if signum in held:
                    stopping.request(signum)
                    self.count(signum)

    def count(self, signum: int) -> None:
        self.counts[signum] += 1
        if self.counts[signum] >= FORCE_AFTER:  # the user insists: finished chunks are on disk
            os.write(2, _FORCED_LINE)
            os._exit(128 + signum)

    def stop(self) -> None:
        if self._fds is None:
            return
        signal.set_wakeup_fd(-1)
        read_fd, write_fd = self._fds
        os.close(write_fd)  # the thread reads the end of the pipe and returns
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._thread is None or not self._thread.is_alive():
            os.close(read_fd)  # (a thread still reading keeps it: a daemon, it ends with us)
        self.running, self._fds = False, None


@contextmanager
def deferred_interrupts() -> Iterator[list[int]]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs (writing results must not be cut
    short).

    Yields a list that receives the numbers of the signals that arrived; they are not
    re-raised afterwards: the caller decides (a run whose files are all written is kept).
    Inside :func:`supervised` the signals are held already and are recorded there.
    """
    received: list[int] = []
    if not _main_thread() or _active.is_set():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)

    old = _install(handler)
    try:
        yield received
    finally:
        _restore(old)


def stop_on_signals() -> None:
    """For the life of this process, SIGINT, SIGTERM and SIGHUP request a stop
    (:mod:`symplid._stopping`) instead of raising: the initializer of a worker process."""
    stopping.clear()
    if _main_thread():
        _install(lambda signum, frame: stopping.request(signum))


def results_or_stop(futures: Sequence[concurrent.futures.Future]) -> list[Any]:
    """The futures' results, in order; a stop requested while waiting is passed on to this
    process's worker processes (which stop at their safe points and keep what they made),
    and once they have ended, raised here (:class:`symplid._stopping.StopRequested`)."""
    pending, passed_on = set(futures), False
    while pending:
        _, pending = concurrent.futures.wait(pending, timeout=0.1)
        signum = stopping.requested()
        if signum is not None and not passed_on:
            for child in multiprocessing.active_children():
                os.kill(child.pid, signum)
            passed_on = True
    stopping.check()  # the workers' own stops come back as their results or exceptions
    return [future.result() for future in futures]
