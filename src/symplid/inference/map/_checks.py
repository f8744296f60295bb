"""Is the point :func:`~symplid.inference.map.find_map` found a MAP worth reporting?

A MAP is reported failed (``MapResult.success`` is False, ``MapResult.failure`` says why)
when any of these holds at the best start's end point:

1. **Not converged**: the best start did not pass the convergence test of
   :class:`~symplid.inference.map._result.StartResult` (L-BFGS-B stopped by its own test and
   the Newton decrement ½ gᵀH⁻¹g over the parameters no bound holds is below 1e-3), and no
   start that did ended within 0.1 nats of it.
2. **Never moved**: the best point is its own start (every coordinate within 1e-9 in the
   search space) and that start was not handed in (``init``): the search did nothing,
   whatever its message says. (A start handed in may be a previous MAP, where staying put
   is right.)
3. **Not a maximum**: the Hessian of −log π over the parameters off their bounds is not
   positive definite (a saddle, a flat direction, non-finite entries).
4. **Residuals contradict the noise**: the MAP's observation-noise variance is more than
   :data:`NOISE_RATIO_LIMIT` times the variance that the data show without any model
   (:func:`~symplid.inference.map._data_start.difference_variance`: differences of the
   measured series remove any smooth signal and keep the noise). A MAP that calls the
   motion itself noise (an orbit fitted as "no force, noise of the orbit's size") has
   explained nothing, whatever its log posterior.

In cases 1–3 the point is not an optimum and no evidence is computed there: the log evidence
(Laplace or quadrature) is NaN, never a number that looks meaningful. In case 4 the point is
an optimum of the model, and the evidence is kept (it then rightly ranks the model low).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from symplid.inference.map._data_start import difference_variance
from symplid.inference.map._result import StartResult
from symplid.inference.map._space import SearchSpace
from symplid.inference.map._starts import OPTIMUM_LOG_POSTERIOR_TOL

NOISE_RATIO_LIMIT = 25.0
"""Largest ratio of the MAP's observation variance to the model-free noise variance (a
standard deviation five times larger)."""
NOT_AN_OPTIMUM = ("did not converge", "did not move", "is not a maximum")
"""Failure reasons (their opening words) of a point where no evidence is computed."""


def model_free_noise(posterior: Any) -> np.ndarray | None:
    """Each observed component's noise variance by difference estimators, averaged over
    the trajectories (None when there are no data or none can be estimated)."""
    datasets = getattr(posterior, "datasets", None)
    if not datasets:
        return None
    with np.errstate(all="ignore"):
        rows = [[difference_variance(np.where(o.mask[:, j], o.values[:, j], np.nan))
                 for j in range(o.dim)] for o in datasets]
        noise = np.nanmean(np.asarray(rows, dtype=float), axis=0)
    return noise if np.any(np.isfinite(noise) & (noise > 0)) else None


def moved(result: StartResult, space: SearchSpace) -> bool:
    """Whether the start's end point differs from where it began (in the search space)."""
    u0, u1 = space.to_u(result.start), space.to_u(result.theta)
    return bool(np.any(np.abs(u1 - u0) > 1e-9 * np.maximum(1.0, np.abs(u0))))


def positive_definite(hessian: np.ndarray | None, free: np.ndarray) -> bool:
    """Whether the Hessian over the free parameters is finite and positive definite."""
    if hessian is None:
        return True
    block = np.asarray(hessian)[np.ix_(free, free)]
    if block.size == 0:
        return True
    if not np.all(np.isfinite(block)):
        return False
    try:
        np.linalg.cholesky(0.5 * (block + block.T))
    except np.linalg.LinAlgError:
        return False
    return True


def noise_contradiction(groups: tuple[str, ...], theta: np.ndarray,
                        noise: np.ndarray | None) -> str:
    """Case 4 of the module docstring: a one-line reason, or "" when the noise is plausible."""
    obs = [i for i, g in enumerate(groups) if g == "obs_var"]
    if noise is None or not obs:
        return ""
    reference = float(np.nanmax(noise))
    fitted = float(np.max(np.asarray(theta)[obs]))
    if not (math.isfinite(reference) and reference > 0 and fitted > NOISE_RATIO_LIMIT * reference):
        return ""
    return (f"has an observation noise (sd {math.sqrt(fitted):.3g}) "
            f"{math.sqrt(fitted / reference):.0f} times the noise the data show without a "
            f"model (sd {math.sqrt(reference):.3g}): the fit explains the motion as noise")


def judge(best: StartResult, results: tuple[StartResult, ...], hessian: np.ndarray | None,
          space: SearchSpace, groups: tuple[str, ...], noise: np.ndarray | None,
          given_start: bool = False) -> str:
    """Why the best point is not a MAP to report ("" when it is); module docstring."""
    if not best.success and not any(
            r.success and best.log_posterior - r.log_posterior <= OPTIMUM_LOG_POSTERIOR_TOL
            for r in results):
        return f"did not converge (best start: {best.message})"
    if not moved(best, space) and not (given_start and best is results[0]):
        return "did not move from its start"
    free = np.flatnonzero(~space.at_bounds(space.to_u(best.theta)))
    if not positive_definite(hessian, free):
        return "is not a maximum: the Hessian there is not positive definite"
    return noise_contradiction(groups, best.theta, noise)


def is_optimum(failure: str) -> bool:
    """Whether a point with this failure reason is an optimum (evidence computed there)."""
    return not failure.startswith(NOT_AN_OPTIMUM)


class MapFailedError(ValueError):
    """A MAP search that failed (:func:`judge`); the run stops before sampling. A
    ``ValueError``, so that the command line reports it in one line with exit code 2."""


def failure_message(failure: str) -> str:
    """The one line a failed MAP is reported with, saying what to try."""
    return (f"the MAP search failed: the best point {failure}. Try more starts "
            "(map.num_starts), priors on the parameters' own scale, a smaller dt, or a "
            "start near the answer (find_map(init=...))")


__all__ = [
    "NOISE_RATIO_LIMIT",
    "MapFailedError",
    "failure_message",
    "is_optimum",
    "judge",
    "model_free_noise",
    "moved",
    "noise_contradiction",
    "positive_definite",
]
