"""Chunked, multi-chain driver for any ``step(rng_key, state) -> (state, info)`` kernel.

A run of ``burn_in + num_draws·thin`` iterations is cut into chunks of ``chunk_size``
iterations. Each chunk is **one** compiled loop over iterations (:mod:`~._chunk`).
Between chunks control returns to Python: the progress bar moves, the chunk's draws and the
chains' states go to the ``sink`` (a run folder streams them to disk), a callback runs, a
budget set by the answer checks its targets (:mod:`~._budget`), and a stop requested by a
signal (:mod:`symplid._stopping`: checked before every chunk) or a ``KeyboardInterrupt`` ends
the run while keeping every draw already made. A chunk whose iterations are slow runs as
several compiled calls of about half a second each (:mod:`~._pacing`), and a stop requested
between two of them ends the run there, the iterations done kept as a shorter last chunk: a
stop is obeyed within about a second whatever an iteration costs (the first call, which
compiles, is waited for in a worker thread, :func:`symplid._stopping.waiting`), and a crash
loses at most one chunk.

Randomness: the key of iteration ``t`` of chain ``c`` is ``fold_in(chain_key[c], t)`` with
``chain_key = split(rng_key, num_chains)``. The draws therefore depend only on the key and
the kernel, not on the chunk size, and an interrupted run is a prefix of the full run.
Every chunk has the same length (``total`` is split into equal chunks of at most
``chunk_size``), and the compiled chunk runs as many of its iterations as it is asked (a
loop whose trip count is an argument), so a run compiles exactly once; the compiled chunk is
kept on the ``step`` function object (:func:`symplid._compiled.cached`, keyed by ``record``
and the chunk's shape), so a second run of the same kernel does not compile, and nothing
outlives the kernel.
A single chain runs unbatched.
"""

from __future__ import annotations

import inspect
import time
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid._stopping import requested as stop_requested
from symplid._stopping import waiting
from symplid.sampling._budget import BudgetMonitor, TargetsOutOfReach
from symplid.sampling._chunk import DataStep, RecordFn, StepFn, chunk_runner
from symplid.sampling._options import RunOptions, Targets
from symplid.sampling._pacing import Pacer
from symplid.sampling._progress import progress_bar
from symplid.sampling._restart import (
    BurnInMonitor,
    restart_threshold,
    restarted_message,
)

__all__ = ["ChainRun", "ChunkReport", "ChunkSink", "DataStep", "SamplingInterrupted",
           "StuckChainsRestarted", "run_chains"]

ChunkSink = Callable[[dict[str, np.ndarray], Any, int, int, float], None]
"""``sink(draws, states, start, done, elapsed)``, called after every chunk: the draws the chunk
kept (``name -> (num_chains, kept, ...)``, possibly none kept), the chains' states after it,
the iterations per chain before and after it and the sampling time so far. A sink whose call
takes a ``monitor`` keyword also gets, in a run that restarts stuck chains, the arrays that
continue the restart rule (:meth:`~._restart.BurnInMonitor.arrays`), to keep with the states."""
CHAIN_METHODS = ("vectorized", "sequential")


class SamplingInterrupted(UserWarning):
    """Warning: a run was stopped by ``KeyboardInterrupt``; the draws made so far are kept."""


class StuckChainsRestarted(UserWarning):
    """Warning: chains stuck far below the best one at the end of the burn-in were restarted
    from good chains' states (:mod:`~symplid.sampling._restart`)."""


class ChunkReport(NamedTuple):
    """Passed to the ``callback`` of :func:`run_chains` after every chunk.

    Attributes
    ----------
    chunk
        Index of the chunk just finished (0-based).
    iterations_done
        Iterations completed so far (burn-in included).
    total_iterations
        Iterations planned.
    draws_kept
        Draws kept per chain so far.
    states
        The chain states after the chunk (stacked over chains).
    best
        (log π, θ) of the highest point any chain has visited so far, burn-in included
        (``None`` before the first finite one): a MAP below it was no maximum of π.
    """

    chunk: int
    iterations_done: int
    total_iterations: int
    draws_kept: int
    states: Any
    best: tuple[float, np.ndarray] | None = None


