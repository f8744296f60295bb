"""Figures: the paper's four (Section IV) and general ones for runs on user data.

Every function takes plain arrays or small dataclasses, returns a
:class:`matplotlib.figure.Figure`, and writes a PNG when ``path`` is given. Figures are built
without :mod:`matplotlib.pyplot` (no global state, no window, nothing to close) and saved
through the Agg canvas, so they work the same on a headless machine, in a notebook and in
threads.

The paper's figures:

* :func:`plot_phase_portraits`: Fig. 1, trajectories in the (q1, q2) plane.
* :func:`plot_hamiltonians`: Fig. 2, H along trajectories (a) at the fine step, (b) with the
  learning integrator at the learning step.
* :func:`plot_trajectory_bands`: Fig. 3, q1(t): MAP, 2.5–97.5 % band, sample paths, data, truth.
* :func:`plot_process_noise`: Fig. 4, histograms of the process-noise posterior.

General ones: :func:`plot_traces` (chains), :func:`plot_pair` (corner plot) and
:func:`plot_predictive` (data and predictive band for every observed component).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import Formatter, MaxNLocator

__all__ = [
    "COLORS",
    "Curves",
    "plot_hamiltonians",
    "plot_pair",
    "plot_phase_portraits",
    "plot_predictive",
    "plot_process_noise",
    "plot_traces",
    "plot_trajectory_bands",
    "save_figure",
]

#: Colours shared by the figures (the paper's: blue for leapfrog, red for RK2, green truth).
COLORS = {
    "leapfrog": "#1f5fa8",
    "rk2": "#c0392b",
    "truth": "#2ca02c",
    "data": "black",
    "end_of_data": "#d62fc4",
}
_CYCLE = ("#1f5fa8", "#c0392b", "#7b3fa0", "#d98a00", "#16867f", "#6b6b6b")
DPI = 100


@dataclass(frozen=True)
class Curves:
    """One approach's curves against time, for :func:`plot_hamiltonians` and
    :func:`plot_trajectory_bands`.

    Attributes
    ----------
    label
        Legend and panel label (e.g. ``"leapfrog"``).
    times, values
        The main curve (e.g. the MAP's), shapes ``(T,)``.
    samples
        Optional posterior sample curves, shape ``(K, Ts)``, drawn light.
    sample_times
        Times of ``samples``, ``lower`` and ``upper`` (default ``times``).
    lower, upper
        Optional band limits, shape ``(Ts,)``.
    color
        Any matplotlib colour (default: from the label, see :data:`COLORS`).
    """

    label: str
    times: np.ndarray
    values: np.ndarray
    samples: np.ndarray | None = None
    sample_times: np.ndarray | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    color: str | None = None

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        values = np.asarray(self.values, dtype=float)
        if times.ndim != 1 or values.shape != times.shape:
            raise ValueError(
                f"{self.label}: times and values must be 1-D of equal length, "
                f"got {times.shape} and {values.shape}"
            )
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)
        st = times if self.sample_times is None else np.asarray(self.sample_times, dtype=float)
        object.__setattr__(self, "sample_times", st)
        if self.samples is not None:
            samples = np.atleast_2d(np.asarray(self.samples, dtype=float))
            if samples.shape[1] != st.shape[0]:
                raise ValueError(
                    f"{self.label}: samples must have shape (K, {st.shape[0]}), got {samples.shape}"
                )
            object.__setattr__(self, "samples", samples)
        if (self.lower is None) != (self.upper is None):
            raise ValueError(f"{self.label}: give both lower and upper, or neither")
        for name in ("lower", "upper"):
            band = getattr(self, name)
            if band is not None:
                band = np.asarray(band, dtype=float)
                if band.shape != st.shape:
                    raise ValueError(f"{self.label}: {name} must have shape {st.shape}")
                object.__setattr__(self, name, band)

    @property
    def resolved_color(self) -> str:
        return self.color or _color_for(self.label, 0)


# ---------------------------------------------------------------------------- helpers
def _color_for(label: str, index: int) -> str:
    key = label.lower()
    if "leapfrog" in key or ("symplectic" in key and "non" not in key):
        return COLORS["leapfrog"]
    if "rk2" in key or "runge" in key or "non-symplectic" in key:
        return COLORS["rk2"]
    return _CYCLE[index % len(_CYCLE)]


def _new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def save_figure(fig: Figure, path: str | Path, dpi: int = DPI) -> Path:
    """Write ``fig`` as a PNG (Agg canvas; the folder is created) and return the path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=dpi, facecolor="white")
    return path


