"""The evidence of a MAP computed beside other work (``find_map(defer_evidence=True)``).

The quadrature evidence (:mod:`symplid.inference.map._evidence`) is a hundred or more small
L-BFGS-B fits at the nodes of its grid: on a user's model of a few parameters, about half of
a warm fit's MAP phase. Nothing in a fit reads it before the run's summary, after sampling,
and its inputs are fixed once the MAP is found. So a fit can find the MAP without it, start
it in a background thread (:meth:`PendingEvidence.start`) and sample meanwhile: the thread
takes the second core, the sampler the first. :meth:`PendingEvidence.finish` waits for it and
gives the MAP result with its evidence: the same function on the same inputs as the
sequential ``find_map``, so the same numbers (``tests/test_map_pending.py``).

Until then the result carries the Laplace evidence (``evidence_method`` ``"laplace"``,
``evidence["deferred"]`` naming the rule still to run), what a run interrupted before the
end keeps. A stop requested meanwhile (:mod:`symplid._stopping`) ends the thread at its next
evaluation, and so does :meth:`PendingEvidence.cancel` (the MAP searched again, the caller
interrupted); :meth:`~PendingEvidence.finish` then gives the result with the stand-in.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from typing import Any

from symplid._stopping import POLL

Evidence = tuple[float, str, dict[str, Any]]
"""(log evidence, method, details), as ``find_map`` records them."""


class EvidenceCancelled(Exception):
    """The pending evidence was cancelled (:meth:`PendingEvidence.cancel`)."""


class PendingEvidence:
    """A MAP's evidence still to be computed: ``compute(value_and_grad)`` is the sequential
    search's own call, given the search's compiled ``value_and_grad`` (wrapped here so that
    :meth:`cancel` ends it at its next evaluation)."""

    def __init__(self, compute: Callable[[Callable], Evidence], value_and_grad: Callable,
                 rule: str) -> None:
        self.rule = rule
        self._compute, self._vg = compute, value_and_grad
        self._cancelled = False
        self._thread: threading.Thread | None = None
        self._outcome: dict[str, Any] = {}

    def _checked(self, u: Any) -> Any:
        if self._cancelled:
            raise EvidenceCancelled("the pending evidence was cancelled")
        return self._vg(u)

    def _run(self) -> None:
        start = time.perf_counter()
        try:
            self._outcome["value"] = self._compute(self._checked)
        except BaseException as err:  # handed to finish()
            self._outcome["error"] = err
        self._outcome["seconds"] = time.perf_counter() - start

    def start(self) -> PendingEvidence:
        """Compute it in a background (daemon) thread; returns self."""
        if self._thread is None and not self._outcome:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name="symplid-evidence")
            self._thread.start()
        return self

    @property
    def done(self) -> bool:
        """Whether it has ended (computed, failed or cancelled)."""
        return "seconds" in self._outcome

    def cancel(self) -> None:
        """End the computation at its next evaluation (its result is not wanted)."""
        self._cancelled = True

    def finish(self, result: Any) -> Any:
        """``result`` (the MAP result that carries this) with its evidence: waits for the
        thread (in waits of :data:`~symplid._stopping.POLL` seconds, so that signal handlers
        run), or computes it here when it was never started. ``seconds`` adds the
        evidence's. Where a stop request or :meth:`cancel` ended it, ``result`` keeps its
        Laplace stand-in (a run stopped meanwhile is saved with it); any other error of
        the computation is raised here."""
        if self._thread is None and not self._outcome:
            self._run()
        while self._thread is not None and self._thread.is_alive():
            self._thread.join(POLL)
        error = self._outcome.get("error")
        if isinstance(error, KeyboardInterrupt | EvidenceCancelled):  # a stop, or cancelled
            return dataclasses.replace(result, pending=None)  # the Laplace stand-in stays
        if error is not None:
            raise error
        log_evidence, method, details = self._outcome["value"]
        return dataclasses.replace(
            result, log_evidence=log_evidence, evidence_method=method, evidence=details,
            seconds=result.seconds + self._outcome["seconds"], pending=None)


def provisional(laplace: float, rule: str) -> Evidence:
    """What a result records while its evidence by ``rule`` is pending: the Laplace value."""
    return laplace, "laplace", {"deferred": rule}


__all__ = ["EvidenceCancelled", "PendingEvidence", "provisional"]
