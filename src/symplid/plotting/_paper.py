"""The paper's four figures (Section IV).

* :func:`plot_phase_portraits`: Fig. 1, trajectories in the (q1, q2) plane.
* :func:`plot_hamiltonians`: Fig. 2, H along trajectories (a) at the fine step, (b) with the
  learning integrator at the learning step.
* :func:`plot_trajectory_bands`: Fig. 3, q1(t): MAP, 2.5–97.5 % band, sample paths, data, truth.
* :func:`plot_process_noise`: Fig. 4, histograms of the process-noise posterior.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from symplid.plotting._style import (
    COLORS,
    Curves,
    color_for,
    compact_ticks,
    energy_limits,
    finish,
    legend_above,
    mark_end_of_data,
    new_figure,
    robust_limits,
    sample_lines,
    time_span,
)

__all__ = ["plot_hamiltonians", "plot_phase_portraits", "plot_process_noise",
           "plot_trajectory_bands"]


# ---------------------------------------------------------------------------- Fig. 1
def plot_phase_portraits(
    trajectories: Mapping[str, np.ndarray],
    truth: np.ndarray,
    data: np.ndarray | None = None,
    *,
    components: tuple[int, int] = (0, 1),
    names: tuple[str, str] = ("q1", "q2"),
    truth_title: str = "truth",
    data_title: str = "noisy position data",
    colors: Mapping[str, str] | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Fig. 1: phase portraits in the (q1, q2) plane, two panels per row.

    Parameters
    ----------
    trajectories
        Panel title → states ``(T, ≥2)`` (e.g. the MAP models learned with leapfrog and with
        RK2, both integrated by leapfrog at the fine step for 200 s).
    truth
        True states ``(T, ≥2)``.
    data
        Observed values ``(n, ≥2)`` (positions in ``components``), drawn as points; or None.
    components
        Columns drawn on the horizontal and vertical axes.
    names
        Axis labels.
    path
        Where to write the PNG (optional).

    Returns
    -------
    Figure with ``len(trajectories) + 1 (+1 with data)`` axes sharing their limits.
    """
    i, j = components
    panels: list[tuple[str, np.ndarray, str, bool]] = []
    for k, (title, states) in enumerate(trajectories.items()):
        color = (colors or {}).get(title) or color_for(title, k)
        panels.append((title, np.asarray(states, dtype=float), color, False))
    truth = np.asarray(truth, dtype=float)
    panels.append((truth_title, truth, COLORS["truth"], False))
    if data is not None:
        panels.append((data_title, np.asarray(data, dtype=float), COLORS["data"], True))
    ncols = 2 if len(panels) > 1 else 1
    nrows = -(-len(panels) // ncols)
    fig = new_figure(4.2 * ncols, 3.9 * nrows)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False).ravel()
    xlim = robust_limits(truth[:, i], *(p[1][:, i] for p in panels), clip=1.6)
    ylim = robust_limits(truth[:, j], *(p[1][:, j] for p in panels), clip=1.6)
    for ax, (title, states, color, points) in zip(axes, panels, strict=False):
        if points:
            ax.plot(states[:, i], states[:, j], "o", ms=4, color=color, label=title)
        else:
            ax.plot(states[:, i], states[:, j], "-", lw=0.35, color=color, label=title)
        ax.set_title(title)
        ax.set_xlabel(names[0])
        ax.set_ylabel(names[1])
        ax.grid(alpha=0.25)
        if xlim is not None and ylim is not None:
            ax.set_xlim(xlim)
            ax.set_ylim(ylim)
    for ax in axes[len(panels) :]:
        fig.delaxes(ax)
    for ax in axes[: len(panels)]:
        ax.label_outer()
        if len(panels) % ncols and ax is axes[len(panels) - ncols]:
            ax.xaxis.set_tick_params(labelbottom=True)  # above an empty slot
            ax.set_xlabel(names[0])
    return finish(fig, path)


