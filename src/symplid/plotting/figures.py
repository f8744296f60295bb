"""Former home of the figures, kept for older imports: use :mod:`symplid.plotting`."""

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
