"""The SBC study's statistics, figure and report (:mod:`._sbc` runs the replications).

Uniformity of the ranks of each parameter over the replications is judged two ways:

* a χ² test on binned ranks (:func:`~symplid.studies._claims_stats.rank_uniformity`);
* the ECDF of the fractional ranks r/(L + 1) against the uniform's, with a **simultaneous**
  95 % band (:func:`ecdf_band`): the band that holds the whole ECDF of N uniform ranks with
  probability 0.95, found by simulation as in Säilynoja, Bürkner & Vehtari (2022).

Replications whose chains did not converge (R-hat > :data:`RHAT_MAX` or ESS <
:data:`ESS_MIN` in any parameter) are counted and reported apart: their ranks are judged
separately from the converged ones, so a sampler failure is not mistaken for a miscalibrated
posterior, nor hidden in it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from symplid.studies._claims_stats import RANK_DRAWS, rank_uniformity

__all__ = [
    "ESS_MIN",
    "RHAT_MAX",
    "converged_mask",
    "ecdf_band",
    "ecdf_inside",
    "groups",
    "plot_ranks",
    "rank_columns",
    "sbc_summary",
    "write_sbc_report",
]

RHAT_MAX = 1.05
ESS_MIN = 50.0
#: Simulated rank sets behind the ECDF band.
BAND_SIMULATIONS = 4000


def ecdf_band(n: int, num_draws: int = RANK_DRAWS, level: float = 0.95,
              seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simultaneous ``level`` band for the ECDF of ``n`` ranks uniform on {0, …, L}.

    At the points z_j = (j + 1)/(L + 1), j = 0..L−1, the ECDF F̂(z_j) (the fraction of ranks
    ≤ j) of uniform ranks has mean z_j and sd s_j = √(z_j(1 − z_j)/n). The band is
    z_j ± c·s_j with c the ``level`` quantile of max_j |F̂(z_j) − z_j| / s_j over
    :data:`BAND_SIMULATIONS` simulated rank sets (seeded), so the whole uniform ECDF lies in
    it with probability ``level``.

    Returns ``(z, lower, upper)``.
    """
    if n < 1:
        raise ValueError(f"need at least one rank, got n={n}")
    z = np.arange(1, num_draws + 1) / (num_draws + 1)
    sd = np.sqrt(z * (1 - z) / n)
    rng = np.random.default_rng(seed)
    sims = rng.integers(0, num_draws + 1, size=(BAND_SIMULATIONS, n))
    counts = np.apply_along_axis(np.bincount, 1, sims, minlength=num_draws + 1)
    ecdf = np.cumsum(counts, axis=1)[:, :num_draws] / n
    c = float(np.quantile(np.max(np.abs(ecdf - z) / sd, axis=1), level))
    return z, z - c * sd, z + c * sd


def ecdf_inside(ranks: Any, num_draws: int = RANK_DRAWS, level: float = 0.95) -> bool:
    """Whether the ECDF of ``ranks`` lies inside the simultaneous band of :func:`ecdf_band`."""
    r = np.asarray(ranks, dtype=int).ravel()
    _, lower, upper = ecdf_band(r.size, num_draws, level)
    ecdf = np.cumsum(np.bincount(r, minlength=num_draws + 1))[:num_draws] / r.size
    return bool(np.all((ecdf >= lower - 1e-12) & (ecdf <= upper + 1e-12)))


def rank_columns(table: Any) -> list[str]:
    """The parameters with rank columns (``sbc.<name>.rank``) in a results table, but those
    with no finite rank in it (Σ where the likelihood is deterministic)."""
    return [c[len("sbc."):-len(".rank")] for c in table.columns
            if c.startswith("sbc.") and c.endswith(".rank")
            and np.isfinite(table[c].to_numpy(dtype=float)).any()]


def groups(table: Any) -> list[tuple[str, str, Any]]:
    """``(sampler, likelihood, rows)`` of the finished replications, by sampler then
    likelihood (rows without a sampler column were DRAM's, rows without a likelihood column
    had the default process noise, once per gap)."""
    ok = table[table["status"] == "ok"] if "status" in table else table
    samplers = _column(ok, "sampler", "dram")
    likelihoods = _column(ok, "likelihood", "gap")
    out = []
    for sampler in sorted(samplers.unique()):
        mine = samplers == sampler
        out += [(sampler, v, ok[mine & (likelihoods == v)])
                for v in sorted(likelihoods[mine].unique())]
    return out


