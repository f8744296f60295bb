"""Tests of symplid.plotting: each figure draws what it should (axes, lines, bands) and saves a PNG.

The inputs are small synthetic arrays; the checks read the Figure's artists back.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure

import symplid
from symplid.inference._predict import PosteriorPredictive
from symplid.plotting import (
    COLORS,
    Curves,
    plot_hamiltonians,
    plot_pair,
    plot_phase_portraits,
    plot_predictive,
    plot_process_noise,
    plot_traces,
    plot_trajectory_bands,
    save_figure,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def assert_png(path, min_bytes: int = 5000) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > min_bytes


def sample_collections(ax) -> list[LineCollection]:
    return [c for c in ax.collections if isinstance(c, LineCollection)]


def legend_texts(ax) -> list[str]:
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


@pytest.fixture(scope="module")
def t():
    return np.linspace(0.0, 20.0, 201)


@pytest.fixture(scope="module")
def orbit(t):
    return np.column_stack([np.cos(t), np.sin(1.3 * t), -np.sin(t), 1.3 * np.cos(1.3 * t)])


def test_phase_portraits(tmp_path, orbit):
    path = tmp_path / "fig1.png"
    fig = plot_phase_portraits(
        {"learned with leapfrog": orbit * 1.01, "learned with RK2": orbit * 0.98},
        orbit,
        orbit[::20, :2] + 0.05,
        path=path,
    )
    assert isinstance(fig, Figure)
    assert_png(path)
    axes = fig.get_axes()
    assert [ax.get_title() for ax in axes] == [
        "learned with leapfrog", "learned with RK2", "truth", "noisy position data"
    ]
    assert all(len(ax.get_lines()) == 1 for ax in axes)
    lines = [ax.get_lines()[0] for ax in axes]
    assert [ln.get_color() for ln in lines[1:3]] == [COLORS["rk2"], COLORS["truth"]]
    np.testing.assert_allclose(lines[2].get_xdata(), orbit[:, 0])
    np.testing.assert_allclose(lines[2].get_ydata(), orbit[:, 1])
    assert lines[3].get_linestyle() == "None" and lines[3].get_marker() == "o"
    assert len(lines[3].get_xdata()) == 11
    assert len({ax.get_xlim() for ax in axes}) == 1  # one scale for every panel
    # without data: three panels, the empty fourth slot removed
    fig = plot_phase_portraits({"a": orbit}, orbit)
    assert len(fig.get_axes()) == 2


def test_phase_portraits_keep_the_truth_in_view_when_a_model_escapes(orbit):
    escaped = orbit.copy()
    escaped[-5:] = 1e6
    fig = plot_phase_portraits({"escaped": escaped}, orbit)
    lo, hi = fig.get_axes()[0].get_xlim()
    assert -3.0 < lo < -1.0 and 1.0 < hi < 3.0


def test_hamiltonians(tmp_path, t):
    rng = np.random.default_rng(0)
    h_true = np.full_like(t, 0.1227)
    fine = [
        Curves("leapfrog", t, h_true - 0.0008, samples=0.1219 + 1e-4 * rng.standard_normal((5, 21)),
               sample_times=t[::10]),
        Curves("rk2", t, h_true - 0.0016, samples=0.1211 + 3e-4 * rng.standard_normal((5, 21)),
               sample_times=t[::10]),
    ]
    fine[1].samples[0, -1] = np.inf  # a diverged sample is a gap, not a crash
    growth = 0.1211 + 0.001 * t
    growth[-3:] = -1e200  # escaped: must not flatten the panel
    coarse = [Curves("rk2 by RK2, Δt = 0.25", t, growth, color=COLORS["rk2"])]
    path = tmp_path / "fig2.png"
    fig = plot_hamiltonians(fine, (t, h_true), coarse, t_data_end=10.0, path=path)
    assert_png(path)
    ax_a, ax_b = fig.get_axes()
    # (a): 2 MAPs, truth, end-of-data line; 5 samples per approach as one collection each
    assert len(ax_a.get_lines()) == 4
    samples = sample_collections(ax_a)
    assert [len(c.get_segments()) for c in samples] == [5, 5]
    np.testing.assert_allclose(samples[1].get_segments()[2][:, 1], fine[1].samples[2])
    np.testing.assert_allclose(samples[1].get_segments()[2][:, 0], t[::10])
    assert np.isnan(samples[1].get_paths()[0].vertices[-1, 1])
    assert {"leapfrog MAP", "rk2 MAP", "truth", "end of data", "leapfrog samples"} <= set(
        legend_texts(ax_a)
    )
    truth_lines = [ln for ln in ax_a.get_lines() if ln.get_label() == "truth"]
    assert truth_lines[0].get_color() == COLORS["truth"]
    vlines = [ln for ln in ax_a.get_lines() if ln.get_label() == "end of data"]
    np.testing.assert_allclose(vlines[0].get_xdata(), [10.0, 10.0])
    lo, hi = ax_a.get_ylim()
    assert lo < 0.1205 and 0.1227 < hi < 0.125
    # (b): the growing curve, truth, end of data; limits ignore the escaped values
    assert len(ax_b.get_lines()) == 3
    lo, hi = ax_b.get_ylim()
    assert 0.1 < lo < 0.1211 and 0.141 < hi < 0.16
    assert ax_b.get_xlabel() == "t [s]"
    # without panel (b)
    assert len(plot_hamiltonians(fine, (t, h_true)).get_axes()) == 1


def test_trajectory_bands(tmp_path, t, orbit):
    ts = t[::5]
    approaches = []
    for label, scale in (("leapfrog", 1.0), ("rk2", 1.05)):
        samples = orbit[::5, 0] * scale + 0.02 * np.arange(4)[:, None]
        approaches.append(
            Curves(label, t, orbit[:, 0] * scale, samples=samples, sample_times=ts,
                   lower=samples.min(axis=0), upper=samples.max(axis=0))
        )
    path = tmp_path / "fig3.png"
    fig = plot_trajectory_bands(
        approaches, (t, orbit[:, 0]), (t[10:101:10], orbit[10:101:10, 0]), t_data_end=10.0,
        path=path,
    )
    assert_png(path)
    axes = fig.get_axes()
    assert len(axes) == 2 and axes[-1].get_xlabel() == "t [s]"
    for ax, a in zip(axes, approaches, strict=True):
        # MAP + truth + data + end-of-data line, 4 samples in one collection, one band
        assert len(ax.get_lines()) == 4
        assert [len(c.get_segments()) for c in sample_collections(ax)] == [4]
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(bands) == 1
        texts = legend_texts(ax)
        assert {"MAP", "truth", "data", "end of data", "2.5–97.5 % band"} <= set(texts)
        map_line = next(ln for ln in ax.get_lines() if ln.get_label() == "MAP")
        np.testing.assert_allclose(map_line.get_ydata(), a.values)
    assert axes[0].get_ylim() == axes[1].get_ylim()
    assert axes[0].get_xlim() == (0.0, 20.0)


def test_process_noise(tmp_path):
    rng = np.random.default_rng(1)
    samples = {
        "leapfrog": np.exp(rng.normal(np.log(1e-6), 0.4, (2, 300))),
        "rk2": np.exp(rng.normal(np.log(1e-5), 0.4, 600)),
    }
    path = tmp_path / "fig4.png"
    fig = plot_process_noise(samples, {"leapfrog": 1e-6, "rk2": 1.1e-5}, bins=30, path=path)
    assert_png(path)
    axes = fig.get_axes()
    assert len(axes) == 2
    for ax, v in zip(axes, samples.values(), strict=True):
        assert ax.get_xscale() == "log"
        assert len(ax.patches) == 30
        assert sum(p.get_height() for p in ax.patches) == np.size(v)
        assert len(ax.get_lines()) == 2  # median and MAP
        assert any(t.startswith("median") for t in legend_texts(ax))
    assert axes[0].get_xlim() == axes[1].get_xlim()
    with pytest.raises(ValueError, match="positive"):
        plot_process_noise({"a": -np.ones(5)})
    lin = plot_process_noise({"a": np.linspace(-1, 1, 50)}, log=False, bins=10)
    assert lin.get_axes()[0].get_xscale() == "linear"


@pytest.fixture(scope="module")
def chains():
    rng = np.random.default_rng(2)
    return rng.standard_normal((2, 50, 3)) * [1.0, 1e-6, 10.0] + [0.0, 2e-6, 5.0]


def test_traces(tmp_path, chains):
    path = tmp_path / "traces.png"
    fig = plot_traces(chains, ["a", "b", "c"], path=path)
    assert_png(path)
    axes = fig.get_axes()
    assert len(axes) == 6
    trace_axes, hist_axes = axes[0::2], axes[1::2]
    assert [ax.get_ylabel() for ax in trace_axes] == ["a", "b", "c"]
    for k, ax in enumerate(trace_axes):
        assert len(ax.get_lines()) == 2  # one per chain
        np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), chains[1, :, k])
    assert all(len(ax.patches) == 2 for ax in hist_axes)  # one step histogram per chain
    assert legend_texts(trace_axes[0]) == ["chain 0", "chain 1"]
    # a mapping (and a subset by name)
    fig = plot_traces({"x": chains[..., 0], "v": chains[..., 1:]}, params=["v[1]"])
    assert [ax.get_ylabel() for ax in fig.get_axes()[0::2]] == ["v[1]"]


def test_traces_from_inference_data(chains):
    az = pytest.importorskip("arviz")
    idata = az.from_dict(posterior={"theta": chains, "sigma": chains[..., 0] ** 2})
    fig = plot_traces(idata)
    assert [ax.get_ylabel() for ax in fig.get_axes()[0::2]] == [
        "theta[0]", "theta[1]", "theta[2]", "sigma"
    ]


def test_pair(tmp_path, chains):
    path = tmp_path / "pair.png"
    fig = plot_pair(chains, ["a", "b", "c"], reference={"a": 0.0, "c": 5.0}, max_points=60,
                    path=path)
    assert_png(path)
    axes = fig.get_axes()
    assert len(axes) == 6  # 3 histograms + 3 scatter panels
    diag = [ax for ax in axes if ax.patches]
    assert len(diag) == 3
    scatter = [ax for ax in axes if not ax.patches]
    points = [ln for ax in scatter for ln in ax.get_lines() if ln.get_marker() == "."]
    assert len(points) == 3 and all(len(p.get_xdata()) == 60 for p in points)
    # the (a, c) panel marks the reference; panels involving b do not
    marks = [ln for ax in scatter for ln in ax.get_lines() if ln.get_marker() == "s"]
    assert len(marks) == 1
    np.testing.assert_allclose([marks[0].get_xdata()[0], marks[0].get_ydata()[0]], [0.0, 5.0])
    with pytest.raises(ValueError, match="unknown parameter"):
        plot_pair(chains, ["a", "b", "c"], params=["d"])


def fake_predictive(t: np.ndarray, orbit: np.ndarray) -> PosteriorPredictive:
    paths = orbit[None] + 0.01 * np.arange(-2, 3)[:, None, None]
    return PosteriorPredictive(
        times=t, quantile_levels=(0.025, 0.975),
        quantiles=np.stack([paths.min(axis=0), paths.max(axis=0)]), median=orbit,
        paths=paths, path_indices=np.arange(5), finite_fraction=np.ones(t.shape[0]),
        num_draws=5, dt=0.1, every=1, integrator="leapfrog", seed=0,
    )


def test_predictive(tmp_path, t, orbit):
    pred = fake_predictive(t, orbit)
    data = symplid.Observations(t[10:101:10], orbit[10:101:10][:, [0, 2]], ("q1", "p1"))
    path = tmp_path / "predictive.png"
    fig = plot_predictive(pred, data, map_path=(t, orbit), truth=(t, orbit), path=path)
    assert_png(path)
    axes = fig.get_axes()
    assert [ax.get_ylabel() for ax in axes] == ["q1", "p1"]  # the observed components
    for ax, col in zip(axes, (0, 2), strict=True):
        # median, MAP, truth, data, end-of-data line; 5 sample paths; one band
        assert len(ax.get_lines()) == 5
        segments = sample_collections(ax)[0].get_segments()
        assert len(segments) == 5
        np.testing.assert_allclose(segments[4][:, 1], pred.paths[4, :, col])
        assert len([c for c in ax.collections if isinstance(c, PolyCollection)]) == 1
        data_line = next(ln for ln in ax.get_lines() if ln.get_label() == "data")
        np.testing.assert_allclose(data_line.get_ydata(), orbit[10:101:10, col])
        end = next(ln for ln in ax.get_lines() if ln.get_label() == "end of data")
        assert end.get_xdata()[0] == pytest.approx(10.0)
    assert "2.5–97.5 % band" in legend_texts(axes[0])
    # no data: every state component
    fig = plot_predictive(pred)
    assert [ax.get_ylabel() for ax in fig.get_axes()] == ["q1", "q2", "p1", "p2"]


def test_curves_validation_and_save(tmp_path, t):
    with pytest.raises(ValueError, match="equal length"):
        Curves("x", t, t[:-1])
    with pytest.raises(ValueError, match="samples must have shape"):
        Curves("x", t, t, samples=np.zeros((2, 5)))
    with pytest.raises(ValueError, match="both lower and upper"):
        Curves("x", t, t, lower=t)
    fig = plot_hamiltonians([Curves("x", t, t)], (t, t))
    out = save_figure(fig, tmp_path / "sub" / "dir" / "f.png")
    assert_png(out, min_bytes=1000)
