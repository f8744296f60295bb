"""Small-matrix linear algebra for the filter, written to fuse under XLA.

For dimensions up to :data:`SMALL_DIM` the Cholesky factorisation and the triangular solves
are unrolled at trace time, so XLA fuses them with the surrounding arithmetic instead of
calling LAPACK for a 4×4 matrix; larger problems fall back to ``jnp.linalg``. Small matrices
are multiplied by broadcast-and-sum rather than ``dot``: for 4×9 operands XLA fuses the former
with its neighbours, while every ``dot`` is a separate library call. A factorisation that fails
gives NaN or inf, never an error.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "MAX_UNROLLED_DIM",
    "SMALL_DIM",
    "cholesky",
    "cholesky_columns",
    "matmul",
    "solve_lower",
    "symmetrize",
]

Array = jax.Array

SMALL_DIM = 8
#: Largest dimension for which a caller may ask for the unrolled versions explicitly (the
#: sampler's proposal covariance: 11 parameters for the paper's posterior).
MAX_UNROLLED_DIM = 16


def symmetrize(a: Array) -> Array:
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def matmul(a: Array, b: Array) -> Array:
    """``a @ b`` for small matrices or a matrix and a vector, by broadcast-and-sum (fuses)."""
    if b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def cholesky(a: Array, max_unrolled: int = SMALL_DIM + 1) -> Array:
    """Lower Cholesky factor; NaN or inf (never an error) when ``a`` is not positive definite.

    For n ≤ ``max_unrolled`` this is the right-looking algorithm unrolled at trace time: one
    column and one rank-1 update of the trailing matrix per step, a few fused kernels per
    column instead of a LAPACK call (a custom call, which keeps XLA from compiling the
    surrounding loop as one kernel) or one kernel per scalar.
    """
    n = a.shape[-1]
    if n > max_unrolled:
        return jnp.linalg.cholesky(a)
    return cholesky_columns(a, n)


def cholesky_columns(a: Array, num_columns: int) -> Array:
    """The first ``num_columns`` columns of the lower Cholesky factor, shape ``(n, num_columns)``.

    Right-looking and unrolled; later columns are never formed, so nothing is computed (or
    differentiated) from the trailing block beyond them.
    """
    n = a.shape[-1]
    idx = jnp.arange(n)
    cols = []
    for j in range(num_columns):
        col = jnp.where(idx >= j, a[:, j] / jnp.sqrt(a[j, j]), 0.0)
        cols.append(col)
        if j < num_columns - 1:
            a = a - col[:, None] * col[None, :]
    return jnp.stack(cols, axis=1)


def solve_lower(chol: Array, b: Array, max_unrolled: int = SMALL_DIM) -> Array:
    """Solve L x = b by forward substitution; ``b`` has shape ``(n,)`` or ``(n, k)``.

    Unrolled at trace time for n ≤ ``max_unrolled``, ``solve_triangular`` beyond.
    """
    n = chol.shape[-1]
    if n > max_unrolled:
        return jax.scipy.linalg.solve_triangular(chol, b, lower=True)
    xs: list[Array] = []
    for i in range(n):
        s = b[i]
        for k in range(i):
            s = s - chol[i, k] * xs[k]
        xs.append(s / chol[i, i])
    return jnp.stack(xs)
