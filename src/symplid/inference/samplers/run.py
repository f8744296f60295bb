"""Chunked, multi-chain driver for any ``step(rng_key, state) -> (state, info)`` kernel.

A run of ``burn_in + num_draws·thin`` iterations is cut into chunks of ``chunk_size``
iterations. Each chunk is **one** compiled ``lax.scan`` over iterations whose body advances
all chains at once (``vmap``), or, for ``chain_method="sequential"``, one chain (the same
compiled one-chain chunk is then called for each chain in turn, which compiles faster than
a batched kernel and lets data-dependent branches skip work). Between
chunks control returns to Python: the progress bar moves, the chunk's draws and the chains'
states go to the ``sink`` (a run folder streams them to disk), a callback runs, and a stop
requested by a signal (:mod:`symplid.stopping`: checked before every chunk) or a
``KeyboardInterrupt`` ends the run while keeping every draw already made. A chunk whose
iterations are slow runs as several compiled calls of about half a second each
(:mod:`~symplid.inference.samplers.pacing`), and a stop requested between two of them ends
the run there, the iterations done kept as a shorter last chunk: a stop is obeyed within
about a second whatever an iteration costs (the first call, which compiles, is waited for in
a worker thread, :func:`symplid.stopping.waiting`), and a crash loses at most one chunk.

Randomness: the key of iteration ``t`` of chain ``c`` is ``fold_in(chain_key[c], t)`` with
``chain_key = split(rng_key, num_chains)``. The draws therefore depend only on the key and
the kernel, not on the chunk size, and an interrupted run is a prefix of the full run.
Every chunk has the same length (``total`` is split into equal chunks of at most
``chunk_size``), and the compiled chunk runs as many of its iterations as it is asked (a
loop whose trip count is an argument), so a run compiles exactly once; the compiled chunk is
kept on the ``step`` function object (:func:`symplid.compiled.cached`, keyed by ``record``
and the chunk's shape), so a second run of the same kernel does not compile, and nothing
outlives the kernel.
A single chain runs unbatched.
"""

from __future__ import annotations

import functools
import inspect
import time
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from symplid.compiled import cached_or_built
from symplid.inference.samplers.pacing import Pacer
from symplid.inference.samplers.restart import (
    BurnInMonitor,
    restart_threshold,
    restarted_message,
)
from symplid.stopping import requested as stop_requested
from symplid.stopping import waiting

__all__ = ["ChainRun", "ChunkReport", "ChunkSink", "DataStep", "SamplingInterrupted",
           "StuckChainsRestarted", "run_chains"]

StepFn = Callable[[jax.Array, Any], tuple[Any, Any]]
RecordFn = Callable[[Any, Any], dict[str, jax.Array]]
ChunkSink = Callable[[dict[str, np.ndarray], Any, int, int, float], None]
"""``sink(draws, states, start, done, elapsed)``, called after every chunk: the draws the chunk
kept (``name -> (num_chains, kept, ...)``, possibly none kept), the chains' states after it,
the iterations per chain before and after it and the sampling time so far. A sink whose call
takes a ``monitor`` keyword also gets, in a run that restarts stuck chains, the arrays that
continue the restart rule (:meth:`~.restart.BurnInMonitor.arrays`), to keep with the states."""
CHAIN_METHODS = ("vectorized", "sequential")


class SamplingInterrupted(UserWarning):
    """Warning: a run was stopped by ``KeyboardInterrupt``; the draws made so far are kept."""


class StuckChainsRestarted(UserWarning):
    """Warning: chains stuck far below the best one at the end of the burn-in were restarted
    from good chains' states (:mod:`~symplid.inference.samplers.restart`)."""


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
    """

    chunk: int
    iterations_done: int
    total_iterations: int
    draws_kept: int
    states: Any


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
        The restart rule's arrays (:meth:`~.restart.BurnInMonitor.arrays`: the window read so
        far, or the decision taken) when the run restarts stuck chains, else None.
    restarted_chains
        The chains restarted at the end of the burn-in
        (:meth:`~.restart.BurnInMonitor.records`); empty when none were.
    """

    draws: dict[str, np.ndarray]
    states: Any
    iterations_done: int
    interrupted: bool
    elapsed: float
    monitor: dict[str, np.ndarray] | None = None
    restarted_chains: tuple[dict[str, Any], ...] = ()


