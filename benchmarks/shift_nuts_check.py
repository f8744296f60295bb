"""Is the DRAM interval below its own MAP the posterior's shape, or a DRAM bias? NUTS and IS.

Setting: the paper-claims study's ``no-process-noise`` variant with yoshida4 (deterministic-
trajectory likelihood, Hénon–Heiles at the paper's setting: 20 observations 5 s apart, noise
sd 0.05, dt = 0.25), seeds 1, 3, 7 and 8 by default: the same data and settings as the
study's cells (rebuilt from each cell's JSON in ``--cells``, so nothing is re-simulated
differently). For each seed:

* the MAP, by the fit's own path (:func:`symplid.workflow._fit.find_map_for`);
* NUTS (BlackJAX, Stan's window adaptation) from the MAP, ``--chains`` chains of ``--warmup``
  warm-up and ``--draws`` kept iterations, started within ``--init-spread`` (0.5) Laplace sds
  of the MAP (the deterministic likelihood of this chaotic record has secondary modes, into
  which a chain started 2 sds away can fall); bulk and tail ESS and split-R-hat per parameter;
* DRAM's 95 % interval from the cell (the study's 4 × 200,000 iterations, 100,000 burn-in).

Per coefficient it prints the MAP, DRAM's interval midpoint, NUTS's median and 95 % interval,
all as offsets from the truth in units of NUTS's posterior sd, and the distance of each
centre from the MAP. The same in ×1e-3 of the coefficient goes to the CSV.

With ``--is-seed``, an independent check on that seed: self-normalised importance sampling
from the Laplace approximation, in the unconstrained space of the posterior (Jacobian in
the target), with a multivariate t proposal (``--is-df`` degrees of freedom, the Laplace
covariance pushed to that space, ``--is-draws`` draws); Pareto-smoothed weights (PSIS,
Vehtari et al. 2024) with their k̂, the effective sample size 1/Σw², and the weighted median and
95 % interval of each coefficient. k̂ < 0.7 means the estimates are reliable.

Run (the MAP about 40 s of CPU per seed; NUTS about 17 ms of CPU per iteration and chain)::

    nice python benchmarks/shift_nuts_check.py --cells docs/studies/paper-claims/cells \\
        --seeds 1 3 7 8 --is-seed 7 --is-inflation 1 2 --out shift-nuts.csv

The table of ``docs/studies/paper-claims.md`` (section "NUTS and importance sampling on the
same seeds") was measured with smaller budgets, given there with their commands.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from symplid import runtime

runtime.limit_threads()

import arviz as az  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from symplid.model._params import ParameterSpace  # noqa: E402
from symplid.sampling import RunOptions, draws_array, sample  # noqa: E402
from symplid.studies._paper import EXPERIMENT, cell_data, cell_data_noise  # noqa: E402
from symplid.studies._paper_calibration import true_values  # noqa: E402
from symplid.workflow._building import build_model, build_posterior  # noqa: E402
from symplid.workflow._fit import find_map_for  # noqa: E402
from symplid.workflow._sweep import cell_settings  # noqa: E402

VARIANT = {"model.process_noise_per": "none", "integrator": "yoshida4"}


def find_cell(folder: Path, seed: int) -> dict:
    """The study's cell of the no-process-noise yoshida4 variant for ``seed``."""
    for path in sorted(folder.glob("*.json")):
        cell = json.loads(path.read_text())
        s = cell["settings"]
        if s["seed"] == seed and all(s.get(k) == v for k, v in VARIANT.items()):
            return cell
    raise SystemExit(f"no no-process-noise yoshida4 cell for seed {seed} in {folder}")


def fit_seed(cell: dict, args: argparse.Namespace):
    """MAP and NUTS draws of one cell's data (same settings as the cell); no draws (None)
    with ``--is-only``."""
    settings = cell_settings(cell["settings"], experiment=EXPERIMENT)
    system, obs = cell_data(cell["settings"])
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        map_result = find_map_for(settings, posterior)
    t_map = time.perf_counter() - t0
    if map_result.failure:
        raise SystemExit(f"seed {cell['settings']['seed']}: the MAP failed: {map_result.failure}")
    t0 = time.perf_counter()
    if args.is_only:
        return posterior, map_result, None, *_truth(system, model, cell), (t_map, 0.0)
    idata = sample(posterior, method="nuts", num_draws=args.draws, num_chains=args.chains,
                   seed=args.nuts_seed, init=map_result, burn_in=args.warmup,
                   options=RunOptions(progress=False, init_spread=args.init_spread))
    t_nuts = time.perf_counter() - t0
    return posterior, map_result, idata, *_truth(system, model, cell), (t_map, t_nuts)


