"""Plotting (layer 5): figures from arrays and results; never fits, samples or reads run folders.

Every function takes plain arrays or small dataclasses, returns a
:class:`matplotlib.figure.Figure`, and writes a PNG when ``path`` is given.

* :mod:`~symplid.plotting._paper`: the paper's four figures (Section IV);
* :mod:`~symplid.plotting._diagnostics`: :func:`plot_traces` (chains), :func:`plot_pair` (corner);
* :mod:`~symplid.plotting._potential`: :func:`plot_potential` (U(q) with its posterior band);
* :mod:`~symplid.plotting._predictive`: :func:`plot_predictive` (data and predictive band for every
  observed component);
* :mod:`~symplid.plotting._style`: :data:`COLORS`, :class:`Curves`, :func:`save_figure`;
* :mod:`~symplid.plotting._sweep`: a sweep's results table.
"""

from symplid.plotting._diagnostics import plot_pair, plot_traces
from symplid.plotting._paper import (
    plot_hamiltonians,
    plot_phase_portraits,
    plot_process_noise,
    plot_trajectory_bands,
)
from symplid.plotting._potential import PotentialSlice, plot_potential
from symplid.plotting._predictive import plot_forecast, plot_predictive
from symplid.plotting._style import COLORS, Curves, save_figure

__all__ = [
    "COLORS",
    "Curves",
    "PotentialSlice",
    "plot_forecast",
    "plot_hamiltonians",
    "plot_pair",
    "plot_phase_portraits",
    "plot_potential",
    "plot_predictive",
    "plot_process_noise",
    "plot_traces",
    "plot_trajectory_bands",
    "save_figure",
]
