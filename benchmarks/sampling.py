"""DRAM iterations per second and ESS per second of DRAM against NUTS, on the paper's posterior.

Workload (seed paper, Section IV): Hénon–Heiles, cubic potential (9 coefficients) plus the
process and observation variances (11 parameters), leapfrog at dt = 0.25, 20 full-state
observations 5 s apart (data seed 0), Laplace(0, 10) and half-normal(1) priors, known
initial state. The MAP and its covariance come from ``symplid.find_map``.

Tables:

1. **DRAM throughput**: iterations per second per chain for one chain and for four chains
   (vectorised with ``vmap``, and sequential with ``lax.map``), compilation excluded, beside
   the rate of bare log-density evaluations in a compiled loop. One DRAM iteration costs one
   evaluation plus one more whenever stage 1 rejects (with ``vmap`` both stages always run,
   the batch being evaluated in lockstep).
2. **ESS per second**: DRAM and NUTS through ``symplid.sample`` with four chains, in the same
   run; the minimum bulk ESS over the parameters divided by the wall time of the whole call
   (burn-in or warm-up and compilation included: what a user waits for).

Everything runs on one CPU thread, as in ``benchmarks/likelihood.py``.
Run: ``python benchmarks/sampling.py`` (``--quick`` for a shorter run).
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {0})  # pinned to one core: the machine may be shared

from symplid import runtime  # noqa: E402  (sets the small-loop flag before JAX starts)

runtime.limit_threads()  # one XLA thread, merged so that no flag is lost behind a bare token

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from typing import Any  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import symplid  # noqa: E402
from symplid.inference._diagnostics import import_arviz  # noqa: E402
from symplid.inference.samplers import dram  # noqa: E402
from symplid.sampling import RunOptions, run_chains, sample  # noqa: E402

TARGET_ITERATIONS_PER_SECOND = 50_000  # issue #10


# ------------------------------------------------------------------------------ the posterior


def build_posterior() -> tuple[Any, Any, str]:
    """The paper's leapfrog posterior and its MAP; falls back to an inline posterior (the
    model's log-likelihood plus the paper's priors) if ``symplid.model._posterior`` is absent."""
    system = symplid.get_system("henon-heiles")
    data = symplid.simulate(system, seed=0)
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    try:
        from symplid.model._posterior import Posterior
    except ImportError:
        posterior, source = _InlinePosterior(model, data, system.initial_state), "inline"
    else:
        posterior, source = Posterior(model, data, x0=system.initial_state), "symplid.Posterior"
    try:
        from symplid.inference.map import find_map
    except ImportError:
        start = model.pack(system.coefficients, 1e-4, 0.05**2)
        return posterior, _inline_map(posterior, start), source + " + inline MAP"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the process variance's MAP sits on its bound
        return posterior, find_map(posterior, seed=0), source + " + find_map"


class _InlinePosterior:
    """log π(θ) = log-likelihood + Σ Laplace(0, 10) over coefficients + Σ half-normal(1)
    over variances; log transform of the variances for NUTS."""

    def __init__(self, model, data, x0) -> None:
        self.num_params = model.num_params
        self.param_names = model.param_names
        self._loglik = model.log_likelihood_fn(data, x0)
        is_var = np.zeros(self.num_params, dtype=bool)
        is_var[model.variance_slice] = True
        self._is_var = is_var
        self.lower = np.where(is_var, 0.0, -np.inf)
        self.upper = np.full(self.num_params, np.inf)

    def log_density(self, theta):
        laplace = -jnp.abs(theta) / 10.0 - np.log(20.0)
        half_normal = -0.5 * theta**2 + 0.5 * np.log(2.0 / np.pi)
        prior = jnp.sum(jnp.where(self._is_var, half_normal, laplace))
        inside = jnp.all(jnp.where(self._is_var, theta > 0, True))
        safe = jnp.where(inside, theta, jnp.where(self._is_var, 1.0, theta))
        total = jnp.where(inside, prior + self._loglik(safe), -jnp.inf)
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    def to_unconstrained(self, theta):
        return jnp.where(self._is_var, jnp.log(jnp.where(self._is_var, theta, 1.0)), theta)

    def from_unconstrained(self, z):
        return jnp.where(self._is_var, jnp.exp(z), z)

    def log_density_unconstrained(self, z):
        return self.log_density(self.from_unconstrained(z)) + jnp.sum(
            jnp.where(self._is_var, z, 0.0))


class _InlineMap:
    def __init__(self, theta, hessian, log_posterior) -> None:
        self.theta, self.hessian, self.log_posterior = theta, hessian, log_posterior
        values, vectors = np.linalg.eigh(hessian)
        values = np.maximum(values, 1e-8 * values.max())  # repair to positive definite
        self.covariance = (vectors / values) @ vectors.T


def _inline_map(posterior, start) -> _InlineMap:
    from scipy.optimize import minimize

    value_and_grad = jax.jit(jax.value_and_grad(lambda t: -posterior.log_density(t)))

    def fun(theta):
        value, grad = value_and_grad(jnp.asarray(theta))
        return float(value), np.asarray(grad)

    bounds = [(lo if np.isfinite(lo) else None, None) for lo in posterior.lower]
    bounds = [(1e-14, None) if lo == 0.0 else b for lo, b in zip(posterior.lower, bounds,
                                                               strict=True)]
    result = minimize(fun, start, jac=True, method="L-BFGS-B", bounds=bounds)
    hessian = np.asarray(jax.hessian(lambda t: -posterior.log_density(t))(result.x))
    return _InlineMap(result.x, 0.5 * (hessian + hessian.T), -result.fun)


# --------------------------------------------------------------------------- measurements


def log_density_rate(posterior, theta, number: int = 500) -> float:
    """Log-density evaluations per CPU second inside one compiled loop."""
    fn = posterior.log_density

    @jax.jit
    def loop(theta):
        return jax.lax.fori_loop(0, number, lambda i, acc: acc + fn(theta + 1e-15 * i), 0.0)

    jax.block_until_ready(loop(theta))
    best = float("inf")
    for _ in range(3):
        start = time.process_time()
        jax.block_until_ready(loop(theta))
        best = min(best, time.process_time() - start)
    return number / best


def dram_throughput(posterior, map_result, num_chains: int, chain_method: str,
                    iterations: int, chunk: int) -> dict[str, float]:
    """DRAM iterations per second per chain (compilation excluded) and stage-2 share."""
    cov = jnp.asarray(map_result.covariance)
    step = dram.build_kernel(posterior.log_density)
    states = jax.jit(jax.vmap(lambda p: dram.init(p, posterior.log_density, cov)))(
        jnp.tile(jnp.asarray(map_result.theta), (num_chains, 1)))

    def record(state, info):
        return {"stage2": info.stage2_attempted}

    common = dict(record=record, options=RunOptions(chunk_size=chunk, chain_method=chain_method,
                                                    progress=False))
    warm = run_chains(step, states, jax.random.key(0), chunk, **common)  # compiles
    cpu = time.process_time()
    run = run_chains(step, warm.states, jax.random.key(1), iterations, **common)
    cpu = time.process_time() - cpu
    return {"it_per_s": iterations / run.elapsed, "it_per_cpu_s": iterations / cpu,
            "stage2_share": float(run.draws["stage2"].mean()),
            "compile_s": warm.elapsed}


def ess_rate(posterior, map_result, method: str, num_samples: int, burn_in: int,
             chunk: int, chain_method: str | None = None) -> dict[str, Any]:
    """Minimum bulk ESS per second of one ``symplid.sample`` call with four chains."""
    az = import_arviz()
    started, cpu = time.perf_counter(), time.process_time()
    idata = sample(posterior, method, num_draws=num_samples, num_chains=4, seed=0,
                   init=map_result, burn_in=burn_in,
                   options=RunOptions(chunk_size=chunk, chain_method=chain_method, progress=False))
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    table = az.summary(idata, kind="diagnostics", round_to="none")
    stats = idata.sample_stats
    extra = (f"stage-1 acc {float(stats['stage1_accepted'].mean()):.2f}, "
             f"overall {float(stats['accepted'].mean()):.2f}" if method == "dram" else
             f"divergences {int(stats['diverging'].sum())}, "
             f"mean steps {float(stats['n_steps'].mean()):.0f}")
    min_ess = float(table["ess_bulk"].min())
    return {"method": method, "draws": f"4 x {num_samples} (+{burn_in})", "wall_s": wall,
            "cpu_s": cpu, "min_ess_bulk": min_ess, "ess_per_s": min_ess / wall,
            "ess_per_cpu_s": min_ess / cpu,
            "max_rhat": float(table["r_hat"].max()), "worst": str(table["ess_bulk"].idxmin()),
            "notes": extra}


# ---------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs")
    parser.add_argument("--dram-iterations", type=int, default=10_000,
                        help="timed DRAM iterations per chain for the throughput table")
    parser.add_argument("--dram-samples", type=int, default=20_000)
    parser.add_argument("--dram-burn-in", type=int, default=None,
                        help="default: as many as --dram-samples (the paper's half)")
    parser.add_argument("--nuts-samples", type=int, default=200)
    parser.add_argument("--nuts-warmup", type=int, default=200)
    parser.add_argument("--nuts-chain-method", choices=("vectorized", "sequential"),
                        default=None, help="default: the library's (sequential)")
    parser.add_argument("--only", choices=("throughput", "ess"), default=None,
                        help="run one of the two tables")
    parser.add_argument("--json", type=str, default=None, help="also write results here")
    args = parser.parse_args(argv)
    if args.quick:
        args.dram_iterations //= 4
        args.dram_samples //= 4
        args.nuts_samples //= 2
        args.nuts_warmup //= 2

    posterior, map_result, source = build_posterior()
    theta = jnp.asarray(map_result.theta)
    print(f"posterior: {source}; {posterior.num_params} parameters; JAX {jax.__version__}, "
          f"backend {jax.default_backend()}, one thread")

    evals = log_density_rate(posterior, theta)
    print(f"\nlog density in a compiled loop: {evals:,.0f} evaluations per CPU second "
          f"({1e6 / evals:.0f} µs each)\n")

    results: dict[str, Any] = {"posterior": source, "log_density_per_cpu_s": evals}
    if args.only != "ess":
        results["dram_throughput"] = _throughput_table(posterior, map_result, evals, args)
    if args.only != "throughput":
        results["ess"] = _ess_table(posterior, map_result, args)
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(results, handle, indent=2)
    return results


def _throughput_table(posterior, map_result, evals: float, args) -> list[dict[str, Any]]:
    rows = []
    chunk = 1000
    for num_chains, chain_method in ((1, "vectorized"), (4, "vectorized"), (4, "sequential")):
        result = dram_throughput(posterior, map_result, num_chains, chain_method,
                                 args.dram_iterations, chunk)
        rows.append({"chains": num_chains, "layout": chain_method, **result})
    print("DRAM throughput (compilation excluded; per wall second and per CPU second, the "
          "latter robust to other load on the machine)")
    print(f"{'chains':>6}  {'layout':<10}  {'it/s per chain':>14}  {'per CPU s':>9}  "
          f"{'total per CPU s':>15}  {'stage-2 share':>13}  {'compile s':>9}")
    for row in rows:
        print(f"{row['chains']:>6}  {row['layout']:<10}  {row['it_per_s']:>14,.0f}  "
              f"{row['it_per_cpu_s']:>9,.0f}  {row['it_per_cpu_s'] * row['chains']:>15,.0f}  "
              f"{row['stage2_share']:>13.2f}  {row['compile_s']:>9.1f}")
    single = rows[0]["it_per_cpu_s"]
    print(f"target {TARGET_ITERATIONS_PER_SECOND:,} it/s per chain: "
          f"{'met' if single >= TARGET_ITERATIONS_PER_SECOND else 'not met'} "
          f"({single / TARGET_ITERATIONS_PER_SECOND:.0%} of it); bound from the log density "
          f"alone: {evals / (1 + rows[0]['stage2_share']):,.0f} it/s\n")
    return rows


def _ess_table(posterior, map_result, args) -> list[dict[str, Any]]:
    dram_burn_in = args.dram_samples if args.dram_burn_in is None else args.dram_burn_in
    ess_rows = [
        ess_rate(posterior, map_result, "dram", args.dram_samples, dram_burn_in, 5000),
        ess_rate(posterior, map_result, "nuts", args.nuts_samples, args.nuts_warmup, 100,
                 args.nuts_chain_method),
    ]
    print("ESS per second, 4 chains (wall time of one sample() call, compilation included)")
    print(f"{'method':<6}  {'draws':<18}  {'wall s':>7}  {'CPU s':>7}  {'min bulk ESS':>12}  "
          f"{'ESS/s':>7}  {'ESS/CPU s':>9}  {'max R-hat':>9}  notes")
    for row in ess_rows:
        print(f"{row['method']:<6}  {row['draws']:<18}  {row['wall_s']:>7.1f}  "
              f"{row['cpu_s']:>7.1f}  {row['min_ess_bulk']:>12.0f}  {row['ess_per_s']:>7.2f}  "
              f"{row['ess_per_cpu_s']:>9.2f}  {row['max_rhat']:>9.3f}  "
              f"{row['notes']} (min ESS: {row['worst']})")
    winner = max(ess_rows, key=lambda row: row["ess_per_s"])
    loser = min(ess_rows, key=lambda row: row["ess_per_s"])
    print(f"winner in ESS/s: {winner['method'].upper()} "
          f"({winner['ess_per_s'] / max(loser['ess_per_s'], 1e-300):.1f}x)")
    return ess_rows


if __name__ == "__main__":
    main()
