"""The figures of a run: chains, pairs, the learned U(q) with its band, the data against the fit.

Everything here computes arrays from a run's settings, data, MAP and draws and hands them to
:mod:`symplid.plotting`; :mod:`symplid.workflow._run_tools` writes the figures into the run
folder (``symplid report``, and ``symplid fit`` at its end). The ``[plots]`` settings choose
the time unit of the axes, how many parameters the pair and trace plots show (a note in the
figure and in the report when some are left out) and the true system, when known.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from symplid.dynamics._hamiltonians import is_hamiltonian
from symplid.dynamics._potentials import coefficient_name
from symplid.inference._driven import forced_band, forced_paths
from symplid.inference._measures import potential_slices
from symplid.inference._predict import posterior_predictive, predict_trajectory
from symplid.io import as_list, observation_layout
from symplid.plotting import PotentialSlice, plot_pair, plot_potential, plot_predictive, plot_traces
from symplid.plotting._diagnostics import truncation_note
from symplid.workflow._model_builder import model_description, model_family

__all__ = ["ReportFigure", "report_figures", "trajectory_paths", "truth_values"]

#: Draws used for the U(q) band (a seeded subset when there are more).
POTENTIAL_DRAWS = 400


class ReportFigure(NamedTuple):
    """One figure of the report: its title, file name (``figures/<name>.png``), the figure and
    a note (e.g. the parameters it leaves out) or ""."""

    title: str
    name: str
    figure: Any
    note: str = ""


def truth_values(settings: Any, model: Any) -> tuple[Any, dict[str, float]] | None:
    """The true system of ``plots.truth`` (None when unset) and its coefficients by the
    model's names (0 for a model term the truth lacks), when the bases are comparable."""
    name = settings.plots.truth
    if not name:
        return None
    from symplid.dynamics._systems import get_system

    system = get_system(name)
    true = dict(zip(map(coefficient_name, system.potential.param_names),
                    np.asarray(system.coefficients, float), strict=True))
    names = [coefficient_name(n) for n in model.hamiltonian.param_names]
    if system.potential.dim != model.hamiltonian.dim or not set(true) <= set(names):
        return system, {}
    return system, {n: float(true.get(n, 0.0)) for n in names}


def _subset(flat: np.ndarray, most: int, seed: int) -> np.ndarray:
    if flat.shape[0] <= most:
        return flat
    return flat[np.random.default_rng(seed).choice(flat.shape[0], most, replace=False)]


def potential_figure(settings: Any, data: Any, model: Any, flat: np.ndarray,
                     theta_map: np.ndarray) -> Any | None:
    """U(q) along each axis through the data's mean position, over a range covering the
    data: the posterior's 95 % band and median, the MAP and the truth (``plots.truth``).
    None when the model has no potential U(q; c): a whole, non-separable H(q, p; θ)
    (``polynomial-qp``, a user's H that mixes q and p) has no U(q) to draw."""
    potential = getattr(model, "hamiltonian", None)
    if potential is None or not hasattr(potential, "value") or is_hamiltonian(potential):
        return None
    nc = model.num_coefficients
    d = potential.dim
    positions = np.concatenate([np.asarray(o.values)[:, :d] for o in as_list(data)])
    low, high = np.nanmin(positions, axis=0), np.nanmax(positions, axis=0)
    span = np.where(high > low, high - low, 1.0)
    lower, upper = low - 0.15 * span, high + 0.15 * span
    centre = np.nanmean(positions, axis=0)
    draws = _subset(flat[:, :nc], POTENTIAL_DRAWS, settings.seed)
    band = potential_slices(potential, draws, centre, lower, upper)
    at_map = potential_slices(potential, theta_map[:nc], centre, lower, upper)
    truth = truth_values(settings, model)
    at_truth = None
    if truth is not None:
        system = truth[0]
        at_truth = potential_slices(system.potential, system.coefficients, centre, lower, upper)
    names = [f"q{i + 1}" for i in range(d)]
    slices = []
    for i in range(d):
        fixed = ", ".join(f"{names[j]} = {centre[j]:.3g}" for j in range(d) if j != i)
        q_band = band[i]["quantiles"]
        slices.append(PotentialSlice(
            names[i], band[i]["q"], q_band[0], q_band[1], q_band[2],
            map=at_map[i]["quantiles"][1],
            truth=None if at_truth is None else at_truth[i]["quantiles"][1],
            data=positions[:, i][np.isfinite(positions[:, i])], fixed=fixed))
    return plot_potential(slices)


