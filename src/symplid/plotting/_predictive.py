"""The posterior predictive band against the data, for runs on user data."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from symplid.plotting._style import (
    COLORS,
    as_xy,
    finish,
    legend_above,
    mark_end_of_data,
    new_figure,
    robust_limits,
    sample_lines,
)

__all__ = ["plot_forecast", "plot_predictive"]


def plot_predictive(
    predictive: Any,
    data: Any = None,
    *,
    state_names: Sequence[str] | None = None,
    components: Sequence[int] | None = None,
    map_path: tuple[np.ndarray, np.ndarray] | None = None,
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    t_data_end: float | None = None,
    max_samples: int = 50,
    color: str = COLORS["leapfrog"],
    time_unit: str = "s",
    title: str | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Data and posterior predictive band for every observed component, one row each.

    Parameters
    ----------
    predictive
        A :class:`~.predict.PosteriorPredictive` (``times``, ``quantiles``, ``median``,
        ``paths``, ``quantile_levels``).
    data
        An :class:`~symplid.Observations` (its ``names`` pick the state components) or a
        ``(times, values)`` pair; None for no data.
    state_names
        Names of the state's components (default ``q1..qd, p1..pd``).
    components
        State components to draw (default: those observed in ``data``, else all).
    map_path, truth
        Optional ``(times, states)`` drawn as a dark line and a green line.
    t_data_end
        End of the data (default: the last data time when data are given).
    max_samples
        Sample paths drawn at most.
    time_unit, title
        Unit of the times (axis label); a title above the panels.

    Returns
    -------
    Figure with one axis per drawn component.
    """
    times = np.asarray(predictive.times, dtype=float)
    dim2 = np.asarray(predictive.median).shape[-1]
    if state_names is None:
        d = dim2 // 2
        state_names = [f"q{i + 1}" for i in range(d)] + [f"p{i + 1}" for i in range(d)]
    state_names = list(state_names)
    if len(state_names) != dim2:
        raise ValueError(f"{len(state_names)} state names for {dim2} state components")
    observed = _Observed.of(data, state_names) if data is not None else None
    if observed is not None and t_data_end is None:
        t_data_end = float(observed.times[-1])
    if components is None:
        components = sorted(observed.columns) if observed and observed.columns else range(dim2)
    components = list(components)
    if not components:
        raise ValueError("no component to draw")
    levels = tuple(predictive.quantile_levels)
    band = f"{100 * levels[0]:g}–{100 * levels[-1]:g} % band"
    fig = new_figure(9.0, 2.2 * len(components) + 0.5)
    axes = fig.subplots(len(components), 1, sharex=True, squeeze=False)[:, 0]
    paths = np.asarray(predictive.paths)[:max_samples]
    for ax, c in zip(axes, components, strict=True):
        _band_panel(ax, predictive, times, paths, c, band, color)
        if map_path is not None:
            ax.plot(map_path[0], np.asarray(map_path[1])[:, c], color=color, lw=1.5, label="MAP")
        if truth is not None:
            ax.plot(truth[0], np.asarray(truth[1])[:, c], color=COLORS["truth"], lw=1.2,
                    label="truth")
        values = observed.component(c) if observed is not None else None
        if values is not None:
            ax.plot(observed.times, values, "o", ms=4, color=COLORS["data"], label="data")
        mark_end_of_data(ax, t_data_end)
        ax.set_ylabel(state_names[c])
        ax.grid(alpha=0.25)
        lim = robust_limits(
            predictive.median[:, c], predictive.quantiles[0][:, c],
            predictive.quantiles[-1][:, c], values, clip=3.0,
        )
        if lim is not None:
            ax.set_ylim(lim)
    handles, _ = axes[0].get_legend_handles_labels()
    legend_above(axes[0], handles, ncol=len(handles), fontsize=7.5)
    axes[-1].set_xlabel(f"t [{time_unit}]")
    if title:
        fig.suptitle(title, fontsize=10, x=0.01, ha="left", y=1.0)
    starts = [times[0]] + ([observed.times[0]] if observed and observed.columns else [])
    axes[-1].set_xlim(min(starts), times[-1])
    return finish(fig, path)


