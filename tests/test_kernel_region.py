"""``one_kernel``: the wrapped function's numbers, compiled as one kernel inside a loop that
XLA:CPU otherwise runs operation by operation (one that holds a custom call)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import symplid  # noqa: F401  (float64, XLA flags)
from symplid._kernel_region import one_kernel
from symplid.filters import _linalg as linalg


def _update(chol_input, delta, scale):
    """Arithmetic of DRAM's kind: a rank-one update, an unrolled Cholesky factor, a solve."""
    matrix = chol_input + jnp.outer(delta, delta)
    chol = linalg.cholesky(matrix, 16)
    return {"chol": chol, "white": linalg.solve_lower(chol, scale * delta),
            "finite": jnp.all(jnp.isfinite(chol))}


def _inputs(seed=0, dim=6):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(dim, dim))
    return jnp.asarray(a @ a.T + dim * np.eye(dim)), jnp.asarray(rng.normal(size=dim)), 0.7


def test_same_numbers_as_the_function():
    args = _inputs()
    want = jax.jit(_update)(*args)
    got = jax.jit(one_kernel(_update))(*args)
    for key in want:
        np.testing.assert_allclose(got[key], want[key], rtol=1e-13, atol=0)
    np.testing.assert_allclose(got["chol"] @ got["chol"].T, args[0] + np.outer(args[1], args[1]),
                               rtol=1e-12)


def test_under_vmap_each_member_as_alone():
    chols, deltas = zip(*[_inputs(seed)[:2] for seed in range(5)], strict=True)
    batched = jax.jit(jax.vmap(one_kernel(_update), in_axes=(0, 0, None)))(
        jnp.stack(chols), jnp.stack(deltas), 0.7)
    for i in range(5):
        alone = _update(chols[i], deltas[i], 0.7)
        np.testing.assert_allclose(batched["white"][i], alone["white"], rtol=1e-12)


def test_in_a_loop_with_a_custom_call_the_region_is_one_kernel():
    """In a scan whose body holds a custom call (a LAPACK Cholesky factor), the region stays a
    loop that XLA compiles whole (a 'small call'), and the scan's result is the plain one."""
    chol_input, delta, _ = _inputs()

    def scan_with(region):
        def body(carry, x):
            lapack = jnp.linalg.cholesky(carry + jnp.eye(carry.shape[0]))  # a custom call
            out = region(carry, x * delta, 0.5)
            return carry + 1e-3 * (lapack @ lapack.T), out["white"]

        return jax.jit(lambda c: jax.lax.scan(body, c, jnp.linspace(0.1, 1.0, 7)))

    run = scan_with(one_kernel(_update))
    text = run.lower(chol_input).compile().as_text()
    assert "custom-call" in text
    assert "xla_cpu_small_call" in text
    got = run(chol_input)
    want = scan_with(_update)(chol_input)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-13)
