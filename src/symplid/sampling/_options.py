"""What the runner is told besides the sampler: :class:`RunOptions` and :class:`Targets`.

:func:`~symplid.sampling.sample` takes the sampler's own arguments (method, draws,
chains, seed, MAP, burn-in, thinning, kernel settings) and one :class:`RunOptions`: how the
chains start, how the run is cut into chunks and shown, where each chunk goes, whether stuck
chains are restarted, and, for a run without a fixed number of draws, the :class:`Targets`
that end it (:mod:`~symplid.sampling._budget`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["RunOptions", "Targets"]


@dataclass(frozen=True)
class Targets:
    """When a run without a fixed budget stops: every parameter's bulk and tail ESS at least
    ``ess_bulk``/``ess_tail`` and its R-hat at most ``rhat`` (Vehtari et al. 2021, as ArviZ
    computes them), on the draws kept after the burn-in; or a cap, whichever comes first.

    Parameters
    ----------
    ess_bulk, ess_tail, rhat
        The targets (400, 400, 1.01: Vehtari et al.'s recommendation for four chains).
    max_iterations
        Cap on the iterations per chain, burn-in included (the paper's 200,000).
    max_seconds
        Cap on the sampling's wall time in seconds (``None``: none). Unlike the other
        rules it depends on the machine, so a run it ends is not repeatable draw for draw.
    growth
        The checks come when the iterations done have grown by this factor since the last
        one (at the end of a chunk): their cost stays a small multiple of the last check's,
        and a run overshoots the iterations it needed by at most this factor and a chunk.
    """

    ess_bulk: float = 400.0
    ess_tail: float = 400.0
    rhat: float = 1.01
    max_iterations: int = 200_000
    max_seconds: float | None = None
    growth: float = 1.25

    def __post_init__(self) -> None:
        for name in ("ess_bulk", "ess_tail"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not (math.isfinite(self.rhat) and self.rhat > 1.0):
            raise ValueError(f"rhat must be a number > 1, got {self.rhat!r}")
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise ValueError(f"max_iterations must be an integer >= 1, got "
                             f"{self.max_iterations!r}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise ValueError(f"max_seconds must be > 0 or None, got {self.max_seconds!r}")
        if not (math.isfinite(self.growth) and self.growth > 1.0):
            raise ValueError(f"growth must be a number > 1, got {self.growth!r}")

    def as_dict(self) -> dict[str, Any]:
        """The targets as a run's attributes record them."""
        return {"ess_bulk": float(self.ess_bulk), "ess_tail": float(self.ess_tail),
                "rhat": float(self.rhat), "max_iterations": int(self.max_iterations),
                "max_seconds": self.max_seconds, "growth": float(self.growth)}


@dataclass(frozen=True)
class RunOptions:
    """How :func:`~symplid.sampling.sample` runs its chains (none of it changes a
    draw, except the starting points and the restart of stuck chains).

    Parameters
    ----------
    init_spread, initial_positions
        Overdispersion of the starting points ``θ̂ + s·L z`` (0 starts at the MAP), or
        explicit starting points ``(num_chains, d)``.
    chunk_size
        Iterations per compiled chunk: the progress bar moves, the sink writes, a stop is
        obeyed and the budget is checked once per chunk.
    chain_method
        ``"vectorized"`` (``vmap``) or ``"sequential"`` (``lax.map``) over chains; ``None``
        takes the sampler's default.
    progress, progress_label, progress_position
        Show progress bars; their text and line (one line per process sampling at once).
    callback
        Called after every chunk with a :class:`~._run.ChunkReport`; raising
        ``KeyboardInterrupt`` there stops the run like Ctrl-C.
    sink
        Receives every chunk's draws and the chains' states as the run goes
        (:data:`~._run.ChunkSink`).
    on_draws
        Given the kept draws of θ ``(chain, draw, param)`` as soon as the chains end.
    restart_stuck_chains
        Restart, at the end of the burn-in, a chain stuck far below the best one
        (:mod:`~symplid.sampling._restart`).
    return_state
        Also return the chains' final states (:class:`~._api.SamplerCheckpoint`).
    targets
        What ends a run without a fixed number of draws (``sample(num_draws=None)``).
    """

    init_spread: float = 2.0
    initial_positions: Any = None
    chunk_size: int = 5000
    chain_method: str | None = None
    progress: bool = True
    progress_label: str | None = None
    progress_position: int | None = None
    callback: Callable[[Any], None] | None = None
    sink: Any = None
    on_draws: Callable[[np.ndarray], None] | None = None
    restart_stuck_chains: bool = True
    return_state: bool = False
    targets: Targets = field(default_factory=Targets)

    def __post_init__(self) -> None:
        if int(self.chunk_size) != self.chunk_size or self.chunk_size < 1:
            raise ValueError(f"chunk_size must be an integer >= 1, got {self.chunk_size!r}")
        if not (np.isfinite(self.init_spread) and self.init_spread >= 0):
            raise ValueError(f"init_spread must be a finite number >= 0, got "
                             f"{self.init_spread}")