def _truth(system, model, cell: dict) -> tuple[dict]:
    return (true_values(system, model, float(cell_data_noise(cell["settings"], system))),)


def seed_rows(seed: int, cell: dict, names: tuple[str, ...], map_theta: np.ndarray,
              draws: np.ndarray, idata, truth: dict) -> list[dict]:
    """One row per coefficient: MAP, DRAM midpoint, NUTS median and interval, in sds."""
    ess_bulk = az.ess(idata, method="bulk")
    ess_tail = az.ess(idata, method="tail")
    rhat = az.rhat(idata)
    flat = draws.reshape(-1, draws.shape[-1])
    rows = []
    for j, name in enumerate(names):
        if not name.startswith("c["):
            continue
        cal = cell["metrics"]["calibration"][name]
        x = flat[:, j]
        sd = float(np.std(x, ddof=1))
        q025, q50, q975 = (float(v) for v in np.quantile(x, [0.025, 0.5, 0.975]))
        true = float(truth[name])
        mid_dram = 0.5 * (cal["q025"] + cal["q975"])
        rows.append({
            "seed": seed, "name": name, "truth": true, "map": float(map_theta[j]),
            "dram_q025": cal["q025"], "dram_q975": cal["q975"], "dram_mid": mid_dram,
            "nuts_q025": q025, "nuts_median": q50, "nuts_q975": q975,
            "nuts_mid": 0.5 * (q025 + q975), "nuts_mean": float(np.mean(x)), "nuts_sd": sd,
            "dram_width": cal["q975"] - cal["q025"], "nuts_width": q975 - q025,
            "ess_bulk": float(ess_bulk[name].values), "ess_tail": float(ess_tail[name].values),
            "rhat": float(rhat[name].values),
        })
    return rows


def importance_check(posterior, map_result, names: tuple[str, ...], truth: dict,
                     args: argparse.Namespace, inflation: float = 1.0) -> list[dict]:
    """Self-normalised IS from a t proposal around the Laplace approximation (PSIS), its
    scale the Laplace sds times ``inflation``."""
    space = ParameterSpace.of(posterior)
    theta_map = np.asarray(map_result.theta, dtype=float)
    cov = space.pushforward_covariance(theta_map, np.asarray(map_result.covariance))
    cov = inflation**2 * cov
    z_map = np.asarray(space.to_unconstrained(jnp.asarray(theta_map)))
    chol = np.linalg.cholesky(0.5 * (cov + cov.T))
    rng = np.random.default_rng(args.is_seed_rng)
    d, n, nu = z_map.size, args.is_draws, float(args.is_df)
    normal = rng.standard_normal((n, d))
    scale = np.sqrt(nu / rng.chisquare(nu, size=n))
    z = z_map + scale[:, None] * (normal @ chol.T)
    # log t density (up to a constant shared by all draws)
    maha = np.sum(np.linalg.solve(chol, (z - z_map).T) ** 2, axis=0)
    log_q = -0.5 * (nu + d) * np.log1p(maha / nu)
    log_p_fn = jax.jit(jax.vmap(posterior.log_density_unconstrained))
    log_p = np.concatenate([np.asarray(log_p_fn(jnp.asarray(z[i:i + 2000])))
                            for i in range(0, n, 2000)])
    log_w = np.where(np.isfinite(log_p), log_p - log_q, -np.inf)
    smoothed, k_hat = az.psislw(log_w - np.max(log_w))
    w = np.exp(smoothed - np.max(smoothed))
    w /= w.sum()
    ess = 1.0 / float(np.sum(w * w))
    theta = np.asarray(jax.vmap(posterior.from_unconstrained)(jnp.asarray(z)))
    rows = []
    for j, name in enumerate(names):
        if not name.startswith("c["):
            continue
        order = np.argsort(theta[:, j])
        cdf = np.cumsum(w[order])
        q = [float(theta[order, j][np.searchsorted(cdf, p)]) for p in (0.025, 0.5, 0.975)]
        mean = float(np.sum(w * theta[:, j]))
        sd = math.sqrt(float(np.sum(w * (theta[:, j] - mean) ** 2)))
        rows.append({"inflation": inflation, "name": name, "truth": float(truth[name]),
                     "map": float(theta_map[j]),
                     "is_q025": q[0], "is_median": q[1], "is_q975": q[2], "is_sd": sd,
                     "k_hat": float(k_hat), "ess": ess, "draws": n,
                     "finite": int(np.isfinite(log_p).sum())})
    return rows


