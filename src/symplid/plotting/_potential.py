"""The learned potential U(q) with its posterior band, one panel per axis (1-D: U itself)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from symplid.plotting._style import COLORS, compact_ticks, finish, new_figure

__all__ = ["PotentialSlice", "plot_potential"]


@dataclass
class PotentialSlice:
    """U along one axis: coordinate ``q``, band ``lower``/``upper`` and ``median`` of the
    posterior draws, optionally the MAP's and the true U, and the data's positions (a rug).

    ``label`` names the axis (``q1``); ``fixed`` says where the other coordinates are held
    (``q2 = 0.13``), shown in the panel's title.
    """

    label: str
    q: np.ndarray
    lower: np.ndarray
    median: np.ndarray
    upper: np.ndarray
    map: np.ndarray | None = None
    truth: np.ndarray | None = None
    data: np.ndarray | None = None
    fixed: str = ""


def plot_potential(
    slices: Sequence[PotentialSlice],
    *,
    band_label: str = "95 % band",
    path: str | Path | None = None,
) -> Figure:
    """U(q) from the posterior draws (band and median), the MAP and the truth, per slice.

    The y-axis is fitted to the band, the MAP and the truth over the plotted range, which
    covers the data (a rug of the observed positions at the bottom). U is defined up to a
    constant; the library's polynomial basis has none, so U(0) = 0 for the model and the truth.
    """
    if not slices:
        raise ValueError("give at least one slice")
    n = len(slices)
    fig = new_figure(min(4.2 * n, 12.0) + 0.6, 3.4)
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, s in zip(axes, slices, strict=True):
        ax.fill_between(s.q, s.lower, s.upper, color=COLORS["leapfrog"], alpha=0.25, lw=0,
                        label=band_label)
        ax.plot(s.q, s.median, color=COLORS["leapfrog"], lw=1.2, label="posterior median")
        curves = [s.lower, s.upper]
        if s.map is not None:
            ax.plot(s.q, s.map, color="0.15", lw=1.0, ls="--", label="MAP")
            curves.append(s.map)
        if s.truth is not None:
            ax.plot(s.q, s.truth, color=COLORS["truth"], lw=1.4, label="truth")
            curves.append(s.truth)
        stacked = np.concatenate([np.asarray(c, dtype=float) for c in curves])
        stacked = stacked[np.isfinite(stacked)]
        if stacked.size:
            low, high = float(stacked.min()), float(stacked.max())
            pad = 0.06 * (high - low or 1.0)
            ax.set_ylim(low - pad, high + pad)
        if s.data is not None and np.size(s.data):
            ax.plot(s.data, np.zeros_like(s.data), "|", ms=8, color=COLORS["data"],
                    transform=ax.get_xaxis_transform(), label="data positions")
        ax.set_xlabel(s.label)
        if s.fixed:
            ax.set_title(f"U along {s.label} ({s.fixed})", fontsize=9, loc="left")
        ax.grid(alpha=0.25)
        compact_ticks(ax, "y")
    axes[0].set_ylabel("U(q)")
    axes[0].legend(loc="upper center", fontsize=7.5, framealpha=0.9)
    return finish(fig, path)
