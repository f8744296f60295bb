"""Signals during a run: SIGINT, SIGTERM and SIGHUP stop a command alike, and saving is never
cut short.

A sampler stopped by ``KeyboardInterrupt`` keeps the draws made so far
(:func:`symplid.inference.samplers.run.run_chains`). Three things could still lose them: a
SIGTERM (a batch system ending the job) or a SIGHUP (a closed terminal or ssh session), whose
default actions kill the process at once, and a second signal while those draws are being
written. :func:`terminate_as_interrupt` turns all three into ``KeyboardInterrupt`` and records
each, so that a signal a library swallowed (raised inside one of its callbacks) still ends the
command with 128 + its number; :func:`deferred_interrupts` holds them while the run folder's
files are written and reports afterwards which arrived. A signal ignored when the block starts
(``nohup`` ignores SIGHUP; a background job SIGINT) stays ignored.

Signal handlers can be set only in the main thread; elsewhere (a sweep worker thread) both
context managers do nothing.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["deferred_interrupts", "terminate_as_interrupt"]

_HELD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def terminate_as_interrupt() -> Iterator[list[int]]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise ``KeyboardInterrupt`` as Ctrl-C does.

    Yields a list that receives the numbers of the signals handled this way (so a caller can
    exit with 128 + the signal's number, and can tell a signal a library swallowed).
    """
    received: list[int] = []
    if not _main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)
        raise KeyboardInterrupt(f"signal {signum}")

    old = {sig: signal.signal(sig, handler) for sig in _HELD
           if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        yield received
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


@contextmanager
def deferred_interrupts() -> Iterator[list[int]]:
    """Hold SIGINT, SIGTERM and SIGHUP while the block runs (writing results must not be cut
    short).

    Yields a list that receives the numbers of the signals that arrived; they are not
    re-raised afterwards: the caller decides (a run whose files are all written is kept).
    """
    received: list[int] = []
    if not _main_thread():
        yield received
        return

    def handler(signum: int, frame: object) -> None:
        received.append(signum)

    old = {sig: signal.signal(sig, handler) for sig in _HELD
           if signal.getsignal(sig) is not signal.SIG_IGN}
    try:
        yield received
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