def _band_panel(ax, predictive: Any, times: np.ndarray, paths: np.ndarray, c: int, band: str,
                color: str) -> None:
    """Component ``c``'s band, sample paths and median on ``ax``."""
    ax.fill_between(times, predictive.quantiles[0][:, c], predictive.quantiles[-1][:, c],
                    color=color, alpha=0.22, lw=0, label=band)
    if paths.shape[0]:
        sample_lines(ax, times, paths[:, :, c], color, lw=0.4, alpha=0.15)
    ax.plot(times, predictive.median[:, c], color=color, lw=1.0, ls=":", label="median")


@dataclass(frozen=True)
class _Observed:
    """The data's times and values, and which data column holds each state component."""

    times: np.ndarray
    values: np.ndarray
    columns: dict[int, int]  # state component → data column

    @classmethod
    def of(cls, data: Any, state_names: Sequence[str]) -> _Observed:
        times, values = as_xy(data)
        names = getattr(data, "names", None)
        if names:
            columns = {
                state_names.index(name): col
                for col, name in enumerate(names)
                if name in state_names
            }
        else:  # full state or positions, in order
            columns = {c: c for c in range(min(values.shape[1], len(state_names)))}
        return cls(times, values, columns)

    def component(self, c: int) -> np.ndarray | None:
        """The observed values of state component ``c``, or None when it is not observed."""
        return self.values[:, self.columns[c]] if c in self.columns else None


def plot_forecast(
    forecast: Any,
    data: Any,
    state_dim: int,
    *,
    heldout: Any = None,
    color: str = COLORS["leapfrog"],
    time_unit: str = "s",
    path: str | Path | None = None,
) -> Figure:
    """A forecast from the end of the data: one panel per observed component.

    Each panel shows the data, the 95 % band of the state (dark) and of a new observation
    (light, the state's band plus observation noise), the median, and held-out data when
    given (open circles). ``forecast`` is a
    :class:`~symplid.inference._forecast.NoisyForecast`; ``data`` (and ``heldout``) an
    :class:`~symplid.Observations` whose column names pick the state components.
    """
    d = state_dim // 2
    state_names = [f"q{i + 1}" for i in range(d)] + [f"p{i + 1}" for i in range(d)]
    names = list(getattr(data, "names", None) or state_names[: np.asarray(data.values).shape[1]])
    times = np.asarray(forecast.times, dtype=float)
    t0 = float(forecast.t_start)
    levels = list(forecast.quantile_levels)
    low, high = levels.index(min(levels)), levels.index(max(levels))
    mid = levels.index(0.5) if 0.5 in levels else None
    fig = new_figure(9.0, 2.2 * len(names) + 0.5)
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    for j, (ax, name) in enumerate(zip(axes, names, strict=True)):
        c = state_names.index(name) if name in state_names else j
        obs_q = forecast.obs_quantiles
        ax.fill_between(times, obs_q[low][:, j], obs_q[high][:, j],
                        color=color, alpha=0.15, lw=0, label="new observation, 95 %")
        ax.fill_between(times, forecast.state_quantiles[low][:, c],
                        forecast.state_quantiles[high][:, c], color=color, alpha=0.35, lw=0,
                        label="state, 95 %")
        if mid is not None:
            ax.plot(times, forecast.state_quantiles[mid][:, c], color=color, lw=1.0,
                    label="median")
        ax.plot(data.times, np.asarray(data.values)[:, j], "o", ms=3, color=COLORS["data"],
                label="data")
        if heldout is not None:
            ax.plot(heldout.times, np.asarray(heldout.values)[:, j], "o", ms=4, mfc="none",
                    color=COLORS["truth"], label="held out")
        mark_end_of_data(ax, t0, label=j == 0)
        ax.set_ylabel(name)
        ax.grid(alpha=0.25)
    handles, _ = axes[0].get_legend_handles_labels()
    legend_above(axes[0], handles, ncol=min(len(handles), 6), fontsize=7.5)
    axes[-1].set_xlabel(f"t [{time_unit}]")
    return finish(fig, path)