def _column(rows: Any, name: str, default: str) -> Any:
    """``rows[name]`` with ``default`` where it is missing (the whole column, or a value)."""
    import pandas as pd

    if name not in rows:
        return pd.Series(default, index=rows.index, dtype=object)
    return rows[name].fillna(default)


def converged_mask(table: Any) -> np.ndarray:
    """True for the rows whose every parameter has R-hat ≤ RHAT_MAX and ESS ≥ ESS_MIN."""
    rhat = table["rhat_max"].to_numpy(dtype=float)
    ess = table["ess_min"].to_numpy(dtype=float)
    return (rhat <= RHAT_MAX) & (ess >= ESS_MIN)


def _judge(ranks: np.ndarray, num_draws: int = RANK_DRAWS) -> dict[str, Any]:
    ranks = ranks[np.isfinite(ranks)].astype(int)
    if ranks.size == 0:
        return {"n": 0}
    u = rank_uniformity(ranks, num_draws)
    return {"n": int(ranks.size), "chi2": u["chi2"], "p_value": u["p_value"],
            "bins": u["bins"], "counts": u["counts"],
            "ecdf_inside": ecdf_inside(ranks, num_draws),
            "mean_fraction": float(np.mean(ranks) / num_draws)}


def _judge_param(rows: Any, name: str, good: np.ndarray) -> dict[str, Any]:
    ranks = rows[f"sbc.{name}.rank"].to_numpy(dtype=float)
    judged = {"converged": _judge(ranks[good]), "not_converged": _judge(ranks[~good])}
    column = f"sbc.{name}.rank_thin"
    if column in rows:
        thin = rows[column].to_numpy(dtype=float)
        judged["converged_thin"] = _judge(thin[good], int(rows["thin_draws"].iloc[0]))
    return judged


def sbc_summary(table: Any) -> dict[str, Any]:
    """Per sampler, likelihood and parameter: the rank tests over the converged replications
    and, apart, over the non-converged ones (``table``: the sweep's results); with the
    rank among the fewer, about independent draws (``rank_thin``) where it was recorded.
    ``ess_below_rank_draws``: converged replications whose smallest ESS is below the
    :data:`RANK_DRAWS` draws the rank is counted among (neighbouring thinned draws are then
    correlated)."""
    out: dict[str, Any] = {}
    for sampler, likelihood, rows in groups(table):
        good = converged_mask(rows)
        ess = rows["ess_min"].to_numpy(dtype=float)
        params = {name: _judge_param(rows, name, good) for name in rank_columns(rows)}
        out.setdefault(sampler, {})[likelihood] = {
            "replications": len(rows), "converged": int(good.sum()),
            "not_converged": int((~good).sum()),
            "ess_below_rank_draws": int((good & (ess < RANK_DRAWS)).sum()),
            "wall_time_s_median": float(np.median(rows["wall_time_s"].to_numpy(dtype=float))),
            **_budget_outcome(rows), "params": params}
    return out


def _budget_outcome(rows: Any) -> dict[str, Any]:
    """What a run of the defaults records besides its ranks: how many replications reached
    the sampler's targets (rather than its cap) and the learning steps chosen."""
    out: dict[str, Any] = {}
    if "reached_target" in rows:
        out["reached_target"] = int(np.nansum(rows["reached_target"].to_numpy(dtype=float)))
    if "dt" in rows:
        dt = rows["dt"].to_numpy(dtype=float)
        out["dt"] = {"min": float(np.min(dt)), "median": float(np.median(dt)),
                     "max": float(np.max(dt))}
    return out


