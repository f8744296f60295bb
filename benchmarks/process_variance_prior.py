"""Coverage of the MAP + Laplace 95 % intervals under two priors of the process variance Σ.

Setting (seed paper, Section IV): Hénon–Heiles, 20 full-state observations 5 s apart with
N(0, 0.05²) noise and **no process noise** in the data, the cubic potential learned with
leapfrog at dt = 0.25 (or ``--integrator``/``--dt``), the known initial state, isotropic
observation noise. For each fresh data seed (``--first-seed`` on, never the study's 20) the
MAP and its Laplace covariance are found, then DRAM is run from it (2 chains, ``--iterations``
per chain, half burn-in; the variances moved as log v, the library's default), twice, with the
same data:

* ``half-normal``: Σ ~ HalfNormal(1), the paper's prior (and ``symplid reproduce``'s);
* ``log-uniform``: Σ ~ LogUniform(b·1e-8, b), b the data's variance scale
  (:func:`symplid.model._variance_prior.data_variance_scale`).

Each coefficient's Laplace interval MAP ± 1.96·sd and DRAM's central 95 % interval cover the
truth or not; the table gives the coverage over the seeds with its Wilson 95 % interval, the
mean of z = (MAP − truth)/sd and of (posterior mean − truth)/posterior sd (a shift shows as a
mean far from 0). Seeds whose MAP failed or whose split-R-hat exceeds 1.1 are reported
apart. Results go to a CSV (one row per seed, prior and coefficient), rewritten after every
seed, so the table can be rebuilt without refitting (``--table-only``).

Run: ``nice python benchmarks/process_variance_prior.py --seeds 40 --out bench-sigma.csv``
(about 35 s of CPU per seed, both priors; 5–17 minutes of wall time on a machine
shared at load 15–20).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from symplid import runtime

runtime.limit_threads()

from symplid.dynamics._systems import get_system  # noqa: E402
from symplid.inference.map import find_map  # noqa: E402
from symplid.model._priors import LogUniform  # noqa: E402
from symplid.model._simulate import simulate  # noqa: E402
from symplid.model._variance_prior import data_variance_scale  # noqa: E402
from symplid.sampling import RunOptions, draws_array, sample  # noqa: E402
from symplid.workflow._fit import build_model, build_posterior  # noqa: E402
from symplid.workflow._settings import Settings, merge_overrides  # noqa: E402

Z95 = 1.959963984540054


def wilson(hits: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (Wilson 1927)."""
    if n == 0:
        return (math.nan, math.nan)
    p = hits / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (centre - half, centre + half)


def settings_for(integrator: str, dt: float) -> Settings:
    system = get_system("henon-heiles")
    return merge_overrides(Settings(), {
        "model.order": 3, "model.integrator": integrator, "model.dt": dt,
        "model.noise": "isotropic", "model.standardise": "off",
        "initial_state.x0": [float(v) for v in system.initial_state],
        "map.num_starts": 2, "map.evidence": "laplace",
    })


def _interval_rows(label, names, truth, result, draws, rhat, sigma_median) -> list[dict]:
    sd = np.sqrt(np.clip(np.diag(result.covariance), 0.0, None))
    rows = []
    for i, name in enumerate(names[: len(truth)]):
        z = (result.theta[i] - truth[i]) / sd[i] if sd[i] > 0 else math.nan
        lo, hi = np.quantile(draws[..., i].ravel(), [0.025, 0.975])
        rows.append({"prior": label, "param": name, "truth": float(truth[i]),
                     "map": float(result.theta[i]), "sd": float(sd[i]), "z": float(z),
                     "covered": int(abs(z) <= Z95),
                     "mcmc_mean": float(draws[..., i].mean()),
                     "mcmc_sd": float(draws[..., i].std()),
                     "mcmc_covered": int(lo <= truth[i] <= hi), "rhat": float(rhat[i]),
                     "process_var_map": float(result.theta[names.index("process_var")]),
                     "process_var_median": sigma_median,
                     "converged": int(bool(result.success))})
    return rows


