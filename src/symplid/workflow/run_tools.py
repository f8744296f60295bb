"""Work on a finished run folder: predictions and the report (``symplid predict``/``report``)."""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from symplid.inference.diagnostics import ESS_THRESHOLD, RHAT_THRESHOLD
from symplid.inference.diagnostics import summary as diagnostics_summary
from symplid.inference.predict import posterior_predictive, predict_trajectory
from symplid.inference.samplers import draws_array
from symplid.plotting import plot_pair, plot_predictive, plot_traces, save_figure
from symplid.workflow.fit import build_model, build_posterior
from symplid.workflow.results import RunFolder, format_summary

#: The most integrator steps a prediction may take ((t_end − t0)/dt), so that a mistyped
#: horizon (1e9) is a one-line error rather than hours of work or an exhausted memory.
MAX_PREDICTION_STEPS = 10_000_000


def _load(folder: RunFolder):
    settings = folder.read_settings()
    obs = folder.read_data()
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    return settings, obs, model, posterior


def _draws(folder: RunFolder, wanted: bool, what: str) -> np.ndarray | None:
    if not folder.file(RunFolder.POSTERIOR).exists():
        if wanted:
            warnings.warn(
                f"{folder.path}: posterior.nc is missing (deleted?); {what}", UserWarning,
                stacklevel=3,
            )
        return None
    return draws_array(folder.read_posterior())


def save_atomically(figure: Any, path: Path) -> Path:
    """Write a figure under a hidden name and rename it (never a half-written PNG)."""
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    save_figure(figure, tmp)
    os.replace(tmp, path)
    return path


def _prediction_args(settings, obs, t_end, dt, num_paths) -> tuple[float, float, int, float]:
    """Check the prediction's arguments before anything is computed or written."""
    p = settings.prediction
    t_end = p.t_end if t_end is None else float(t_end)
    dt = p.dt if dt is None else float(dt)
    num_paths = p.num_paths if num_paths is None else int(num_paths)
    t0 = settings.initial_state.start_time(obs.times[0])
    if not np.isfinite(t_end) or t_end <= t0:
        raise ValueError(f"--t-end must be after the initial time {t0:g}, got {t_end:g}")
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"--dt must be positive, got {dt:g}")
    if num_paths < 0:
        raise ValueError(f"--num-paths must be ≥ 0, got {num_paths}")
    steps = (t_end - t0) / dt
    if steps > MAX_PREDICTION_STEPS:
        raise ValueError(
            f"predicting from t = {t0:g} to {t_end:g} at dt = {dt:g} takes {steps:.3g} steps; "
            f"at most {MAX_PREDICTION_STEPS:,} are allowed (a larger --dt or a nearer --t-end)"
        )
    return t_end, dt, num_paths, t0


def predict_run(
    run: str | Path,
    t_end: float | None = None,
    dt: float | None = None,
    num_paths: int | None = None,
) -> str:
    """MAP path and posterior predictive band to ``t_end``; writes predictions.npz and a figure.

    The paths start from the known initial state or, when it was learned, from the MAP's
    (MAP path) and the posterior mean's (band). ``t_end``, ``dt`` and ``num_paths`` default to
    the run's ``[prediction]`` settings. Every argument is checked and every path computed
    before the folder is touched, and the files are replaced atomically: a failed or
    interrupted prediction leaves a finished run finished. Returns a one-line description.
    """

    folder = RunFolder(run, "r")
    settings, obs, model, posterior = _load(folder)
    t_end, dt, num_paths, t0 = _prediction_args(settings, obs, t_end, dt, num_paths)
    p = settings.prediction
    theta_map = np.asarray(folder.read_map()["theta"], dtype=float)
    nc = model.num_dynamics_params  # θ_Ψ: the coefficients, and γ when damped
    x0_map = np.asarray(posterior.initial_state(theta_map))
    every = max(1, round((t_end - t0) / dt / 2000))
    times, path = predict_trajectory(
        model, theta_map[:nc], x0_map, t_end, dt=dt, integrator=p.integrator, t0=t0, every=every
    )
    arrays: dict[str, Any] = {"times": times, "map_path": path}
    draws = _draws(folder, num_paths > 0, "predicting the MAP path only")
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
    figure = None
    if band is not None:
        # State names from the model (q1..qd, p1..pd); the data's columns pick the panels.
        figure = plot_predictive(
            band, obs, map_path=(times, path), t_data_end=float(obs.times[-1])
        )
    with RunFolder(run, "a") as update:
        update.write_npz("predictions.npz", **arrays)
        if figure is not None:
            save_atomically(figure, update.figure_path("predictive"))
    what = "MAP path and posterior band" if band is not None else "MAP path"
    return f"{folder.file('predictions.npz')}: {what} to t = {t_end:g} (dt = {dt:g})"