class DataStep:
    """A step that reads data: ``fn(data, rng_key, state) -> (state, info)``, called as
    ``step(rng_key, state)``.

    :func:`run_chains` passes ``data`` to the compiled chunk as an argument, so that the
    chunk's program does not hold the data as constants: the same kernel on another data set
    of the same shape (another seed of a sweep) is then the same program, which JAX's
    persistent compilation cache serves instead of compiling again.
    """

    def __init__(self, fn: Callable[[Any, jax.Array, Any], tuple[Any, Any]], data: Any):
        self.fn, self.data = fn, data

    def __call__(self, rng_key: jax.Array, state: Any) -> tuple[Any, Any]:
        return self.fn(self.data, rng_key, state)


def _over_chains(fn: Callable, batched: bool) -> Callable:
    """Apply a one-chain function to chains stacked on a leading axis.

    Unbatched (one chain, leading axis of length 1), a ``lax.cond`` in the kernel really
    skips work; under ``vmap`` it becomes a ``select`` that evaluates both branches.
    """
    if batched:
        return jax.vmap(fn)

    def single(*args):
        out = fn(*jax.tree.map(lambda leaf: leaf[0], args))
        return jax.tree.map(lambda leaf: leaf[None], out)

    return single


def _build_chunk(step: StepFn, record: RecordFn, chunk_len: int, batched: bool):
    """One compiled chunk (:func:`_compile_chunk`), kept on ``step`` so that running the
    same kernel again (another seed, more draws) reuses it."""
    return cached_or_built(step, ("chunk", record, chunk_len, batched),
                           lambda: _compile_chunk(step, record, chunk_len, batched))


def _compile_chunk(step: StepFn, record: RecordFn, chunk_len: int, batched: bool):
    """Compile one chunk: room for ``chunk_len`` iterations, of which the first
    ``num_active`` (a run-time number) are run; the records past them are zeros.

    The loop's trip count is an argument, so one compiled program runs any part of a chunk at
    the cost of that part (:class:`~.pacing.Pacer` cuts slow chunks into half-second pieces);
    each iteration computes what a ``lax.scan`` over the whole chunk computed. ``batched``
    vmaps over the chains; otherwise the chunk advances one chain (leading axis of length 1).
    """

    reads = isinstance(step, DataStep)
    data = step.data if reads else None

    def chunk(states, chain_keys, start, num_active, data):
        def one_chain(key, state, t):
            key = jax.random.fold_in(key, t)
            new_state, info = step.fn(data, key, state) if reads else step(key, state)
            return new_state, record(new_state, info)

        advance = _over_chains(one_chain, batched)

        def at(i):
            return jnp.broadcast_to(start + i, chain_keys.shape[:1])

        shapes = jax.eval_shape(lambda s: advance(chain_keys, s, at(0))[1], states)
        room = jax.tree.map(lambda a: jnp.zeros((chunk_len, *a.shape), a.dtype), shapes)

        def body(carry):
            i, current, records = carry
            new, kept = advance(chain_keys, current, at(i))
            records = jax.tree.map(
                lambda all_, one: lax.dynamic_update_index_in_dim(all_, one, i, 0),
                records, kept)
            return i + 1, new, records

        first = jnp.zeros((), jnp.asarray(num_active).dtype)
        _, states, records = lax.while_loop(lambda carry: carry[0] < num_active, body,
                                            (first, states, room))
        return states, records

    return functools.partial(jax.jit(chunk), data=data)


def _chunk_runner(step: StepFn, record: RecordFn, chunk_len: int, chain_method: str,
                  num_chains: int) -> Callable:
    """``run(states, chain_keys, start, num_active) -> (states, records)`` for all chains."""
    if chain_method == "vectorized" and num_chains > 1:
        return _build_chunk(step, record, chunk_len, True)
    single = _build_chunk(step, record, chunk_len, False)
    if num_chains == 1:
        return single

    def one_after_another(states, chain_keys, start, num_active):
        outputs = [
            single(jax.tree.map(lambda leaf, c=c: leaf[c:c + 1], states),
                   chain_keys[c:c + 1], start, num_active)
            for c in range(num_chains)
        ]
        states = jax.tree.map(lambda *parts: jnp.concatenate(parts), *[o[0] for o in outputs])
        # Records are (iteration, chain, ...): the chains go along axis 1.
        records = jax.tree.map(lambda *parts: jnp.concatenate(parts, axis=1),
                               *[o[1] for o in outputs])
        return states, records

    return one_after_another


