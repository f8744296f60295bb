"""A stretch of array code that XLA:CPU compiles as one kernel inside a loop it runs op by op.

XLA:CPU compiles a ``while`` loop whose state is small and whose body holds no custom call as
one kernel (``xla_cpu_small_while_loop_byte_threshold``, set by
:func:`symplid.runtime.configure_xla`). A loop that holds a custom call, such as a DRAM chunk
around the compiled likelihood kernel, is run operation by operation instead: every fused
operation, copy and loop-carried value of its body is dispatched on its own, each at a cost
of tens of nanoseconds however little it computes. A sampler step's own arithmetic (random
draws, the proposal, the acceptance test, the adaptive update with its Cholesky factor) is
some hundred such operations around one likelihood call.

:func:`one_kernel` wraps a function so that its body is the body of a ``while`` loop that
runs once: that loop holds no custom call, so XLA compiles it whole, and the outer loop
dispatches it as one operation. Two details make it stay a loop:

* the trip count starts from an ``optimization_barrier``, so XLA cannot prove that the loop
  runs exactly once (and inline it back);
* the inputs pass through an ``optimization_barrier`` together with the loop counter inside
  the body, so XLA's loop-invariant code motion cannot hoist the computation out of it.

The numbers are those of the unwrapped function up to XLA's own regrouping of the same
operations (rounding; ``tests/test_kernel_region.py``). Only arrays go in and out; bind
anything static with a closure or :func:`functools.partial`. It does not pay, and is not
used, where the surrounding loop is compiled whole anyway (no custom call in it).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

__all__ = ["one_kernel"]


def one_kernel(fn: Callable[..., Any]) -> Callable[..., Any]:
    """``fn`` computed in a one-trip ``while`` loop that XLA:CPU compiles as one kernel.

    Parameters
    ----------
    fn
        A pure function of arrays (pytrees of arrays) returning arrays (a pytree of arrays).

    Returns
    -------
    Callable
        A function with ``fn``'s signature and results; traceable under ``jit`` and ``vmap``.
    """

    @functools.wraps(fn)
    def wrapped(*args: Any) -> Any:
        shapes = jax.eval_shape(fn, *args)
        empty = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        start = lax.optimization_barrier(jnp.zeros((), jnp.int32))

        def body(carry: tuple[jax.Array, Any]) -> tuple[jax.Array, Any]:
            count, inputs = lax.optimization_barrier((carry[0], args))
            return count + 1, fn(*inputs)

        return lax.while_loop(lambda carry: carry[0] < 1, body, (start, empty))[1]

    return wrapped