def _finish(fig: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        save_figure(fig, path)
    return fig


def _end_of_data(ax, t_data_end: float | None, label: bool = True) -> None:
    if t_data_end is not None:
        ax.axvline(
            t_data_end, color=COLORS["end_of_data"], lw=1.2, ls="--",
            label="end of data" if label else None, zorder=1,
        )


def _robust_limits(*arrays: np.ndarray, pad: float = 0.08, clip: float | None = None):
    """Limits that contain every finite value, or, with ``clip``, the first array's range
    widened ``clip`` times (so that a diverging sample does not flatten the figure)."""
    finite = [np.asarray(a, dtype=float)[np.isfinite(a)] for a in arrays if a is not None]
    finite = [f for f in finite if f.size]
    if not finite:
        return None
    lo = min(f.min() for f in finite)
    hi = max(f.max() for f in finite)
    if clip is not None:
        ref = finite[0]
        centre, half = 0.5 * (ref.max() + ref.min()), 0.5 * (ref.max() - ref.min())
        lo, hi = max(lo, centre - clip * half), min(hi, centre + clip * half)
    span = hi - lo if hi > lo else max(abs(hi), 1e-12)
    return lo - pad * span, hi + pad * span


def _energy_limits(truth: np.ndarray, *arrays: np.ndarray, pad: float = 0.08):
    """Limits for energy curves: every value within a window around the true energy.

    A model integrated past its escape energy runs off to ±∞; values further than twice the
    true energy's scale from it are left out of the limits (the curve leaves the axes).
    """
    ref = np.asarray(truth, dtype=float)
    ref = ref[np.isfinite(ref)]
    if ref.size == 0:
        return _robust_limits(*arrays, pad=pad)
    scale = max(float(np.abs(ref).max()), float(np.ptp(ref)), 1e-12)
    lo_w, hi_w = ref.min() - 2.0 * scale, ref.max() + 2.0 * scale
    kept = [ref]
    for a in arrays:
        a = np.asarray(a, dtype=float)
        kept.append(a[np.isfinite(a) & (a >= lo_w) & (a <= hi_w)])
    return _robust_limits(*kept, pad=pad)


class _CompactFormatter(Formatter):
    """Tick labels with just enough significant digits to tell neighbouring ticks apart
    (``2.5e-06``, ``0.12125``), and no offset text to collide with axis labels."""

    _ticks: tuple[float, ...] = ()

    def set_locs(self, locs) -> None:
        self._ticks = tuple(float(v) for v in locs)

    def __call__(self, x: float, pos: int | None = None) -> str:
        locs = np.asarray([v for v in self._ticks if np.isfinite(v)], dtype=float)
        if locs.size < 2:
            return f"{x:.3g}"
        step = float(np.min(np.abs(np.diff(np.sort(locs))))) or 1.0
        scale = float(np.max(np.abs(locs)))
        if abs(x) < 1e-9 * step:
            return "0"
        digits = int(min(max(np.ceil(np.log10(max(scale / step, 1.0))) + 2, 2), 10))
        return f"{x:.{digits}g}"


def _compact(ax, axis: str = "both") -> None:
    """Use :class:`_CompactFormatter` on the x and/or y axis."""
    if axis in ("x", "both"):
        ax.xaxis.set_major_formatter(_CompactFormatter())
    if axis in ("y", "both"):
        ax.yaxis.set_major_formatter(_CompactFormatter())


def _legend_above(ax, handles=None, ncol: int = 6, fontsize: float = 8) -> None:
    """Legend in one row above the axes, right-aligned (the title sits on the left)."""
    kwargs = {} if handles is None else {"handles": handles}
    ax.legend(
        **kwargs, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=ncol, fontsize=fontsize,
        frameon=False, borderaxespad=0.2, handlelength=1.6, columnspacing=1.2,
    )


def _sample_lines(ax, times: np.ndarray, samples: np.ndarray, color, lw: float, alpha: float):
    """Many sample curves as one :class:`~matplotlib.collections.LineCollection` (one artist
    draws hundreds of curves far faster than as many lines). Non-finite points are gaps."""
    samples = np.where(np.isfinite(samples), samples, np.nan)
    segments = np.stack([np.broadcast_to(times, samples.shape), samples], axis=-1)
    lines = LineCollection(segments, colors=color, linewidths=lw, alpha=alpha, zorder=2)
    ax.add_collection(lines, autolim=True)
    ax.autoscale_view()
    return lines


def _as_xy(data: Any) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) from an Observations-like object or a (times, values) pair."""
    if hasattr(data, "times") and hasattr(data, "values"):
        return np.asarray(data.times, dtype=float), np.asarray(data.values, dtype=float)
    times, values = data
    values = np.asarray(values, dtype=float)
    return np.asarray(times, dtype=float), values[:, None] if values.ndim == 1 else values


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
        color = (colors or {}).get(title) or _color_for(title, k)
        panels.append((title, np.asarray(states, dtype=float), color, False))
    truth = np.asarray(truth, dtype=float)
    panels.append((truth_title, truth, COLORS["truth"], False))
    if data is not None:
        panels.append((data_title, np.asarray(data, dtype=float), COLORS["data"], True))
    ncols = 2 if len(panels) > 1 else 1
    nrows = -(-len(panels) // ncols)
    fig = _new_figure(4.2 * ncols, 3.9 * nrows)
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False).ravel()
    xlim = _robust_limits(truth[:, i], *(p[1][:, i] for p in panels), clip=1.6)
    ylim = _robust_limits(truth[:, j], *(p[1][:, j] for p in panels), clip=1.6)
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
    return _finish(fig, path)


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

    Returns
    -------
    Figure with one axis, or two (a above b) when ``coarse`` is given.
    """
    if not isinstance(truth, Curves):
        truth = Curves("truth", *truth, color=COLORS["truth"])
    panels = [(titles[0], list(fine))] + ([(titles[1], list(coarse))] if coarse else [])
    fig = _new_figure(8.0, 3.3 * len(panels))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (title, curves) in zip(axes, panels, strict=True):
        handles = []
        for k, c in enumerate(curves):
            color = c.color or _color_for(c.label, k)
            if c.samples is not None:
                _sample_lines(ax, c.sample_times, c.samples, color, lw=0.5, alpha=0.12)
                handles.append(
                    Line2D([], [], color=color, lw=1.0, alpha=0.35, label=f"{c.label} samples")
                )
            label = f"{c.label} MAP" if c.samples is not None else c.label
            handles += ax.plot(c.times, c.values, color=color, lw=1.8, label=label, zorder=4)
        handles += ax.plot(
            truth.times, truth.values, color=COLORS["truth"], lw=1.6, label="truth", zorder=5
        )
        _end_of_data(ax, t_data_end)
        if t_data_end is not None:
            handles.append(
                Line2D([], [], color=COLORS["end_of_data"], ls="--", label="end of data")
            )
        samples = [c.samples for c in curves if c.samples is not None]
        lim = _energy_limits(truth.values, *(c.values for c in curves), *samples)
        if lim is not None:
            ax.set_ylim(lim)
        ax.set_title(title, loc="left", fontsize=10)
        ax.set_ylabel("H(q, p)")
        ax.grid(alpha=0.25)
        _compact(ax, "y")
        ax.legend(handles=handles, loc="best", fontsize=8, ncol=3, framealpha=0.9)
    axes[-1].set_xlabel("t [s]")
    axes[-1].set_xlim(_span(list(fine) + list(coarse), (truth.times, truth.values)))
    return _finish(fig, path)