def run_chains(
    step: StepFn,
    states: Any,
    rng_key: jax.Array,
    num_draws: int | None = None,
    *,
    record: RecordFn,
    burn_in: int = 0,
    thin: int = 1,
    chunk_size: int = 5000,
    chain_method: str = "vectorized",
    progress: bool = True,
    desc: str = "sampling",
    position: int | None = None,
    callback: Callable[[ChunkReport], None] | None = None,
    num_samples: int | None = None,
    start: int = 0,
    sink: ChunkSink | None = None,
    restart_stuck_chains: bool = False,
    monitor: dict[str, np.ndarray] | None = None,
) -> ChainRun:
    """Run several chains of a kernel in chunks of a compiled ``lax.scan``.

    Parameters
    ----------
    step
        Pure transition of one chain, ``step(rng_key, state) -> (state, info)``.
    states
        Initial states stacked over chains (leading axis = chain).
    rng_key
        Root key; split once into one key per chain.
    num_draws
        Draws to keep per chain after burn-in and thinning (``num_samples``: its deprecated
        old name).
    record
        ``record(state, info) -> dict`` of arrays kept at each kept iteration.
    burn_in
        Iterations run first and discarded.
    thin
        Keep one iteration in ``thin`` after burn-in; ``num_draws·thin`` iterations run.
    chunk_size
        Iterations per compiled chunk (the progress bar moves once per chunk).
    chain_method
        ``"vectorized"`` (``vmap``: all chains in lockstep; data-dependent branches such as
        DRAM's second stage run for every chain whenever one needs them) or
        ``"sequential"`` (the compiled one-chain chunk called for each chain in turn;
        branches really skipped, one compilation for all chains). Irrelevant for one chain,
        which always runs unbatched.
    progress, desc, position
        Show a tqdm progress bar; its label and line.
    callback
        Called with a :class:`ChunkReport` after each chunk; it may raise
        ``KeyboardInterrupt`` to stop the run (used in tests to simulate Ctrl-C).
    start
        Iterations already done: ``states`` are the chains after them (the ``states`` of an
        interrupted :class:`ChainRun`), and the run continues with iteration ``start + 1``.
        Keys, burn-in, thinning and chunks follow the whole run's grid, so an interrupted run
        continued this way gives the draws of the uninterrupted run (those after ``start``).
    sink
        Called after each chunk with its draws and the states (:data:`ChunkSink`), before
        ``callback``; e.g. to write them to disk as the run goes.
    restart_stuck_chains, monitor
        At the end of the burn-in, restart every chain whose log density (``record``'s
        ``"lp"``) stays far below the best chain's from a good chain's state
        (:mod:`~symplid.inference.samplers.restart`; the chunk in which the burn-in ends runs
        as two calls around the decision, one chunk from outside). ``monitor``: the
        interrupted run's, continued.

    Returns
    -------
    ChainRun
        Draws ``(num_chains, kept, ...)``, final states and run information. An interrupted
        run returns the draws of the chunks that finished and warns.
    """
    if num_samples is not None:
        if num_draws is not None:
            raise TypeError("pass num_draws only (num_samples is its deprecated old name)")
        warnings.warn("run_chains(num_samples=...) is deprecated: use num_draws=...",
                      FutureWarning, stacklevel=2)
        num_draws = num_samples
    num_chains = _check_run(num_draws, burn_in, thin, chunk_size, chain_method, states)
    total = int(burn_in) + int(num_draws) * int(thin)
    if int(start) != start or not 0 <= start < total:
        raise ValueError(f"start must be an integer in [0, {total}), got {start!r}")
    # Equal chunks of at most `chunk_size` iterations; the last one runs fewer than
    # `chunk_len` iterations only when `total` does not divide evenly (then by < num_chunks).
    num_chunks = -(-total // int(chunk_size))
    chunk_len = -(-total // num_chunks)
    chunk_fn = _chunk_runner(step, record, chunk_len, chain_method, num_chains)
    chain_keys = jax.random.split(rng_key, num_chains)
    restarts = (BurnInMonitor(num_chains, int(burn_in), rng_key, monitor)
                if restart_stuck_chains else None)
    if restarts is not None:
        restarts.resumed_from(int(start))
    bar = _progress_bar(total, desc, progress, position, int(start))
    started = time.perf_counter()
    try:
        loop = _Loop(chunk_fn, chain_keys, total, chunk_len, int(burn_in), int(thin), callback,
                     int(start), sink, restarts)
        states = loop.run(states, bar, started)
    finally:
        if bar is not None:
            bar.close()
    elapsed = time.perf_counter() - started
    if loop.interrupted:
        warnings.warn(
            f"{desc} interrupted after {loop.done} of {total} iterations; keeping the "
            f"{loop.draws_kept} draws per chain made so far",
            SamplingInterrupted,
            stacklevel=2,
        )
    draws = {
        name: np.swapaxes(np.concatenate(parts, axis=0), 0, 1) for name, parts in loop.kept.items()
    }
    if restarts is None:
        return ChainRun(draws, states, loop.done, loop.interrupted, elapsed)
    return ChainRun(draws, states, loop.done, loop.interrupted, elapsed, restarts.arrays(),
                    tuple(restarts.records()))


def _check_run(num_draws: Any, burn_in: Any, thin: Any, chunk_size: Any, chain_method: str,
               states: Any) -> int:
    """Validate :func:`run_chains`' arguments; returns the number of chains."""
    if num_draws is None:
        raise TypeError("run_chains() needs num_draws, the draws to keep per chain")
    for name, value, low in (("num_draws", num_draws, 1), ("burn_in", burn_in, 0),
                             ("thin", thin, 1), ("chunk_size", chunk_size, 1)):
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
    thin grid, hands each chunk to the sink and the callback, and stops cleanly before a chunk
    when a stop was requested (:mod:`symplid.stopping`) or on ``KeyboardInterrupt``."""

    def __init__(self, chunk_fn: Callable, chain_keys: jax.Array, total: int, chunk_len: int,
                 burn_in: int, thin: int, callback: Callable[[ChunkReport], None] | None,
                 start: int = 0, sink: ChunkSink | None = None,
                 restarts: BurnInMonitor | None = None):
        self.chunk_fn, self.chain_keys = chunk_fn, chain_keys
        self.total, self.chunk_len, self.burn_in, self.thin = total, chunk_len, burn_in, thin
        self.callback, self.sink, self.restarts = callback, sink, restarts
        self.sink_takes_monitor = restarts is not None and _takes_monitor(sink)
        self.kept: dict[str, list[np.ndarray]] = {}
        self.done = start
        self.draws_kept = max(0, start - burn_in) // thin
        self.interrupted = False
        self.pacer = Pacer(chunk_len)

    def run(self, states: Any, bar: Any, started: float) -> Any:
        chunk_index = 0
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
                    extra = {"monitor": self.restarts.arrays()} if self.sink_takes_monitor else {}
                    self.sink(chunk, states, self.done - ran, self.done,
                              time.perf_counter() - started, **extra)
                if self.callback is not None:
                    self.callback(ChunkReport(chunk_index, self.done, self.total,
                                              self.draws_kept, states))
            except KeyboardInterrupt:
                self.interrupted = self.done < self.total
                break
            if ran < num_active:  # stopped inside the chunk: its finished pieces are kept
                self.interrupted = True
                break
            chunk_index += 1
        return states

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
        pieces of about half a second (:class:`~.pacing.Pacer`; the first, which compiles, in a
        worker thread: :func:`symplid.stopping.waiting`); a stop requested between two pieces
        (:mod:`symplid.stopping`) ends it early. Returns the states, the records of the
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
                          StuckChainsRestarted, stacklevel=4)
        return states

    def _keep(self, records: dict[str, Any], num_active: int,
              start: int) -> dict[str, np.ndarray]:
        """Keep the chunk's iterations past burn-in on the thin grid; returns them
        ``(num_chains, kept, ...)`` (empty arrays in the burn-in)."""
        # Iterations start + 1 .. start + num_active; keep those past burn-in on the thin grid.
        iterations = np.arange(start + 1, start + num_active + 1)
        if self.restarts is not None and self.restarts.pending:
            self.restarts.observe(iterations, np.asarray(records["lp"])[:num_active])
        keep = (iterations > self.burn_in) & ((iterations - self.burn_in) % self.thin == 0)
        chunk = {name: np.asarray(value)[:num_active][keep] for name, value in records.items()}
        if keep.any():
            for name, value in chunk.items():
                self.kept.setdefault(name, []).append(value)
            self.draws_kept += int(keep.sum())
        return {name: np.swapaxes(value, 0, 1) for name, value in chunk.items()}


def _takes_monitor(sink: Any) -> bool:
    """Whether ``sink`` accepts the ``monitor`` keyword (:data:`ChunkSink`)."""
    if sink is None:
        return False
    try:
        parameters = inspect.signature(sink).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == "monitor" or p.kind is p.VAR_KEYWORD for p in parameters)


def _progress_bar(total: int, desc: str, enabled: bool, position: int | None = None,
                  initial: int = 0):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="it", unit_scale=True, dynamic_ncols=True,
                position=position, initial=initial)
