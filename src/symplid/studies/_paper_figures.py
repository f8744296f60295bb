"""The paper's four figures (Section IV) from the two approaches' fits.

Matplotlib (:mod:`symplid.plotting`) is imported when the figures are prepared
(:func:`figure_truth`), not with this module: a worker process computes
:func:`approach_predictions` without it.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from symplid.inference._predict import (
    PosteriorPredictive,
    hamiltonian_along,
    posterior_predictive,
    predict_trajectory,
)

if TYPE_CHECKING:
    from symplid.plotting import Curves

__all__ = ["FigureTruth", "approach_predictions", "draw_figures", "figure_stride", "figure_truth"]

LABELS = {"leapfrog": "leapfrog", "rk2": "RK2"}
EVERY = 10  # keep every 10th fine step (0.1 s) in the stored paths


@dataclass(frozen=True)
class FigureTruth:
    """The true path at the figures' stride, H along it, and the plotting functions."""

    times: np.ndarray
    states: np.ndarray
    energy: np.ndarray
    plotting: ModuleType
    """:mod:`symplid.plotting`, loaded with the truth (it loads matplotlib)."""


def figure_truth(system, truth_times, truth, config) -> FigureTruth:
    """What the figures need of the truth, computed before any fit's draws are in.

    Called while a fit still samples, it also takes the figures' fixed costs off the end of
    the run: H along a path of the figures' length compiles once (the approaches' paths
    reuse it) and matplotlib loads (:mod:`symplid.plotting`).
    """
    from symplid import plotting

    stride = figure_stride(config)
    times, states = truth_times[::stride], truth[::stride]
    energy = np.asarray(hamiltonian_along(system.potential, system.coefficients, states))
    return FigureTruth(times, states, energy, plotting)


def draw_figures(folder, results, system, obs, truth_times, truth, config, progress=True,
                 predictions=None, prepared: FigureTruth | None = None) -> None:
    """Figures 1–4 into ``folder/figures``.

    Every path is integrated from the true initial state by leapfrog at the fine step
    (``config.prediction_dt``) for ``config.t_end``, and stored every ``EVERY`` fine steps of
    0.01 s; Fig. 2(b) also integrates the RK2 model by RK2 at the learning step.
    ``predictions`` maps an approach to its :func:`approach_predictions` when they were
    computed already (by the process that fitted it); the others are computed here;
    ``prepared`` is :func:`figure_truth`'s result when it was computed already.
    """
    t_data_end = float(obs.times[-1])
    prepared = prepared or figure_truth(system, truth_times, truth, config)
    plots = prepared.plotting
    truth_t, truth_x = prepared.times, prepared.states
    done = predictions or {}
    made = {name: done.get(name) or approach_predictions(res, system, config)
            for name, res in results.items()}
    maps = {name: pair[0] for name, pair in made.items()}
    bands = {name: pair[1] for name, pair in made.items()}

    # Fig 1: phase portraits (leapfrog at the fine step for 200 s; data over 100 s).
    plots.plot_phase_portraits(
        {f"learned with {LABELS[n]}": maps[n][1] for n in results},
        truth_x,
        obs.values[:, :2],
        path=folder.figure_path("fig1_phase_portraits"),
    )
    # Fig 2: H along trajectories; (a) leapfrog at the fine step, (b) RK2 at the learning dt.
    fine, coarse = _energy_curves(results, system, config, maps, bands)
    plots.plot_hamiltonians(
        fine,
        (truth_t, prepared.energy),
        coarse,
        t_data_end=t_data_end,
        path=folder.figure_path("fig2_hamiltonians"),
    )
    # Fig 3: q1 against time with the posterior band, one row per approach.
    plots.plot_trajectory_bands(
        [_q1_curves(LABELS[name], maps[name], bands[name]) for name in results],
        truth=(truth_t, truth_x[:, 0]),
        data=(obs.times, obs.values[:, 0]),
        t_data_end=t_data_end,
        path=folder.figure_path("fig3_trajectories"),
    )
    # Fig 4: process-noise posteriors.
    plots.plot_process_noise(
        {LABELS[n]: r.process_noise_draws for n, r in results.items()},
        {
            LABELS[n]: float(r.map_theta[r.param_names.index("process_var")])
            for n, r in results.items()
        },
        path=folder.figure_path("fig4_process_noise"),
    )


def figure_stride(config) -> int:
    """Fine steps between stored points of the figures' paths (0.1 s)."""
    return max(1, round(EVERY * 0.01 / config.prediction_dt))


def approach_predictions(result, system, config) -> tuple[tuple[np.ndarray, np.ndarray],
                                                           PosteriorPredictive]:
    """One approach's MAP path ``(times, states)`` and its posterior predictive band (from
    the true initial state, leapfrog at ``config.prediction_dt``, seeded by ``config.seed``)."""
    stride = figure_stride(config)
    x0, pot = system.initial_state, system.potential
    path = predict_trajectory(
        pot, result.coefficients_map, x0, config.t_end, dt=config.prediction_dt, every=stride
    )
    band = posterior_predictive(
        pot,
        result.coefficient_draws,
        x0,
        config.t_end,
        dt=config.prediction_dt,
        num_paths=config.num_paths,
        seed=config.seed,
        every=stride,
    )
    return path, band


def _energy_curves(results, system, config, maps, bands) -> tuple[list[Curves], list[Curves]]:
    """Fig. 2's curves: H along the fine paths (MAP and samples), and along the RK2 model
    integrated by its learning integrator at the learning step."""
    from symplid.plotting import Curves

    pot = system.potential
    fine, coarse = [], []
    for name, res in results.items():
        t_map, x_map = maps[name]
        band = bands[name]
        sample_coeffs = res.coefficient_draws[band.path_indices]
        h_samples = np.stack(
            [
                hamiltonian_along(pot, c, path)
                for c, path in zip(sample_coeffs, band.paths, strict=True)
            ]
        )
        fine.append(
            Curves(
                LABELS[name],
                t_map,
                hamiltonian_along(pot, res.coefficients_map, x_map),
                samples=h_samples,
                sample_times=band.times,
            )
        )
        if name == "rk2":
            t_c, x_c = predict_trajectory(
                pot,
                res.coefficients_map,
                system.initial_state,
                config.t_end,
                dt=config.dt,
                integrator=res.integrator,
            )
            coarse.append(
                Curves(
                    f"{LABELS[name]} model, {res.integrator} at Δt = {config.dt}",
                    t_c,
                    hamiltonian_along(pot, res.coefficients_map, x_c),
                )
            )
    return fine, coarse


def _q1_curves(label: str, map_path, band: PosteriorPredictive) -> Curves:
    """Fig. 3's curves of one approach: the MAP's q1, the band and the sample paths."""
    from symplid.plotting import Curves

    t_map, x_map = map_path
    return Curves(
        label,
        t_map,
        x_map[:, 0],
        samples=band.paths[:, :, 0],
        sample_times=band.times,
        lower=band.lower[:, 0],
        upper=band.upper[:, 0],
    )