# ---------------------------------------------------------------------------- Fig. 3
def plot_trajectory_bands(
    approaches: Sequence[Curves],
    truth: tuple[np.ndarray, np.ndarray] | None = None,
    data: tuple[np.ndarray, np.ndarray] | None = None,
    *,
    t_data_end: float | None = None,
    ylabel: str = "q1",
    band_label: str = "2.5–97.5 % band",
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
    fig = _new_figure(9.0, 2.9 * n + 0.4)
    axes = fig.subplots(n, 1, sharex=True, sharey=True, squeeze=False)[:, 0]
    ref = truth[1] if truth is not None else approaches[0].values
    lim = _robust_limits(
        ref, *(a.values for a in approaches), *(a.lower for a in approaches),
        *(a.upper for a in approaches), clip=1.5, pad=0.05,
    )
    for k, (ax, a) in enumerate(zip(axes, approaches, strict=True)):
        color = a.color or _color_for(a.label, k)
        handles = []
        if a.lower is not None:
            ax.fill_between(a.sample_times, a.lower, a.upper, color=color, alpha=0.22, lw=0,
                            zorder=1)
            handles.append(Patch(color=color, alpha=0.3, label=band_label))
        if a.samples is not None:
            _sample_lines(ax, a.sample_times, a.samples, color, lw=0.4, alpha=0.15)
            handles.append(Line2D([], [], color=color, lw=0.8, alpha=0.5,
                                  label=f"{a.samples.shape[0]} posterior samples"))
        handles += ax.plot(a.times, a.values, color=color, lw=1.5, label="MAP", zorder=4)
        if truth is not None:
            handles += ax.plot(*truth, color=COLORS["truth"], lw=1.2, label="truth", zorder=3)
        if data is not None:
            handles += ax.plot(*data, "o", ms=4.5, color=COLORS["data"], label="data", zorder=5)
        _end_of_data(ax, t_data_end)
        if t_data_end is not None:
            handles.append(
                Line2D([], [], color=COLORS["end_of_data"], ls="--", label="end of data")
            )
        ax.set_title(a.label, loc="left", fontsize=10, fontweight="bold")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.25)
        if lim is not None:
            ax.set_ylim(lim)
        _legend_above(ax, handles, ncol=len(handles), fontsize=7.5)
    axes[-1].set_xlabel("t [s]")
    axes[-1].set_xlim(_span(approaches, truth))
    return _finish(fig, path)