# ---------------------------------------------------------------------------- Fig. 2
def plot_hamiltonians(
    fine: Sequence[Curves],
    truth: Curves | tuple[np.ndarray, np.ndarray],
    coarse: Sequence[Curves] = (),
    *,
    t_data_end: float | None = None,
    titles: tuple[str, str] = (
        "(a) integrated by leapfrog at the fine step",
        "(b) integrated by the learning integrator at the learning step",
    ),
    time_unit: str = "s",
    path: str | Path | None = None,
) -> Figure:
    """Fig. 2: the Hamiltonian along predicted trajectories.

    Parameters
    ----------
    fine
        Panel (a): per approach, H along the MAP trajectory (``values``) and along posterior
        sample trajectories (``samples``, drawn light), integrated by leapfrog at the fine step.
    truth
        H along the true trajectory, as :class:`Curves` or ``(times, values)`` (green).
    coarse
        Panel (b), drawn only when given: e.g. the RK2 model integrated by RK2 at the learning
        step, showing the energy it gains.
    t_data_end
        Time of the last observation (a vertical line).
    time_unit
        Unit of the times, on the axis label.

    A MAP curve that leaves the axis (an energy that runs away, e.g. a path escaping over
    the saddle) is marked "escaped" where it leaves; the legend counts the samples that do.

    Returns
    -------
    Figure with one axis, or two (a above b) when ``coarse`` is given.
    """
    if not isinstance(truth, Curves):
        truth = Curves("truth", *truth, color=COLORS["truth"])
    panels = [(titles[0], list(fine))] + ([(titles[1], list(coarse))] if coarse else [])
    fig = new_figure(8.0, 3.3 * len(panels))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (title, curves) in zip(axes, panels, strict=True):
        handles = []
        for k, c in enumerate(curves):
            color = c.color or color_for(c.label, k)
            if c.samples is not None:
                sample_lines(ax, c.sample_times, c.samples, color, lw=0.5, alpha=0.12)
                handles.append(
                    Line2D([], [], color=color, lw=1.0, alpha=0.35, label=f"{c.label} samples")
                )
            label = f"{c.label} MAP" if c.samples is not None else c.label
            handles += ax.plot(c.times, c.values, color=color, lw=1.8, label=label, zorder=4)
        handles += ax.plot(
            truth.times, truth.values, color=COLORS["truth"], lw=1.6, label="truth", zorder=5
        )
        mark_end_of_data(ax, t_data_end)
        if t_data_end is not None:
            handles.append(
                Line2D([], [], color=COLORS["end_of_data"], ls="--", label="end of data")
            )
        samples = [c.samples for c in curves if c.samples is not None]
        lim = energy_limits(truth.values, *(c.values for c in curves), *samples)
        if lim is not None:
            ax.set_ylim(lim)
            handles += _mark_escapes(ax, curves, lim)
        ax.set_title(title, loc="left", fontsize=10)
        ax.set_ylabel("H(q, p)")
        ax.grid(alpha=0.25)
        compact_ticks(ax, "y")
        ax.legend(handles=handles, loc="best", fontsize=8, ncol=3, framealpha=0.9)
    axes[-1].set_xlabel(f"t [{time_unit}]")
    axes[-1].set_xlim(time_span(list(fine) + list(coarse), (truth.times, truth.values)))
    return finish(fig, path)


def first_exit(times: np.ndarray, values: np.ndarray, lim: tuple[float, float]) -> float | None:
    """The first time a curve is outside ``lim`` (or not finite), or None if it never is."""
    values = np.asarray(values, dtype=float)
    out = ~np.isfinite(values) | (values < lim[0]) | (values > lim[1])
    return float(np.asarray(times)[np.argmax(out)]) if out.any() else None


