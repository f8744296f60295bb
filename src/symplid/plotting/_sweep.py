"""Figures of a sweep's results table: every cell's value of a metric, grouped by setting.

The helpers (the distinct settings of a table, the rows of one setting, a box with its points)
are shared with the studies' own figures (:mod:`symplid.studies._paper_study_report`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "BOOKKEEPING",
    "PALETTE",
    "format_value",
    "numeric",
    "plain",
    "plot_sweep",
    "rows_matching",
    "setting_groups",
    "strip_plot",
]

#: Columns of a results table that are neither settings nor metrics.
BOOKKEEPING = ("cell_id", "status", "elapsed_s", "error", "warnings", "started", "finished")
PALETTE = ("#7b3fa0", "#d98a00", "#16867f", "#6b6b6b", "#1f5fa8", "#c0392b")


def plot_sweep(
    table: Any,
    folder: str | os.PathLike,
    metrics: Sequence[str] | None = None,
    *,
    settings: Sequence[str] | None = None,
    hue: str | None = None,
    colors: Mapping[Any, str] | None = None,
) -> dict[str, Path]:
    """One PNG per metric of a sweep's results table: every cell's value, grouped by setting.

    Parameters
    ----------
    table
        The results table (:func:`symplid.workflow._sweep.load_results`).
    folder
        Where ``<metric>.png`` go.
    metrics
        The metrics drawn (those present in the table); default: every numeric metric column
        (at most 12).
    settings
        The setting columns; default: the columns between ``cell_id`` and ``status`` (the
        layout of :func:`~symplid.workflow._sweep.load_results`). The x axis has one group per
        distinct value of the settings that vary (``seed`` and ``hue`` aside).
    hue
        A setting column drawn in colours within each group (e.g. ``"integrator"``), with a
        box over the other cells (e.g. the seeds).
    colors
        Colour of each ``hue`` value (others get a default palette).

    Returns
    -------
    dict
        The paths by metric. Positive metrics spanning more than a decade get a log axis.
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from symplid.plotting._style import save_figure

    ok = table[table["status"] == "ok"]
    settings = list(settings) if settings is not None else _setting_columns(table)
    if metrics is None:
        metrics = [c for c in table.columns if c not in settings and c not in BOOKKEEPING
                   and table[c].dtype.kind in "if"][:12]
    else:
        metrics = [m for m in metrics if m in table.columns]
    by = [c for c in settings if c not in ("seed", hue) and table[c].nunique(dropna=False) > 1]
    groups = setting_groups(table, by)
    hues = list(dict.fromkeys(ok[hue])) if hue is not None and hue in ok else [None]
    colors = dict(colors or {})
    colors = {h: colors.get(h, PALETTE[i % len(PALETTE)]) for i, h in enumerate(hues)}
    folder = Path(folder)
    paths: dict[str, Path] = {}
    for metric in metrics:
        values = numeric(ok[metric])
        if not np.isfinite(values).any():
            continue
        fig = Figure(figsize=(max(5.0, 1.5 * len(groups) + 2), 4.0), layout="constrained")
        ax = fig.add_subplot()
        rng = np.random.default_rng(0)  # jitter of the points only
        width = 0.7 / max(len(hues), 1)
        for i, g in enumerate(groups):
            rows = rows_matching(ok, g)
            for j, h in enumerate(hues):
                sub = rows if h is None else rows[rows[hue] == h]
                v = numeric(sub[metric])
                x = i + (j - (len(hues) - 1) / 2) * width
                strip_plot(ax, x, v[np.isfinite(v)], colors[h], rng, width=0.85 * width)
        finite = values[np.isfinite(values)]
        if finite.min() > 0 and finite.max() / finite.min() > 10:
            ax.set_yscale("log")
        labels = [", ".join(f"{c}={format_value(g[c])}" for c in by) or "all cells" for g in groups]
        ax.set_xticks(range(len(groups)), labels, fontsize=8)
        ax.set_ylabel(metric)
        if hues != [None]:
            handles = [
                Line2D([], [], marker="o", ls="", color=colors[h], label=str(h)) for h in hues
            ]
            ax.legend(handles=handles, fontsize=8, loc="best")
        ax.grid(axis="y", alpha=0.3)
        paths[metric] = save_figure(fig, folder / f"{metric}.png")
    return paths


def _setting_columns(table: Any) -> list[str]:
    columns = list(table.columns)
    if "cell_id" in columns and "status" in columns:
        return columns[columns.index("cell_id") + 1 : columns.index("status")]
    return []


def setting_groups(table: Any, by: list[str]) -> list[dict[str, Any]]:
    """The distinct values of the columns ``by``, in order of first appearance."""
    seen: list[dict[str, Any]] = []
    for _, row in table[by].iterrows() if by else [(0, {})]:
        values = {c: row[c] for c in by}
        if not any(all(same_value(values[c], s[c]) for c in by) for s in seen):
            seen.append(values)
    return seen


def same_value(a: Any, b: Any) -> bool:
    """Equality in which NaN equals NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def _equal(column: Any, value: Any) -> np.ndarray:
    if isinstance(value, float) and math.isnan(value):
        return column.isna().to_numpy()
    return (column == value).to_numpy()


def rows_matching(table: Any, values: Mapping[str, Any]) -> Any:
    """The rows of ``table`` whose columns hold ``values`` (NaN matches NaN)."""
    mask = np.ones(len(table), dtype=bool)
    for col, v in values.items():
        mask &= _equal(table[col], v)
    return table[mask]


def plain(v: Any) -> Any:
    """A NumPy scalar as the Python value."""
    return v.item() if isinstance(v, np.generic) else v


def format_value(v: Any) -> str:
    """A setting's value for a label: ``0.1``, ``leapfrog``."""
    v = plain(v)
    return f"{v:g}" if isinstance(v, float) else str(v)


def numeric(column: Any) -> np.ndarray:
    """A column as floats (non-numbers become NaN)."""
    import pandas as pd

    return pd.to_numeric(column, errors="coerce").to_numpy(float)


def strip_plot(
    ax: Any, x: float, values: np.ndarray, color: str, rng: Any, width: float = 0.5
) -> None:
    """A box (quartiles, median) with the individual values as jittered points."""
    if values.size == 0:
        return
    ax.boxplot(
        [values],
        positions=[x],
        widths=width,
        showfliers=False,
        medianprops={"color": color, "lw": 1.5},
        boxprops={"color": color},
        whiskerprops={"color": color},
        capprops={"color": color},
    )
    jitter = rng.uniform(-width / 3, width / 3, size=values.size)
    ax.scatter(x + jitter, values, s=10, color=color, alpha=0.6, zorder=3)
