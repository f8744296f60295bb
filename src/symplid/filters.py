"""The unscented Kalman filter and the log marginal likelihood of Theorem 1 (eqs 10–12).

Pure functions over arrays, written for small states (a handful of coordinates): the
Cholesky factorisation and the triangular solves are unrolled at trace time for dimensions up
to :data:`SMALL_DIM`, so XLA fuses them with the surrounding arithmetic instead of calling
LAPACK for a 4×4 matrix. Larger problems fall back to ``jnp.linalg``.

The filter carries the state's mean and the **Cholesky factor** of its covariance. The update
factorises the joint covariance of (y, x) once,

    [[S, Cᵀ], [C, P⁻]] = [[L_S, 0], [W, L⁺]] [[L_S, 0], [W, L⁺]]ᵀ,

which gives at once the innovation's factor L_S (for eq. 12), the gain factor W = C L_S⁻ᵀ and
the factor L⁺ of the filtered covariance P⁺ = P⁻ − W Wᵀ: the next gap's sigma points need no
second factorisation, and P⁺ = L⁺L⁺ᵀ is positive semi-definite by construction.

Small matrices are multiplied by broadcast-and-sum rather than ``dot``: for 4×9 operands XLA
fuses the former with its neighbours, while every ``dot`` is a separate library call.

Numerical hygiene: covariances are symmetrised and receive ``jitter·I`` after prediction; a
factorisation that fails shows up as a non-finite number, and :func:`run_filter` maps any
non-finite log-likelihood to −∞. Nothing raises inside ``jit``.

Building blocks (points are stored as **columns**, shape ``(n, 2n+1)``):

* :func:`unscented_weights`: the scaled unscented transform's weights (α, β, κ).
* :func:`sigma_points`: 2n+1 points whose weighted moments are (m, L Lᵀ).
* :func:`unscented_predict`: prediction step, eq. (10), with process noise Σ added once.
* :func:`observation_moments_linear` / :func:`observation_moments_unscented`: the predicted
  observation, its covariance S (without Γ) and the state–observation cross-covariance C.
* :func:`gaussian_update`: update and marginalisation, eqs (11)–(12), with missing components.
* :func:`run_filter`: the recursion over all observations (one ``lax.scan``).
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
    return 0.5 * (a + jnp.swapaxes(a, -1, -2))


def matmul(a: Array, b: Array) -> Array:
    """``a @ b`` for small matrices or a matrix and a vector, by broadcast-and-sum (fuses)."""
    if b.ndim == 1:
        return jnp.sum(a * b[None, :], axis=1)
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def cholesky(a: Array) -> Array:
    """Lower Cholesky factor; NaN or inf (never an error) when ``a`` is not positive definite.

    For n ≤ SMALL_DIM this is the right-looking algorithm unrolled at trace time: one column
    and one rank-1 update of the trailing matrix per step, a few fused kernels per column
    instead of a LAPACK call or one kernel per scalar.
    """
    n = a.shape[-1]
    if n > SMALL_DIM + 1:
        return jnp.linalg.cholesky(a)
    return cholesky_columns(a, n)


def cholesky_columns(a: Array, num_columns: int) -> Array:
    """The first ``num_columns`` columns of the lower Cholesky factor, shape ``(n, num_columns)``.

    Right-looking and unrolled; later columns are never formed, so nothing is computed (or
    differentiated) from the trailing block beyond them.
    """
    n = a.shape[-1]
    idx = jnp.arange(n)
    cols = []
    for j in range(num_columns):
        col = jnp.where(idx >= j, a[:, j] / jnp.sqrt(a[j, j]), 0.0)
        cols.append(col)
        if j < num_columns - 1:
            a = a - col[:, None] * col[None, :]
    return jnp.stack(cols, axis=1)


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


def gaussian_update(
    mean: Array,
    cov: Array,
    y: Array,
    mask: Array,
    moments: ObservationMoments,
    obs_cov: Array,
) -> tuple[Array, Array, Array]:
    """Update and marginalisation, eqs (11)–(12), for the observed components of ``y``.

    One Cholesky factorisation of the joint covariance of (y, x) gives L_S, W = C L_S⁻ᵀ and
    the factor L⁺ of P⁺ = P⁻ − C S⁻¹ Cᵀ (see the module docstring); with z = L_S⁻¹ v,
    m⁺ = m⁻ + W z and log p(y_k | y_1..k−1) = −½ zᵀz − Σ log diag L_S − ½ d log 2π.

    Missing components (``mask`` False) are decoupled: their innovation is zero, their rows
    and columns of S are replaced by the identity and their cross-covariance by zero, so they
    contribute nothing to the gain, the covariance or the likelihood.

    Returns the filtered mean, the Cholesky factor of the filtered covariance, and the
    log-likelihood term.
    """
    d_y, d_x = y.shape[0], mean.shape[0]
    pair = mask[:, None] & mask[None, :]
    innovation = jnp.where(mask, y - moments.predicted, 0.0)
    s = jnp.where(pair, symmetrize(moments.cov + obs_cov), jnp.eye(d_y, dtype=cov.dtype))
    cross = jnp.where(mask[None, :], moments.cross, 0.0)
    # The innovation rides along as a last row: the factor's last row then holds zᵀ = (L_S⁻¹v)ᵀ.
    # Only the first d_y + d_x columns are formed (the last diagonal entry is not needed).
    joint = jnp.concatenate(
        [
            jnp.concatenate([s, cross.T, innovation[:, None]], axis=1),
            jnp.concatenate([cross, cov, jnp.zeros((d_x, 1), cov.dtype)], axis=1),
            jnp.concatenate([innovation, jnp.zeros(d_x + 1, cov.dtype)])[None, :],
        ],
        axis=0,
    )
    factor = cholesky_columns(joint, d_y + d_x)
    chol_s = factor[:d_y, :d_y]
    gain = factor[d_y : d_y + d_x, :d_y]  # W = C L_S⁻ᵀ
    chol_post = factor[d_y : d_y + d_x, d_y : d_y + d_x]
    z = factor[-1, :d_y]
    new_mean = mean + matmul(gain, z)
    log_lik = (
        -0.5 * jnp.sum(z * z)
        - jnp.sum(jnp.log(jnp.diagonal(chol_s)))
        - 0.5 * jnp.sum(mask) * _LOG_2PI
    )
    return new_mean, chol_post, log_lik


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
) -> FilterResult:
    """The UKF recursion of Theorem 1 over all observations, as one ``lax.scan``.

    Parameters
    ----------
    predict
        ``predict(mean, chol, inputs_k) -> (mean⁻, cov⁻)``: eq. (10) over the gap before
        y_k, from the filtered mean and the Cholesky factor of the filtered covariance.
    moments
        ``moments(mean⁻, cov⁻) -> ObservationMoments`` for the observation operator.
    mean0, cov0
        The initial state's distribution at t0.
    inputs
        A pytree with a leading axis of length n: what ``predict`` needs per gap.
    ys, masks
        Observations ``(n, d_y)`` with missing entries set to any finite value, and the
        ``(n, d_y)`` boolean mask of measured entries.
    """

    def body(carry, xs):
        mean, chol = carry
        inp, y, mask = xs
        m_pred, p_pred = predict(mean, chol, inp)
        m_new, chol_new, ll = gaussian_update(
            m_pred, p_pred, y, mask, moments(m_pred, p_pred), obs_cov
        )
        return (m_new, chol_new), (m_new, chol_new, m_pred, p_pred, ll)

    chol0 = cholesky(symmetrize(cov0))
    _, (means, chols, m_preds, p_preds, terms) = jax.lax.scan(
        body, (mean0, chol0), (inputs, ys, masks)
    )
    total = jnp.sum(terms)
    total = jnp.where(jnp.isfinite(total), total, -jnp.inf)
    covs = jnp.einsum("kij,klj->kil", chols, chols)
    return FilterResult(total, means, covs, m_preds, p_preds, terms)