def trajectory_paths(settings: Any, model: Any, posterior: Any, theta_map: np.ndarray,
                     flat: np.ndarray | None, k: int, t0: float, t_end: float, dt: float,
                     num_paths: int) -> tuple[np.ndarray, np.ndarray, Any]:
    """Trajectory k's MAP path and, with draws, its posterior band from ``t0`` to ``t_end``.

    The paths start from the known initial state or, when it was learned, the MAP path from
    the MAP's and each path of the band from its own draw's: the band carries the posterior
    of x0 with that of the dynamics (and is not pinched to a point at t0)."""
    p = settings.prediction
    nc = model.num_dynamics_params  # θ_Ψ: the coefficients, and γ when damped (or θ_F)
    every = max(1, round((t_end - t0) / dt / 2000))
    x0_map = np.asarray(posterior.initial_state(theta_map, k))
    if getattr(model, "force", None) is not None:  # driven: the inputs integrated along
        return _driven_paths(settings, model, posterior, theta_map, flat, k, t0, t_end, dt,
                             num_paths, x0_map)
    times, path = predict_trajectory(model, theta_map[:nc], x0_map, t_end, dt=dt,
                                     integrator=p.integrator, t0=t0, every=every)
    band = None
    if flat is not None and num_paths > 0:
        x0 = (np.asarray(posterior.initial_state(flat, k))
              if posterior.learn_initial_state else x0_map)
        band = posterior_predictive(model, flat[:, :nc], x0, t_end, dt=dt,
                                    integrator=p.integrator, num_paths=num_paths,
                                    seed=settings.seed + k, t0=t0, every=every)
    return times, path, band


def _driven_paths(settings: Any, model: Any, posterior: Any, theta_map: np.ndarray,
                  flat: np.ndarray | None, k: int, t0: float, t_end: float, dt: float,
                  num_paths: int, x0_map: np.ndarray) -> tuple[np.ndarray, np.ndarray, Any]:
    """:func:`trajectory_paths` of a driven model, with trajectory k's inputs."""
    signal = posterior.datasets[k].inputs
    nc, integrator = model.num_dynamics_params, settings.prediction.integrator
    times, path = forced_paths(model, signal, theta_map[None, :nc], x0_map[None], t0, t_end,
                               dt, integrator)
    band = None
    if flat is not None and num_paths > 0:
        x0 = (np.asarray(posterior.initial_state(flat, k))
              if posterior.learn_initial_state else x0_map)
        band = forced_band(model, signal, flat[:, :nc], x0, t0, t_end, dt, integrator,
                           num_paths, settings.seed + k)
    return times, path[0], band


def fit_figures(settings: Any, data: Any, model: Any, posterior: Any, theta_map: np.ndarray,
                flat: np.ndarray) -> list[ReportFigure]:
    """Per trajectory, the observed positions against the MAP path and the posterior band over
    the span of the data."""
    out = []
    trajectories = as_list(data)
    d = model.hamiltonian.dim if hasattr(model, "hamiltonian") else observation_layout(
        trajectories[0]).dim
    num_paths = min(settings.prediction.num_paths, 100) or 50
    for k, obs in enumerate(trajectories):
        t0 = settings.initial_state.start_time(obs.times[0])
        t_end = float(obs.times[-1])
        times, path, band = trajectory_paths(settings, model, posterior, theta_map, flat, k,
                                             t0, t_end, settings.prediction.dt, num_paths)
        which = f" (trajectory {k})" if len(trajectories) > 1 else ""
        figure = plot_predictive(band, obs, components=range(d), map_path=(times, path),
                                 t_data_end=None, time_unit=settings.plots.time_unit,
                                 title=f"data and fit{which}: positions")
        name = "fit" if len(trajectories) == 1 else f"fit_{k}"
        out.append(ReportFigure(f"Data and fit{which}", name, figure))
    return out


def report_figures(settings: Any, data: Any, model: Any, posterior: Any, draws: np.ndarray,
                   theta_map: np.ndarray) -> list[ReportFigure]:
    """Traces, pairs (MAP and truth marked), U(q) with its band, and data against the fit."""
    plots = settings.plots
    names = list(posterior.param_names)
    truth = truth_values(settings, model)
    reference = truth[1] if truth is not None and truth[1] else None
    n, most_traces, most_pairs = len(names), plots.max_trace_params, plots.max_pair_params
    traces = plot_traces(draws, names, max_params=most_traces, option="plots.max_trace_params")
    pairs = plot_pair(draws, names, max_params=most_pairs, reference=reference,
                      map_values=dict(zip(names, theta_map, strict=True)),
                      option="plots.max_pair_params")
    figures = [
        ReportFigure("Traces", "traces", traces, truncation_note(
            min(n, most_traces), n, "plots.max_trace_params") or ""),
        ReportFigure("Pairs", "pairs", pairs, truncation_note(
            min(n, most_pairs), n, "plots.max_pair_params") or ""),
    ]
    flat = draws.reshape(-1, draws.shape[-1])
    potential = potential_figure(settings, data, model, flat, theta_map)
    if potential is not None:
        user = model_family(settings.model).name == "user"
        potential.suptitle(model_description(settings.model, limit=90), fontsize=9)
        figures.append(ReportFigure("Potential U(q)" + (f": {model_description(settings.model)}"
                                                          if user else ""),
                                    "potential", potential))
    return figures + fit_figures(settings, data, model, posterior, theta_map, flat)
