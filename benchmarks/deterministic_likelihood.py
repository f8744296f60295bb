"""Time the deterministic-trajectory likelihood against the UKF likelihood, same run.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential (9 coefficients), leapfrog at
dt = 0.25, 20 full-state observations 5 s apart: 20 gaps × 20 substeps. The UKF pushes
2n + 1 = 9 sigma points through every substep and adds Σ; the deterministic likelihood
(``process_noise_per="none"``, :mod:`symplid.model._deterministic`) pushes one path and sums
Gaussian log densities.

Rows: each likelihood's value, and its value with the gradient (``jax.value_and_grad``, what
MAP, the Laplace Hessian and NUTS need), one jitted call from Python; the UKF both as the JAX
reference (``backend="jax"``) and as the compiled kernel where it is available (the default
``backend="auto"``). Each time is the smallest mean over 30 batches of 50 calls (the least
disturbed by other processes on a shared machine).

Everything runs on one CPU thread, pinned to CPU 0, with the XLA flags of ``import symplid``.
Run: ``taskset -c 0 python benchmarks/deterministic_likelihood.py``.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {0})  # pinned to one core: the machine may be shared

from symplid import runtime  # noqa: E402  (sets the small-loop flag before JAX starts)

runtime.limit_threads()  # one XLA thread


import jax  # noqa: E402
import numpy as np  # noqa: E402

import symplid  # noqa: E402
from likelihood import best_time  # noqa: E402  (the same timing as the filter's benchmark)


def _timings(model, theta, data, x0, number: int) -> tuple[float, float, float]:
    """(log-likelihood, µs per value, µs per value and gradient) of ``model`` at ``theta``."""
    loglik = model.log_likelihood_fn(data, x0)
    value = jax.jit(loglik)
    value_grad = jax.jit(jax.value_and_grad(loglik))
    ll = float(value(theta))
    return (ll, 1e6 * best_time(value, theta, number=number, repeats=30),
            1e6 * best_time(value_grad, theta, number=number, repeats=30))


def main() -> None:
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    x0 = system.initial_state
    # away from the truth, as inside a MAP search or a chain
    coefficients = system.coefficients + 0.01 * np.sin(np.arange(1, 10))
    rows = []
    for label, per, backend in (
        ("deterministic (process_noise_per = none)", "none", "auto"),
        ("UKF, JAX reference (backend = jax)", "gap", "jax"),
        ("UKF, default backend (auto)", "gap", "auto"),
    ):
        model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25,
                                         process_noise_per=per, backend=backend)
        theta = (model.pack(coefficients, (), 0.05**2) if per == "none"
                 else model.pack(coefficients, 1e-6, 0.05**2))
        name = f"{label} [{model.likelihood_backend}]"
        rows.append((name, *_timings(model, theta, data, x0, number=50)))
    det_value, det_grad = rows[0][2], rows[0][3]
    print("Hénon–Heiles, cubic U, leapfrog dt 0.25, 20 observations × 20 substeps, one thread")
    print("| likelihood [backend] | log L | value µs | × det. | value+grad µs | × det. |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, ll, value, grad in rows:
        print(f"| {name} | {ll:.4f} | {value:.1f} | {value / det_value:.1f} | {grad:.1f} | "
              f"{grad / det_grad:.1f} |")


if __name__ == "__main__":
    main()
