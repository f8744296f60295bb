"""The deterministic-trajectory likelihood: the observations around one integrated path.

With ``process_noise_per="none"`` the state-space model of eq. (7) loses its process noise,

    X_k = Ψ(X_{k−1}; θ_Ψ),   Y_k = h(X_k) + η_k   (or the multiplicative models of
    :mod:`symplid.filters.noise`),

so the states are one path of the propagator Ψ (the integrator over each gap in ⌈gap/dt⌉
equal substeps, eq. 14, exactly as inside the filter) from the initial state x0, and the
observations are independent given θ and x0. The log-likelihood is then exact and needs no
filter:

    log p(y_1..n | θ, x0) = Σ_k log N(y_k; h(x_k), R_k),   x_k = Ψ(x_{k−1}),

with R_k = Γ for additive noise and Γ + diag(r ∘ h(x_k)∘h(x_k)) for multiplicative noise (the
noise model's covariance with the state's covariance zero: for a known state it is the exact
variance of Y_k). Missing components (NaN in the data, ``mask`` False) are left out of each
term. No sigma points and no jitter: one path instead of 2n + 1, so it costs about 1/(2n+1)
of the unscented filter's prediction.

The initial state is the point x0 (known or learned); its covariance P0 does not enter (a
spread initial state would need a filter, see
:class:`~symplid.model.posterior.Posterior`). The result is a
:class:`~symplid.filters.FilterResult` like the filter's, with the path as the filtered and
predicted means and zero covariances, so forecasts and predictions that start from "the
filtered state at the last observation" start from the path's end.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics.damping import bind_dynamics
from symplid.dynamics.potentials import inverse_mass
from symplid.dynamics.trajectory import propagate
from symplid.filters import FilterResult, ObservationMoments, cholesky, solve_lower, symmetrize

Array = jax.Array

__all__ = ["build_trajectory_likelihood", "masked_gaussian_log_density"]

_LOG_2PI = math.log(2.0 * math.pi)


def masked_gaussian_log_density(y: Array, mean: Array, cov: Array, mask: Array) -> Array:
    """log N(y; mean, cov) over the components where ``mask`` is True.

    The unmeasured components are decoupled as in the filter's update
    (:func:`~symplid.filters.gaussian_update`): zero residual, identity rows and columns, so
    they contribute nothing. NaN or inf (never an error) when ``cov`` restricted to the
    measured components is not positive definite.
    """
    d_y = y.shape[0]
    pair = mask[:, None] & mask[None, :]
    residual = jnp.where(mask, y - mean, 0.0)
    s = jnp.where(pair, symmetrize(cov), jnp.eye(d_y, dtype=cov.dtype))
    chol = cholesky(s)
    z = solve_lower(chol, residual)
    log_diag = jnp.log(jnp.sum(jnp.where(jnp.eye(d_y, dtype=bool), chol, 0.0), axis=-1))
    return -0.5 * jnp.sum(z * z) - jnp.sum(log_diag) - 0.5 * jnp.sum(mask) * _LOG_2PI


def build_trajectory_likelihood(
    model: Any, max_steps: int, uniform_steps: bool
) -> Callable[..., FilterResult]:
    """The deterministic likelihood as ``fn(theta, inputs, ys, masks, x0, P0) -> FilterResult``.

    The same call signature as :func:`~symplid.model.likelihood.build_filter` (``P0`` is not
    used); not jitted. ``max_steps`` and ``uniform_steps`` come from the prepared data.
    ``log_likelihood`` is −∞ when a variance is not positive or a term is not finite.
    """
    nc = model.num_dynamics_params  # θ_Ψ: the coefficients, and γ for a damped model
    d = model.potential.dim
    observe = _observer(model)
    multiplicative = bool(model.noise_model.multiplicative)

    def trajectory_fn(theta, inputs, ys, masks, x0, p0) -> FilterResult:
        del p0  # one path from the point x0 (module docstring)
        variances = theta[nc:]
        variances_ok = jnp.all(variances > 0)
        # Invalid variances give −∞; meanwhile the terms use their absolute values so that no
        # NaN reaches the gradient through the discarded branch (as in the filter).
        theta = theta.at[nc:].set(jnp.where(variances > 0, variances, jnp.abs(variances) + 1e-12))
        inv_mass = inverse_mass(model.mass, d)
        dynamics = bind_dynamics(model.integrator, model.potential, theta[:nc], inv_mass)
        noise = model.noise_covariance(theta)  # Γ, or moments -> R_k (filters.noise)

        def gap(x, xs):
            inp, y, mask = xs
            q, p = propagate(model.integrator, dynamics, x[:d], x[d:], inp.step_size,
                             inp.num_steps, max_steps, model.unroll, masked=not uniform_steps)
            x = jnp.concatenate([q, p])
            y_hat = observe(x)
            if multiplicative:  # the state is known: S_h = 0, C = 0
                zero = jnp.zeros((y_hat.shape[0], y_hat.shape[0]), y_hat.dtype)
                cov = noise(ObservationMoments(y_hat, zero, jnp.zeros((2 * d, y_hat.shape[0]))))
            else:
                cov = noise
            return x, (x, masked_gaussian_log_density(y, y_hat, cov, mask))

        _, (path, terms) = jax.lax.scan(gap, jnp.asarray(x0, dtype=float), (inputs, ys, masks))
        total = jnp.sum(terms)
        total = jnp.where(variances_ok & jnp.isfinite(total), total, -jnp.inf)
        covs = jnp.zeros((*path.shape, path.shape[-1]), path.dtype)
        return FilterResult(total, path, covs, path, covs, terms)

    return trajectory_fn


def _observer(model: Any) -> Callable[[Array], Array]:
    """``x -> h(x)`` as a flat vector: the matrix product for a linear h, else the function."""
    matrix = model.observation_matrix
    if matrix is not None:
        h = np.asarray(matrix)  # a constant: built outside any trace
        return lambda x: jnp.sum(h * x[None, :], axis=1)
    observe = model.observation
    return lambda x: jnp.ravel(observe(x))
