"""How long each compiled call of the sampler runs: about half a second, whatever an
iteration costs.

The sampler (:func:`symplid.sampling._run.run_chains`) runs in chunks of
``chunk_size`` iterations, and control comes back to Python only between two compiled calls:
that is where a stop (:mod:`symplid._stopping`) is obeyed. A chunk of DRAM iterations takes a
fraction of a second, but one of NUTS iterations, each a tree of gradient evaluations of the
filter, can take minutes. :class:`Pacer` therefore sizes the calls by time: a chunk runs as
pieces of about :attr:`Pacer.SECONDS` (one compiled program runs any number of iterations up
to the chunk's, so the pieces compile nothing more), and a stop is obeyed within about a
second. The draws do not depend on the pieces: the key of iteration ``t`` is derived from
``t`` alone.
"""

from __future__ import annotations

__all__ = ["Pacer"]


class Pacer:
    """How many iterations the next compiled call runs, so that each takes about
    :attr:`SECONDS`: a stop is obeyed between two calls, within about that time whatever an
    iteration costs (a NUTS iteration can take a second, a DRAM one microseconds).

    The first call compiles; its time bounds an iteration's from above, so the second runs
    few. Later lengths follow the last call's time per iteration, growing at most
    :attr:`GROWTH` times per call (a short call's time is mostly overhead) and never beyond
    the chunk. Where a whole chunk takes less than that, a chunk is one call, as before.
    """

    SECONDS = 0.5
    GROWTH = 8

    def __init__(self, chunk_len: int) -> None:
        self.chunk_len, self.last, self.per_iteration = chunk_len, 0, None

    def length(self, remaining: int) -> int:
        """Iterations of the next call (at least one, at most ``remaining``)."""
        if self.per_iteration is None:
            return 1
        fits = int(self.SECONDS / max(self.per_iteration, 1e-12))
        return int(max(1, min(remaining, self.chunk_len, fits, self.GROWTH * self.last)))

    @property
    def first(self) -> bool:
        """Whether no call was made yet (the next one may compile)."""
        return self.per_iteration is None

    def took(self, iterations: int, seconds: float) -> None:
        """Record that a call of ``iterations`` iterations took ``seconds``."""
        self.last, self.per_iteration = iterations, seconds / iterations