class ChainRun(NamedTuple):
    """Result of :func:`run_chains`.

    Attributes
    ----------
    draws
        ``name -> array`` of shape ``(num_chains, num_kept, ...)`` from the ``record`` function.
    states
        Final chain states (stacked over chains), e.g. to continue the run.
    iterations_done
        Iterations completed (burn-in included).
    interrupted
        Whether a ``KeyboardInterrupt`` ended the run early.
    elapsed
        Wall time in seconds, compilation included.
    monitor
        The restart rule's arrays (:meth:`~._restart.BurnInMonitor.arrays`: the window read so
        far, or the decision taken) when the run restarts stuck chains, else None.
    restarted_chains
        The chains restarted at the end of the burn-in
        (:meth:`~._restart.BurnInMonitor.records`); empty when none were.
    budget
        For a run with targets (``until``), what ended it and the statistics reached
        (:meth:`~._budget.BudgetMonitor.record`); None for a fixed budget.
    """

    draws: dict[str, np.ndarray]
    states: Any
    iterations_done: int
    interrupted: bool
    elapsed: float
    monitor: dict[str, np.ndarray] | None = None
    restarted_chains: tuple[dict[str, Any], ...] = ()
    budget: dict[str, Any] | None = None


def run_chains(
    step: StepFn,
    states: Any,
    rng_key: jax.Array,
    num_draws: int | None = None,
    *,
    record: RecordFn,
    burn_in: int = 0,
    thin: int = 1,
    options: RunOptions | None = None,
    until: Targets | None = None,
    start: int = 0,
    monitor: dict[str, np.ndarray] | None = None,
    earlier: np.ndarray | None = None,
) -> ChainRun:
    """Run several chains of a kernel in compiled chunks (:mod:`~._chunk`).

    Parameters
    ----------
    step
        Pure transition of one chain, ``step(rng_key, state) -> (state, info)``.
    states
        Initial states stacked over chains (leading axis = chain).
    rng_key
        Root key; split once into one key per chain.
    num_draws
        Draws to keep per chain after burn-in and thinning (with ``until``: at most).
    record
        ``record(state, info) -> dict`` of arrays kept at each kept iteration.
    burn_in
        Iterations run first and discarded (with ``until``: the first burn-in).
    thin
        Keep one iteration in ``thin`` after burn-in; ``num_draws·thin`` iterations run.
    options
        The runner's :class:`~._options.RunOptions` (chunks, chain layout, progress bar,
        ``sink`` and ``callback`` of every chunk, the restart of stuck chains from
        ``record``'s ``"lp"``: :mod:`~._restart`); ``None``: the defaults without the restart.
    until
        Stop as soon as the draws meet these targets (:mod:`~._budget`), checked between
        chunks; ``burn_in + num_draws·thin`` is then the cap on the iterations.
    start, monitor, earlier
        Iterations already done: ``states`` are the chains after them, the run continues
        with iteration ``start + 1``; ``monitor`` is the interrupted run's
        :attr:`ChainRun.monitor` and ``earlier`` (with ``until``) its draws of θ since the
        first burn-in. Keys, burn-in, thinning, chunks and checks follow the whole run's
        grid: continued this way, an interrupted run gives the uninterrupted run's draws.

    Returns
    -------
    ChainRun
        Draws ``(num_chains, kept, ...)``, final states and run information (an interrupted
        run: the chunks that finished, and a warning). With ``until``: every draw since the
        first burn-in (:attr:`ChainRun.budget` says where the extended burn-in ends).
    """
    options = RunOptions(restart_stuck_chains=False) if options is None else options
    chain_method = options.chain_method or "vectorized"
    num_chains = _check_run(num_draws, burn_in, thin, chain_method, states)
    total = int(burn_in) + int(num_draws) * int(thin)
    if int(start) != start or not 0 <= start < total:
        raise ValueError(f"start must be an integer in [0, {total}), got {start!r}")
    # Equal chunks of at most `chunk_size` iterations; the last one runs fewer than
    # `chunk_len` iterations only when `total` does not divide evenly (then by < num_chunks).
    chunk_len = -(-total // -(-total // int(options.chunk_size)))
    chunk_fn = chunk_runner(step, record, chunk_len, chain_method, num_chains)
    loop = _Loop(chunk_fn, jax.random.split(rng_key, num_chains), total, chunk_len,
                 int(burn_in), int(thin), options, int(start),
                 _restarts(options, num_chains, int(burn_in), rng_key, monitor, int(start)),
                 None if until is None else BudgetMonitor(until, int(burn_in), int(thin),
                                                          num_chains, monitor))
    loop.earlier = earlier
    desc = options.progress_label or "sampling"
    states, elapsed = loop.run(states, progress_bar(total, desc, options.progress,
                                                     options.progress_position, int(start)))
    if loop.interrupted:
        warnings.warn(f"{desc} interrupted after {loop.done} of {total} iterations; keeping "
                      f"the {loop.draws_kept} draws per chain made so far",
                      SamplingInterrupted, stacklevel=2)
    return loop.result(states, elapsed)


def _restarts(options: RunOptions, num_chains: int, burn_in: int, rng_key: jax.Array,
              monitor: dict[str, np.ndarray] | None, start: int) -> BurnInMonitor | None:
    """The restart rule of stuck chains (:mod:`~._restart`), continued from ``monitor``; None
    when the run does not restart them."""
    if not options.restart_stuck_chains:
        return None
    restarts = BurnInMonitor(num_chains, burn_in, rng_key, monitor)
    restarts.resumed_from(start)
    return restarts


def _check_run(num_draws: Any, burn_in: Any, thin: Any, chain_method: str,
               states: Any) -> int:
    """Validate :func:`run_chains`' arguments; returns the number of chains."""
    if num_draws is None:
        raise TypeError("run_chains() needs num_draws, the draws to keep per chain")
    for name, value, low in (("num_draws", num_draws, 1), ("burn_in", burn_in, 0),
                             ("thin", thin, 1)):
        if int(value) != value or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if chain_method not in CHAIN_METHODS:
        raise ValueError(f"chain_method must be one of {CHAIN_METHODS}, got {chain_method!r}")
    leaves = jax.tree.leaves(states)
    if not leaves:
        raise ValueError("states must be a non-empty pytree stacked over chains")
    return int(leaves[0].shape[0])


class _Loop:
    """The chunk loop of :func:`run_chains`: runs chunks, keeps the draws past burn-in on the
    thin grid, hands each chunk to the sink and the callback, checks the budget
    (:mod:`~._budget`) when one is set, and stops cleanly before a chunk when a stop was
    requested (:mod:`symplid._stopping`) or on ``KeyboardInterrupt``."""

    def __init__(self, chunk_fn: Callable, chain_keys: jax.Array, total: int, chunk_len: int,
                 burn_in: int, thin: int, options: RunOptions, start: int = 0,
                 restarts: BurnInMonitor | None = None, budget: BudgetMonitor | None = None):
        self.chunk_fn, self.chain_keys = chunk_fn, chain_keys
        self.total, self.chunk_len, self.burn_in, self.thin = total, chunk_len, burn_in, thin
        self.callback, self.sink, self.restarts = options.callback, options.sink, restarts
        self.budget, self.out_of_time = budget, False
        self.earlier: np.ndarray | None = None  # a continued run's draws of θ before start
        self.sink_takes_monitor = ((restarts is not None or budget is not None)
                                   and _takes_monitor(self.sink))
        self.kept: dict[str, list[np.ndarray]] = {}
        self.done = start
        self.draws_kept = max(0, start - burn_in) // thin
        self.interrupted = False
        self.pacer = Pacer(chunk_len)
        self.best: tuple[float, np.ndarray] | None = None  # highest (log π, θ) visited

    def result(self, states: Any, elapsed: float) -> ChainRun:
        """The run's :class:`ChainRun`: the draws kept, and what ended a budget's run."""
        draws = {name: np.swapaxes(np.concatenate(parts, axis=0), 0, 1)
                 for name, parts in self.kept.items()}
        budget = self.budget
        if budget is not None and not budget.stopped_by:
            budget.stopped_by = "interrupted" if self.interrupted else (
                "wall time" if self.out_of_time else "iterations")
        return ChainRun(draws, states, self.done, self.interrupted, elapsed,
                        self.monitor_arrays(elapsed),
                        () if self.restarts is None else tuple(self.restarts.records()),
                        None if budget is None else budget.record())

    def monitor_arrays(self, elapsed: float = 0.0) -> dict[str, np.ndarray] | None:
        """What a checkpoint keeps of the restart rule and the budget (None: neither)."""
        if self.restarts is None and self.budget is None:
            return None
        arrays = {} if self.restarts is None else self.restarts.arrays()
        return arrays if self.budget is None else {**arrays, **self.budget.arrays(elapsed)}

    def run(self, states: Any, bar: Any) -> tuple[Any, float]:
        """The chains' states at the end, and the seconds it took; the bar closed."""
        started = time.perf_counter()
        try:
            states = self._chunks(states, bar, started)
        finally:
            if bar is not None:
                bar.close()
        return states, time.perf_counter() - started

    def _chunks(self, states: Any, bar: Any, started: float) -> Any:
        chunk_index = 0
        if self._enough(started):  # a resumed run whose last check had not been made
            return states
        while self.done < self.total:
            if stop_requested() is not None:  # a signal asked to stop: a safe point
                self.interrupted = True
                break
            # Chunks on the whole run's grid (a resumed run starts at a chunk's end).
            num_active = min(self.chunk_len - self.done % self.chunk_len, self.total - self.done)
            try:
                states, chunk, ran = self._advance(states, num_active)
            except KeyboardInterrupt:
                self.interrupted = True
                break
            self.done += ran
            if bar is not None:
                bar.update(ran)
            try:
                if self.sink is not None:
                    extra = ({"monitor": self.monitor_arrays(time.perf_counter() - started)}
                             if self.sink_takes_monitor else {})
                    self.sink(chunk, states, self.done - ran, self.done,
                              time.perf_counter() - started, **extra)
                if self.callback is not None:
                    self.callback(ChunkReport(chunk_index, self.done, self.total,
                                              self.draws_kept, states, self.best))
            except KeyboardInterrupt:
                self.interrupted = self.done < self.total
                break
            if ran < num_active:  # stopped inside the chunk: its finished pieces are kept
                self.interrupted = True
                break
            chunk_index += 1
            if self._enough(started):
                break
        return states

    def _enough(self, started: float) -> bool:
        """With a budget: whether its targets are met or its wall-time cap is reached
        (:mod:`~._budget`), checking the draws when a check is due."""
        if self.budget is None:
            return False
        self.out_of_time = (self.budget.out_of_time(time.perf_counter() - started)
                            and self.budget.has_draws(self.done))
        final = self.out_of_time or self.done >= self.total
        if self.budget.due(self.done, final):
            parts = [np.swapaxes(p, 0, 1) for p in self.kept.get("theta", [])]
            before = [] if self.earlier is None else [np.asarray(self.earlier)]
            theta = np.concatenate(before + parts, axis=1)
            if self.budget.check(theta, self.done, final):
                return True
            if not final and (line := self.budget.out_of_reach()) is not None:
                warnings.warn(line, TargetsOutOfReach, stacklevel=5)
        return self.out_of_time

    def _advance(self, states: Any,
                 num_active: int) -> tuple[Any, dict[str, np.ndarray], int]:
        """One chunk of the grid: the states after it, its kept draws and the iterations
        run (``num_active``, or fewer when a stop came between two of its pieces). When the
        burn-in ends inside it and the restart rule is to decide, the chunk runs as two calls
        with the decision between them: the same draws, and from outside (sink, callback,
        stops) the same one chunk. A ``KeyboardInterrupt`` leaves the loop as the chunk
        found it."""
        cut = num_active
        if self.restarts is not None and self.restarts.pending and self.done < self.burn_in:
            cut = min(num_active, self.burn_in - self.done)
        states, records, ran = self._compute(states, self.done, cut)
        chunk = self._keep(records, ran, self.done)
        if ran < cut:
            return states, chunk, ran
        saved = None if self.restarts is None else (self.restarts.window.copy(),
                                                    self.restarts.restarted)
        states = self._restart_stuck(states, records, self.done + cut)
        if cut == num_active:
            return states, chunk, ran
        try:
            states, records, ran = self._compute(states, self.done + cut, num_active - cut)
        except KeyboardInterrupt:  # the decision is taken again when the chunk is
            self.restarts.window, self.restarts.restarted = saved
            raise
        rest = self._keep(records, ran, self.done + cut)
        return (states, {k: np.concatenate([chunk[k], v], axis=1) for k, v in rest.items()},
                cut + ran)

    def _compute(self, states: Any, start: int, num_active: int) -> tuple[Any, dict, int]:
        """The compiled chunk from iteration ``start`` for ``num_active`` iterations, run as
        pieces of about half a second (:class:`~._pacing.Pacer`; the first, which compiles, in a
        worker thread: :func:`symplid._stopping.waiting`); a stop requested between two pieces
        (:mod:`symplid._stopping`) ends it early. Returns the states, the records of the
        iterations run and their number."""
        parts, ran = [], 0
        while ran < num_active and (ran == 0 or stop_requested() is None):
            piece = self.pacer.length(num_active - ran)
            began = time.perf_counter()
            args = (states, self.chain_keys, jnp.int64(start + ran), jnp.int64(piece))
            # The first call compiles (seconds to minutes): a stop need not wait for it.
            states, records = (waiting(self.chunk_fn, *args) if self.pacer.first
                               else self.chunk_fn(*args))
            records = jax.device_get(records)
            jax.block_until_ready(states)
            self.pacer.took(piece, time.perf_counter() - began)
            parts.append({name: np.asarray(value)[:piece] for name, value in records.items()})
            ran += piece
        if len(parts) == 1:
            return states, parts[0], ran
        return states, {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}, ran

    def _restart_stuck(self, states: Any, records: dict[str, Any], done: int) -> Any:
        """At the end of the burn-in (``done``), the states with the stuck chains restarted
        (and one warning line when some were)."""
        if self.restarts is None or not self.restarts.pending or done != self.burn_in:
            return states
        num_params = int(np.shape(records["theta"])[-1]) if "theta" in records else 1
        states = self.restarts.decide(states, num_params)
        if self.restarts.records():
            warnings.warn(restarted_message(self.restarts.records(),
                                            restart_threshold(num_params)),
                          StuckChainsRestarted, stacklevel=5)
        return states

    def _keep(self, records: dict[str, Any], num_active: int,
              start: int) -> dict[str, np.ndarray]:
        """Keep the chunk's iterations past burn-in on the thin grid; returns them
        ``(num_chains, kept, ...)`` (empty arrays in the burn-in). ``records`` hold exactly
        the ``num_active`` iterations run (:meth:`_compute` trims them)."""
        # Iterations start + 1 .. start + num_active; keep those past burn-in on the thin grid.
        iterations = np.arange(start + 1, start + num_active + 1)
        self._note_best(records)
        if self.restarts is not None and self.restarts.pending:
            self.restarts.observe(iterations, np.asarray(records["lp"]))
        keep = (iterations > self.burn_in) & ((iterations - self.burn_in) % self.thin == 0)
        chunk = {name: np.asarray(value)[keep] for name, value in records.items()}
        if keep.any():
            for name, value in chunk.items():
                self.kept.setdefault(name, []).append(value)
            self.draws_kept += int(keep.sum())
        return {name: np.swapaxes(value, 0, 1) for name, value in chunk.items()}

    def _note_best(self, records: dict[str, Any]) -> None:
        """Remember the highest (log π, θ) of the iterations just run (:class:`ChunkReport`)."""
        if "lp" not in records or "theta" not in records:
            return
        lp = np.asarray(records["lp"], dtype=float)
        if lp.size == 0:
            return
        finite = np.where(np.isfinite(lp), lp, -np.inf)
        flat = int(np.argmax(finite))
        value = float(finite.flat[flat])
        if value > -np.inf and (self.best is None or value > self.best[0]):
            where = np.unravel_index(flat, lp.shape)
            self.best = (value, np.array(np.asarray(records["theta"])[where], dtype=float))


def _takes_monitor(sink: Any) -> bool:
    """Whether ``sink`` accepts the ``monitor`` keyword (:data:`ChunkSink`)."""
    if sink is None:
        return False
    try:
        parameters = inspect.signature(sink).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == "monitor" or p.kind is p.VAR_KEYWORD for p in parameters)
