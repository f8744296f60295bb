"""The scaled unscented transform: weights, sigma points and the prediction step, eq. (10).

Points are stored as **columns**, shape ``(n, 2n+1)``, so that every substep of the
propagator is elementwise over the points:

* :func:`unscented_weights`: the scaled unscented transform's weights (α, β, κ).
* :func:`sigma_points`: 2n+1 points whose weighted moments are (m, L Lᵀ).
* :func:`unscented_predict`: prediction step, eq. (10), with process noise Σ added once.
* :func:`observation_moments_linear` / :func:`observation_moments_unscented`: the predicted
  observation, its covariance S (without Γ) and the state–observation cross-covariance C.

Covariances are symmetrised and receive ``jitter·I`` after prediction.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid.filters._linalg import cholesky, matmul, symmetrize

__all__ = [
    "ObservationMoments",
    "UnscentedWeights",
    "observation_moments_linear",
    "observation_moments_unscented",
    "sigma_points",
    "unscented_predict",
    "unscented_weights",
    "weighted_moments",
]

Array = jax.Array


class UnscentedWeights(NamedTuple):
    """Weights of the scaled unscented transform for an ``n``-dimensional state."""

    mean: np.ndarray  # (2n+1,)
    cov: np.ndarray  # (2n+1,)
    scale: float  # sqrt(n + λ)


def unscented_weights(n: int, alpha: float, beta: float, kappa: float) -> UnscentedWeights:
    """Van der Merwe's scaled weights: λ = α²(n+κ) − n, W₀ᵐ = λ/(n+λ), W₀ᶜ = W₀ᵐ + 1 − α² + β.

    Raises ``ValueError`` when n + λ ≤ 0 (the sigma points would not exist).
    """
    if alpha <= 0:
        raise ValueError(f"alpha must be positive, got {alpha}")
    lam = alpha**2 * (n + kappa) - n
    if n + lam <= 0:
        raise ValueError(f"n + λ = {n + lam:g} ≤ 0 for alpha={alpha}, kappa={kappa}: choose κ > −n")
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = wm[0] + 1.0 - alpha**2 + beta
    return UnscentedWeights(wm, wc, math.sqrt(n + lam))


def sigma_points(mean: Array, chol: Array, scale: float) -> Array:
    """The 2n+1 sigma points ``m, m + scale·L[:, i], m − scale·L[:, i]`` as columns ``(n, 2n+1)``.

    ``chol`` is the lower Cholesky factor L of the covariance (L Lᵀ = P).
    """
    spread = scale * chol
    return jnp.concatenate([mean[:, None], mean[:, None] + spread, mean[:, None] - spread], axis=1)


def weighted_moments(points: Array, weights: UnscentedWeights) -> tuple[Array, Array, Array]:
    """Mean, covariance and centred points of weighted points stored as columns ``(k, 2n+1)``."""
    mean = jnp.sum(points * weights.mean, axis=1)
    centred = points - mean[:, None]
    cov = jnp.sum(weights.cov * centred[:, None, :] * centred[None, :, :], axis=-1)
    return mean, cov, centred


def unscented_predict(
    mean: Array,
    chol: Array,
    transition: Callable[[Array], Array],
    process_cov: Array,
    weights: UnscentedWeights,
    jitter: float,
) -> tuple[Array, Array, Array]:
    """Prediction, eq. (10): push sigma points through ``transition`` and add Σ once.

    ``transition`` maps the whole ``(n, 2n+1)`` set of sigma points (columns) at once.
    Returns the predicted mean, the predicted covariance and the propagated points.
    """
    points = transition(sigma_points(mean, chol, weights.scale))
    m, p, _ = weighted_moments(points, weights)
    p = symmetrize(p + process_cov) + jitter * jnp.eye(p.shape[0], dtype=p.dtype)
    return m, p, points


class ObservationMoments(NamedTuple):
    predicted: Array  # ŷ, (d_y,)
    cov: Array  # S without Γ, (d_y, d_y)
    cross: Array  # C = Cov(x, y), (d_x, d_y)


def observation_moments_linear(mean: Array, cov: Array, matrix: Array) -> ObservationMoments:
    """ŷ = Hm, S = HPHᵀ, C = PHᵀ: exact for a linear observation operator."""
    cross = matmul(cov, matrix.T)
    return ObservationMoments(matmul(matrix, mean), matmul(matrix, cross), cross)


def observation_moments_unscented(
    mean: Array, cov: Array, observe: Callable[[Array], Array], weights: UnscentedWeights
) -> ObservationMoments:
    """Moments of h(X) for a nonlinear observation, from sigma points redrawn at (m, P)."""
    points = sigma_points(mean, cholesky(cov), weights.scale)
    obs = jax.vmap(observe, in_axes=1, out_axes=1)(points)
    y_mean, s, y_centred = weighted_moments(obs, weights)
    centred = points - mean[:, None]
    cross = jnp.sum(weights.cov * centred[:, None, :] * y_centred[None, :, :], axis=-1)
    return ObservationMoments(y_mean, s, cross)
