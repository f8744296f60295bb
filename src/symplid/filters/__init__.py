"""Filters: the unscented Kalman filter and its log marginal likelihood (Theorem 1, eqs 10–12).

Layer 2 of the package (above :mod:`symplid.dynamics`): small-matrix linear algebra
(:mod:`~symplid.filters._linalg`), the unscented transform (:mod:`~symplid.filters._unscented`),
the Gaussian update and the recursion (:mod:`~symplid.filters._update`), the observation-noise
models (:mod:`~symplid.filters._noise`) and what a likelihood backend is
(:mod:`~symplid.filters._backends`; their registry is :mod:`symplid.model._backends`).
"""

from symplid.filters._backends import LikelihoodBackend
from symplid.filters._linalg import (
    SMALL_DIM,
    cholesky,
    cholesky_columns,
    matmul,
    solve_lower,
    symmetrize,
)
from symplid.filters._unscented import (
    ObservationMoments,
    UnscentedWeights,
    observation_moments_linear,
    observation_moments_unscented,
    sigma_points,
    unscented_predict,
    unscented_weights,
    weighted_moments,
)
from symplid.filters._update import FilterResult, gaussian_update, run_filter

__all__ = [
    "SMALL_DIM",
    "FilterResult",
    "LikelihoodBackend",
    "ObservationMoments",
    "UnscentedWeights",
    "cholesky",
    "cholesky_columns",
    "gaussian_update",
    "matmul",
    "observation_moments_linear",
    "observation_moments_unscented",
    "run_filter",
    "sigma_points",
    "solve_lower",
    "symmetrize",
    "unscented_predict",
    "unscented_weights",
    "weighted_moments",
]
