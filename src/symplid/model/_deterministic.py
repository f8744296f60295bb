"""The deterministic-trajectory likelihood: the observations around one integrated path.

With ``process_noise_per="none"`` the state-space model of eq. (7) loses its process noise,

    X_k = Ψ(X_{k−1}; θ_Ψ),   Y_k = h(X_k) + η_k   (or the multiplicative models of
    :mod:`symplid.filters._noise`),

so the states are one path of the propagator Ψ (the integrator over each gap in ⌈gap/dt⌉
equal substeps, eq. 14, exactly as inside the filter) from the initial state x0, and the
observations are independent given θ and x0. The log-likelihood is then exact and needs no
filter:

    log p(y_1..n | θ, x0) = Σ_k log N(y_k; h(x_k), R_k),   x_k = Ψ(x_{k−1}),

with R_k = Γ for additive noise and Γ + diag(r ∘ h(x_k)∘h(x_k)) for multiplicative noise (the
noise model's covariance with the state's covariance zero: for a known state it is the exact
variance of Y_k; every registered noise model has independent components, so each term is a
sum of univariate densities). Missing components (NaN in the data, ``mask`` False) are left
out of each term. No sigma points and no jitter: one path instead of 2n + 1
(``benchmarks/deterministic_likelihood.py`` times it against the filter).

The initial state is the point x0 (known or learned); its covariance P0 does not enter (a
spread initial state would need a filter, see
:class:`~symplid.model._posterior.Posterior`). The result is a
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

from symplid.dynamics._damping import bind_dynamics
from symplid.dynamics._forced import at_gap, bind_forced
from symplid.dynamics._potentials import inverse_mass
from symplid.dynamics._trajectory import propagate
from symplid.filters import FilterResult, ObservationMoments

Array = jax.Array

__all__ = ["bind_model_dynamics", "build_trajectory_likelihood", "noise_variances"]

_LOG_2PI = math.log(2.0 * math.pi)


def bind_model_dynamics(model: Any, theta: Array, inv_mass: Any) -> Any:
    """The dynamics the model's integrator steps, from θ: a driven model's force bound with
    θ_Ψ = [H's parameters, θ_F] (:func:`~symplid.dynamics._forced.bind_forced`; each gap's
    inputs are put in by the prediction), else H's coefficients and γ, read through the
    layout (:func:`~symplid.dynamics._damping.bind_dynamics`)."""
    force = getattr(model, "force", None)
    if force is not None:
        return bind_forced(model.hamiltonian, force, theta[..., :model.num_dynamics_params],
                           inv_mass)
    return bind_dynamics(model.integrator, model.hamiltonian, model.split(theta)[0], inv_mass,
                         model.damping_rate(theta))


def build_trajectory_likelihood(
    model: Any, max_steps: int, uniform_steps: bool
) -> Callable[..., FilterResult]:
    """The deterministic likelihood as ``fn(theta, inputs, ys, masks, x0, P0) -> FilterResult``.

    The same call signature as :func:`~symplid.model._likelihood.build_filter` (``P0`` is not
    used); not jitted. ``max_steps`` and ``uniform_steps`` come from the prepared data.
    ``log_likelihood`` is −∞ when a variance is not positive or a term is not finite.
    """
    nc = model.num_dynamics_params  # θ_Ψ: the coefficients, and γ for a damped model
    d = model.hamiltonian.dim
    observe = _observer(model)

    def trajectory_fn(theta, inputs, ys, masks, x0, p0) -> FilterResult:
        del p0  # one path from the point x0 (module docstring)
        variances = theta[nc:]
        variances_ok = jnp.all(variances > 0)
        # Invalid variances give −∞; meanwhile the terms use their absolute values so that no
        # NaN reaches the gradient through the discarded branch (as in the filter).
        theta = theta.at[nc:].set(jnp.where(variances > 0, variances, jnp.abs(variances) + 1e-12))
        inv_mass = inverse_mass(model.mass, d)
        dynamics = bind_model_dynamics(model, theta, inv_mass)
        force = getattr(model, "force", None)

        def gap(x, inp):
            if force is not None:
                gap_dynamics = at_gap(dynamics, inp.times, inp.inputs)
            else:
                gap_dynamics = dynamics
            q, p = propagate(model.integrator, gap_dynamics, x[:d], x[d:], inp.step_size,
                             inp.num_steps, max_steps, model.unroll, masked=not uniform_steps)
            x = jnp.concatenate([q, p])
            return x, x

        # The loop carries the path only; the observation terms are elementwise over all
        # times at once after it (inside the loop they cost several times the path itself).
        _, path = jax.lax.scan(gap, jnp.asarray(x0, dtype=float), inputs)
        y_hat = jax.vmap(observe)(path)
        var = jax.vmap(noise_variances(model, theta))(y_hat)
        residual = jnp.where(masks, ys - y_hat, 0.0)
        var = jnp.where(masks, var, 1.0)
        terms = jnp.sum(jnp.where(masks, -0.5 * (residual**2 / var + jnp.log(var) + _LOG_2PI),
                                  0.0), axis=1)
        total = jnp.sum(terms)
        total = jnp.where(variances_ok & jnp.isfinite(total), total, -jnp.inf)
        covs = jnp.zeros((*path.shape, path.shape[-1]), path.dtype)
        return FilterResult(total, path, covs, path, covs, terms)

    return trajectory_fn


def noise_variances(model: Any, theta: Array) -> Callable[[Array], Array]:
    """``h(x) -> Var[Y | X = x]`` per observed component: the diagonal of the noise model's
    covariance (:mod:`symplid.filters._noise`) at a known state, Γ or Γ + diag(r ∘ h∘h).

    Every noise model of :data:`~symplid.filters._noise.OBSERVATION_NOISE` has independent
    components (Γ and r are diagonal), so this diagonal is the whole covariance.
    """
    noise = model.noise_covariance(theta)  # Γ, or moments -> R_k
    d_x = int(model.state_dim)

    def variances(y_hat: Array) -> Array:
        d_y = y_hat.shape[0]
        eye = jnp.eye(d_y, dtype=y_hat.dtype)
        if callable(noise):  # the state is known: S_h = 0, C = 0
            cov = noise(ObservationMoments(y_hat, 0.0 * eye, jnp.zeros((d_x, d_y), y_hat.dtype)))
        else:
            cov = noise
        return jnp.sum(eye * cov, axis=-1)  # the diagonal by a mask (no gather)

    return variances


def _observer(model: Any) -> Callable[[Array], Array]:
    """``x -> h(x)`` as a flat vector: the matrix product for a linear h, else the function."""
    matrix = model.observation_matrix
    if matrix is not None:
        h = np.asarray(matrix)  # a constant: built outside any trace
        return lambda x: jnp.sum(h * x[None, :], axis=1)
    observe = model.observation
    return lambda x: jnp.ravel(observe(x))
