"""DRAM's step arithmetic around the compiled likelihood: inline, LAPACK, or one kernel per stretch.

Workload: the paper's posterior of ``speed_tiers.py`` (its ``paper_target``: Hénon–Heiles,
cubic U, leapfrog at dt = 0.25, 20 full-state observations, Laplace(0, 10) on the coefficients
and half-normal(1) on the variances), on the compiled kernel, started at the truth with a fixed
diagonal proposal covariance; and, to show what the step costs beside the likelihood, a
Gaussian log density of the same dimension, alone (the whole chunk is then one kernel) and
with a one-element LAPACK call added (a custom call: the chunk runs operation by operation).

Each ``linalg`` choice (``unrolled`` inline, ``lapack``, ``fused``: one kernel per stretch
between log-density calls, :func:`symplid._kernel_region.one_kernel`) runs in this one process,
pinned to one core, one chain stage by stage and four vectorised chains with paired stages;
µs of CPU time per iteration, the best of ``--repeats``. The machine may be shared: read the
ratios.

Run: ``taskset -c 0 python benchmarks/dram_regions.py [--iterations 20000] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

CHOICES = ("unrolled", "lapack", "fused")


def _pin() -> None:
    if hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, {0})


def targets():
    """The three log densities: the paper's posterior, a Gaussian, the Gaussian + a custom call."""
    import jax.numpy as jnp

    from speed_tiers import paper_target

    theta, _, paper = paper_target("compiled")
    scales = jnp.asarray([1e-6] * 9 + [1e-14, 1e-8])

    def gaussian(t):
        return -0.5 * jnp.sum((t - theta) ** 2 / scales)

    def gaussian_and_call(t):
        one = jnp.linalg.cholesky(jnp.eye(1) * (1.0 + t[0] ** 2))[0, 0]  # a LAPACK custom call
        return gaussian(t) + 0.0 * one

    return theta, jnp.diag(scales), {"paper's posterior": paper, "Gaussian": gaussian,
                                     "Gaussian + custom call": gaussian_and_call}


def per_iteration(log_density, theta, cov, linalg: str, chains: int, iterations: int,
                  repeats: int) -> float:
    """Best CPU µs per iteration (of all chains together) over ``repeats`` runs."""
    import jax
    import jax.numpy as jnp

    from symplid.inference.samplers import dram
    from symplid.sampling import RunOptions, run_chains

    settings = dram.DRAMSettings(linalg=linalg, paired_stages=chains > 1)
    step = dram.build_kernel(log_density, settings)
    states = jax.jit(jax.vmap(lambda p: dram.init(p, log_density, cov)))(
        jnp.tile(theta, (chains, 1)))
    common = dict(record=lambda s, i: {"stage2": i.stage2_attempted},
                  options=RunOptions(chunk_size=1000, chain_method="vectorized", progress=False))
    warm = run_chains(step, states, jax.random.key(0), 1000, **common)
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        run_chains(step, warm.states, jax.random.key(1), iterations, **common)
        best = min(best, (time.process_time() - start) / iterations)
    return best * 1e6


def main(argv: list[str] | None = None) -> list[tuple[str, int, dict[str, float]]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--iterations", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    _pin()
    from symplid import runtime

    runtime.limit_threads()
    theta, cov, densities = targets()
    rows = []
    print("| log density | chains | " + " | ".join(f"{c} (µs/it)" for c in CHOICES)
          + " | unrolled / fused |")
    print("|---|---:|" + "---:|" * (len(CHOICES) + 1))
    for name, fn in densities.items():
        for chains in (1, 4):
            cells = {c: per_iteration(fn, theta, cov, c, chains, args.iterations, args.repeats)
                     for c in CHOICES}
            rows.append((name, chains, cells))
            print(f"| {name} | {chains} | " + " | ".join(f"{cells[c]:.2f}" for c in CHOICES)
                  + f" | {cells['unrolled'] / cells['fused']:.2f}× |", flush=True)
    return rows


if __name__ == "__main__":
    main()