def print_table(rows: list[dict]) -> None:
    """Per coefficient and seed: centres from the truth in NUTS sds, and from the MAP."""
    print(f"{'seed':>4} {'coefficient':<12} {'MAP':>6} {'DRAM mid':>8} {'NUTS med':>8} "
          f"{'NUTS mid':>8} | {'DRAM−MAP':>8} {'NUTS med−MAP':>12} {'NUTS mid−MAP':>12} | "
          f"{'sd':>8} {'ESS bulk':>8} {'R-hat':>6} {'width DRAM/NUTS':>15}")
    for r in rows:
        sd = r["nuts_sd"]
        print(f"{r['seed']:>4} {r['name']:<12} {(r['map'] - r['truth']) / sd:>6.2f} "
              f"{(r['dram_mid'] - r['truth']) / sd:>8.2f} "
              f"{(r['nuts_median'] - r['truth']) / sd:>8.2f} "
              f"{(r['nuts_mid'] - r['truth']) / sd:>8.2f} | "
              f"{(r['dram_mid'] - r['map']) / sd:>8.2f} "
              f"{(r['nuts_median'] - r['map']) / sd:>12.2f} "
              f"{(r['nuts_mid'] - r['map']) / sd:>12.2f} | {sd:>8.4f} {r['ess_bulk']:>8.0f} "
              f"{r['rhat']:>6.3f} {r['dram_width'] / r['nuts_width']:>15.3f}")


def write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--cells", type=Path, default=Path("docs/studies/paper-claims/cells"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 3, 7, 8])
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=1500)
    parser.add_argument("--nuts-seed", type=int, default=0)
    parser.add_argument("--init-spread", type=float, default=0.5,
                        help="chains start this many Laplace sds from the MAP")
    parser.add_argument("--is-seed", type=int, default=None,
                        help="data seed of the importance-sampling check (none: skipped)")
    parser.add_argument("--is-draws", type=int, default=100_000)
    parser.add_argument("--is-df", type=float, default=5.0)
    parser.add_argument("--is-inflation", type=float, nargs="+", default=[1.0],
                        help="proposal scales, as multiples of the Laplace sds")
    parser.add_argument("--is-seed-rng", type=int, default=0)
    parser.add_argument("--is-only", action="store_true",
                        help="the MAP and the importance-sampling check only, no NUTS")
    parser.add_argument("--out", type=Path, default=Path("shift-nuts.csv"))
    args = parser.parse_args(argv)
    rows: list[dict] = []
    is_rows: list[dict] = []
    for seed in args.seeds:
        cell = find_cell(args.cells, seed)
        posterior, map_result, idata, truth, (t_map, t_nuts) = fit_seed(cell, args)
        names = tuple(str(n) for n in posterior.param_names)
        print(f"seed {seed}: MAP {t_map:.0f} s, NUTS {t_nuts:.0f} s", flush=True)
        if idata is not None:
            draws = draws_array(idata)
            rows += seed_rows(seed, cell, names, np.asarray(map_result.theta), draws, idata,
                              truth)
            write_csv(args.out, rows)
        if seed == args.is_seed:
            for inflation in args.is_inflation:
                is_rows += importance_check(posterior, map_result, names, truth, args,
                                            inflation)
                write_csv(args.out.with_name(args.out.stem + "-is.csv"), is_rows)
    if rows:
        print_table(rows)
    for r in is_rows:
        gap = 1e3 * (r["is_median"] - r["map"])
        print(f"IS seed {args.is_seed} ×{r['inflation']:g} {r['name']:<12} median−MAP {gap:+.1f}e-3"
              f" median−truth {1e3 * (r['is_median'] - r['truth']):+.1f}e-3 "
              f"[{r['is_q025']:.4f}, {r['is_q975']:.4f}] k̂ {r['k_hat']:.2f} ESS {r['ess']:.0f}"
              f" of {r['draws']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
