"""Signals during a run: SIGTERM stops a sampler like Ctrl-C, and saving is never cut short.

A sampler stopped by ``KeyboardInterrupt`` keeps the draws made so far
(:func:`symplid.inference.samplers.run.run_chains`). Two things could still lose them: a
SIGTERM (a batch system ending the job), whose default action kills the process at once, and
a second Ctrl-C while those draws are being written. :func:`terminate_as_interrupt` turns
SIGTERM into ``KeyboardInterrupt``; :func:`deferred_interrupts` holds SIGINT and SIGTERM while
the run folder's files are written and reports afterwards which arrived.

Signal handlers can be set only in the main thread; elsewhere (a sweep worker thread) both
context managers do nothing.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["deferred_interrupts", "terminate_as_interrupt"]

_HELD = (signal.SIGINT, signal.SIGTERM)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def terminate_as_interrupt() -> Iterator[list[int]]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` as Ctrl-C does.

    Yields a list that receives the signal numbers handled this way (so a caller can exit
    with 128 + SIGTERM rather than 128 + SIGINT).
    """
    received: list[int] = []
    if not _main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)
        raise KeyboardInterrupt(f"signal {signum}")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield received
    finally:
        signal.signal(signal.SIGTERM, old)


@contextmanager
def deferred_interrupts() -> Iterator[list[int]]:
    """Hold SIGINT and SIGTERM while the block runs (writing results must not be cut short).

    Yields a list that receives the numbers of the signals that arrived; they are not
    re-raised afterwards: the caller decides (a run whose files are all written is kept).
    """
    received: list[int] = []
    if not _main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)

    old = {sig: signal.signal(sig, handler) for sig in _HELD}
    try:
        yield received
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
