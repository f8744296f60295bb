"""The figures' common style: colours, the Agg canvas, axis limits, tick labels, legends.

Figures are built without :mod:`matplotlib.pyplot` (no global state, no window, nothing to
close) and saved through the Agg canvas, so they work the same on a headless machine, in a
notebook and in threads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.ticker import Formatter

__all__ = [
    "COLORS",
    "CYCLE",
    "DPI",
    "Curves",
    "as_xy",
    "color_for",
    "compact_ticks",
    "energy_limits",
    "finish",
    "legend_above",
    "mark_end_of_data",
    "new_figure",
    "robust_limits",
    "sample_lines",
    "save_figure",
    "time_span",
    "write_figure",
]

#: Colours shared by the figures (the paper's: blue for leapfrog, red for RK2, green truth).
COLORS = {
    "leapfrog": "#1f5fa8",
    "rk2": "#c0392b",
    "truth": "#2ca02c",
    "data": "black",
    "end_of_data": "#d62fc4",
}
#: Colours of curves whose label names no integrator (chains, extra approaches), in turn.
CYCLE = ("#1f5fa8", "#c0392b", "#7b3fa0", "#d98a00", "#16867f", "#6b6b6b")
DPI = 100


@dataclass(frozen=True)
class Curves:
    """One approach's curves against time, for :func:`~symplid.plotting.plot_hamiltonians` and
    :func:`~symplid.plotting.plot_trajectory_bands`.

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
        return self.color or color_for(self.label, 0)


# ---------------------------------------------------------------------------- helpers
def color_for(label: str, index: int) -> str:
    key = label.lower()
    if "leapfrog" in key or ("symplectic" in key and "non" not in key):
        return COLORS["leapfrog"]
    if "rk2" in key or "runge" in key or "non-symplectic" in key:
        return COLORS["rk2"]
    return CYCLE[index % len(CYCLE)]