def _span(approaches: Sequence[Curves], truth) -> tuple[float, float]:
    times = [a.times for a in approaches] + ([np.asarray(truth[0])] if truth is not None else [])
    return min(float(t.min()) for t in times), max(float(t.max()) for t in times)


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
    fig = _new_figure(7.0, 2.2 * n + 0.5)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for k, (ax, (label, v)) in enumerate(zip(axes, values.items(), strict=True)):
        color = (colors or {}).get(label) or _color_for(label, k)
        ax.hist(v[v > 0] if log else v, bins=edges, color=color, alpha=0.75, edgecolor="white",
                lw=0.4, label=f"{label} ({v.size} draws)")
        med = float(np.median(v))
        ax.axvline(med, color="black", lw=1.2, label=f"median {med:.3g}")
        if map_values and label in map_values:
            ax.axvline(map_values[label], color="black", lw=1.2, ls="--",
                       label=f"MAP {map_values[label]:.3g}")
        ax.set_ylabel("draws")
        ax.set_title(label, loc="left", fontsize=10)
        ax.legend(fontsize=8, loc="upper right")
        ax.grid(alpha=0.25)
        if log:
            ax.set_xscale("log")
    axes[-1].set_xlabel(xlabel)
    return _finish(fig, path)


# ---------------------------------------------------------------------------- chains
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


