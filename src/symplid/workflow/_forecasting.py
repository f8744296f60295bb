"""Forecasts of a run from the end of its data, and held-out scores (``predict --from end``,
``fit --holdout``).

Every posterior draw θ^s gives the filter's distribution of the state at the last observation
(Theorem 1); one state drawn from it is carried forward by the learned state-space model with
its process noise (eq. 7, :func:`symplid.inference._forecast.forecast_with_noise`). The band of
new observations adds the observation noise Γ(θ^s): it is the band a held-out datum should fall
in 95 % of the time when the model is right, which is what :func:`holdout_scores` checks.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from symplid.inference._forecast import NoisyForecast, filtered_end_states, forecast_with_noise
from symplid.model._data import DataError, Observations
from symplid.plotting._predictive import plot_forecast
from symplid.sampling import draws_array
from symplid.workflow._driven import refuse_forecast
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._results import RunFolder
from symplid.workflow._run_tools import save_atomically

__all__ = [
    "MAX_FORECAST_DRAWS",
    "MAX_FORECAST_POINTS",
    "forecast_run",
    "holdout_scores",
    "score_holdout",
    "split_holdout",
]

#: Posterior draws a forecast uses at most (one filter run each), chosen at random by seed.
MAX_FORECAST_DRAWS = 400
#: Forecast times at most (one per data gap, so a mistyped horizon is a one-line error).
MAX_FORECAST_POINTS = 100_000


@dataclass(frozen=True)
class _Run:
    folder: RunFolder
    settings: Any
    data: Observations
    model: Any
    posterior: Any
    draws: np.ndarray


def _open(run: str | Path, plan: Any = None) -> _Run:
    folder = RunFolder(run, "r")
    settings = folder.read_settings()
    refuse_forecast(settings, "a forecast from the end of the data (and its held-out scores)")
    obs = folder.read_data()
    if isinstance(obs, list):
        raise DataError(f"{folder.path}: a forecast from the end of the data follows one "
                        f"trajectory; this run has {len(obs)} (predict them with --from start)")
    model = build_model(settings, obs) if plan is None else plan.model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    if not folder.file(RunFolder.POSTERIOR).exists():
        raise DataError(f"{folder.path}: posterior.nc is missing; a forecast needs the draws")
    draws = draws_array(folder.read_posterior())
    return _Run(folder, settings, obs, model, posterior, draws.reshape(-1, draws.shape[-1]))


def _forecast(r: _Run, times: np.ndarray, max_draws: int = MAX_FORECAST_DRAWS) -> NoisyForecast:
    """The noisy forecast of a run's posterior at ``times`` (after its last observation)."""
    seed = r.settings.seed
    rng = np.random.default_rng(seed)
    rows = rng.permutation(r.draws.shape[0])[:max_draws]
    theta = r.draws[rows]
    model_theta = np.asarray(r.posterior.model_theta(theta))
    x0s = np.stack([np.asarray(r.posterior.initial_state(row)) for row in theta])
    init = r.settings.initial_state
    data, t0 = r.data, init.start_time(r.data.times[0])
    if init.at_first_observation:  # the state sits at t_1: filter the rest from there
        data = r.data.subset(slice(1, None))
    starts = filtered_end_states(r.model, model_theta, data, x0s, init.p0_var, t0, seed)
    return forecast_with_noise(r.model, model_theta, starts, float(r.data.times[-1]), times,
                               seed=seed + 1)


