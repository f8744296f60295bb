"""How the figures are drawn cheaply without changing what they show.

* a trace line keeps every run's range (:func:`envelope_indices`), checked against the
  runs' minima and maxima computed directly;
* the histograms are drawn as one step patch each, with the counts of every draw
  (``np.histogram`` of the full chains);
* the tick labels are those of the per-label formula they replace;
* a PNG drawn once (:func:`write_figure`) has the pixels of matplotlib's ``savefig``.
"""

from __future__ import annotations

import io

import matplotlib
import numpy as np
import pytest
from matplotlib.patches import StepPatch
from PIL import Image

from symplid.plotting import plot_pair, plot_traces
from symplid.plotting._diagnostics import envelope_indices
from symplid.plotting._style import CompactFormatter, new_figure, write_figure


def spiky_chain(n: int, seed: int) -> np.ndarray:
    """A random walk with a few lone spikes, the excursions an even thinning would drop."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.standard_normal(n)) * 0.05 + rng.standard_normal(n)
    x[np.linspace(0.1 * n, 0.9 * n, 5).astype(int) + 3] += [40.0, -40.0, 40.0, 40.0, -40.0]
    return x


@pytest.mark.parametrize("n, most", [(9000, 2000), (10_001, 2000), (5000, 37), (2001, 2000)])
def test_envelope_keeps_every_runs_range(n, most):
    x = spiky_chain(n, seed=n)
    kept = envelope_indices(x, most)
    assert kept.size <= most
    assert np.all(np.diff(kept) > 0) and kept[0] == 0 and kept[-1] == n - 1
    # each of the equal runs the indices were chosen from: its min and max are kept
    runs = -(-n // ((most - 2) // 2))
    for start in range(0, n, runs):
        run = x[start:start + runs]
        inside = x[kept[(kept >= start) & (kept < start + runs)]]
        assert inside.min() == run.min() and inside.max() == run.max()
    # every spike is on the line; an even thinning to as many points would miss some
    spikes = np.flatnonzero(np.abs(x) > 20)
    assert set(spikes) <= set(kept)
    if n >= 2 * most:
        even = np.linspace(0, n - 1, kept.size).round().astype(int)
        assert not set(spikes) <= set(even)


def test_envelope_keeps_everything_when_short_or_not_finite():
    np.testing.assert_array_equal(envelope_indices(np.arange(50.0), 100), np.arange(50))
    x = spiky_chain(5000, 1)
    x[10] = np.nan
    np.testing.assert_array_equal(envelope_indices(x, 100), np.arange(5000))
    with pytest.raises(ValueError, match="≥ 4"):
        envelope_indices(x, 3)


def test_traces_of_long_chains():
    chains = np.stack([np.stack([spiky_chain(9000, 10 * c + k) for k in range(2)], axis=-1)
                       for c in range(3)])  # (3 chains, 9000 draws, 2 parameters)
    fig = plot_traces(chains, ["a", "b"], max_points=2000)
    axes = fig.get_axes()
    for k, (ax_t, ax_h) in enumerate(zip(axes[0::2], axes[1::2], strict=True)):
        lines = ax_t.get_lines()
        assert len(lines) == 3
        for c, line in enumerate(lines):
            x, y = line.get_xdata(), line.get_ydata()
            assert len(x) <= 2000
            assert (x[0], x[-1]) == (0, 8999)
            assert (y.min(), y.max()) == (chains[c, :, k].min(), chains[c, :, k].max())
            np.testing.assert_array_equal(y, chains[c, x, k])
        # the histograms count every draw, in common bins over all chains
        steps = [p for p in ax_h.patches if isinstance(p, StepPatch)]
        assert len(steps) == 3
        edges = np.histogram_bin_edges(chains[:, :, k], bins=40)
        for c, step in enumerate(steps):
            values, step_edges, _ = step.get_data()
            np.testing.assert_array_equal(step_edges, edges)
            np.testing.assert_array_equal(values, np.histogram(chains[c, :, k], edges)[0])
    # the axes still span every draw and every value
    assert axes[0].get_xlim()[0] < 0 and axes[0].get_xlim()[1] > 8999
    low, high = axes[0].get_ylim()
    assert low < chains[:, :, 0].min() and high > chains[:, :, 0].max()


def test_pair_diagonal_counts_every_draw():
    rng = np.random.default_rng(4)
    draws = rng.standard_normal((4, 2000, 3)) * [1.0, 3.0, 0.1]
    fig = plot_pair(draws, ["a", "b", "c"], max_points=500)
    diagonal = [ax for ax in fig.get_axes() if ax.patches]
    assert len(diagonal) == 3
    flat = draws.reshape(-1, 3)
    for i, ax in enumerate(diagonal):
        (step,) = ax.patches
        values, edges, _ = step.get_data()
        counts, expected_edges = np.histogram(flat[:, i], bins=40)
        np.testing.assert_array_equal(values, counts)
        np.testing.assert_allclose(edges, expected_edges)
        assert step.get_fill()


def reference_label(x: float, ticks: list[float]) -> str:
    """The tick label as it was computed, label by label, before the digits were cached."""
    locs = np.asarray([v for v in ticks if np.isfinite(v)], dtype=float)
    if locs.size < 2:
        return f"{x:.3g}"
    step = float(np.min(np.abs(np.diff(np.sort(locs))))) or 1.0
    scale = float(np.max(np.abs(locs)))
    if abs(x) < 1e-9 * step:
        return "0"
    digits = int(min(max(np.ceil(np.log10(max(scale / step, 1.0))) + 2, 2), 10))
    return f"{x:.{digits}g}"


def test_compact_formatter_labels_unchanged():
    rng = np.random.default_rng(5)
    formatter = CompactFormatter()
    assert formatter(0.123456) == "0.123"  # no ticks set yet
    cases = [[0.0, 2.5e-6, 5e-6], [0.1212, 0.12125, 0.1213], [1e-20, 1.0, 2.0], [3.0],
             [np.nan, 1.0, 2.0], [-1e9, 0.0, 1e9]]
    cases += [list(np.sort(rng.normal(size=rng.integers(2, 8)) * 10.0 ** rng.integers(-8, 8)))
              for _ in range(200)]
    for ticks in cases:
        formatter.set_locs(ticks)
        for x in [*ticks, 0.0, 1e-30, 7.77]:
            assert formatter(x) == reference_label(x, ticks), (x, ticks)


def pixels(buffer: io.BytesIO) -> np.ndarray:
    buffer.seek(0)
    return np.asarray(Image.open(buffer).convert("RGBA"))


def test_write_figure_has_savefigs_pixels():
    rng = np.random.default_rng(6)
    chains = rng.standard_normal((2, 300, 3))
    for fig in (plot_traces(chains), plot_pair(chains, ["a", "b", "c"]), new_figure(3, 2)):
        fig.set_facecolor("0.8")  # a colour of its own: the PNG is white all the same
        ours, theirs = io.BytesIO(), io.BytesIO()
        write_figure(fig, ours)
        fig.savefig(theirs, format="png", dpi=fig.dpi, facecolor="white")
        np.testing.assert_array_equal(pixels(ours), pixels(theirs))
        assert fig.get_facecolor() == (0.8, 0.8, 0.8, 1.0)
        assert fig.get_layout_engine() is not None  # the figure is left as it was
    # another dpi or format: matplotlib's own way
    fig = plot_traces(chains)
    other, theirs = io.BytesIO(), io.BytesIO()
    write_figure(fig, other, dpi=50)
    fig.savefig(theirs, format="png", dpi=50, facecolor="white")
    np.testing.assert_array_equal(pixels(other), pixels(theirs))
    svg = io.BytesIO()
    write_figure(fig, svg, fmt="svg")
    assert svg.getvalue().lstrip().startswith(b"<?xml")
    # a matplotlibrc asking savefig for a tight box is honoured, as savefig would
    with matplotlib.rc_context({"savefig.bbox": "tight"}):
        tight, theirs = io.BytesIO(), io.BytesIO()
        write_figure(fig, tight)
        fig.savefig(theirs, format="png", dpi=fig.dpi, facecolor="white")
    np.testing.assert_array_equal(pixels(tight), pixels(theirs))