def fit_seed(seed: int, settings: Settings, iterations: int) -> list[dict]:
    """Both priors' MAP + Laplace and DRAM on one fresh data set; one row per prior and
    coefficient. The log-uniform MAP starts from the half-normal one (the library's
    :func:`~symplid.inference.map._homotopy.half_normal_start`, here without refitting)."""
    system = get_system("henon-heiles")
    obs = simulate(system, times=5.0 * np.arange(1, 21), noise_std=0.05, seed=seed)
    model = build_model(settings, obs)
    half = build_posterior(settings, obs, model)
    scale = data_variance_scale(obs)
    log_uniform = half.with_prior(dataclasses.replace(
        half.prior, process_var=LogUniform(scale * 1e-8, scale)))
    terms = dict(zip(system.potential.param_names, system.coefficients, strict=True))
    truth = model.potential.coefficients_from(terms)
    names = list(half.param_names)
    rows, init = [], None
    for label, posterior in (("half-normal", half), ("log-uniform", log_uniform)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if init is not None:
                k = names.index("process_var")
                init[k] = float(np.clip(init[k], scale * 1.01e-8, 0.99 * scale))
            result = find_map(posterior, seed=0, num_starts=2, evidence="laplace", warn=False,
                              init=init)
            idata = sample(posterior, "dram", num_draws=iterations // 2, num_chains=2,
                           burn_in=iterations // 2, init=result, seed=seed,
                           options=RunOptions(progress=False))
        init = np.array(result.theta, dtype=float)
        draws = draws_array(idata)
        rhat = split_rhat(draws)
        sigma = float(np.median(draws[..., names.index("process_var")]))
        rows += _interval_rows(label, names, truth, result, draws, rhat, sigma)
    return [{"seed": seed, **r} for r in rows]


def split_rhat(draws: np.ndarray) -> np.ndarray:
    """Split-R̂ of each parameter (Gelman et al. 2013, BDA3 eq. 11.4), draws (chain, draw, p)."""
    half = draws.shape[1] // 2
    chains = np.concatenate([draws[:, :half], draws[:, half:2 * half]], axis=0)
    n = chains.shape[1]
    within = chains.var(axis=1, ddof=1).mean(axis=0)
    between = n * chains.mean(axis=1).var(axis=0, ddof=1)
    with np.errstate(all="ignore"):
        return np.sqrt(((n - 1) / n * within + between / n) / within)


def _coverage(sel: list[dict], key: str) -> str:
    hits = sum(int(r[key]) for r in sel)
    lo, hi = wilson(hits, len(sel))
    return f"{hits / max(len(sel), 1):.3f} [{lo:.2f}, {hi:.2f}]"


def table(rows: list[dict], rhat_max: float = 1.1) -> str:
    """Markdown: per coefficient and prior, the coverage (Wilson 95 %) of the Laplace and the
    DRAM intervals, the mean z of the MAP, the mean shift of the posterior mean in posterior
    sds. Seeds whose MAP failed or whose R̂ exceeds ``rhat_max`` in any coefficient are left
    out (and counted in the caption line)."""
    bad = {(r["seed"], r["prior"]) for r in rows
           if not int(r["converged"]) or not float(r["rhat"]) <= rhat_max}
    lines = [f"non-converged (MAP failed or R̂ > {rhat_max}) seed/prior pairs left out: "
             f"{len(bad)}", "",
             "| coefficient | prior | seeds | Laplace coverage | DRAM coverage "
             "| MAP mean z | DRAM mean shift (sd) |", "|---|---|---:|---|---|---:|---:|"]
    for param in dict.fromkeys(r["param"] for r in rows):
        for prior in ("half-normal", "log-uniform"):
            sel = [r for r in rows if r["param"] == param and r["prior"] == prior
                   and (r["seed"], r["prior"]) not in bad]
            z = np.mean([float(r["z"]) for r in sel]) if sel else math.nan
            shift = np.mean([(float(r["mcmc_mean"]) - float(r["truth"])) / float(r["mcmc_sd"])
                             for r in sel]) if sel else math.nan
            lines.append(f"| {param} | {prior} | {len(sel)} | {_coverage(sel, 'covered')} "
                         f"| {_coverage(sel, 'mcmc_covered')} | {z:+.2f} | {shift:+.2f} |")
    sigma = {p: np.median([float(r["process_var_median"]) for r in rows if r["prior"] == p])
             for p in ("half-normal", "log-uniform")}
    lines += ["", "median over seeds of the posterior median of Σ: "
              + ", ".join(f"{p} {v:.2g}" for p, v in sigma.items())]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--integrator", default="leapfrog")
    parser.add_argument("--dt", type=float, default=0.25)
    parser.add_argument("--iterations", type=int, default=6000,
                        help="DRAM iterations per chain (2 chains), half of them burn-in")
    parser.add_argument("--out", type=Path, default=Path("process_variance_prior.csv"))
    parser.add_argument("--rhat-max", type=float, default=1.1,
                        help="seed/prior pairs with a larger split-R-hat are left out")
    parser.add_argument("--table-only", action="store_true",
                        help="rebuild the table from --out without fitting")
    args = parser.parse_args(argv)
    if args.table_only:
        with args.out.open() as f:
            print(table(list(csv.DictReader(f)), args.rhat_max))
        return 0
    settings = settings_for(args.integrator, args.dt)
    rows: list[dict] = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        t = time.perf_counter()
        rows += fit_seed(seed, settings, args.iterations)
        with args.out.open("w", newline="") as f:  # rewritten each seed: a partial run counts
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"seed {seed}: {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    print(table(rows, args.rhat_max))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
