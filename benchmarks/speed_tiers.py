"""Speed tiers of the likelihood and of DRAM, each as a ratio measured in the same run.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential, leapfrog at dt = 0.25,
20 full-state observations 5 s apart (data seed 0): 20 gaps × 20 substeps × 9 sigma points.
The DRAM target is the paper's posterior (Laplace(0, 10) on the 9 coefficients, half-normal(1)
on the 2 variances, written inline so that no MAP search is compiled), started at the truth
with a fixed diagonal proposal covariance.

Tiers (each measured in its own child process, pinned to CPU 0, one XLA thread):

* ``tier 0``: XLA's default loop compilation (``SYMPLID_XLA_FLAGS=off``): every operation of
  a ``while`` body is dispatched on its own.
* ``tier 1``: what ``import symplid`` sets up: small loops compiled whole
  (``xla_cpu_small_while_loop_byte_threshold``), DRAM's linear algebra unrolled; the JAX
  likelihood (``backend="jax"``).
* ``tier 2``: tier 1 with the compiled C++ likelihood kernel (``backend="compiled"``, what
  ``backend="auto"`` picks where it is built); its gradient is the kernel's adjoint (the
  symplectic compositions; the JAX tier's otherwise).

Rows: the value in a compiled loop, the value batched over 64 θ (per θ), the gradient in a
compiled loop, DRAM iterations per CPU second (one chain; four chains one after another, four
chains vectorised, and four vectorised with both stages evaluated in one batch of eight — what
``sample`` picks for four chains on the compiled kernel; counting the iterations of all
chains), the bound on DRAM from the
value alone (evaluations per second / (1 + stage-2 share)), and the NumPy baseline (same
filter, plain NumPy). Times are the minimum over repeats; the machine may be shared, so read
the ratios.

Run: ``python benchmarks/speed_tiers.py`` (``--quick`` for fewer repeats).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TARGETS = {
    "value, compiled loop (µs)": "≤ 6",
    "value, vmap 64 (µs per θ)": "≤ 3",
    "gradient, compiled loop (µs)": "≤ 10× value",
    "DRAM 1 chain (it/s)": "≥ 50,000",
}


def _pin() -> None:
    if hasattr(os, "sched_setaffinity"):
        with contextlib.suppress(OSError):
            os.sched_setaffinity(0, {0})


def best_time(fn, *args, number: int, repeats: int) -> float:
    """Smallest mean CPU time per call over ``repeats`` batches of ``number`` calls."""
    import jax

    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        for _ in range(number):
            out = fn(*args)
        jax.block_until_ready(out)
        best = min(best, (time.process_time() - start) / number)
    return best


def paper_target(backend: str):
    """The workload of the module docstring: ``(theta, loglik, log_density)``, θ the truth."""
    import jax.numpy as jnp
    import numpy as np

    import symplid

    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25,
                                     backend=backend)
    theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
    loglik = model.log_likelihood_fn(data, system.initial_state)
    is_var = np.zeros(theta.shape[0], bool)
    is_var[-2:] = True  # the process and observation variances

    def log_density(t):
        prior = jnp.sum(jnp.where(is_var, -0.5 * t**2 + 0.5 * np.log(2 / np.pi),
                                  -jnp.abs(t) / 10.0 - np.log(20.0)))
        inside = jnp.all(jnp.where(is_var, t > 0, True))
        safe = jnp.where(inside, t, jnp.where(is_var, 1.0, t))
        return jnp.where(inside, prior + loglik(safe), -jnp.inf)

    return theta, loglik, log_density


def measure(repeats: int, dram_iterations: int) -> dict[str, float]:
    """Run in a child process: every row of one tier."""
    import jax
    import jax.numpy as jnp

    from symplid.inference.samplers import dram
    from symplid.sampling import RunOptions, run_chains

    backend = os.environ.get("SYMPLID_BENCH_BACKEND", "jax")
    theta, loglik, log_density = paper_target(backend)
    num_loop = 200
    thetas = theta * (1.0 + 1e-3 * jax.random.normal(jax.random.key(1), (num_loop, 11)))

    def looped(fn):
        @jax.jit
        def run(ths):
            return jax.lax.scan(lambda acc, th: (acc + jnp.sum(fn(th)), None), 0.0, ths)[0]

        return run

    out = {
        "value, compiled loop (µs)": best_time(looped(loglik), thetas, number=3,
                                              repeats=repeats) / num_loop * 1e6,
        "value, vmap 64 (µs per θ)": best_time(jax.jit(jax.vmap(loglik)), thetas[:64],
                                               number=10, repeats=repeats) / 64 * 1e6,
        "gradient, compiled loop (µs)": best_time(looped(jax.grad(loglik)), thetas[:50],
                                                 number=2, repeats=repeats) / 50 * 1e6,
    }

    cov = jnp.diag(jnp.asarray([1e-6] * 9 + [1e-14, 1e-8]))
    # What sample() resolves (registry.resolve_dram): around the compiled kernel's custom call
    # each stretch of the step compiled as one kernel ("fused"); for four vectorised chains,
    # both stages in one batch.
    algebra = "fused" if backend == "compiled" else "unrolled"
    staged = dram.build_kernel(log_density, dram.DRAMSettings(linalg=algebra))
    paired = dram.build_kernel(log_density, dram.DRAMSettings(paired_stages=True,
                                                              linalg=algebra))
    share = 0.0
    for chains, layout, step in ((1, "vectorized", staged), (4, "sequential", staged),
                                 (4, "vectorized", staged), (4, "paired", paired)):
        states = jax.jit(jax.vmap(lambda p: dram.init(p, log_density, cov)))(
            jnp.tile(theta, (chains, 1)))
        common = dict(record=lambda s, i: {"stage2": i.stage2_attempted},
                      options=RunOptions(chunk_size=1000, progress=False,
                                         chain_method="vectorized" if layout == "paired"
                                         else layout))
        warm = run_chains(step, states, jax.random.key(0), 1000, **common)
        best = 0.0
        for _ in range(max(1, repeats // 3)):
            cpu = time.process_time()
            run = run_chains(step, warm.states, jax.random.key(1), dram_iterations, **common)
            best = max(best, dram_iterations / (time.process_time() - cpu))
        name = ("DRAM 1 chain (it/s)" if chains == 1
                else f"DRAM 4 chains, {layout} (it/s, all chains)")
        if layout == "paired":
            name = "DRAM 4 chains, vectorized, paired stages (it/s, all chains)"
        out[name] = best * chains
        if chains == 1:
            share = float(run.draws["stage2"].mean())
    out["DRAM bound from the value (it/s)"] = (
        1e6 / out["value, compiled loop (µs)"] / (1.0 + share))
    out["stage-2 share"] = share
    return out


def numpy_baseline(repeats: int) -> float:
    """µs per NumPy log-likelihood (tests/reference_filters.py), same workload."""
    import numpy as np

    import symplid

    sys.path.insert(0, str(HERE.parent / "tests"))
    from reference_filters import (
        numpy_leapfrog,
        numpy_substeps,
        numpy_ukf_loglik,
        polynomial_gradient,
    )

    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    leapfrog = numpy_leapfrog(polynomial_gradient(system.potential.exponents,
                                                  system.coefficients))
    num_steps, step_sizes = numpy_substeps(data.times, 0.25)
    args = (leapfrog, system.initial_state, 1e-16 * np.eye(4), num_steps, step_sizes,
            data.values, 1e-6 * np.eye(4), 0.05**2 * np.eye(4))
    best = float("inf")
    for _ in range(repeats):
        start = time.process_time()
        numpy_ukf_loglik(*args, jitter=1e-12)
        best = min(best, time.process_time() - start)
    return best * 1e6


def _child(tier: str, repeats: int, dram_iterations: int) -> dict[str, float]:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    env.pop("XLA_FLAGS", None)
    if tier == "tier 0":
        env["SYMPLID_XLA_FLAGS"] = "off"
    else:
        env.pop("SYMPLID_XLA_FLAGS", None)
    env["SYMPLID_BENCH_BACKEND"] = "compiled" if tier == "tier 2" else "jax"
    code = (f"import sys; sys.path.insert(0, {str(HERE)!r}); import speed_tiers as b; "
            f"b._pin(); from symplid import runtime; runtime.limit_threads(); import json; "
            f"print(json.dumps(b.measure({repeats}, {dram_iterations})))")
    result = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                            capture_output=True, text=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats and iterations")
    parser.add_argument("--json", type=str, default=None, help="also write results here")
    args = parser.parse_args(argv)
    repeats, iterations = (3, 2000) if args.quick else (7, 6000)
    _pin()
    names = ("tier 0", "tier 1", "tier 2")
    tiers = {tier: _child(tier, repeats, iterations) for tier in names}
    baseline = numpy_baseline(repeats)
    t0, t1, t2 = (tiers[name] for name in names)
    value = "value, compiled loop (µs)"
    print("| measurement | tier 0 | tier 1 | tier 2 | tier 1 / tier 0 | tier 2 / tier 0 | target |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for name in t0:
        if name == "stage-2 share":
            continue
        ratios = [t0[name] / t[name] if "µs" in name else t[name] / t0[name] for t in (t1, t2)]
        print(f"| {name} | {t0[name]:,.1f} | {t1[name]:,.1f} | {t2[name]:,.1f} "
              f"| {ratios[0]:.2f}× | {ratios[1]:.2f}× | {TARGETS.get(name, '')} |")
    print(f"| NumPy baseline (µs) | {baseline:,.0f} | | | value ×{baseline / t1[value]:.0f} "
          f"faster than NumPy (tier 1), ×{baseline / t2[value]:.0f} (tier 2) | | |")
    for label, t in (("tier 1", t1), ("tier 2", t2)):
        ratio = t["gradient, compiled loop (µs)"] / t[value]
        print(f"\n{label}: gradient / value = {ratio:.1f}; stage-2 share "
              f"{t['stage-2 share']:.2f}", end="")
    print("\n(ratios: how many times faster than tier 0; CPU seconds, pinned to CPU 0)")
    if args.json:
        Path(args.json).write_text(json.dumps({**tiers, "numpy_us": baseline}, indent=2))
    return tiers


if __name__ == "__main__":
    main()