def _mark_escapes(ax, curves: Sequence[Curves], lim: tuple[float, float]) -> list:
    """Annotate "escaped" where a MAP curve leaves the axis; legend entries counting the
    samples that leave it."""
    extra = []
    for k, c in enumerate(curves):
        color = c.color or color_for(c.label, k)
        t = first_exit(c.times, c.values, lim)
        if t is not None:
            after = np.asarray(c.values)[np.asarray(c.times) >= t][:1]
            top = not (after.size and np.isfinite(after[0]) and after[0] < lim[0])
            y = lim[1] if top else lim[0]
            ax.annotate(f"{c.label} escaped (t ≈ {t:.3g})", xy=(t, y),
                        xytext=(-30, -45 if top else 45), textcoords="offset points",
                        ha="right", va="center", fontsize=8, color=color, zorder=6,
                        bbox=dict(boxstyle="round,pad=0.2", fc="white", ec=color, lw=0.6),
                        arrowprops=dict(arrowstyle="->", color=color, lw=0.8))
        if c.samples is not None:
            gone = sum(first_exit(c.sample_times, row, lim) is not None for row in c.samples)
            if gone:
                extra.append(Line2D([], [], color="none", label=f"{c.label}: {gone} of "
                                    f"{len(c.samples)} samples leave the axis"))
    return extra


# ---------------------------------------------------------------------------- Fig. 3
def plot_trajectory_bands(
    approaches: Sequence[Curves],
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    data: tuple[np.ndarray, np.ndarray] | None = None,
    *,
    t_data_end: float | None = None,
    ylabel: str = "q1",
    band_label: str = "2.5–97.5 % band",
    time_unit: str = "s",
    path: str | Path | None = None,
) -> Figure:
    """Fig. 3: one component against time, one row per approach.

    Parameters
    ----------
    approaches
        Per approach: the MAP trajectory (``times``, ``values``), the band (``lower``,
        ``upper``) and sample paths (``samples``) on ``sample_times``.
    truth
        ``(times, values)`` of the true trajectory (green).
    data
        ``(times, values)`` of the observations of this component (points).
    t_data_end
        Time of the last observation (a vertical line).
    ylabel
        Name of the component.

    Returns
    -------
    Figure with one axis per approach (shared axes).
    """
    n = len(approaches)
    if n == 0:
        raise ValueError("give at least one approach")
    fig = new_figure(9.0, 2.9 * n + 0.4)
    axes = fig.subplots(n, 1, sharex=True, sharey=True, squeeze=False)[:, 0]
    ref = truth[1] if truth is not None else approaches[0].values
    lim = robust_limits(
        ref, *(a.values for a in approaches), *(a.lower for a in approaches),
        *(a.upper for a in approaches), clip=1.5, pad=0.05,
    )
    for k, (ax, a) in enumerate(zip(axes, approaches, strict=True)):
        color = a.color or color_for(a.label, k)
        handles = []
        if a.lower is not None:
            ax.fill_between(a.sample_times, a.lower, a.upper, color=color, alpha=0.22, lw=0,
                            zorder=1)
            handles.append(Patch(color=color, alpha=0.3, label=band_label))
        if a.samples is not None:
            sample_lines(ax, a.sample_times, a.samples, color, lw=0.4, alpha=0.15)
            handles.append(Line2D([], [], color=color, lw=0.8, alpha=0.5,
                                  label=f"{a.samples.shape[0]} posterior samples"))
        handles += ax.plot(a.times, a.values, color=color, lw=1.5, label="MAP", zorder=4)
        if truth is not None:
            handles += ax.plot(*truth, color=COLORS["truth"], lw=1.2, label="truth", zorder=3)
        if data is not None:
            handles += ax.plot(*data, "o", ms=4.5, color=COLORS["data"], label="data", zorder=5)
        mark_end_of_data(ax, t_data_end)
        if t_data_end is not None:
            handles.append(
                Line2D([], [], color=COLORS["end_of_data"], ls="--", label="end of data")
            )
        ax.set_title(a.label, loc="left", fontsize=10, fontweight="bold")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.25)
        if lim is not None:
            ax.set_ylim(lim)
        legend_above(ax, handles, ncol=len(handles), fontsize=7.5)
    axes[-1].set_xlabel(f"t [{time_unit}]")
    axes[-1].set_xlim(time_span(approaches, truth))
    return finish(fig, path)