def plot_traces(
    draws: Any,
    names: Sequence[str] | None = None,
    *,
    params: Sequence[str | int] | None = None,
    max_params: int = 16,
    path: str | Path | None = None,
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
        Names or indices to draw (default: the first ``max_params``).

    Returns
    -------
    Figure with two axes per parameter (trace, histogram).
    """
    arr, labels = _select(*_as_draws(draws, names), params, max_params)
    p = arr.shape[2]
    fig = _new_figure(10.0, 1.55 * p + 0.5)
    axes = fig.subplots(p, 2, squeeze=False, width_ratios=(3, 1))
    iters = np.arange(arr.shape[1])
    for k in range(p):
        ax_t, ax_h = axes[k]
        col = arr[:, :, k]
        finite = col[np.isfinite(col)]
        edges = np.histogram_bin_edges(finite if finite.size else [0.0, 1.0], bins=40)
        for c in range(arr.shape[0]):
            color = _CYCLE[c % len(_CYCLE)]
            ax_t.plot(iters, col[c], lw=0.4, alpha=0.8, color=color,
                      label=f"chain {c}" if k == 0 else None)
            ax_h.hist(col[c][np.isfinite(col[c])], bins=edges, histtype="step", color=color,
                      lw=1.0)
        ax_t.set_ylabel(labels[k], fontsize=9)
        ax_t.grid(alpha=0.25)
        ax_h.set_yticks([])
        ax_h.xaxis.set_major_locator(MaxNLocator(3))
        ax_h.tick_params(axis="x", labelsize=7)
        ax_t.tick_params(labelsize=7)
        _compact(ax_t, "y")
        _compact(ax_h, "x")
        if k < p - 1:
            ax_t.set_xticklabels([])
    axes[0, 0].set_title("trace", fontsize=10, loc="left")
    axes[0, 1].set_title("marginal per chain", fontsize=10)
    axes[-1, 0].set_xlabel("draw")
    if arr.shape[0] > 1:
        _legend_above(axes[0, 0], ncol=min(arr.shape[0], 8), fontsize=7.5)
    return _finish(fig, path)


def plot_pair(
    draws: Any,
    names: Sequence[str] | None = None,
    *,
    params: Sequence[str | int] | None = None,
    max_params: int = 6,
    max_points: int = 3000,
    reference: Mapping[str, float] | Sequence[float] | None = None,
    seed: int = 0,
    path: str | Path | None = None,
) -> Figure:
    """Corner plot: pairwise scatter below the diagonal, marginal histograms on it.

    Parameters
    ----------
    draws, names
        As in :func:`plot_traces` (chains are pooled).
    params
        Names or indices (default: the first ``max_params``).
    max_points
        Scatter at most this many draws (a seeded random subset).
    reference
        Optional values to mark (e.g. the truth or the MAP), by name or in the order of
        ``params``.

    Returns
    -------
    Figure with k(k+1)/2 axes for k parameters.
    """
    arr, labels = _select(*_as_draws(draws, names), params, max_params)
    flat = arr.reshape(-1, arr.shape[2])
    flat = flat[np.all(np.isfinite(flat), axis=1)]
    if flat.shape[0] == 0:
        raise ValueError("no finite draws to plot")
    if flat.shape[0] > max_points:
        flat_s = flat[np.random.default_rng(seed).choice(flat.shape[0], max_points, replace=False)]
    else:
        flat_s = flat
    ref = None
    if reference is not None:
        if isinstance(reference, Mapping):
            ref = [reference.get(n) for n in labels]
        else:
            ref = list(reference)
            if len(ref) != len(labels):
                raise ValueError(f"reference has {len(ref)} values for {len(labels)} parameters")
    k = len(labels)
    fig = _new_figure(1.9 * k + 0.8, 1.9 * k + 0.6)
    grid = fig.add_gridspec(k, k)
    axes: dict[tuple[int, int], Any] = {}
    for i in range(k):
        for j in range(i + 1):
            share_x = axes.get((k - 1, j)) if i != k - 1 else None
            ax = fig.add_subplot(grid[i, j], sharex=axes.get((j, j)) if j < i else share_x)
            axes[i, j] = ax
            if i == j:
                ax.hist(flat[:, i], bins=40, color=COLORS["leapfrog"], alpha=0.75)
                ax.set_yticks([])
                if ref is not None and ref[i] is not None:
                    ax.axvline(ref[i], color=COLORS["truth"], lw=1.2)
            else:
                ax.plot(flat_s[:, j], flat_s[:, i], ".", ms=1.5, alpha=0.35,
                        color=COLORS["leapfrog"])
                if ref is not None and ref[i] is not None and ref[j] is not None:
                    ax.plot(ref[j], ref[i], "s", color=COLORS["truth"], ms=5)
            ax.tick_params(labelsize=6.5)
            ax.xaxis.set_major_locator(MaxNLocator(3))
            _compact(ax, "x" if i == j else "both")
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
    return _finish(fig, path)


# ---------------------------------------------------------------------------- user data
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
    data_cols: dict[int, int] = {}
    if data is not None:
        d_times, d_values = _as_xy(data)
        data_names = getattr(data, "names", None)
        if data_names:
            for col, name in enumerate(data_names):
                if name in state_names:
                    data_cols[state_names.index(name)] = col
        else:  # full state or positions, in order
            data_cols = {c: c for c in range(min(d_values.shape[1], dim2))}
        if t_data_end is None:
            t_data_end = float(d_times[-1])
    if components is None:
        components = sorted(data_cols) if data_cols else list(range(dim2))
    components = list(components)
    if not components:
        raise ValueError("no component to draw")
    levels = tuple(predictive.quantile_levels)
    band = f"{100 * levels[0]:g}–{100 * levels[-1]:g} % band"
    fig = _new_figure(9.0, 2.2 * len(components) + 0.5)
    axes = fig.subplots(len(components), 1, sharex=True, squeeze=False)[:, 0]
    paths = np.asarray(predictive.paths)[:max_samples]
    for ax, c in zip(axes, components, strict=True):
        ax.fill_between(times, predictive.quantiles[0][:, c], predictive.quantiles[-1][:, c],
                        color=color, alpha=0.22, lw=0, label=band)
        if paths.shape[0]:
            _sample_lines(ax, times, paths[:, :, c], color, lw=0.4, alpha=0.15)
        ax.plot(times, predictive.median[:, c], color=color, lw=1.0, ls=":", label="median")
        if map_path is not None:
            ax.plot(map_path[0], np.asarray(map_path[1])[:, c], color=color, lw=1.5, label="MAP")
        if truth is not None:
            ax.plot(truth[0], np.asarray(truth[1])[:, c], color=COLORS["truth"], lw=1.2,
                    label="truth")
        if c in data_cols:
            ax.plot(d_times, d_values[:, data_cols[c]], "o", ms=4, color=COLORS["data"],
                    label="data")
        _end_of_data(ax, t_data_end)
        ax.set_ylabel(state_names[c])
        ax.grid(alpha=0.25)
        lim = _robust_limits(
            predictive.median[:, c], predictive.quantiles[0][:, c],
            predictive.quantiles[-1][:, c],
            None if c not in data_cols else d_values[:, data_cols[c]],
            clip=3.0,
        )
        if lim is not None:
            ax.set_ylim(lim)
    handles, _ = axes[0].get_legend_handles_labels()
    _legend_above(axes[0], handles, ncol=len(handles), fontsize=7.5)
    axes[-1].set_xlabel("t [s]")
    starts = [times[0]] + ([d_times[0]] if data_cols else [])
    axes[-1].set_xlim(min(starts), times[-1])
    return _finish(fig, path)