def plot_ranks(table: Any, folder: Any) -> dict[str, Path]:
    """One figure per likelihood: for each parameter the rank histogram (converged
    replications) over the uniform's 99 % range, and the ECDF difference F̂ − z in the
    simultaneous 95 % band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import binom

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for sampler, likelihood, rows in groups(table):
        rows = rows[converged_mask(rows)]
        names = rank_columns(rows)
        if rows.empty or not names:
            continue
        fig, axes = plt.subplots(2, len(names), figsize=(2.6 * len(names), 5.0), squeeze=False)
        n = len(rows)
        z, lower, upper = ecdf_band(n)
        for k, name in enumerate(names):
            ranks = rows[f"sbc.{name}.rank"].to_numpy(dtype=int)
            bins = 10
            counts = np.bincount(ranks * bins // (RANK_DRAWS + 1), minlength=bins)
            ax = axes[0, k]
            lo, hi = binom.ppf([0.005, 0.995], n, 1.0 / bins)
            ax.axhspan(lo, hi, color="0.85")
            ax.bar(np.arange(bins) + 0.5, counts, width=0.9, color="C0")
            ax.set_title(name, fontsize=9)
            ax.set_xticks([])
            ecdf = np.cumsum(np.bincount(ranks, minlength=RANK_DRAWS + 1))[:RANK_DRAWS] / n
            ax = axes[1, k]
            ax.fill_between(z, lower - z, upper - z, color="0.85")
            ax.plot(z, ecdf - z, color="C0")
            ax.axhline(0.0, color="0.4", lw=0.5)
            ax.set_xlabel("fractional rank")
        axes[0, 0].set_ylabel("replications")
        axes[1, 0].set_ylabel("ECDF − uniform")
        fig.suptitle(f"SBC, {sampler.upper()}, process noise: {likelihood} "
                     f"({n} converged replications)")
        fig.tight_layout()
        suffix = likelihood if sampler == "dram" else f"{sampler}_{likelihood}"
        path = folder / f"sbc_ranks_{suffix}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths[suffix] = path
    return paths


def _fmt(judged: dict[str, Any]) -> str:
    if not judged.get("n"):
        return "– | – | –"
    p = judged["p_value"]
    return (f"{judged['n']} | {'–' if p is None else f'{p:.3f}'} | "
            f"{'yes' if judged['ecdf_inside'] else 'NO'}")


def format_report(summary: dict[str, Any], budget: dict[str, Any],
                  title: str = "Simulation-based calibration") -> str:
    """The study's ``report.md``: per likelihood and parameter, the χ² p-value and whether the
    ECDF stays in its band, converged and non-converged replications apart."""
    lines = [f"# {title}", "",
             f"Budget per replication: {budget.get('words', budget)}. Ranks among "
             f"{RANK_DRAWS} thinned draws (and, last columns, among the fewer draws of "
             "`rank_thin`); "
             f"converged: R-hat ≤ {RHAT_MAX} and ESS ≥ {ESS_MIN:g} in every parameter.", ""]
    for sampler, by_likelihood in summary.items():
        for likelihood, s in by_likelihood.items():
            lines += [f"## {sampler.upper()}, process noise: {likelihood}", "",
                      f"{s['replications']} replications: {s['converged']} converged, "
                      f"{s['not_converged']} not (reported apart); "
                      f"{s['ess_below_rank_draws']} converged with ESS < {RANK_DRAWS}; "
                      f"median wall time {s['wall_time_s_median']:.1f} s.", "",
                      *_outcome_lines(s),
                      "| parameter | n | χ² p | ECDF in band | n (not conv.) | χ² p | "
                      "ECDF in band | n (thinned) | χ² p | ECDF in band |",
                      "|---|---:|---:|---|---:|---:|---|---:|---:|---|"]
            for name, judged in s["params"].items():
                lines.append(f"| {name} | {_fmt(judged['converged'])} | "
                             f"{_fmt(judged['not_converged'])} | "
                             f"{_fmt(judged.get('converged_thin', {}))} |")
            lines.append("")
    return "\n".join(lines)


def _outcome_lines(s: dict[str, Any]) -> list[str]:
    lines = []
    if "reached_target" in s:
        lines.append(f"{s['reached_target']} of {s['replications']} replications reached the "
                     "sampler's targets (the rest stopped at its cap).")
    if "dt" in s:
        lines.append(f"Learning step chosen: {s['dt']['min']:.4g} to {s['dt']['max']:.4g} "
                     f"(median {s['dt']['median']:.4g}).")
    return [*lines, ""] if lines else []


def write_sbc_report(out_dir: Any, table: Any = None, budget: dict[str, Any] | None = None,
                     title: str = "Simulation-based calibration") -> dict[str, Any]:
    """``report.md``, ``sbc.json`` and ``figures/`` of a study folder from its finished
    replications (``table``: default, the folder's results)."""
    from symplid.workflow._results import write_json
    from symplid.workflow._sweep import load_results

    out = Path(out_dir)
    table = load_results(out) if table is None else table
    summary = sbc_summary(table)
    write_json({"budget": budget, "summary": summary}, out / "sbc.json")
    plot_ranks(table, out / "figures")
    tmp = out / ".report.md.tmp"
    tmp.write_text(format_report(summary, budget or {}, title), encoding="utf-8")
    os.replace(tmp, out / "report.md")
    return summary
