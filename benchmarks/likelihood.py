"""Time one UKF log-likelihood of the paper's workload against a NumPy baseline, same run.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential (9 coefficients), leapfrog at
dt = 0.25, 20 full-state observations 5 s apart: 20 gaps × 20 substeps × 9 sigma points.

Rows:
* ``jax single``: one jitted call from Python (includes the dispatch of a jitted function).
* ``jax in a compiled loop``: 200 evaluations inside one ``lax.scan`` (what a sampler sees).
* ``jax vmap 8`` / ``jax vmap 64``: one call over a batch of θ, time per θ (amortised).
* ``numpy``: a plain vectorised NumPy UKF (tests/reference_filters.py), the baseline.

Everything runs on one CPU thread, pinned to CPU 0, with the XLA flags of ``import symplid``.
Run: ``python benchmarks/likelihood.py``.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {0})  # pinned to one core: the machine may be shared

from symplid import runtime  # noqa: E402  (sets the small-loop flag before JAX starts)

runtime.limit_threads()  # one XLA thread, merged so that no flag is lost behind a bare token

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import symplid  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference_filters import (  # noqa: E402
    numpy_leapfrog,
    numpy_substeps,
    numpy_ukf_loglik,
    polynomial_gradient,
)


def best_time(fn, *args, number: int, repeats: int = 7) -> float:
    """Smallest mean wall time per call over ``repeats`` batches of ``number`` calls (seconds)."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            out = fn(*args)
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - start) / number)
    return best


def main() -> None:
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    theta = model.pack(system.coefficients, 1e-6, 0.05**2)
    loglik = model.log_likelihood_fn(data, x0)

    single = jax.jit(loglik)
    batched = jax.jit(jax.vmap(loglik))
    noise = 1.0 + 1e-3 * jax.random.normal(jax.random.key(0), (64, theta.shape[0]))
    thetas64 = jnp.asarray(theta) * noise
    thetas8 = thetas64[:8]

    num_loop = 200

    @jax.jit
    def in_loop(thetas):
        def body(total, th):
            return total + loglik(th), None

        return jax.lax.scan(body, 0.0, thetas)[0]

    thetas_loop = jnp.asarray(theta) * (
        1.0 + 1e-3 * jax.random.normal(jax.random.key(1), (num_loop, theta.shape[0]))
    )

    # The NumPy baseline: same filter, same settings, plain vectorised NumPy.
    grad = polynomial_gradient(system.potential.exponents, system.coefficients)
    leapfrog = numpy_leapfrog(grad)
    num_steps, step_sizes = numpy_substeps(data.times, 0.25)

    def numpy_loglik():
        return numpy_ukf_loglik(
            leapfrog,
            x0,
            1e-16 * np.eye(4),
            num_steps,
            step_sizes,
            data.values,
            1e-6 * np.eye(4),
            0.05**2 * np.eye(4),
            jitter=1e-12,
        )

    ref = numpy_loglik()
    got = float(single(theta))
    if not np.isclose(ref, got, rtol=1e-8):
        raise SystemExit(f"JAX and NumPy disagree: {got} vs {ref}")

    t_numpy = best_time(numpy_loglik, number=5, repeats=5)
    rows = [
        ("jax single (from Python)", best_time(single, theta, number=200)),
        ("jax in a compiled loop", best_time(in_loop, thetas_loop, number=5) / num_loop),
        ("jax vmap 8, per θ", best_time(batched, thetas8, number=50) / 8),
        ("jax vmap 64, per θ", best_time(batched, thetas64, number=10) / 64),
        ("numpy (baseline)", t_numpy),
    ]
    print(f"log-likelihood = {got:.10f} (NumPy {ref:.10f})")
    print("| implementation | µs / eval | × numpy |")
    print("|---|---:|---:|")
    for name, seconds in rows:
        print(f"| {name} | {seconds * 1e6:.1f} | {t_numpy / seconds:.0f} |")
    print("(tiers as same-run ratios: benchmarks/speed_tiers.py)")


if __name__ == "__main__":
    main()
