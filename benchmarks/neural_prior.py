"""The log prior of a network's weights: one vector per shared prior against one term per weight.

An MLP potential (16 × 2, 336 weights, the baselines study's) puts one Normal(0, 1) prior on
every weight. ``log_density_sum`` evaluates the parameters that share a prior as one vector;
before, it added one traced term per parameter, so every program that contains the log prior
(value and gradient, log density, the Laplace step's diagonal prior Hessian) traced and
compiled hundreds of scalar expressions. The baseline here is that per-parameter sum, written
out in this file, run in the same process.

Rows (the minimum over repeats of the process's CPU time; XLA on one thread):

* ``trace + compile``: ``jax.jit`` of the prior's value and gradient and of its diagonal
  Hessian (what each new posterior pays, once per program; the compilation cache is off);
* ``eager diagonal Hessian``: the diagonal Hessian run without ``jax.jit``, primitive by
  primitive, as the Laplace step did before;
* ``call``: one call of the compiled value and gradient.

Run on one idle core: ``taskset -c 0 python benchmarks/neural_prior.py``.
"""

from __future__ import annotations

import os

os.environ.setdefault(
    "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
)
os.environ.setdefault("SYMPLID_CACHE_DIR", "off")

import time

import jax
import jax.numpy as jnp
import numpy as np

import symplid  # noqa: F401  (float64)
from symplid.inference.map._neural import _diagonal_hessian as diagonal_hessian
from symplid.model._prior_spec import log_density_sum
from symplid.model._priors import Normal

NUM_WEIGHTS = 336  # MLPPotential(dim=2, width=16, depth=2)
REPEATS = 3


def per_parameter_sum(priors, theta):
    """The earlier ``log_density_sum``: one term per parameter."""
    total = jnp.zeros(theta.shape[:-1])
    for i, prior in enumerate(priors):
        total = total + prior.log_density(theta[..., i])
    return total


def cpu_seconds(work, repeats: int = REPEATS) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.process_time()
        work()
        best = min(best, time.process_time() - start)
    return best


def measure(sum_fn, priors, theta) -> dict[str, float]:
    def prior(t):
        return sum_fn(priors, t)

    def build():  # a fresh jit each time: what a new posterior traces and compiles
        vg = jax.jit(jax.value_and_grad(prior))
        jax.block_until_ready(vg(theta))
        jax.block_until_ready(jax.jit(diagonal_hessian(prior))(theta))

    vg = jax.jit(jax.value_and_grad(prior))
    jax.block_until_ready(vg(theta))
    return {
        "trace + compile": cpu_seconds(build),
        "eager diagonal Hessian": cpu_seconds(
            lambda: jax.block_until_ready(diagonal_hessian(prior)(theta))),
        "call": cpu_seconds(lambda: jax.block_until_ready(vg(theta)), 200) * 1e6,
    }


def main() -> None:
    priors = [Normal(0.0, 1.0)] * NUM_WEIGHTS
    theta = jnp.asarray(np.random.default_rng(0).normal(size=NUM_WEIGHTS))
    want = float(per_parameter_sum(priors, theta))
    got = float(log_density_sum(priors, theta))
    assert abs(got - want) <= 1e-12 * abs(want), (got, want)
    before = measure(per_parameter_sum, priors, theta)
    after = measure(log_density_sum, priors, theta)
    print(f"log prior of {NUM_WEIGHTS} weights sharing Normal(0, 1); CPU time, min of {REPEATS}")
    print("| row | one term per weight | one vector | ratio |\n|---|---|---|---|")
    for row, unit in (("trace + compile", "s"), ("eager diagonal Hessian", "s"),
                      ("call", "µs")):
        print(f"| {row} ({unit}) | {before[row]:.3g} | {after[row]:.3g} | "
              f"{before[row] / after[row]:.1f}× |")


if __name__ == "__main__":
    main()
