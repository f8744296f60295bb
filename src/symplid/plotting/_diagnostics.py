"""Figures of the chains: traces per parameter and a corner plot."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from symplid.plotting._style import (
    COLORS,
    CYCLE,
    compact_ticks,
    finish,
    legend_above,
    new_figure,
)

__all__ = ["envelope_indices", "plot_pair", "plot_traces", "truncation_note"]


def _as_draws(draws: Any, names: Sequence[str] | None) -> tuple[np.ndarray, list[str]]:
    """Draws ``(chains, draws, P)`` and names from an array, a mapping or an InferenceData."""
    if hasattr(draws, "posterior"):
        draws = draws.posterior
    if hasattr(draws, "data_vars"):  # an xarray Dataset
        draws = {k: draws[k].values for k in draws.data_vars}
    if isinstance(draws, Mapping):
        cols, labels = [], []
        for key, arr in draws.items():
            arr = np.asarray(arr, dtype=float)
            if arr.ndim < 2:
                raise ValueError(f"{key}: expected shape (chains, draws, ...), got {arr.shape}")
            flat = arr.reshape(arr.shape[0], arr.shape[1], -1)
            cols.append(flat)
            if flat.shape[2] == 1:
                labels.append(str(key))
            else:
                labels += [f"{key}[{i}]" for i in range(flat.shape[2])]
        return np.concatenate(cols, axis=2), labels if names is None else list(names)
    arr = np.asarray(draws, dtype=float)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise ValueError(f"draws must have shape (chains, draws, P) or (draws, P), got {arr.shape}")
    if names is None:
        names = [f"θ{i + 1}" for i in range(arr.shape[2])]
    if len(names) != arr.shape[2]:
        raise ValueError(f"{len(names)} names for {arr.shape[2]} parameters")
    return arr, list(names)


def _select(arr: np.ndarray, names: list[str], params: Sequence[str | int] | None, limit: int):
    if limit < 1:
        raise ValueError(f"max_params must be ≥ 1, got {limit}")
    if params is None:
        idx = list(range(min(arr.shape[2], limit)))
    else:
        idx = []
        for p in params:
            if isinstance(p, str):
                if p not in names:
                    raise ValueError(f"unknown parameter {p!r}; choose from {', '.join(names)}")
                idx.append(names.index(p))
            else:
                idx.append(int(p))
    return arr[:, :, idx], [names[i] for i in idx]


def envelope_indices(values: np.ndarray, most: int) -> np.ndarray:
    """Indices of at most ``most`` (≥ 4) entries of the 1-D ``values`` that keep its envelope:
    the first and the last, and, with ``values`` cut into runs of equal length (the last one
    shorter), each run's lowest and highest entry, in order.

    A line through them spans the same range as the line through every value, run by run:
    every excursion of a trace stays in view (thinning to every k-th draw would drop a lone
    spike), while the line has a few thousand vertices instead of every draw. All indices
    when there are at most ``most``, or when a value is not finite.
    """
    n = values.shape[0]
    if most < 4:
        raise ValueError(f"most must be ≥ 4, got {most}")
    if n <= most or not np.all(np.isfinite(values)):
        return np.arange(n)
    length = -(-n // ((most - 2) // 2))  # ceil: at most (most - 2) // 2 runs
    runs = -(-n // length)
    padded = np.full(runs * length, np.nan)
    padded[:n] = values
    padded = padded.reshape(runs, length)
    starts = np.arange(runs) * length
    kept = np.concatenate([[0, n - 1], starts + np.nanargmin(padded, axis=1),
                           starts + np.nanargmax(padded, axis=1)])
    return np.unique(kept)


def truncation_note(shown: int, total: int, option: str) -> str | None:
    """"showing the first k of P parameters (option)" when a figure leaves some out."""
    if shown >= total:
        return None
    return f"showing the first {shown} of {total} parameters (raise {option} to see more)"


def _note(fig: Figure, text: str | None, corner: bool = False) -> None:
    """A grey note at the top of the figure (``corner``: in the empty upper right of a corner
    plot)."""
    if text and corner:
        fig.text(0.97, 0.9, text.replace(" (", "\n("), fontsize=8.5, color="0.3", ha="right",
                 va="top")
    elif text:
        fig.suptitle(text, fontsize=8.5, color="0.3", x=0.01, ha="left")


def _values(given: Mapping[str, float] | Sequence[float] | None, labels: list[str],
            what: str) -> list[float | None] | None:
    if given is None:
        return None
    if isinstance(given, Mapping):
        return [given.get(n) for n in labels]
    values = list(given)
    if len(values) != len(labels):
        raise ValueError(f"{what} has {len(values)} values for {len(labels)} parameters")
    return values


def plot_traces(
    draws: Any,
    names: Sequence[str] | None = None,
    *,
    params: Sequence[str | int] | None = None,
    max_params: int = 16,
    max_points: int = 2000,
    path: str | Path | None = None,
    option: str = "max_params",
) -> Figure:
    """Trace plot per parameter: draws against iteration per chain, and per-chain histograms.

    Parameters
    ----------
    draws
        ``(chains, draws, P)`` or ``(draws, P)`` array, ``{name: (chains, draws, ...)}``, or an
        ArviZ ``InferenceData`` (its posterior group).
    names
        Parameter names for an array (default θ1, θ2, ...).
    params
        Names or indices to draw (default: the first ``max_params``; when that leaves some
        out, a note at the top says so, naming ``option``).
    max_points
        The most points of a chain's trace line (:func:`envelope_indices`: the first and
        last draw and the lowest and highest of each run of consecutive draws, so the line
        covers the same range run by run; the histograms count every draw).

    Returns
    -------
    Figure with two axes per parameter (trace, histogram).
    """
    full, all_labels = _as_draws(draws, names)
    arr, labels = _select(full, all_labels, params, max_params)
    p = arr.shape[2]
    fig = new_figure(10.0, 1.55 * p + 0.5)
    axes = fig.subplots(p, 2, squeeze=False, width_ratios=(3, 1))
    iters = np.arange(arr.shape[1])
    for k in range(p):
        ax_t, ax_h = axes[k]
        col = arr[:, :, k]
        finite = col[np.isfinite(col)]
        edges = np.histogram_bin_edges(finite if finite.size else [0.0, 1.0], bins=40)
        for c in range(arr.shape[0]):
            color = CYCLE[c % len(CYCLE)]
            kept = envelope_indices(col[c], max_points)
            ax_t.plot(iters[kept], col[c][kept], lw=0.4, alpha=0.8, color=color,
                      label=f"chain {c}" if k == 0 else None)
            counts, _ = np.histogram(col[c][np.isfinite(col[c])], bins=edges)
            ax_h.stairs(counts, edges, color=color, lw=1.0)
        ax_t.set_ylabel(labels[k], fontsize=9)
        ax_t.grid(alpha=0.25)
        ax_h.set_yticks([])
        ax_h.xaxis.set_major_locator(MaxNLocator(3))
        ax_h.tick_params(axis="x", labelsize=7)
        ax_t.tick_params(labelsize=7)
        compact_ticks(ax_t, "y")
        compact_ticks(ax_h, "x")
        if k < p - 1:
            ax_t.tick_params(labelbottom=False)
    axes[0, 0].set_title("trace", fontsize=10, loc="left")
    axes[0, 1].set_title("marginal per chain", fontsize=10)
    axes[-1, 0].set_xlabel("draw")
    if arr.shape[0] > 1:
        legend_above(axes[0, 0], ncol=min(arr.shape[0], 8), fontsize=7.5)
    if params is None:
        _note(fig, truncation_note(p, len(all_labels), option))
    return finish(fig, path)


def plot_pair(
    draws: Any,
    names: Sequence[str] | None = None,
    *,
    params: Sequence[str | int] | None = None,
    max_params: int = 6,
    max_points: int = 3000,
    reference: Mapping[str, float] | Sequence[float] | None = None,
    map_values: Mapping[str, float] | Sequence[float] | None = None,
    seed: int = 0,
    path: str | Path | None = None,
    option: str = "max_params",
) -> Figure:
    """Corner plot: pairwise scatter below the diagonal, marginal histograms on it.

    Parameters
    ----------
    draws, names
        As in :func:`plot_traces` (chains are pooled).
    params
        Names or indices (default: the first ``max_params``; a note at the top says when
        that leaves some out, naming ``option``).
    max_points
        Scatter at most this many draws (a seeded random subset).
    reference
        The true values to mark (lines and squares), by name or in the order shown.
    map_values
        The MAP to mark (dashed lines and crosses), by name or in the order shown.

    Returns
    -------
    Figure with k(k+1)/2 axes for k parameters.
    """
    full, all_labels = _as_draws(draws, names)
    arr, labels = _select(full, all_labels, params, max_params)
    flat = arr.reshape(-1, arr.shape[2])
    flat = flat[np.all(np.isfinite(flat), axis=1)]
    if flat.shape[0] == 0:
        raise ValueError("no finite draws to plot")
    if flat.shape[0] > max_points:
        flat_s = flat[np.random.default_rng(seed).choice(flat.shape[0], max_points, replace=False)]
    else:
        flat_s = flat
    marks = [(v, style) for v, style in (
        (_values(reference, labels, "reference"), dict(color=COLORS["truth"], ls="-", m="s")),
        (_values(map_values, labels, "map_values"), dict(color="0.15", ls="--", m="x")),
    ) if v is not None]
    k = len(labels)
    fig = new_figure(1.9 * k + 0.8, 1.9 * k + 0.6)
    grid = fig.add_gridspec(k, k)
    axes: dict[tuple[int, int], Any] = {}
    for i in range(k):
        for j in range(i + 1):
            share_x = axes.get((k - 1, j)) if i != k - 1 else None
            ax = fig.add_subplot(grid[i, j], sharex=axes.get((j, j)) if j < i else share_x)
            axes[i, j] = ax
            if i == j:
                counts, edges = np.histogram(flat[:, i], bins=40)
                ax.stairs(counts, edges, fill=True, color=COLORS["leapfrog"], alpha=0.75)
                ax.set_yticks([])
                for ref, st in marks:
                    if ref[i] is not None:
                        ax.axvline(ref[i], color=st["color"], ls=st["ls"], lw=1.2)
            else:
                ax.plot(flat_s[:, j], flat_s[:, i], ".", ms=1.5, alpha=0.35,
                        color=COLORS["leapfrog"])
                for ref, st in marks:
                    if ref[i] is not None and ref[j] is not None:
                        ax.plot(ref[j], ref[i], st["m"], color=st["color"], ms=5)
            ax.tick_params(labelsize=6.5)
            ax.xaxis.set_major_locator(MaxNLocator(3))
            compact_ticks(ax, "x" if i == j else "both")
            if i != j:
                ax.yaxis.set_major_locator(MaxNLocator(4))
            if i == k - 1:
                ax.set_xlabel(labels[j], fontsize=9)
            else:
                ax.tick_params(labelbottom=False)
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i], fontsize=9)
            elif i != j:
                ax.tick_params(labelleft=False)
    _pair_legend(fig, marks)
    if params is None:
        _note(fig, truncation_note(k, len(all_labels), option), corner=True)
    return finish(fig, path)


def _pair_legend(fig: Figure, marks: list) -> None:
    from matplotlib.lines import Line2D

    names = {"s": "truth", "x": "MAP"}
    handles = [Line2D([], [], color=st["color"], ls=st["ls"], marker=st["m"], label=names[st["m"]])
               for _, st in marks]
    if handles:
        fig.legend(handles=handles, loc="upper right", fontsize=8, frameon=False)
