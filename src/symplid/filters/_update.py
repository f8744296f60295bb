"""The Gaussian update and the UKF recursion: the log marginal likelihood of Theorem 1 (eqs 10–12).

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

from symplid.filters._linalg import cholesky, cholesky_columns, matmul, symmetrize
from symplid.filters._unscented import ObservationMoments

__all__ = ["FilterResult", "gaussian_update", "run_filter"]

Array = jax.Array

_LOG_2PI = math.log(2.0 * math.pi)


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
        - jnp.sum(jnp.log(_diagonal(chol_s)))
        - 0.5 * jnp.sum(mask) * _LOG_2PI
    )
    return new_mean, chol_post, log_lik


def _diagonal(a: Array) -> Array:
    """``jnp.diagonal(a)`` by a mask: exact, and its gradient is a select, not a scatter-add.

    A scatter in the filter's loop body would keep XLA:CPU from compiling the gradient's
    loop as one kernel (see :func:`symplid.runtime.configure_xla`).
    """
    eye = jnp.eye(a.shape[-1], dtype=bool)
    return jnp.sum(jnp.where(eye, a, 0.0), axis=-1)


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
    obs_cov: Array | Callable[[ObservationMoments], Array],
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
    obs_cov
        The observation-noise covariance Γ added to S (eq. 12), or a function of the step's
        :class:`ObservationMoments` that gives it (a noise model whose covariance depends on
        the prediction, e.g. multiplicative noise: :mod:`symplid.filters._noise`).
    """

    def body(carry, xs):
        mean, chol = carry
        inp, y, mask = xs
        m_pred, p_pred = predict(mean, chol, inp)
        obs_moments = moments(m_pred, p_pred)
        noise_cov = obs_cov(obs_moments) if callable(obs_cov) else obs_cov
        m_new, chol_new, ll = gaussian_update(m_pred, p_pred, y, mask, obs_moments, noise_cov)
        return (m_new, chol_new), (m_new, chol_new, m_pred, p_pred, ll)

    chol0 = cholesky(symmetrize(cov0))
    _, (means, chols, m_preds, p_preds, terms) = jax.lax.scan(
        body, (mean0, chol0), (inputs, ys, masks)
    )
    total = jnp.sum(terms)
    total = jnp.where(jnp.isfinite(total), total, -jnp.inf)
    covs = jnp.einsum("kij,klj->kil", chols, chols)
    return FilterResult(total, means, covs, m_preds, p_preds, terms)
