"""Work on a finished run folder: predictions and the report (``symplid predict``/``report``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from symplid.inference.predict import posterior_predictive, predict_trajectory
from symplid.inference.samplers import draws_array
from symplid.plotting import plot_pair, plot_predictive, plot_traces
from symplid.workflow.fit import build_model, build_posterior
from symplid.workflow.results import RunFolder, format_summary


def _load(run: str | Path, mode: str = "a"):
    folder = RunFolder(run, mode)
    settings = folder.read_settings()
    obs = folder.read_data()
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    return folder, settings, obs, model, posterior


def _draws(folder) -> np.ndarray | None:
    if not folder.file("posterior.nc").exists():
        return None
    return draws_array(folder.read_posterior())


def predict_run(
    run: str | Path,
    t_end: float,
    dt: float | None = None,
    num_paths: int | None = None,
) -> str:
    """MAP path and posterior predictive band to ``t_end``; writes predictions.npz and a figure.

    The paths start from the known initial state or, when it was learned, from the MAP's
    (MAP path) and the posterior mean's (band). Returns a one-line description.
    """

    folder, settings, obs, model, posterior = _load(run)
    p = settings.prediction
    dt = p.dt if dt is None else float(dt)
    num_paths = p.num_paths if num_paths is None else int(num_paths)
    t0 = settings.initial_state.t0
    if not np.isfinite(t_end) or t_end <= t0:
        raise ValueError(f"--t-end must be after the initial time {t0:g}, got {t_end:g}")
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"--dt must be positive, got {dt:g}")
    theta_map = np.asarray(folder.read_map()["theta"], dtype=float)
    nc = model.num_coefficients
    x0_map = np.asarray(posterior.initial_state(theta_map))
    every = max(1, round((t_end - t0) / dt / 2000))
    times, path = predict_trajectory(
        model, theta_map[:nc], x0_map, t_end, dt=dt, integrator=p.integrator, t0=t0, every=every
    )
    arrays: dict[str, Any] = {"times": times, "map_path": path}
    draws = _draws(folder)
    band = None
    if draws is not None and num_paths > 0:
        flat = draws.reshape(-1, draws.shape[-1])
        if posterior.learn_initial_state:
            # Every draw's coefficients from one start: the posterior mean initial state.
            x0 = np.asarray(posterior.initial_state(flat.mean(axis=0)))
        else:
            x0 = x0_map
        band = posterior_predictive(
            model,
            flat[:, :nc],
            x0,
            t_end,
            dt=dt,
            integrator=p.integrator,
            num_paths=num_paths,
            seed=settings.seed,
            t0=t0,
            every=every,
        )
        arrays.update(
            band_times=band.times,
            band_lower=band.lower,
            band_upper=band.upper,
            band_median=band.median,
            sample_paths=band.paths,
        )
    np.savez_compressed(folder.file("predictions.npz"), **arrays)
    if band is not None:
        fig_path = folder.figure_path("predictive")
        plot_predictive(
            band,
            obs,
            state_names=obs.names,
            map_path=(times, path),
            t_data_end=float(obs.times[-1]),
            path=fig_path,
        )
    folder.finish(required=("settings.toml", "data.csv", "map.json"))
    what = "MAP path and posterior band" if band is not None else "MAP path"
    return f"{folder.file('predictions.npz')}: {what} to t = {t_end:g} (dt = {dt:g})"


def report_run(run: str | Path) -> str:
    """Write ``report.md`` with the summary table, trace, pair and predictive figures."""

    folder, settings, obs, _model, posterior = _load(run)
    summary = folder.read_summary() if folder.file("summary.json").exists() else {}
    draws = _draws(folder)
    names = list(posterior.param_names)
    figures = []
    if draws is not None:
        plot_traces(draws, names, path=folder.figure_path("traces"))
        figures.append(("Traces", "figures/traces.png"))
        plot_pair(draws, names, path=folder.figure_path("pairs"))
        figures.append(("Pairs", "figures/pairs.png"))
    if folder.figure_path("predictive").exists():
        figures.append(("Predictions", "figures/predictive.png"))
    m = settings.model
    lines = [
        f"# Run {Path(run).name}",
        "",
        f"{obs.num_times} observations of {obs.dim} components, t = {obs.times[0]:g}..."
        f"{obs.times[-1]:g}; polynomial order {m.order}, {m.integrator} at dt = {m.dt:g}; "
        f"{settings.sampler.method.upper()}, {settings.sampler.num_chains} chains × "
        f"{settings.sampler.num_iterations:,} iterations ({settings.sampler.burn_in:,} burn-in).",
        "",
        "```",
        format_summary(summary) if summary else "(no summary)",
        "```",
        "",
    ]
    lines += [f"![{title}]({path})\n" for title, path in figures]
    folder.write_report("\n".join(lines))
    folder.finish(required=("settings.toml", "data.csv"))
    return f"{folder.file('report.md')}: {len(figures)} figures"