# ---------------------------------------------------------------------------- Fig. 4
def plot_process_noise(
    samples: Mapping[str, np.ndarray],
    map_values: Mapping[str, float] | None = None,
    *,
    log: bool = True,
    bins: int = 40,
    xlabel: str = "process-noise variance θ_Σ",
    colors: Mapping[str, str] | None = None,
    path: str | Path | None = None,
) -> Figure:
    """Fig. 4: histograms of the process-noise posterior, one row per approach (shared x).

    Parameters
    ----------
    samples
        Approach label → posterior draws of the process-noise variance (any shape; flattened).
    map_values
        Optional MAP value per approach (a dashed line).
    log
        Logarithmic x-axis and bins (the approaches differ by about an order of magnitude).
    bins
        Number of bins (common to every panel).

    A MAP far outside the draws (e.g. a variance at its lower bound, 1e-14, when the draws
    sit near 1e-7) would stretch the axis over decades with nothing in them: it is drawn as
    an arrow at the axis' edge instead, and its value is given in the legend.

    Returns
    -------
    Figure with one axis per approach.
    """
    if not samples:
        raise ValueError("give the draws of at least one approach")
    values = {k: np.ravel(np.asarray(v, dtype=float)) for k, v in samples.items()}
    values = {k: v[np.isfinite(v)] for k, v in values.items()}
    allv = np.concatenate(list(values.values()))
    if allv.size == 0:
        raise ValueError("no finite draws to plot")
    if log:
        positive = allv[allv > 0]
        if positive.size == 0:
            raise ValueError("log=True needs positive draws")
        edges = np.geomspace(positive.min(), positive.max(), bins + 1)
    else:
        edges = np.linspace(allv.min(), allv.max(), bins + 1)
    n = len(values)
    fig = new_figure(7.0, 2.2 * n + 0.5)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for k, (ax, (label, v)) in enumerate(zip(axes, values.items(), strict=True)):
        color = (colors or {}).get(label) or color_for(label, k)
        ax.hist(v[v > 0] if log else v, bins=edges, color=color, alpha=0.75, edgecolor="white",
                lw=0.4, label=f"{label} ({v.size} draws)")
        med = float(np.median(v))
        ax.axvline(med, color="black", lw=1.2, label=f"median {med:.3g}")
        if map_values and label in map_values:
            _map_line(ax, float(map_values[label]), edges, log)
        ax.set_ylabel("draws")
        ax.set_title(label, loc="left", fontsize=10)
        ax.legend(fontsize=8, loc="upper right")
        ax.grid(alpha=0.25)
        if log:
            ax.set_xscale("log")
    width = np.log(edges[-1] / edges[0]) if log else edges[-1] - edges[0]
    pad = 0.03 * (width if width > 0 else 1.0)
    axes[-1].set_xlim(*((edges[0] * np.exp(-pad), edges[-1] * np.exp(pad)) if log
                        else (edges[0] - pad, edges[-1] + pad)))
    axes[-1].set_xlabel(xlabel)
    return finish(fig, path)


def _map_line(ax, value: float, edges: np.ndarray, log: bool) -> None:
    """The MAP as a dashed line, or, outside the draws' range, an arrow at the axis' edge."""
    if edges[0] <= value <= edges[-1]:
        ax.axvline(value, color="black", lw=1.2, ls="--", label=f"MAP {value:.3g}")
        return
    left = value < edges[0]
    ax.annotate("", xy=(0.0 if left else 1.0, 0.5), xytext=(0.07 if left else 0.93, 0.5),
                xycoords="axes fraction", arrowprops=dict(arrowstyle="->", color="black", lw=1.2))
    ax.plot([], [], color="black", ls="--", label=f"MAP {value:.3g} (off the axis, "
            f"{'below' if left else 'above'} every draw)")
