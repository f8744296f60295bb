"""Where the chains start: overdispersed points around the MAP, or points given, and the
samplers' first states there (see :mod:`~symplid.sampling._api`, "Starting points").
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.inference.samplers._registry import SamplerKernel, SamplerSpec
from symplid.model._params import pushforward_covariance

__all__ = ["chain_starts", "overdispersed_starts"]


def chain_starts(posterior: Any, spec: Any, kernel: SamplerKernel, batch_logdensity: Any,
                  init: Any, num_params: int, seed: int, num_chains: int,
                  init_spread: float, initial_positions: Any) -> tuple[Any, ...]:
    """The MAP (θ, covariance) the chains start around, their starting points and states,
    the kernel's initial attributes, and the key the run then draws from."""
    theta_map, cov_map = _check_map(init, num_params, batch_logdensity, num_chains)
    init_key, run_key = jax.random.split(jax.random.key(seed), 2)
    if initial_positions is None:
        starts = overdispersed_starts(init_key, batch_logdensity, theta_map, cov_map,
                                      num_chains, init_spread)
    else:
        starts = _explicit_starts(initial_positions, num_chains, num_params)
    states, extra_attrs = _initial_states(posterior, spec, kernel, starts, theta_map, cov_map)
    return theta_map, cov_map, starts, states, extra_attrs, run_key


def _check_map(init: Any, num_params: int, batch_logdensity: Callable,
               num_chains: int) -> tuple[np.ndarray, np.ndarray]:
    for name in ("theta", "covariance"):
        if not hasattr(init, name):
            raise TypeError(
                f"init lacks .{name}: pass the result of symplid.find_map (an object with "
                ".theta and .covariance)"
            )
    theta = np.asarray(init.theta, dtype=np.float64)
    cov = np.asarray(init.covariance, dtype=np.float64)
    if theta.shape != (num_params,):
        raise ValueError(f"init.theta must have shape ({num_params},), got {theta.shape}")
    if cov.shape != (num_params, num_params):
        raise ValueError(
            f"init.covariance must have shape ({num_params}, {num_params}), got {cov.shape}"
        )
    if not np.all(np.isfinite(cov)):
        raise ValueError("init.covariance contains non-finite entries")
    try:
        np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        raise ValueError("init.covariance is not positive definite") from None
    # Same batch shape as the starting points: one compilation serves both.
    value = float(batch_logdensity(jnp.tile(jnp.asarray(theta), (num_chains, 1)))[0])
    if not np.isfinite(value):
        raise ValueError(f"the log density at init.theta is not finite ({value})")
    return theta, 0.5 * (cov + cov.T)


def overdispersed_starts(
    rng_key: jax.Array,
    batch_logdensity: Callable[[jax.Array], jax.Array],
    center: np.ndarray,
    cov: np.ndarray,
    num_chains: int,
    spread: float = 2.0,
    max_tries: int = 100,
) -> np.ndarray:
    """Starting points ``center + spread·L z`` with a finite log density, one per chain.

    Parameters
    ----------
    rng_key
        Key for the draws (round ``r`` uses ``fold_in(rng_key, r)``).
    batch_logdensity
        Log density over the parameters, vectorised over a leading axis
        (e.g. ``jax.jit(jax.vmap(posterior.log_density))``).
    center, cov
        The MAP and its covariance (``L`` is the Cholesky factor of ``cov``).
    num_chains
        Number of starting points.
    spread
        Multiplier of ``L z``; 0 puts every chain at ``center``.
    max_tries
        Rounds of redrawing before a chain falls back to ``center`` (with a warning).

    Returns
    -------
    numpy.ndarray
        Shape ``(num_chains, d)``.
    """
    center = np.asarray(center, dtype=np.float64)
    starts = np.tile(center, (num_chains, 1))
    if spread == 0:
        return starts
    chol = np.linalg.cholesky(cov)
    pending = np.ones(num_chains, dtype=bool)
    for attempt in range(max_tries):
        z = np.asarray(jax.random.normal(jax.random.fold_in(rng_key, attempt),
                                         (num_chains, center.size)))
        candidates = center + spread * z @ chol.T
        finite = np.isfinite(np.asarray(batch_logdensity(jnp.asarray(candidates))))
        take = pending & finite
        starts[take] = candidates[take]
        pending &= ~take
        if not pending.any():
            return starts
    warnings.warn(
        f"{int(pending.sum())} chain(s) found no start with a finite log density within "
        f"{max_tries} draws at init_spread={spread}; they start at the MAP",
        UserWarning,
        stacklevel=3,
    )
    return starts


def _explicit_starts(initial_positions: Any, num_chains: int, num_params: int) -> np.ndarray:
    starts = np.asarray(initial_positions, dtype=np.float64)
    if starts.shape != (num_chains, num_params):
        raise ValueError(
            f"initial_positions must have shape ({num_chains}, {num_params}), "
            f"got {starts.shape}"
        )
    return starts


def _initial_states(posterior: Any, spec: SamplerSpec, kernel: SamplerKernel,
                    starts: np.ndarray, theta_map: np.ndarray,
                    cov_map: np.ndarray) -> tuple[Any, dict[str, Any]]:
    """The chains' first states, from θ and the MAP covariance (pushed to z when the sampler
    moves in the unconstrained space), and the attributes that records."""
    if not spec.unconstrained:
        if kernel.covariance_at is not None:  # e.g. DRAM with the variances on a log scale
            cov_map = kernel.covariance_at(theta_map, cov_map)
        return kernel.init_states(jnp.asarray(starts), jnp.asarray(cov_map)), {}
    cov_z = pushforward_covariance(posterior.to_unconstrained, theta_map, cov_map)
    z_starts = np.asarray(jax.vmap(posterior.to_unconstrained)(jnp.asarray(starts)))
    if not np.all(np.isfinite(z_starts)):
        raise ValueError(
            "a starting point lies on a bound of the parameters (its unconstrained "
            "value is infinite); use init_spread > 0 or move initial_positions inside"
        )
    states = kernel.init_states(jnp.asarray(starts), jnp.asarray(cov_z))
    return states, {"unconstrained_map_covariance": cov_z.tolist()}
