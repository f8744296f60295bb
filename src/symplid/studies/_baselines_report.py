"""The baselines study's results: medians by method and size, the deciding numbers, the figure.

Everything here is a pure function of the sweep's results table (one row per cell, the keys
of :data:`~._baselines_study.CELL_KEYS` and the metrics of :func:`~._baselines_study.score`), so
the README's table is text generated from ``results.csv``, never typed by hand.

**The numbers that decide it** (per potential family), from the medians over data seeds of
``hamiltonian_rel_error``:

* at the smallest data size n₀ (the paper's 20), the ratio of each method's H error to the
  UKF-leapfrog posterior's;
* the smallest data size at which each method's median H error reaches the UKF-leapfrog's
  error at n₀, or "not reached" within the sizes run.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from symplid.plotting._sweep import PALETTE
from symplid.studies._baselines_methods import METHODS, REFERENCE

__all__ = ["deciding_numbers", "format_report", "medians", "plot_error_vs_size"]

#: Columns of the tables: (metric, heading, format).
TABLE_METRICS = (
    ("hamiltonian_rel_error", "relative error of the learned H(x0)", "{:.3g}"),
    ("coefficient_error", "largest coefficient error (polynomial)", "{:.3g}"),
    ("potential_rmse", "RMS error of U along the true path", "{:.3g}"),
    ("prediction_horizon_s", "prediction horizon [s] (|Δq1| ≤ 0.1, up to 200 s)", "{:.1f}"),
    ("h_covered", "coverage of the true H(x0) by the 95 % Laplace interval", "{:.0%}"),
    ("coefficient_coverage", "coverage of the true coefficients by 95 % Laplace intervals",
     "{:.0%}"),
)
#: Metrics summarised by the mean over seeds (coverages: a fraction); the others by the median.
MEAN_METRICS = ("h_covered", "coefficient_coverage")


def _ok(table: Any) -> Any:
    return table[table["status"] == "ok"] if "status" in table else table


def medians(table: Any, metric: str) -> dict[tuple[str, str, int], tuple[float, int]]:
    """``{(potential, method, num_obs): (summary over seeds, number of seeds)}``.

    The median over seeds (the mean for the coverages); non-finite values (a diverged fit's
    infinite error) count in the median as +∞, NaN values are left out.
    """
    import pandas as pd

    ok = _ok(table)
    out: dict[tuple[str, str, int], tuple[float, int]] = {}
    if metric not in ok:
        return out
    for (potential, method, n), rows in ok.groupby(["potential", "method", "num_obs"]):
        v = pd.to_numeric(rows[metric], errors="coerce").to_numpy(float)
        v = v[~np.isnan(v)]
        if v.size == 0:
            continue
        value = float(np.mean(v)) if metric in MEAN_METRICS else float(np.median(v))
        out[(str(potential), str(method), int(n))] = (value, int(v.size))
    return out


def _order(table: Any) -> tuple[list[str], list[str], list[int]]:
    ok = _ok(table)
    potentials = [p for p in ("polynomial", "mlp") if p in set(ok["potential"])]
    methods = [m for m in METHODS.names() if m in set(ok["method"])]
    sizes = sorted(int(n) for n in set(ok["num_obs"]))
    return potentials, methods, sizes


def deciding_numbers(table: Any) -> dict[str, Any]:
    """The ratio at the smallest size and the size that reaches the reference (module doc).

    Returns
    -------
    dict
        ``{potential: {"n0", "reference_error", "methods": {method: {"ratio", "reached_at",
        "largest_size"}}}}``; ``reached_at`` is None when the method does not reach the
        reference error within the sizes it has results for (the largest: ``largest_size``).
    """
    potentials, methods, sizes = _order(table)
    med = medians(table, "hamiltonian_rel_error")
    out: dict[str, Any] = {}
    for potential in potentials:
        n0 = sizes[0]
        ref = med.get((potential, REFERENCE, n0), (math.nan, 0))[0]
        entry: dict[str, Any] = {"n0": n0, "reference_error": ref, "methods": {}}
        for method in methods:
            if method == REFERENCE or (potential, method, n0) not in med:
                continue
            ratio = med[(potential, method, n0)][0] / ref if ref > 0 else math.nan
            have = [n for n in sizes if (potential, method, n) in med]
            reached = [n for n in have if med[(potential, method, n)][0] <= ref]
            entry["methods"][method] = {"ratio": ratio,
                                        "reached_at": reached[0] if reached else None,
                                        "largest_size": have[-1]}
        out[potential] = entry
    return out


def _cell(value: tuple[float, int] | None, fmt: str, seeds: int) -> str:
    if value is None:
        return "–"
    v, n = value
    text = "∞ (diverged)" if v == math.inf else fmt.format(v)
    return text if n == seeds else f"{text} ({n})"


def format_report(table: Any, budget: Mapping[str, Any] | None = None) -> str:
    """Markdown: one table per metric (rows: potential × method, columns: data size), then
    the deciding numbers. A cell with fewer seeds than the most shows its count."""
    potentials, methods, sizes = _order(table)
    ok = _ok(table)
    seeds = {p: int(ok[ok["potential"] == p]["seed"].nunique()) for p in potentials}
    lines = ["Hénon–Heiles, σ = 0.05, observations spread over 100 s; "
             + "; ".join(f"{p}: {seeds[p]} data seed(s)" for p in potentials)
             + ". Medians over seeds (coverages: the fraction of seeds)."]
    if budget:
        lines.append("Budget: " + ", ".join(f"{k} {v}" for k, v in budget.items()) + ".")
    for metric, heading, fmt in TABLE_METRICS:
        med = medians(table, metric)
        if not med:
            continue
        lines += ["", f"**{heading}**", "", "| potential | method | "
                  + " | ".join(f"n = {n}" for n in sizes) + " |", "|---|---|" + "---|" * len(sizes)]
        for p in potentials:
            for m in methods:
                if not any((p, m, n) in med for n in sizes):
                    continue
                cells = [_cell(med.get((p, m, n)), fmt, seeds[p]) for n in sizes]
                lines.append(f"| {p} | {METHODS.get_entry(m).label} | " + " | ".join(cells) + " |")
    lines += ["", "**Numbers that decide it** (H error of each method against the UKF-leapfrog "
              "posterior's):", ""]
    for p, entry in deciding_numbers(table).items():
        lines.append(f"- {p}: UKF-leapfrog H error at n = {entry['n0']}: "
                     f"{entry['reference_error']:.3g}")
        for m, d in entry["methods"].items():
            where = (f"reaches it at n = {d['reached_at']}" if d["reached_at"] is not None
                     else f"does not reach it by n = {d['largest_size']}")
            lines.append(f"  - {METHODS.get_entry(m).label}: ratio {d['ratio']:.3g} at "
                         f"n = {entry['n0']}; {where}")
    return "\n".join(lines) + "\n"


def plot_error_vs_size(table: Any, folder: str | os.PathLike,
                       metrics: tuple[str, ...] = ("hamiltonian_rel_error",
                                                   "prediction_horizon_s")) -> dict[str, Path]:
    """One PNG per metric: median over seeds against data size (log–log for errors), one
    line per method, one panel per potential family; the band spans the seeds' quartiles."""
    import pandas as pd
    from matplotlib.figure import Figure

    from symplid.plotting._style import save_figure

    potentials, methods, sizes = _order(table)
    ok = _ok(table)
    paths: dict[str, Path] = {}
    for metric in metrics:
        if metric not in ok:
            continue
        fig = Figure(figsize=(5.0 * len(potentials), 4.0), layout="constrained")
        axes = fig.subplots(1, len(potentials), squeeze=False)[0]
        for ax, p in zip(axes, potentials, strict=True):
            for i, m in enumerate(methods):
                rows = ok[(ok["potential"] == p) & (ok["method"] == m)]
                ns, mid, lo, hi = [], [], [], []
                for n in sizes:
                    v = pd.to_numeric(rows[rows["num_obs"] == n][metric],
                                      errors="coerce").to_numpy(float)
                    v = v[np.isfinite(v)]
                    if v.size:
                        ns.append(n)
                        q = np.quantile(v, [0.25, 0.5, 0.75])
                        lo.append(q[0]), mid.append(q[1]), hi.append(q[2])
                if not ns:
                    continue
                color = PALETTE[i % len(PALETTE)]
                style = "-" if METHODS.get_entry(m).bayesian else "--"
                ax.plot(ns, mid, style, marker="o", color=color, label=METHODS.get_entry(m).label)
                ax.fill_between(ns, lo, hi, color=color, alpha=0.12)
            ax.set_xscale("log")
            if metric != "prediction_horizon_s":
                ax.set_yscale("log")
            ax.set_xlabel("number of observations over 100 s")
            ax.set_ylabel(metric)
            ax.set_title(f"{p} potential")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7, loc="best")
        paths[metric] = save_figure(fig, Path(folder) / f"{metric}_vs_size.png")
    return paths