def new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def save_figure(fig: Figure, path: str | Path, dpi: int = DPI) -> Path:
    """Write ``fig`` as a PNG (Agg canvas; the folder is created) and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_figure(fig, path, path.suffix.lstrip(".") or "png", dpi)
    return path


def write_figure(fig: Figure, target: Any, fmt: str = "png", dpi: int = DPI) -> None:
    """``fig.savefig(target, format=fmt, dpi=dpi, facecolor="white")`` on the Agg canvas,
    drawn once.

    ``savefig`` draws a figure with a layout engine twice: once without output, to run the
    layout, and once to render. A PNG at the figure's own dpi is rendered here by the canvas
    in one draw, which runs the same layout with the same renderer first: the same pixels
    without the output-less draw (a fifth to a third of saving the trace and pair plots).
    Other formats and dpis, and a matplotlibrc that asks ``savefig`` for a tight or
    transparent image, take ``savefig``.
    """
    canvas = FigureCanvasAgg(fig)
    plain = rcParams["savefig.bbox"] in (None, "standard") and not rcParams["savefig.transparent"]
    if fmt != "png" or dpi != fig.dpi or not plain:
        fig.savefig(target, format=fmt, dpi=dpi, facecolor="white")
        return
    face = fig.get_facecolor()
    fig.set_facecolor("white")
    try:
        canvas.print_png(target)
    finally:
        fig.set_facecolor(face)


def finish(fig: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        save_figure(fig, path)
    return fig


def mark_end_of_data(ax, t_data_end: float | None, label: bool = True) -> None:
    if t_data_end is not None:
        ax.axvline(
            t_data_end, color=COLORS["end_of_data"], lw=1.2, ls="--",
            label="end of data" if label else None, zorder=1,
        )


def robust_limits(*arrays: np.ndarray, pad: float = 0.08, clip: float | None = None):
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


def energy_limits(truth: np.ndarray, *arrays: np.ndarray, pad: float = 0.08):
    """Limits for energy curves: every value within a window around the true energy.

    A model integrated past its escape energy runs off to ±∞; values further than twice the
    true energy's scale from it are left out of the limits (the curve leaves the axes).
    """
    ref = np.asarray(truth, dtype=float)
    ref = ref[np.isfinite(ref)]
    if ref.size == 0:
        return robust_limits(*arrays, pad=pad)
    scale = max(float(np.abs(ref).max()), float(np.ptp(ref)), 1e-12)
    lo_w, hi_w = ref.min() - 2.0 * scale, ref.max() + 2.0 * scale
    kept = [ref]
    for a in arrays:
        a = np.asarray(a, dtype=float)
        kept.append(a[np.isfinite(a) & (a >= lo_w) & (a <= hi_w)])
    return robust_limits(*kept, pad=pad)


class CompactFormatter(Formatter):
    """Tick labels with just enough significant digits to tell neighbouring ticks apart
    (``2.5e-06``, ``0.12125``), and no offset text to collide with axis labels.

    The digits depend on the ticks alone; they are worked out once per set of ticks
    (:meth:`set_locs`), not once per label."""

    _ticks: tuple[float, ...] = ()
    _step: float = 1.0
    _digits: int | None = None  # None: fewer than two finite ticks, "%.3g"

    def set_locs(self, locs) -> None:
        self._ticks = tuple(float(v) for v in locs)
        finite = np.asarray([v for v in self._ticks if np.isfinite(v)], dtype=float)
        if finite.size < 2:
            self._digits = None
            return
        self._step = float(np.min(np.abs(np.diff(np.sort(finite))))) or 1.0
        scale = float(np.max(np.abs(finite)))
        self._digits = int(min(max(np.ceil(np.log10(max(scale / self._step, 1.0))) + 2, 2),
                               10))

    def __call__(self, x: float, pos: int | None = None) -> str:
        if self._digits is None:
            return f"{x:.3g}"
        if abs(x) < 1e-9 * self._step:
            return "0"
        return f"{x:.{self._digits}g}"


def compact_ticks(ax, axis: str = "both") -> None:
    """Use :class:`CompactFormatter` on the x and/or y axis."""
    if axis in ("x", "both"):
        ax.xaxis.set_major_formatter(CompactFormatter())
    if axis in ("y", "both"):
        ax.yaxis.set_major_formatter(CompactFormatter())


def legend_above(ax, handles=None, ncol: int = 6, fontsize: float = 8) -> None:
    """Legend in one row above the axes, right-aligned (the title sits on the left)."""
    kwargs = {} if handles is None else {"handles": handles}
    ax.legend(
        **kwargs, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=ncol, fontsize=fontsize,
        frameon=False, borderaxespad=0.2, handlelength=1.6, columnspacing=1.2,
    )


def sample_lines(ax, times: np.ndarray, samples: np.ndarray, color, lw: float, alpha: float):
    """Many sample curves as one :class:`~matplotlib.collections.LineCollection` (one artist
    draws hundreds of curves far faster than as many lines). Non-finite points are gaps."""
    samples = np.where(np.isfinite(samples), samples, np.nan)
    segments = np.stack([np.broadcast_to(times, samples.shape), samples], axis=-1)
    lines = LineCollection(segments, colors=color, linewidths=lw, alpha=alpha, zorder=2)
    ax.add_collection(lines, autolim=True)
    ax.autoscale_view()
    return lines


def as_xy(data: Any) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) from an Observations-like object or a (times, values) pair."""
    if hasattr(data, "times") and hasattr(data, "values"):
        return np.asarray(data.times, dtype=float), np.asarray(data.values, dtype=float)
    times, values = data
    values = np.asarray(values, dtype=float)
    return np.asarray(times, dtype=float), values[:, None] if values.ndim == 1 else values


def time_span(approaches: Sequence[Curves], truth) -> tuple[float, float]:
    """The time range covered by the approaches' main curves and the truth's ``(times, ...)``."""
    times = [a.times for a in approaches] + ([np.asarray(truth[0])] if truth is not None else [])
    return min(float(t.min()) for t in times), max(float(t.max()) for t in times)
