"""Forecasts from the end of the data: parameter and state uncertainty together.

For data whose initial state is not known, a prediction starts from what the unscented
Kalman filter (Theorem 1) knows at the last observation, for every posterior draw of θ.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from symplid.dynamics.integrators import Integrator
from symplid.dynamics.potentials import inverse_mass
from symplid.inference.predictive import (
    PosteriorPredictive,
    check_state,
    flatten_draws,
    key_and_seed,
    positive_int,
    predictive_band,
)
from symplid.model.data import Observations
from symplid.model.statespace import HamiltonianModel

Array = jax.Array

__all__ = ["forecast_from_filter"]


def forecast_from_filter(
    model: HamiltonianModel,
    theta_draws: Any,
    data: Observations,
    x0: Any,
    t_end: float,
    P0: Any = None,
    dt: float = 0.01,
    integrator: str | Integrator = "leapfrog",
    quantiles: Sequence[float] = (0.025, 0.975),
    num_paths: int = 100,
    seed: int | Array = 0,
    *,
    t0: float = 0.0,
    every: int | None = None,
    max_draws: int | None = 1000,
    batch_size: int = 256,
) -> PosteriorPredictive:
    """Forecast from the end of the data with parameter and state uncertainty.

    For each posterior draw θ, the unscented Kalman filter of ``model`` (Theorem 1) is run over
    ``data``; a state is drawn from its last filtered distribution N(m_n, P_n) at the last
    observation time t_n and integrated deterministically to ``t_end``. The band mixes the
    posterior over θ_Ψ with what the data leave uncertain about the current state: the right
    starting point when the initial state is not known. No process noise is added along the
    forecast (as in Fig. 3). A draw whose filter fails gives a NaN path, reported through
    ``finite_fraction``.

    Parameters
    ----------
    model
        The model the draws come from (its filter settings and learning integrator are used
        for the filter; ``integrator`` and ``dt`` for the forecast).
    theta_draws
        Full θ draws, shape ``(S, num_params)`` or ``(chains, draws, num_params)``.
    data, x0, P0, t0
        As in :meth:`HamiltonianModel.filter`.
    t_end
        Forecast horizon, after the last observation time.
    dt, integrator, quantiles, num_paths, seed, every, max_draws, batch_size
        As in :func:`posterior_predictive`.

    Returns
    -------
    PosteriorPredictive
        Times run from the last observation time to ``t_end``; ``path_indices`` are rows of the
        flattened ``theta_draws``.
    """
    if not isinstance(model, HamiltonianModel):
        raise TypeError("forecast_from_filter needs the HamiltonianModel the draws come from")
    theta = flatten_draws(np.asarray(theta_draws, dtype=float))
    if theta.shape[-1] != model.num_params:
        raise ValueError(
            f"theta_draws must end with {model.num_params} entries "
            f"({', '.join(model.param_names)}), got {theta.shape[-1]}"
        )
    if not isinstance(data, Observations):
        raise TypeError("data must be a symplid.Observations")
    t_last = float(data.times[-1])
    if not t_end > t_last:
        raise ValueError(f"t_end = {t_end:g} must be after the last observation t = {t_last:g}")
    x0 = check_state(x0, model.potential.dim)
    key, seed_int = key_and_seed(seed)
    key_select, key_state = jax.random.split(key)
    order = np.asarray(jax.random.permutation(key_select, theta.shape[0]))
    used = order if max_draws is None else order[: positive_int(max_draws, "max_draws")]
    prepared = model.prepare(data, t0)
    # One filter call per draw reuses the model's compiled filter (the one the fit used),
    # which costs less than compiling a vmapped filter for a one-off forecast.
    z = np.asarray(jax.random.normal(key_state, (used.shape[0], model.state_dim)))
    starts = np.empty((used.shape[0], model.state_dim))
    for i, row in enumerate(used):
        res = model.filter(theta[row], prepared, x0, P0)
        m = np.asarray(res.filtered_means[-1])
        cov = np.asarray(res.filtered_covs[-1])
        starts[i] = m + _cholesky_or_nan(cov) @ z[i]
    starts[~np.all(np.isfinite(starts), axis=1)] = np.nan
    inv_mass = inverse_mass(model.mass, model.potential.dim)
    coefficients = theta[used, : model.num_coefficients]
    return predictive_band(
        model.potential, inv_mass, coefficients, starts, used, t_last, t_end, dt, integrator,
        quantiles, num_paths, seed_int, every, batch_size,
    )


def _cholesky_or_nan(cov: np.ndarray) -> np.ndarray:
    """Cholesky factor of a (symmetrised, slightly jittered) covariance; NaN if it fails."""
    cov = 0.5 * (cov + cov.T)
    cov = cov + 1e-14 * max(float(np.trace(cov)), 1.0) * np.eye(cov.shape[0])
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return np.full_like(cov, np.nan)
