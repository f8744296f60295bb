"""The fit's convergence table against ArviZ's ``summary`` and the previous implementation.

Workload: the paper's posterior size, 4 chains × 100,000 kept draws × 11 parameters, as
synthetic AR(1) chains (ρ from 0.5 to 0.99 across the parameters) with the repeated values
of a Metropolis chain's rejections (a draw repeats the last one with probability 0.7), so
that ties in the ranks matter. Timed, taking turns, ``--repeats`` times each (minimum
reported):

* ``az.summary(idata, kind="diagnostics")`` (ArviZ's own; it also computes the MCSE);
* the previous :func:`~symplid.inference._diagnostics.convergence_table` (kept below: ArviZ's
  ``_ess`` per statistic, a stable sort per rank normalisation);
* the current one.

Each table's ``ess_bulk``, ``ess_tail`` and ``r_hat`` are compared with ArviZ's (largest
relative difference). Pin it to one core: ``taskset -c 0 python
benchmarks/convergence_table.py [--repeats 5] [--draws 100000]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "src"))

from symplid.inference._diagnostics import (
    convergence_table,
    import_arviz,
    quiet_arviz,
)

COLUMNS = ["ess_bulk", "ess_tail", "r_hat"]


def ar1_draws(chains: int, draws: int, params: int, seed: int = 0) -> np.ndarray:
    """(chains, draws, params) AR(1) chains with Metropolis-style repeated values."""
    rng = np.random.default_rng(seed)
    rho = np.linspace(0.5, 0.99, params)
    noise = rng.normal(size=(draws, chains, params)) * np.sqrt(1 - rho**2)
    stay = rng.random((draws, chains, params)) < 0.7
    out = np.empty((draws, chains, params))
    out[0] = rng.normal(size=(chains, params))
    for t in range(1, draws):
        fresh = rho * out[t - 1] + noise[t]
        out[t] = np.where(stay[t], out[t - 1], fresh)
    return np.moveaxis(out, 0, 1)


# ---- the previous implementation (this project's, before the batched ESS), the baseline ----


def previous_convergence_table(idata):
    """The convergence table as computed before: ArviZ's ``_ess`` per statistic."""
    import pandas as pd
    from arviz.stats.diagnostics import _ess, _quantile

    posterior = idata.posterior
    rows = {}
    for name in posterior.data_vars:
        ary = np.asarray(posterior[name], dtype=float)
        rows[str(name)] = _previous_convergence(ary, _ess, _quantile)
    return pd.DataFrame.from_dict(rows, orient="index", columns=COLUMNS)


def _previous_convergence(ary, ess, quantile):
    chains, draws = ary.shape
    if draws < 4 or np.isnan(ary).any():
        return np.nan, np.nan, np.nan
    split = _split_chains(ary)
    order = np.argsort(split.ravel(), kind="stable")
    z_split = _z_scale(split, order)
    q05, q95 = quantile(ary, [0.05, 0.95])
    ess_tail = min(ess(_split_chains(ary <= q05)), ess(_split_chains(ary <= q95)))
    if chains < 2:
        rhat = np.nan
    else:
        folded = _split_chains(np.abs(ary - np.median(ary)))
        flat = folded.ravel()
        folded_order = order[np.argsort(flat[order], kind="stable")]
        rhat = max(_rhat(z_split), _rhat(_z_scale(folded, folded_order)))
    return float(ess(z_split)), float(ess_tail), float(rhat)


def _split_chains(ary):
    half = ary.shape[1] // 2
    return np.vstack((ary[:, :half], ary[:, -half:]))


def _z_scale(ary, order):
    from scipy.special import ndtri

    flat = ary.ravel()
    ordered = flat[order]
    first = np.empty(flat.size, dtype=bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, flat.size))
    ranks = np.empty(flat.size)
    ranks[order] = np.repeat(starts + (counts + 1) / 2.0, counts)
    c = 3 / 8
    return ndtri((ranks - c) / (flat.size - 2 * c + 1)).reshape(ary.shape)


def _rhat(ary):
    num_samples = ary.shape[1]
    chain_mean = np.mean(ary, axis=1)
    chain_var = np.var(ary, axis=1, ddof=1)
    between = num_samples * np.var(chain_mean, axis=None, ddof=1)
    within = np.mean(chain_var)
    return float(np.sqrt((between / within + num_samples - 1) / num_samples))


# ---- timing ----


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--draws", type=int, default=100_000)
    parser.add_argument("--chains", type=int, default=4)
    parser.add_argument("--params", type=int, default=11)
    args = parser.parse_args()
    az = import_arviz()
    draws = ar1_draws(args.chains, args.draws, args.params)
    idata = az.from_dict(posterior={f"p{k}": draws[..., k] for k in range(args.params)})
    contenders = {
        "az.summary(kind='diagnostics')":
            lambda: az.summary(idata, round_to="none", kind="diagnostics")[COLUMNS],
        "previous convergence_table": lambda: previous_convergence_table(idata),
        "convergence_table": lambda: convergence_table(idata),
    }
    times: dict[str, list[float]] = {name: [] for name in contenders}
    tables = {}
    with quiet_arviz():
        for _ in range(args.repeats):
            for name, run in contenders.items():
                start = time.perf_counter()
                tables[name] = run()
                times[name].append(time.perf_counter() - start)
    reference = tables["az.summary(kind='diagnostics')"].to_numpy()
    print(f"{args.chains} chains x {args.draws:,} draws x {args.params} parameters, "
          f"min of {args.repeats} repeats")
    print("| implementation | min s | vs ArviZ | vs previous | max rel. diff. from ArviZ |")
    print("|---|---:|---:|---:|---:|")
    base_az = min(times["az.summary(kind='diagnostics')"])
    base_prev = min(times["previous convergence_table"])
    for name, values in times.items():
        best = min(values)
        diff = np.max(np.abs(tables[name].to_numpy() / reference - 1))
        print(f"| {name} | {best:.3f} | {best / base_az:.2f} | {best / base_prev:.2f} | "
              f"{diff:.1e} |")


if __name__ == "__main__":
    main()