def forecast_run(run: str | Path, t_end: float | None = None) -> str:
    """``symplid predict RUN --from end``: forecast.npz and figures/forecast.png.

    The forecast times are one median data gap apart from the last observation to ``t_end``
    (default: the run's ``prediction.t_end``). Arguments are checked and everything computed
    before the folder is touched; the files are replaced atomically.
    """
    r = _open(run)
    t_last = float(r.data.times[-1])
    t_end = r.settings.prediction.t_end if t_end is None else float(t_end)
    if not np.isfinite(t_end) or t_end <= t_last:
        raise ValueError(f"--t-end must be after the last observation t = {t_last:g}, got "
                         f"{t_end:g}")
    gap = float(np.median(np.diff(r.data.times)))
    count = int(np.ceil((t_end - t_last) / gap - 1e-9))
    if count > MAX_FORECAST_POINTS:
        raise ValueError(f"forecasting to t = {t_end:g} in data gaps of {gap:g} takes {count:,} "
                         f"points; at most {MAX_FORECAST_POINTS:,} are allowed")
    times = t_last + gap * np.arange(1, count + 1)
    times[-1] = min(times[-1], t_end) if count > 1 else t_end
    fc = _forecast(r, times)
    figure = plot_forecast(fc, r.data, r.model.state_dim, time_unit=r.settings.plots.time_unit)
    _write(r.folder.path, "forecast", fc, figure)
    return (f"{r.folder.file('forecast.npz')}: forecast from t = {t_last:g} to {times[-1]:g} "
            f"with process noise ({fc.states.shape[0]} draws)")


def _write(run: Path, name: str, fc: NoisyForecast, figure: Any) -> None:
    with RunFolder(run, "a") as update:
        update.write_npz(
            f"{name}.npz", times=fc.times, quantile_levels=np.asarray(fc.quantile_levels),
            state_quantiles=fc.state_quantiles, obs_quantiles=fc.obs_quantiles,
            state_paths=fc.states[:100],
        )
        save_atomically(figure, update.figure_path(name))


# ----------------------------------------------------------------------------- held out
def split_holdout(
    obs: Observations, fraction: float | None = None, after: float | None = None
) -> tuple[Observations, Observations]:
    """(training, held-out): the last ``fraction`` of the observation times, or those after
    time ``after``. Both parts keep at least two times (one-line error otherwise)."""
    if (fraction is None) == (after is None):
        raise ValueError("give one of --holdout FRACTION and --holdout-after T")
    n = obs.num_times
    if fraction is not None:
        if not 0 < fraction < 1:
            raise ValueError(f"--holdout must be between 0 and 1, got {fraction:g}")
        cut = n - max(1, round(fraction * n))
    else:
        cut = int(np.searchsorted(obs.times, float(after), side="right"))
    if cut < 2 or cut >= n:
        raise DataError(
            f"holding out leaves {cut} observation times to fit and {n - cut} to score; "
            "both parts need data (the fit at least 2 times)"
        )
    return obs.subset(slice(0, cut)), obs.subset(slice(cut, None))


def holdout_scores(fc: NoisyForecast, heldout: Observations) -> dict[str, float]:
    """RMSE of the median new observation, coverage of the 95 % band of new observations
    (fraction of held-out values inside it), and the log predictive density Σ_k log p(y_k)."""
    y = np.asarray(heldout.values, dtype=float)
    measured = np.isfinite(y)
    median = fc.obs_quantiles[list(fc.quantile_levels).index(0.5)]
    lower, upper = fc.band(0.95)
    inside = (y >= lower) & (y <= upper)
    return {
        "num_times": int(heldout.num_times),
        "num_values": int(measured.sum()),
        "t_start": float(heldout.times[0]),
        "rmse": float(np.sqrt(np.mean((y - median)[measured] ** 2))),
        "coverage_95": float(np.mean(inside[measured])),
        "log_predictive_density": fc.log_predictive_density(y),
    }


def score_holdout(run: str | Path, heldout: Observations, plan: Any = None) -> dict[str, float]:
    """Forecast a finished run at the held-out times; write heldout.csv, holdout.npz,
    figures/holdout.png and ``summary.json["holdout"]``. Returns the scores. ``plan``: the
    fit's :class:`~symplid.workflow._plan.ModelPlan`, whose U or H the forecast reuses."""
    from symplid.io import write_observations

    r = _open(run, plan)
    fc = _forecast(r, np.asarray(heldout.times, dtype=float))
    scores = holdout_scores(fc, heldout)
    figure = plot_forecast(fc, r.data, r.model.state_dim, heldout=heldout,
                           time_unit=r.settings.plots.time_unit)
    summary = r.folder.read_summary()
    summary["holdout"] = scores
    _write(r.folder.path, "holdout", fc, figure)
    with RunFolder(run, "a") as update:
        write_observations(heldout, update.file("heldout.csv"))
        update.write_summary(summary)
    return scores
