"""The paper's four figures (Section IV) from the two approaches' fits."""

from __future__ import annotations

from typing import Any

import numpy as np

from symplid.inference.predict import hamiltonian_along, posterior_predictive, predict_trajectory
from symplid.plotting import (
    Curves,
    plot_hamiltonians,
    plot_phase_portraits,
    plot_process_noise,
    plot_trajectory_bands,
)

LABELS = {"leapfrog": "leapfrog", "rk2": "RK2"}
EVERY = 10  # keep every 10th fine step (0.1 s) in the stored paths


def draw_figures(folder, results, system, obs, truth_times, truth, config, progress=True) -> None:
    """Figures 1–4 into ``folder/figures``."""
    x0 = system.initial_state
    pot = system.potential
    t_data_end = float(obs.times[-1])
    stride = max(1, round(EVERY * 0.01 / config.prediction_dt))
    truth_t, truth_x = truth_times[::stride], truth[::stride]

    maps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    bands: dict[str, Any] = {}
    for name, res in results.items():
        maps[name] = predict_trajectory(
            pot, res.coefficients_map, x0, config.t_end, dt=config.prediction_dt, every=stride
        )
        bands[name] = posterior_predictive(
            pot,
            res.coefficient_draws,
            x0,
            config.t_end,
            dt=config.prediction_dt,
            num_paths=config.num_paths,
            seed=config.seed,
            every=stride,
        )

    # Fig 1: phase portraits (leapfrog at the fine step for 200 s; data over 100 s).
    plot_phase_portraits(
        {f"learned with {LABELS[n]}": maps[n][1] for n in results},
        truth_x,
        obs.values[:, :2],
        path=folder.figure_path("fig1_phase_portraits"),
    )

    # Fig 2: H along trajectories; (a) leapfrog at the fine step, (b) RK2 at the learning dt.
    h_truth = hamiltonian_along(pot, system.coefficients, truth_x)
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
                pot, res.coefficients_map, x0, config.t_end, dt=config.dt, integrator=res.integrator
            )
            coarse.append(
                Curves(
                    f"{LABELS[name]} model, {res.integrator} at Δt = {config.dt}",
                    t_c,
                    hamiltonian_along(pot, res.coefficients_map, x_c),
                )
            )
    plot_hamiltonians(
        fine,
        (truth_t, h_truth),
        coarse,
        t_data_end=t_data_end,
        path=folder.figure_path("fig2_hamiltonians"),
    )

    # Fig 3: q1 against time with the posterior band, one row per approach.
    approaches = []
    for name in results:
        t_map, x_map = maps[name]
        band = bands[name]
        approaches.append(
            Curves(
                LABELS[name],
                t_map,
                x_map[:, 0],
                samples=band.paths[:, :, 0],
                sample_times=band.times,
                lower=band.lower[:, 0],
                upper=band.upper[:, 0],
            )
        )
    plot_trajectory_bands(
        approaches,
        truth=(truth_t, truth_x[:, 0]),
        data=(obs.times, obs.values[:, 0]),
        t_data_end=t_data_end,
        path=folder.figure_path("fig3_trajectories"),
    )

    # Fig 4: process-noise posteriors.
    plot_process_noise(
        {LABELS[n]: r.process_noise_draws for n, r in results.items()},
        {
            LABELS[n]: float(r.map_theta[r.param_names.index("process_var")])
            for n, r in results.items()
        },
        path=folder.figure_path("fig4_process_noise"),
    )
