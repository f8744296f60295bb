"""The compiled likelihood kernel against the JAX reference, same run, on the paper's workload.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential (9 coefficients), leapfrog at
dt = 0.25, 20 full-state observations 5 s apart (20 gaps × 20 substeps × 9 sigma points),
isotropic noise added once per gap.

Every row is the time per evaluation inside one compiled ``lax.fori_loop`` (what a sampler
sees), the minimum over repeats:

* ``log L``: one θ per iteration;
* ``log L, vmap 64``: a batch of 64 θ per iteration, time per θ;
* ``value and gradient``: ``jax.value_and_grad`` of log L (under differentiation the compiled
  tier evaluates the JAX reference's value and tangent, so it cannot be faster there).

Times are the process's CPU time (``time.process_time``), the minimum over repeats: on a
shared machine wall time would count other people's work. XLA runs on one thread.

Run on one idle core: ``taskset -c 0 python benchmarks/compiled_kernel.py``.
"""

from __future__ import annotations

import dataclasses
import os

os.environ.setdefault(
    "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
)

import time
from collections.abc import Callable

import jax
import jax.numpy as jnp

import symplid
from symplid.model import kernel as compiled_kernel


def loop_time(step: Callable[[jax.Array], jax.Array], thetas: jax.Array, repeats: int) -> float:
    """CPU seconds per iteration of ``step`` in a compiled ``fori_loop`` (minimum of repeats)."""
    count = thetas.shape[0]

    @jax.jit
    def run(thetas):
        def body(i, total):
            return total + jnp.sum(step(thetas[i]))

        return jax.lax.fori_loop(0, count, body, 0.0)

    jax.block_until_ready(run(thetas))
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        jax.block_until_ready(run(thetas))
        best = min(best, (time.process_time() - start) / count)
    return best


def main(repeats: int = 7) -> None:
    if not compiled_kernel.available():
        raise SystemExit("the compiled kernel is not built: pip install the package first")
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
    prepared = model.prepare(data)
    # the JAX tier explicitly: backend="auto" would pick the compiled kernel itself
    reference = dataclasses.replace(model, backend="jax").log_likelihood_fn(data, x0)

    def compiled(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0)

    key = jax.random.key(0)
    singles = theta * (1.0 + 1e-3 * jax.random.normal(key, (400, theta.shape[0])))
    batches = theta * (1.0 + 1e-3 * jax.random.normal(key, (20, 64, theta.shape[0])))
    grads = singles[:100]

    rows = [
        ("log L", lambda f: loop_time(f, singles, repeats), 1),
        ("log L, vmap 64 (per θ)", lambda f: loop_time(jax.vmap(f), batches, repeats), 64),
        ("value and gradient", lambda f: loop_time(_value_and_grad(f), grads, repeats), 1),
    ]
    print(f"kernel instruction set: {compiled_kernel.instruction_set()}\n")
    print("| per evaluation | JAX reference (µs) | compiled kernel (µs) | speed-up |")
    print("|---|---:|---:|---:|")
    for name, timer, per in rows:
        t_ref = timer(reference) / per * 1e6
        t_new = timer(compiled) / per * 1e6
        print(f"| {name} | {t_ref:.2f} | {t_new:.2f} | {t_ref / t_new:.1f}× |")


def _value_and_grad(fn: Callable[[jax.Array], jax.Array]) -> Callable[[jax.Array], jax.Array]:
    def step(th):
        value, grad = jax.value_and_grad(fn)(th)
        return value + jnp.sum(grad)

    return step


if __name__ == "__main__":
    main()