def report_run(run: str | Path) -> str:
    """Write ``report.md``: the summary, a per-parameter R-hat/ESS table, and the figures.

    Everything is computed before the folder is touched; a failed or interrupted report leaves
    a finished run finished. A run whose ``posterior.nc`` is missing gets a one-line warning
    and a report without the posterior's table and figures.
    """

    folder = RunFolder(run, "r")
    settings, obs, _model, posterior = _load(folder)
    summary = folder.read_summary() if folder.file("summary.json").exists() else {}
    idata = None
    if folder.file(RunFolder.POSTERIOR).exists():
        idata = folder.read_posterior()
    else:
        _draws(folder, True, "the report has no posterior table or figures")
    names = list(posterior.param_names)
    figures: list[tuple[str, str, Any]] = []
    table = None
    if idata is not None:
        draws = draws_array(idata)
        table = convergence_table(idata)
        figures.append(("Traces", "traces", plot_traces(draws, names)))
        figures.append(("Pairs", "pairs", plot_pair(draws, names)))
    lines = [
        *_report_header(run, settings, obs),
        "```",
        format_summary(summary) if summary else "(no summary)",
        "```",
        "",
    ]
    if table is not None:
        lines += ["## Convergence", "", table, ""]
    with RunFolder(run, "a") as update:
        for _title, name, figure in figures:
            save_atomically(figure, update.figure_path(name))
        shown = [(title, f"figures/{name}.png") for title, name, _ in figures]
        if update.figure_path("predictive").exists():
            shown.append(("Predictions", "figures/predictive.png"))
        lines += [f"![{title}]({path})\n" for title, path in shown]
        update.write_report("\n".join(lines))
    return f"{folder.file('report.md')}: {len(shown)} figures"


def _report_header(run: str | Path, settings, obs) -> list[str]:
    m = settings.model
    return [
        f"# Run {Path(run).name}",
        "",
        f"{obs.num_times} observations of {obs.dim} components, t = {obs.times[0]:g}..."
        f"{obs.times[-1]:g}; polynomial order {m.order}, {m.integrator} at dt = {m.dt:g}; "
        f"{settings.sampler.method.upper()}, {settings.sampler.num_chains} chains × "
        f"{settings.sampler.num_iterations:,} iterations ({settings.sampler.burn_in:,} burn-in).",
        "",
    ]


def convergence_table(idata: Any) -> str:
    """A Markdown table: each parameter's posterior mean, sd, R-hat, bulk and tail ESS, and
    a flag where R-hat > 1.01 or an ESS < 400 (the thresholds of
    :mod:`symplid.inference.diagnostics`)."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ArviZ/NumPy on very short chains: the flags say it
        table = diagnostics_summary(idata, show=False, warn=False)
    rows = [
        "| parameter | mean | sd | R-hat | ESS bulk | ESS tail | |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, row in table.iterrows():
        rhat, bulk, tail = (float(row[k]) for k in ("r_hat", "ess_bulk", "ess_tail"))
        ok = rhat <= RHAT_THRESHOLD and min(bulk, tail) >= ESS_THRESHOLD
        rows.append(
            f"| {name} | {row['mean']:.4g} | {row['sd']:.3g} | {rhat:.3f} | {bulk:.0f} | "
            f"{tail:.0f} | {'' if ok else 'not converged'} |"
        )
    return "\n".join(rows)
