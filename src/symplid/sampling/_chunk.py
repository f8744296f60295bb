"""One compiled chunk of iterations over several chains: the unit :mod:`~._run` drives.

A chunk is **one** compiled loop over iterations whose body advances all chains at once
(``vmap``), or, for ``chain_method="sequential"``, one chain (the same compiled
one-chain chunk is then called for each chain in turn, which compiles faster than a batched
kernel and lets data-dependent branches skip work). The key of iteration ``t`` of chain
``c`` is ``fold_in(chain_key[c], t)``, so the draws do not depend on how the run is cut into
chunks. The loop's trip count is a run-time argument, so one compiled program runs any part
of a chunk at the cost of that part (:class:`~._pacing.Pacer` cuts slow chunks into
half-second pieces). The compiled chunk is kept on the ``step`` function object
(:func:`symplid._compiled.cached`, keyed by ``record`` and the chunk's shape).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from symplid._compiled import cached_or_built
from symplid._saved_programs import identity_of, saved_jit
from symplid.inference.samplers._registry import DataStep

__all__ = ["DataStep", "RecordFn", "StepFn", "chunk_runner"]

StepFn = Callable[[jax.Array, Any], tuple[Any, Any]]
RecordFn = Callable[[Any, Any], dict[str, jax.Array]]


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
    the cost of that part (:class:`~._pacing.Pacer` cuts slow chunks into half-second pieces);
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

    # saved for later processes when the step and record say what they close over
    identities = (identity_of(step), identity_of(record))
    identity = None if None in identities else (*identities, chunk_len, batched)
    return functools.partial(saved_jit(chunk, "sampler-chunk", identity), data=data)


def chunk_runner(step: StepFn, record: RecordFn, chunk_len: int, chain_method: str,
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
