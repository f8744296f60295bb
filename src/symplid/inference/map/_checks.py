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
   (:func:`~symplid.inference.map._noise.noise_variance`: differences of the measured
   series, or a smoothing spline's errors in predicting each point from the others, remove
   a smooth signal and keep the noise, the spline also on a few points of a curved path).
   A MAP that calls the motion itself noise (an orbit fitted as "no force, noise of the
   orbit's size") has explained nothing, whatever its log posterior.

5. **Dynamics removed**: every dynamic coefficient bounded below by zero sits on that bound
   (a positive parameter such as GM on its floor, 1e-14): the force they scale is switched
   off, and whatever the fit explains it explains by noise (an orbit followed by process
   noise alone, or fitted as a straight line through it). Never a MAP worth sampling from.
   One such coefficient on its floor beside another off it (a quartic term the data do not
   need) is an answer, not a failure.

The reason given is never empty: L-BFGS-B's stop message is put in words
(:func:`stop_meaning`), and where the optimiser stopped by its own test but the Newton
decrement says the point is no maximum, the reason says both in one sentence.

In cases 1–3 the point is not an optimum and no evidence is computed there: the log evidence
(Laplace or quadrature) is NaN, never a number that looks meaningful. In case 4 the point is
an optimum of the model, and the evidence is kept (it then rightly ranks the model low).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from symplid.inference.map._data_start import COEFFICIENT_GROUPS
from symplid.inference.map._noise import noise_variance
from symplid.inference.map._result import StartResult
from symplid.inference.map._space import SearchSpace
from symplid.inference.map._starts import OPTIMUM_LOG_POSTERIOR_TOL

NOISE_RATIO_LIMIT = 25.0
"""Largest ratio of the MAP's observation variance to the model-free noise variance (a
standard deviation five times larger)."""
NOT_AN_OPTIMUM = ("did not converge", "did not move", "is not a maximum")
"""Failure reasons (their opening words) of a point where no evidence is computed."""
DYNAMICS_REMOVED = "puts the dynamic parameter"
"""Opening words of case 5's reason."""


def model_free_noise(posterior: Any) -> np.ndarray | None:
    """Each observed component's noise variance without a model
    (:func:`~symplid.inference.map._noise.noise_variance`), averaged over the trajectories
    (None when there are no data or none can be estimated)."""
    datasets = getattr(posterior, "datasets", None)
    if not datasets:
        return None
    with np.errstate(all="ignore"):
        rows = [[noise_variance(np.asarray(o.times, dtype=float),
                                np.where(o.mask[:, j], o.values[:, j], np.nan))
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
          given_start: bool = False, names: tuple[str, ...] = ()) -> str:
    """Why the best point is not a MAP to report ("" when it is); module docstring."""
    if not best.success and not any(
            r.success and best.log_posterior - r.log_posterior <= OPTIMUM_LOG_POSTERIOR_TOL
            for r in results):
        return f"did not converge: {not_converged_reason(best)}"
    if not moved(best, space) and not (given_start and best is results[0]):
        return "did not move from its start"
    free = np.flatnonzero(~space.at_bounds(space.to_u(best.theta)))
    if not positive_definite(hessian, free):
        return "is not a maximum: the Hessian there is not positive definite"
    return (noise_contradiction(groups, best.theta, noise)
            or dynamics_removed(best.theta, space, groups, names))


def dynamics_removed(theta: np.ndarray, space: SearchSpace, groups: tuple[str, ...],
                     names: tuple[str, ...] = ()) -> str:
    """Case 5 of the module docstring: every dynamic coefficient bounded below by zero held
    on that bound (the terms they scale, and with them the force, switched off); "" when
    one of them is off its bound. A single term the data do not need (a quartic coefficient
    on its floor beside a stiffness that is not) is an answer, not a failure."""
    u = space.to_u(np.asarray(theta, dtype=float))
    hits = space.at_bounds(u)
    zero_bounded = [i for i, group in enumerate(groups)
                    if group in COEFFICIENT_GROUPS and space.lower[i] == 0.0]
    held = [i for i in zero_bounded if hits[i] and space.on_lower_side(u, i)]
    if not held or len(held) < len(zero_bounded):
        return ""
    label = [names[i] if i < len(names) else f"parameter {i}" for i in held]
    values = ", ".join(f"{theta[i]:.3g}" for i in held)
    if len(held) == 1:
        return (f"{DYNAMICS_REMOVED} {label[0]} on its bound ({values}): the term it scales "
                "is switched off and the motion is left to the noise")
    return (f"{DYNAMICS_REMOVED}s {', '.join(label)} on their bounds ({values}): the terms "
            "they scale are switched off and the motion is left to the noise")


# L-BFGS-B's stop messages (SciPy's wording varies between versions, and its "ABNORMAL"
# stop may come with no text at all): what each means, by the words it opens with.
STOP_MEANINGS = (
    ("CONVERGENCE: NORM", "the optimiser stopped because its projected gradient was below gtol"),
    ("CONVERGENCE: REL", "the optimiser stopped because −log π no longer decreased by more "
     "than its relative tolerance"),
    ("ABNORMAL", "the optimiser's line search could not lower −log π along its direction "
     "(a rough, flat or non-finite log posterior there)"),
    ("STOP: TOTAL NO. OF ITERATIONS", "the optimiser reached its iteration limit"),
    ("STOP: TOTAL NO. OF F", "the optimiser reached its limit of evaluations"),
    ("STOP", "the optimiser was stopped by one of its limits"),
)


def stop_meaning(message: str) -> str:
    """What an L-BFGS-B stop message means, in words (never empty)."""
    text = " ".join(str(message).upper().replace("_", " ").split())
    for opening, meaning in STOP_MEANINGS:
        if text.startswith(opening.replace("_", " ")):
            return meaning
    words = str(message).strip()
    return f"the optimiser stopped ({words})" if words else "the optimiser stopped without a reason"


def not_converged_reason(best: StartResult) -> str:
    """One reason for a start that did not pass the convergence test: how the optimiser
    stopped and, when that was by its own test, why symplid's test still says no."""
    meaning = stop_meaning(best.message)
    if not math.isfinite(best.log_posterior):
        return f"{meaning}, at a point where the log posterior is not finite"
    decrement = best.newton_decrement
    if math.isfinite(decrement):
        return (f"{meaning}, but a Newton step from there would still raise log π by "
                f"{decrement:.3g} (a maximum needs < 0.001)")
    if math.isnan(decrement) and math.isfinite(best.projected_gradient):
        return f"{meaning}, with a gradient of {best.projected_gradient:.3g} left there"
    return f"{meaning}, where the Hessian is not finite"


def removes_dynamics(failure: str) -> bool:
    """Whether a failure reason is case 5 (:func:`dynamics_removed`)."""
    return failure.startswith(DYNAMICS_REMOVED)


def is_optimum(failure: str) -> bool:
    """Whether a point with this failure reason is an optimum (evidence computed there)."""
    return not failure.startswith(NOT_AN_OPTIMUM)


class MapFailedError(ValueError):
    """A MAP search that failed (:func:`judge`); the run stops before sampling. A
    ``ValueError``, so that the command line reports it in one line with exit code 2."""


def failure_message(failure: str, advice: str = "python",
                    names: tuple[str, ...] = ()) -> str:
    """The one line a failed MAP is reported with, saying what to try: in the words of the
    Python call (``advice="python"``) or of the settings file and command line
    (``advice="settings"``, where ``names`` are a user model's declared parameters, which
    a start can be declared for)."""
    if advice == "settings":
        tries = ["more starts (map.num_starts)", "priors on the parameters' own scale",
                 "a smaller model.dt"]
        if names:
            tries.append(f"a start near the answer ([model.parameters] {names[0]} = "
                         "{..., initial = ...})")
        what = ", ".join(tries[:-1]) + ", or " + tries[-1]
    else:
        what = ("more starts (num_starts=...), priors on the parameters' own scale, a smaller "
                "dt, or a start near the answer (find_map(init=...))")
    return f"the MAP search failed: the best point {failure}. Try {what}"


__all__ = [
    "NOISE_RATIO_LIMIT",
    "MapFailedError",
    "dynamics_removed",
    "failure_message",
    "is_optimum",
    "judge",
    "model_free_noise",
    "moved",
    "noise_contradiction",
    "not_converged_reason",
    "positive_definite",
    "removes_dynamics",
    "stop_meaning",
]
