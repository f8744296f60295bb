"""Forecasts from the end of the data: parameter and state uncertainty together.

For data whose initial state is not known, a prediction starts from what the unscented
Kalman filter (Theorem 1) knows at the last observation, for every posterior draw of θ.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import jit_for
from symplid.dynamics._damping import bind_dynamics, with_damping
from symplid.dynamics._integrators import Integrator
from symplid.dynamics._potentials import inverse_mass
from symplid.dynamics._trajectory import propagate, substeps
from symplid.inference._predictive import (
    PosteriorPredictive,
    check_state,
    flatten_draws,
    key_and_seed,
    positive_int,
    predictive_band,
)
from symplid.model._data import Observations
from symplid.model._statespace import HamiltonianModel

Array = jax.Array

__all__ = [
    "NoisyForecast",
    "filtered_end_states",
    "forecast_from_filter",
    "forecast_with_noise",
]


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
    x0 = check_state(x0, model.hamiltonian.dim)
    key, seed_int = key_and_seed(seed)
    key_select, key_state = jax.random.split(key)
    order = np.asarray(jax.random.permutation(key_select, theta.shape[0]))
    used = order if max_draws is None else order[: positive_int(max_draws, "max_draws")]
    prepared = model.prepare(data, t0)
    # One filter call per draw reuses the model's compiled filter (the one the fit used),
    # which costs less than compiling a vmapped filter for a one-off forecast.
    z = np.asarray(jax.random.normal(key_state, (used.shape[0], model.state_dim)))
    starts = _sample_filtered(model, theta[used], prepared, [x0] * used.shape[0], P0, z)
    inv_mass = inverse_mass(model.mass, model.hamiltonian.dim)
    coefficients = theta[used, : model.num_dynamics_params]  # θ_Ψ: with γ when damped
    if model.damping:
        integrator = with_damping(integrator)
    return predictive_band(
        model.hamiltonian, inv_mass, coefficients, starts, used, t_last, t_end, dt, integrator,
        quantiles, num_paths, seed_int, every, batch_size,
    )


def _sample_filtered(model, thetas, prepared, x0s, P0, z) -> np.ndarray:
    """One state per row of ``thetas`` from the filter's last N(m_n, P_n); NaN rows for draws
    whose filter fails."""
    starts = np.empty((len(thetas), model.state_dim))
    for i, theta in enumerate(thetas):
        res = model.filter(theta, prepared, x0s[i], P0)
        m = np.asarray(res.filtered_means[-1])
        cov = np.asarray(res.filtered_covs[-1])
        starts[i] = m + _cholesky_or_nan(cov) @ z[i]
    starts[~np.all(np.isfinite(starts), axis=1)] = np.nan
    return starts


def _cholesky_or_nan(cov: np.ndarray) -> np.ndarray:
    """Cholesky factor of a (symmetrised, slightly jittered) covariance; NaN if it fails."""
    cov = 0.5 * (cov + cov.T)
    cov = cov + 1e-14 * max(float(np.trace(cov)), 1.0) * np.eye(cov.shape[0])
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return np.full_like(cov, np.nan)


# ----------------------------------------------------------------------------- with noise
@dataclass(frozen=True)
class NoisyForecast:
    """Forecast of the state-space model (eq. 7) itself: process noise added per gap.

    Attributes
    ----------
    times
        Forecast times after the start time ``t_start`` (the last observation), shape ``(T,)``.
    t_start
        The time the forecast starts from.
    quantile_levels
        E.g. ``(0.025, 0.5, 0.975)``.
    state_quantiles, obs_quantiles
        Pointwise quantiles over the draws, shapes ``(L, T, 2d)`` and ``(L, T, d_y)``: the
        state X_k, and a new observation Y_k = h(X_k) + η (observation noise added).
    states, observations
        Every draw's sampled path and new observations, ``(S, T, 2d)`` and ``(S, T, d_y)``
        (NaN for a draw whose filter or path failed).
    obs_var
        Every draw's observation-noise variances ``(S, d_y)`` (for predictive densities;
        zeros for purely multiplicative noise).
    obs_means
        h(X) of every draw's path (no observation noise), ``(S, T, d_y)``.
    rel_var
        Every draw's relative variances of multiplicative noise ``(S, d_y)`` (zeros for
        additive noise): given X, Y has variance Γ + r ∘ h(X)² (:mod:`symplid.filters._noise`).
    """

    times: np.ndarray
    t_start: float
    quantile_levels: tuple[float, ...]
    state_quantiles: np.ndarray
    obs_quantiles: np.ndarray
    states: np.ndarray
    observations: np.ndarray
    obs_var: np.ndarray
    obs_means: np.ndarray = field(repr=False)
    rel_var: np.ndarray | None = field(default=None, repr=False)

    def band(self, level: float = 0.95, observations: bool = True) -> tuple[np.ndarray, ...]:
        """(lower, upper) of the central ``level`` band, from the draws (not the stored
        quantiles), for new observations or the state."""
        values = self.observations if observations else self.states
        tail = 0.5 * (1.0 - level)
        return tuple(_nanquantile(values, [tail, 1.0 - tail]))

    def log_predictive_density(self, values: np.ndarray) -> float:
        """Σ_k log p(y_k | data) for new values ``(T, d_y)`` at :attr:`times` (NaN = missing).

        The predictive density of each time is the Monte-Carlo mixture over the draws,
        (1/S) Σ_s N(y_k; h(x_k^s), Γ^s + r^s ∘ h(x_k^s)²), with the measured components of
        y_k only (r = 0 for additive noise).
        """
        y = np.asarray(values, dtype=float)
        mean = self.obs_means
        ok = np.all(np.isfinite(mean), axis=(1, 2))
        mean, var = mean[ok], self.obs_var[ok][:, None, :]
        if self.rel_var is not None:
            var = var + self.rel_var[ok][:, None, :] * mean**2
        measured = np.isfinite(y)
        resid = np.where(measured, y - mean, 0.0)
        terms = np.where(measured, -0.5 * (np.log(2 * np.pi * var) + resid**2 / var), 0.0)
        per_draw = terms.sum(axis=-1)  # (S, T)
        top = per_draw.max(axis=0)
        lpd = top + np.log(np.mean(np.exp(per_draw - top), axis=0))
        return float(np.sum(lpd[np.any(measured, axis=1)]))



def _nanquantile(values: np.ndarray, levels: Sequence[float]) -> np.ndarray:
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns stay NaN
        return np.nanquantile(values, levels, axis=0)


def forecast_with_noise(
    model: HamiltonianModel,
    theta_draws: Any,
    starts: Any,
    t_start: float,
    times: Any,
    seed: int | Array = 0,
    quantiles: Sequence[float] = (0.025, 0.5, 0.975),
) -> NoisyForecast:
    """Integrate the learned state-space model (eq. 7) forward from sampled states, with noise.

    Each draw θ^s starts from its own state ``starts[s]`` at ``t_start`` (e.g. a sample of
    its filtered distribution at the last observation, :func:`filtered_end_states`) and is
    carried to every time of ``times`` by the model's own propagator Ψ (its integrator at
    ⌈gap/dt⌉ equal substeps, eq. 14), with process noise ξ ~ N(0, Σ(θ^s)) added once per gap
    (for ``process_noise_per="step"``: N(0, n·Σ) over a gap of n substeps). New observations
    follow the model's observation noise (:mod:`symplid.filters._noise`): h(X) + η with
    η ~ N(0, Γ(θ^s)), h(X)∘(1 + ε) with ε ~ N(0, diag r(θ^s)), or both. This is the model
    the likelihood of Theorem 1 assumes, so a band from it can be checked against held-out data.

    Parameters
    ----------
    model
        The fitted model (a linear observation operator).
    theta_draws
        The model's θ, shape ``(S, num_params)``.
    starts
        Starting states ``(S, 2d)``; a NaN row gives a NaN path.
    t_start, times
        Start time and the increasing forecast times after it.
    seed
        Integer seed or key of the noise.
    quantiles
        Levels of the stored pointwise quantiles.
    """
    H = model.observation_matrix
    if H is None:
        raise ValueError("forecast_with_noise needs a linear observation operator")
    theta = np.atleast_2d(np.asarray(theta_draws, dtype=float))
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if starts.shape != (theta.shape[0], model.state_dim):
        raise ValueError(f"starts must have shape ({theta.shape[0]}, {model.state_dim})")
    gaps = np.diff(np.concatenate([[float(t_start)], times]))
    if times.size == 0 or np.any(gaps <= 0) or not np.all(np.isfinite(gaps)):
        raise ValueError("times must be finite, increasing and after t_start")
    num_steps, step_sizes = substeps(gaps, model.dt)  # the model's own substeps (eq. 14)
    key, _ = key_and_seed(seed)
    key_x, key_y = jax.random.split(key)
    S, T = theta.shape[0], times.size
    z = jax.random.normal(key_x, (S, T, model.state_dim))
    e = np.asarray(jax.random.normal(key_y, (S, T, H.shape[0])))
    proc, obs_var = (np.asarray(v) for v in jax.vmap(_noise_diagonals(model))(theta))
    states = _noisy_states(model, theta, starts, proc, z, num_steps, step_sizes)
    obs_mean = states @ H.T
    observations, rel_var = _new_observations(model, theta, obs_mean, obs_var, e,
                                              jax.random.fold_in(key_y, 1))
    levels = tuple(float(q) for q in quantiles)
    return NoisyForecast(
        times, float(t_start), levels, _nanquantile(states, levels),
        _nanquantile(observations, levels), states, observations, obs_var, obs_mean, rel_var,
    )


def _noise_diagonals(model: HamiltonianModel):
    """θ ↦ (diag Σ, diag Γ), to be vmapped over the draws."""

    def diagonals(theta):
        _, proc, obs = model.split(theta)
        return jnp.diagonal(proc), jnp.diagonal(obs)

    return diagonals


def _noisy_states(model: HamiltonianModel, theta: np.ndarray, starts: np.ndarray,
                  proc: np.ndarray, z: Array, num_steps: np.ndarray,
                  step_sizes: np.ndarray) -> np.ndarray:
    """Every draw's states at the forecast times ``(S, T, 2d)``: Ψ over each gap, process
    noise of variance ``proc`` added per gap (per substep: ``n·Σ`` over n), NaN where a start
    or a path is not finite. θ_Ψ is read by the layout (the coefficients' block and γ)."""
    coefficients = model.layout.unpack(theta).get(model.parameter_group, theta[:, :0])
    gammas = np.asarray(model.damping_rate(theta))  # 0 when undamped (then unused)
    noise_scale = np.sqrt(np.maximum(proc, 0.0))
    per_step = model.process_noise_per == "step"
    scale_by_gap = np.sqrt(num_steps) if per_step else np.ones(num_steps.size)
    inv_mass = inverse_mass(model.mass, model.hamiltonian.dim)
    run = jit_for(model.hamiltonian, _noisy_paths, model.integrator, int(num_steps.max()))
    states = np.array(
        run(
            jnp.asarray(coefficients),
            jnp.asarray(gammas),
            jnp.asarray(np.nan_to_num(starts)),
            jnp.asarray(noise_scale),
            z * jnp.asarray(scale_by_gap)[None, :, None],
            jnp.asarray(step_sizes),
            jnp.asarray(num_steps),
            inv_mass,
        )
    )
    states[~np.all(np.isfinite(starts), axis=1)] = np.nan
    states[~np.isfinite(states)] = np.nan
    return states


def _new_observations(model: HamiltonianModel, theta: np.ndarray, obs_mean: np.ndarray,
                      obs_var: np.ndarray, e: np.ndarray,
                      key_rel: Array) -> tuple[np.ndarray, np.ndarray | None]:
    """New observations around ``obs_mean`` by the model's observation noise (additive with
    the normals ``e``; multiplicative with normals drawn from ``key_rel``), and the relative
    variances (None without multiplicative noise)."""
    noise = model.noise_model
    if not noise.multiplicative:
        return obs_mean + np.sqrt(np.maximum(obs_var, 0.0))[:, None, :] * e, None
    rel_var = np.asarray(jax.vmap(model.relative_variances)(theta))
    e_rel = np.asarray(jax.random.normal(key_rel, e.shape))
    observations = noise.sample(
        obs_mean, np.maximum(obs_var, 0.0)[:, None, :],
        np.maximum(rel_var, 0.0)[:, None, :], np.stack([e_rel, e]),
    )
    return observations, rel_var


def _noisy_paths(potential: Any, integrator: Integrator, max_steps: int, coefficients, gammas,
                 starts, scale, z, step_sizes, num_steps, inv_mass):
    """Every draw's path over the gaps, process noise added per gap (compiled per potential
    by :func:`~symplid._compiled.jit_for`)."""
    d = potential.dim

    def one(c, g, start, sc, zz):
        dynamics = bind_dynamics(integrator, potential, c, inv_mass, g)

        def gap(x, inputs):
            h, n, zk = inputs
            q, p = propagate(integrator, dynamics, x[:d], x[d:], h, n, max_steps)
            x = jnp.concatenate([q, p]) + sc * zk
            return x, x

        _, xs = jax.lax.scan(gap, start, (step_sizes, num_steps, zz))
        return xs

    return jax.vmap(one)(coefficients, gammas, starts, scale, z)


def filtered_end_states(
    model: HamiltonianModel,
    theta_draws: Any,
    data: Observations,
    x0s: Any,
    P0: Any = None,
    t0: float = 0.0,
    seed: int | Array = 0,
) -> np.ndarray:
    """One state per draw from the filter's distribution N(m_n, P_n) at the last observation.

    ``x0s`` is one initial state ``(2d,)`` for all draws or one per draw ``(S, 2d)`` (a
    learned initial state); ``data``, ``P0`` and ``t0`` as in :meth:`HamiltonianModel.filter`.
    Rows are NaN where the filter fails.
    """
    theta = np.atleast_2d(np.asarray(theta_draws, dtype=float))
    x0s = np.asarray(x0s, dtype=float)
    if x0s.ndim == 1:
        x0s = np.broadcast_to(x0s, (theta.shape[0], x0s.shape[0]))
    key, _ = key_and_seed(seed)
    z = np.asarray(jax.random.normal(key, (theta.shape[0], model.state_dim)))
    return _sample_filtered(model, theta, model.prepare(data, t0), x0s, P0, z)
