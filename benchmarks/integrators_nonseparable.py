"""Per-step cost of the non-separable propagators against leapfrog, on one core.

Tao's explicit methods (``tao``, ``tao4``), the Newton-solved implicit midpoint rule
(``implicit-midpoint``) and the two-stage Gauss–Legendre method (``gauss4``) accept any
H(q, p); leapfrog needs H = ½pᵀM⁻¹p + U(q). This script
times one step of each, in the shape the likelihood uses them (the 2n+1 = 9 sigma points of a
2-degree-of-freedom system pushed through together, coordinates first), on

* **Hénon–Heiles** (separable, the paper's cubic U): leapfrog on its potential; the others on
  the same system written as a whole H (``SeparableHamiltonian``);
* **the double pendulum** (non-separable, ``DoublePendulum``): the four non-separable
  methods and RK4 (leapfrog cannot run it).

Each timing is the minimum over ``--repeats`` runs of a jitted loop of ``--steps`` steps,
divided by the steps; ratios are to leapfrog on Hénon–Heiles in the same run. It also reports
the largest error over one 0.25 s gap (the double pendulum's observation spacing) at step 0.05
against a fine RK4 solution, from 40 states along the system's trajectory.

Run: ``taskset -c 0 python benchmarks/integrators_nonseparable.py`` (about a minute, most of
it compiling).
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {0})  # pinned to one core: the machine may be shared

from symplid import runtime  # noqa: E402  (sets the small-loop flag before JAX starts)

runtime.limit_threads()

import argparse  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import symplid  # noqa: E402
from symplid.dynamics._hamiltonians import SeparableHamiltonian  # noqa: E402
from symplid.dynamics._integrators import get_integrator, make_dynamics  # noqa: E402
from symplid.dynamics._trajectory import propagate  # noqa: E402

METHODS = ("leapfrog", "tao", "tao4", "implicit-midpoint", "gauss4", "rk4")


def step_seconds(ham: Any, params: Any, name: str, steps: int, repeats: int) -> float:
    """Seconds per step for 9 sigma points (minimum over repeats), compilation excluded."""
    integ = get_integrator(name)
    points = jnp.asarray(np.random.default_rng(0).normal(0.0, 0.1, size=(4, 9)))

    @jax.jit
    def run(x):
        q, p = propagate(integ, make_dynamics(ham, params), x[:2], x[2:], 0.01, steps, steps,
                         masked=False)
        return jnp.concatenate([q, p])

    jax.block_until_ready(run(points))
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run(points))
        best = min(best, time.perf_counter() - start)
    return best / steps


def gap_error(system: Any, name: str, step: float = 0.05) -> float:
    """Largest state error over one 0.25 s gap at ``step``, from 40 states of the truth."""
    ham, params = system.potential, jnp.asarray(system.coefficients)
    times = 0.25 * np.arange(1, 41)
    truth = symplid.true_trajectory(ham, params, system.initial_state, times, 1e-3, "rk4")
    starts = np.vstack([system.initial_state, truth[:-1]]).T
    n = round(0.25 / step)
    q, p = jax.jit(lambda x: propagate(get_integrator(name), make_dynamics(ham, params), x[:2],
                                       x[2:], step, n, n, masked=False))(jnp.asarray(starts))
    return float(np.max(np.abs(np.concatenate([q, p]).T - truth)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    hh = symplid.get_system("henon-heiles")
    pendulum = symplid.get_system("double-pendulum")
    rows = []
    base = step_seconds(hh.potential, jnp.asarray(hh.coefficients), "leapfrog", args.steps,
                        args.repeats)
    for name in METHODS:
        sep = base if name == "leapfrog" else step_seconds(
            SeparableHamiltonian(hh.potential), jnp.asarray(hh.coefficients), name,
            args.steps, args.repeats)
        if name == "leapfrog":
            dp, err = float("nan"), float("nan")
        else:
            dp = step_seconds(pendulum.potential, jnp.asarray(pendulum.coefficients), name,
                              args.steps, args.repeats)
            err = gap_error(pendulum, name)
        rows.append((name, sep, dp, err))
    print(f"one core, 9 sigma points, min of {args.repeats} runs of {args.steps} steps; "
          f"ratios to leapfrog on Hénon–Heiles ({base * 1e6:.2f} µs/step)")
    print("| method | Hénon–Heiles µs/step | ratio | double pendulum µs/step | ratio | "
          "gap error (δ = 0.05) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, sep, dp, err in rows:
        dp_text = "—" if np.isnan(dp) else f"{dp * 1e6:.2f} | {dp / base:.1f}"
        err_text = "—" if np.isnan(err) else f"{err:.1e}"
        if np.isnan(dp):
            dp_text = "— | —"
        print(f"| {name} | {sep * 1e6:.2f} | {sep / base:.1f} | {dp_text} | {err_text} |")


if __name__ == "__main__":
    main()
