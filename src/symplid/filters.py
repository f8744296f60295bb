"""The unscented Kalman filter and the log marginal likelihood of Theorem 1 (eqs 10–12).

Pure functions over arrays, written for small states (a handful of coordinates): the
Cholesky factorisation and the triangular solves are unrolled at trace time for dimensions up
to :data:`SMALL_DIM`, so XLA fuses them with the surrounding arithmetic instead of calling
LAPACK for a 4×4 matrix. Larger problems fall back to ``jnp.linalg``.

Numerical hygiene: every covariance is symmetrised and receives ``jitter·I``; a Cholesky
factorisation that fails shows up as a non-finite number, and :func:`filter_log_likelihood`
maps any non-finite log-likelihood to −∞. Nothing raises inside ``jit``.

Building blocks:

* :func:`unscented_weights`: the scaled unscented transform's weights (α, β, κ).
* :func:`sigma_points`: 2n+1 points whose weighted moments are (m, P).
* :func:`unscented_predict`: prediction step, eq. (10), with process noise Q added once.
* :func:`observation_moments_linear` / :func:`observation_moments_unscented`: the predicted
  observation, its covariance S and the state–observation cross-covariance C.
* :func:`gaussian_update`: update and marginalisation, eqs (11)–(12), with missing components.
* :func:`filter_log_likelihood`: the recursion over all observations (``lax.scan``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array

SMALL_DIM = 8
_LOG_2PI = math.log(2.0 * math.pi)


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


def symmetrize(a: Array) -> Array:
    return 0.5 * (a + a.T)


def cholesky(a: Array) -> Array:
    """Lower Cholesky factor. Unrolled for n ≤ SMALL_DIM; NaN or inf (never an error) on failure."""
    n = a.shape[-1]
    if n > SMALL_DIM:
        return jnp.linalg.cholesky(a)
    rows: list[list[Array]] = [[None] * n for _ in range(n)]  # type: ignore[list-item]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s = s - rows[j][k] * rows[j][k]
        d = jnp.sqrt(s)
        rows[j][j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t = t - rows[i][k] * rows[j][k]
            rows[i][j] = t / d
    zero = jnp.zeros_like(a[0, 0])
    return jnp.stack(
        [jnp.stack([rows[i][j] if j <= i else zero for j in range(n)]) for i in range(n)]
    )


def solve_lower(chol: Array, b: Array) -> Array:
    """Solve L x = b by forward substitution; ``b`` has shape ``(n,)`` or ``(n, k)``."""
    n = chol.shape[-1]
    if n > SMALL_DIM:
        return jax.scipy.linalg.solve_triangular(chol, b, lower=True)
    xs: list[Array] = []
    for i in range(n):
        s = b[i]
        for k in range(i):
            s = s - chol[i, k] * xs[k]
        xs.append(s / chol[i, i])
    return jnp.stack(xs)


def sigma_points(mean: Array, cov: Array, scale: float) -> Array:
    """The 2n+1 sigma points ``m, m ± scale·L[:, i]`` with L Lᵀ = P; shape ``(2n+1, n)``."""
    spread = scale * cholesky(cov).T  # row i = scale * column i of L
    return jnp.concatenate([mean[None, :], mean + spread, mean - spread], axis=0)


def weighted_moments(points: Array, weights: UnscentedWeights) -> tuple[Array, Array, Array]:
    """Mean, covariance and centred points of a weighted point set ``(2n+1, k)``."""
    mean = jnp.einsum("s,si->i", weights.mean, points)
    centred = points - mean
    cov = jnp.einsum("s,si,sj->ij", weights.cov, centred, centred)
    return mean, cov, centred


def unscented_predict(
    mean: Array,
    cov: Array,
    transition: Callable[[Array], Array],
    process_cov: Array,
    weights: UnscentedWeights,
    jitter: float,
) -> tuple[Array, Array]:
    """Prediction, eq. (10): push sigma points through ``transition`` and add Σ once.

    ``transition`` maps the whole ``(2n+1, n)`` set of sigma points at once.
    """
    points = transition(sigma_points(mean, cov, weights.scale))
    m, p, _ = weighted_moments(points, weights)
    p = symmetrize(p + process_cov) + jitter * jnp.eye(p.shape[0], dtype=p.dtype)
    return m, p


class ObservationMoments(NamedTuple):
    predicted: Array  # ŷ, (d_y,)
    cov: Array  # S without Γ, (d_y, d_y)
    cross: Array  # C = Cov(x, y), (d_x, d_y)


def observation_moments_linear(mean: Array, cov: Array, matrix: Array) -> ObservationMoments:
    """ŷ = Hm, S = HPHᵀ, C = PHᵀ: exact for a linear observation operator."""
    cross = cov @ matrix.T
    return ObservationMoments(matrix @ mean, matrix @ cross, cross)


def observation_moments_unscented(
    mean: Array, cov: Array, observe: Callable[[Array], Array], weights: UnscentedWeights
) -> ObservationMoments:
    """Moments of h(X) for a nonlinear observation, from sigma points redrawn at (m, P)."""
    points = sigma_points(mean, cov, weights.scale)
    obs = jax.vmap(observe)(points)
    y_mean, s, y_centred = weighted_moments(obs, weights)
    cross = jnp.einsum("s,si,sj->ij", weights.cov, points - mean, y_centred)
    return ObservationMoments(y_mean, s, cross)


def gaussian_update(
    mean: Array,
    cov: Array,
    y: Array,
    mask: Array,
    moments: ObservationMoments,
    obs_cov: Array,
    jitter: float,
) -> tuple[Array, Array, Array]:
    """Update and marginalisation, eqs (11)–(12), for the observed components of ``y``.

    Missing components (``mask`` False) are decoupled: their innovation is zero, their rows
    and columns of S are replaced by the identity and their cross-covariance by zero, so they
    contribute nothing to the gain, the covariance or the likelihood.

    Returns the filtered mean, covariance and log p(y_k | y_1..k−1).
    """
    d_y = y.shape[0]
    pair = mask[:, None] & mask[None, :]
    innovation = jnp.where(mask, y - moments.predicted, 0.0)
    s = jnp.where(pair, symmetrize(moments.cov + obs_cov), jnp.eye(d_y, dtype=cov.dtype))
    cross = jnp.where(mask[None, :], moments.cross, 0.0)
    chol = cholesky(s)
    z = solve_lower(chol, innovation)  # L⁻¹ v
    w = solve_lower(chol, cross.T).T  # C L⁻ᵀ, so K = W L⁻¹
    new_mean = mean + w @ z
    new_cov = symmetrize(cov - w @ w.T) + jitter * jnp.eye(cov.shape[0], dtype=cov.dtype)
    num_observed = jnp.sum(mask)
    log_lik = (
        -0.5 * jnp.dot(z, z)
        - jnp.sum(jnp.log(jnp.diagonal(chol)))
        - 0.5 * num_observed * _LOG_2PI
    )
    return new_mean, new_cov, log_lik


class FilterResult(NamedTuple):
    """Output of :func:`run_filter`."""

    log_likelihood: Array  # scalar, −∞ when anything failed
    filtered_means: Array  # (n, d_x)
    filtered_covs: Array  # (n, d_x, d_x)
    predicted_means: Array  # (n, d_x)
    predicted_covs: Array  # (n, d_x, d_x)
    log_likelihood_terms: Array  # (n,)


def run_filter(
    predict: Callable[[Array, Array, object], tuple[Array, Array]],
    moments: Callable[[Array, Array], ObservationMoments],
    mean0: Array,
    cov0: Array,
    inputs: object,
    ys: Array,
    masks: Array,
    obs_cov: Array,
    jitter: float,
) -> FilterResult:
    """The UKF recursion of Theorem 1 over all observations, as one ``lax.scan``.

    Parameters
    ----------
    predict
        ``predict(mean, cov, inputs_k) -> (mean⁻, cov⁻)``: eq. (10) over the gap before y_k.
    moments
        ``moments(mean⁻, cov⁻) -> ObservationMoments`` for the observation operator.
    inputs
        A pytree with a leading axis of length n: what ``predict`` needs per gap.
    ys, masks
        Observations ``(n, d_y)`` with missing entries set to any finite value, and the
        ``(n, d_y)`` boolean mask of measured entries.
    """

    def body(carry, xs):
        mean, cov = carry
        inp, y, mask = xs
        m_pred, p_pred = predict(mean, cov, inp)
        m_new, p_new, ll = gaussian_update(
            m_pred, p_pred, y, mask, moments(m_pred, p_pred), obs_cov, jitter
        )
        return (m_new, p_new), (m_new, p_new, m_pred, p_pred, ll)

    _, (means, covs, m_preds, p_preds, terms) = jax.lax.scan(
        body, (mean0, cov0), (inputs, ys, masks)
    )
    total = jnp.sum(terms)
    total = jnp.where(jnp.isfinite(total), total, -jnp.inf)
    return FilterResult(total, means, covs, m_preds, p_preds, terms)
