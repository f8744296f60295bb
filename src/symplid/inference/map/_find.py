"""The MAP point, the Hessian there, and the Laplace approximation (Sections II-B.2 and IV).

:func:`find_map` maximises the log posterior with SciPy's bounded quasi-Newton method
(L-BFGS-B) from several seeded starts, using the exact gradient by JAX (``value_and_grad``,
compiled once per posterior). The paper used MATLAB's fmincon for the MAP and the inverse
Hessian of the negative log posterior there as the first DRAM proposal; so does this module.

Search space
------------
Parameters bounded below only (the variances, bound 0) are searched as u = log(θ − a), with the
bound u ≥ log(``positive_floor``) (default 1e-14, below the filter's 1e-12 jitter, where the
likelihood no longer changes); parameters in a positive range 0 < a < b < ∞ (a log-uniform
process variance, :mod:`symplid.model._variance_prior`) as u = log θ within [log a, log b]
(:class:`~symplid.inference.map._space.SearchSpace`); every other parameter is searched as
itself, with its bounds given to L-BFGS-B. The log scale lets one method handle coefficients of
order one and variances of order 1e-7. The MAP is a property of the density over θ, so no
Jacobian is added: the point found is the mode of π(θ | Y). Because the gradient in u vanishes
as θ approaches its bound, a log-searched parameter is finally moved onto the floor when the log
posterior there is no lower, and is then reported as sitting on its bound (with the paper's data
and leapfrog this happens to the process variance: no process noise is detectable).

Starting points
---------------
Start 0 is ``init`` when given; otherwise the **data start** of
:mod:`symplid.inference.map._data_start`: the dynamic parameters (and the momenta) from a
collocation fit of Hamilton's equations to a smoothing spline of the measured positions, the
observation variances at a model-free noise estimate, the process variance at the fit's
momentum defect, and a learned initial state on the smoothed path. Start 1 is the same point
with the variances of the default start (a process variance as large as the data's variance,
an observation variance a tenth of it): with such process noise the filter follows the data
whatever the dynamics, and as the optimiser lowers it the search moves to the deterministic
fit (a homotopy that the marginal likelihood gives for free). Start 2 (without ``init``) is
the **rougher data start**: the same fit to splines that follow the positions to a thirtieth
of the noise estimate (:data:`~._data_start.ROUGHER`). The estimate is an upper bound that a
fast motion sampled a few times a period inflates; the spline it sets then smooths the
motion away, and starts 0 and 1 see a slower one (a Morse oscillator sampled 3.5 times a
period: every other start ended 38 nats below the mode this one finds). Start 3 (without
``init``) is the **spectral data start**: the same fit to a sum of sinusoids through the
positions, collocated between the observations too (:mod:`._spectral`), with the default
start's variances (as start 1), when it explains the data at least as well as start 0 (a
larger log posterior before those variances are set). Sparse samples of an oscillation at
uneven times defeat the splines: two coupled oscillators seen about five times a period,
whose spline starts could not even be evaluated, ended 70 nats below the mode this one
finds. On a Kepler orbit (a sum of many harmonics) it reads the data worse than the
splines, and its search, 2 s of a 12 s fit, ended in a minor optimum. Starts 4, ... (2, ...
with ``init``) perturb start 0 on each parameter's own scale: by max(3 × its
least-squares standard error, 10 % of its value) for the dynamic parameters and the initial
state, and by a factor exp(N(0, 1)) for the variances; a start with a non-finite log
posterior is drawn again with half the step.

When the model or the data do not allow a data start (a nonlinear observation operator,
unmeasured positions, fewer than five observations), or the spline's start cannot be
evaluated (the filter fails there), start 0 is the **default start**
(:func:`~._starts.default_start`): coefficients at their prior median, the process
variance at the data's variance and the observation variance at a tenth of it, a learned
initial state at its prior's centre; starts 1, ... then perturb it by ``start_spread`` ×
each prior's standard deviation (variances by a factor exp(N(0, 1))), and the last start
(without ``init``) is the spectral data start when the model allows one. Draws use
``jax.random.fold_in(jax.random.key(seed), k)`` for start k.

A non-finite objective (a failed filter, an overflow) is returned to L-BFGS-B as a large
value, so its line search backs off. A start counts as converged only when L-BFGS-B says so
and the Newton decrement ½ gᵀH⁻¹g there, over the parameters that no bound holds (a bound
holds a parameter when the gradient of −log π points out of its range there: the KKT sign
condition, :func:`~._search.active_bounds`), is below 1e-3 (see :class:`StartResult`); the best
start (highest log posterior) gives the MAP. A start that L-BFGS-B ends where the decrement
says log π still rises goes on from a Newton point in θ (:func:`~._search.escaped`, up to three
more runs, each kept only if it ends higher): on the log scale a dynamics parameter driven to
its floor has no gradient left to leave it by (a quartic coefficient of 1e-14, say), while in θ
the way up is plain. For the same reason a data start that leaves such a parameter on its
bound lifts it by its collocation scale (halved until log π is finite). The MAP is reported
failed (``success`` False, the reason in ``failure``, a :class:`MapConvergenceWarning`) when
it did not converge, never moved from its start, is not a maximum, or explains the data as noise
(:mod:`symplid.inference.map._checks`); at a point that is no optimum the evidence is NaN.

The Hessian, the covariance and the Laplace evidence are :mod:`symplid.inference.map._laplace`'s;
``MapResult.log_evidence`` integrates the variances on their log scale by quadrature
(:mod:`symplid.inference.map._evidence`), the Laplace value is kept as ``log_evidence_laplace``.
Starts that end in different optima are grouped (:func:`~._starts.distinct_optima`),
recorded as ``MapResult.optima`` and reported in one line (:class:`MultipleOptimaWarning`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import cached_or_built
from symplid._saved_programs import identity_of, saved_jit
from symplid._stopping import first_call_waits
from symplid.inference.map._checks import failure_message, is_optimum, judge, model_free_noise
from symplid.inference.map._data_start import data_start
from symplid.inference.map._evidence import EvidenceSettings, quadrature_evidence
from symplid.inference.map._laplace import (
    hessian_function,
    laplace_covariance,
    scan_from_bound,
)
from symplid.inference.map._result import (
    BoundWarning,
    MapConvergenceWarning,
    MapResult,
    MultipleOptimaWarning,
    StartResult,
)
from symplid.inference.map._search import Objective, escaped, judge_with_hessian, run_start
from symplid.inference.map._space import SearchSpace
from symplid.inference.map._starts import (
    as_theta,
    default_start,
    distinct_optima,
    homotopy_start,
    perturbed_start,
    scaled_start,
    warn_optima,
)
from symplid.model._params import ParameterSpace
from symplid.runtime import one_blas_thread

Array = jax.Array
EVIDENCE_METHODS = ("quadrature", "laplace", "log-laplace")
"""Choices of ``find_map(evidence=...)``."""


# ----------------------------------------------------------------------------- compiled
def _compiled(posterior: Any, space: SearchSpace) -> dict[str, Callable]:
    """The search's ``u ↦ (−log π, gradient)`` and ``θ ↦ ∇²(−log π)``, cached on the posterior.

    A posterior that takes its data as an argument (``log_density_with``) keeps the data out
    of the compiled programs, so another data set of the same shape reuses them (persistent
    cache).
    """
    with_data = getattr(posterior, "log_density_with", None)
    data = getattr(posterior, "data", None)
    if with_data is None or data is None:
        log_density = posterior.log_density

        def with_data(_, theta):
            return log_density(theta)

    # what the programs close over, for their saved copies (symplid._saved_programs)
    identity = identity_of(posterior)

    def build_value_and_grad() -> Callable:
        def negative_u(u: Array, data: Any) -> Array:
            return -with_data(data, space.to_theta(u))

        bounds = (space.log, space.log_box, space.lower, space.upper, space.floor)
        vg = saved_jit(jax.value_and_grad(negative_u), "map-value-and-grad",
                       None if identity is None else (identity, bounds))
        # the first call compiles: a stop asked for meanwhile is obeyed (symplid._stopping)
        return first_call_waits(lambda u: vg(u, data))

    key = ("map-search", space.log.tobytes(), space.lower.tobytes())
    return {
        "value_and_grad": cached_or_built(posterior, key, build_value_and_grad),
        "hessian": cached_or_built(
            posterior, "map-hessian",
            lambda: first_call_waits(hessian_function(with_data, data, identity)),
        ),
    }


# ----------------------------------------------------------------------------- the search
@one_blas_thread()  # LAPACK on a few rows, thousands of times
def find_map(
    posterior: Any,
    seed: int = 0,
    num_starts: int = 4,
    init: Any = None,
    *,
    start_spread: float = 0.02,
    positive_floor: float = 1e-14,
    maxiter: int = 10_000,
    ftol: float = 1e-14,
    gtol: float = 1e-8,
    maxcor: int = 30,
    compute_hessian: bool = True,
    evidence: str = "quadrature",
    warn: bool = True,
) -> MapResult:
    """The maximum a posteriori point of ``posterior`` by L-BFGS-B from several starts.

    Parameters
    ----------
    posterior
        A :class:`~symplid.model._posterior.Posterior`, or any object with ``num_params``,
        ``param_names``, ``lower``, ``upper`` and a JAX ``log_density(theta)``.
    seed
        Seed of the perturbed starts (start k uses ``fold_in(key(seed), k)``).
    num_starts
        Number of L-BFGS-B runs; the first starts at ``init``, else at the data start (else
        the default start); see "Starting points" in the module docstring.
    init
        First start: an array, a ``{name: value}`` mapping (the others at the data start, else
        the default start) or a previous :class:`MapResult`. The further starts perturb it.
    start_spread
        Perturbation of the further starts, as a fraction of each prior's standard
        deviation, where no data start sets each parameter's own scale.
    positive_floor
        Smallest value searched for a parameter bounded below only (above its bound).
    maxiter, ftol, gtol, maxcor
        L-BFGS-B settings (iterations, relative reduction of the objective, projected
        gradient, number of stored corrections).
    compute_hessian
        Compute the Hessian, covariance and evidence (one extra compilation).
    evidence
        ``"quadrature"`` (default): the variances integrated on their log scale, Gaussian
        in the other parameters (:mod:`symplid.inference.map._evidence`); ``"laplace"``: the
        Laplace evidence only (no extra fits); ``"log-laplace"``: the Laplace approximation
        in the coefficients and the log-variances at their joint mode (one fit, no grid; the
        screening evidence of :mod:`symplid.inference._term_search`). The Laplace value is
        always recorded.
    warn
        Warn (:class:`BoundWarning`) when the MAP is on a bound, and
        (:class:`MapConvergenceWarning`) when the search failed (``MapResult.failure``).

    Returns
    -------
    MapResult
    """
    t_begin = time.perf_counter()
    _check_options(num_starts, positive_floor, start_spread, evidence)
    names = tuple(str(n) for n in posterior.param_names)
    parameter_space = ParameterSpace.of(posterior)
    space = SearchSpace.of(parameter_space, positive_floor)
    fns = _compiled(posterior, space)
    objective = Objective(space, fns["value_and_grad"])
    options = {"maxiter": int(maxiter), "ftol": float(ftol), "gtol": float(gtol),
               "maxcor": int(maxcor)}
    starts = _starts(posterior, objective, init, seed, int(num_starts), start_spread, names)
    results, hessians = _searched(starts, objective, options, fns["hessian"], compute_hessian)
    k_best = max(
        range(len(results)),
        key=lambda k: (
            results[k].log_posterior if np.isfinite(results[k].log_posterior) else -np.inf
        ),
    )
    best = results[k_best]
    u_best = space.to_u(best.theta)
    at_bounds = tuple(n for n, hit in zip(names, space.at_bounds(u_best), strict=True) if hit)
    if compute_hessian and hessians[k_best] is None:
        hessians[k_best] = np.asarray(fns["hessian"](jnp.asarray(best.theta)), dtype=float)
    failure = judge(best, tuple(results), hessians[k_best], space,
                    tuple(parameter_space.groups), model_free_noise(posterior),
                    given_start=init is not None, names=names)
    # the joint mode's second start, for an evidence beyond the Laplace one
    raised = (homotopy_start(posterior, best.theta, default_start(posterior))
              if compute_hessian and evidence != "laplace" else None)
    laplace, log_evidence, method, details = _evidence_at(
        best, hessians[k_best], failure, at_bounds, names, objective, u_best, fns,
        parameter_space.groups, evidence if compute_hessian else "none", warn, raised)
    optima = distinct_optima(results, laplace[1], space)
    if warn:
        _warn_outcome(best, failure, at_bounds, names, space, u_best)
        warn_optima(optima, len(results))
    settings = {
        "num_starts": int(num_starts), "start_spread": float(start_spread),
        "positive_floor": float(positive_floor), **options, "init": init is not None,
    }
    return MapResult(
        theta=best.theta, log_posterior=float(best.log_posterior),
        success=not failure,
        message=best.message, num_starts=int(num_starts), starts=tuple(results),
        hessian=laplace[0], covariance=laplace[1], covariance_repaired=laplace[2],
        log_evidence=log_evidence, param_names=names, at_bounds=at_bounds, seed=int(seed),
        seconds=time.perf_counter() - t_begin, settings=settings,
        log_evidence_laplace=laplace[3], evidence_method=method, evidence=details,
        optima=optima, failure=failure,
    )


def _searched(starts: list[np.ndarray], objective: Objective, options: dict[str, Any],
              hessian_fn: Callable, compute_hessian: bool
              ) -> tuple[list[StartResult], list[np.ndarray | None]]:
    """Each start's L-BFGS-B run, judged by its Hessian and continued from a Newton point
    where it is no maximum (:func:`~._search.escaped`); the Hessians (None where none)."""
    results = [run_start(theta0, objective, options) for theta0 in starts]

    def hessian_at(theta: np.ndarray) -> np.ndarray:
        return np.asarray(hessian_fn(jnp.asarray(theta)), dtype=float)

    hessians: list[np.ndarray | None] = [None] * len(results)
    if compute_hessian:
        for k, r in enumerate(results):
            if np.isfinite(r.log_posterior):
                hessians[k] = hessian_at(r.theta)
                results[k], hessians[k] = escaped(
                    judge_with_hessian(r, hessians[k], objective), hessians[k], objective,
                    options, hessian_at)
    return results, hessians


def _evidence_at(best: StartResult, hessian: np.ndarray | None, failure: str,
                 at_bounds: tuple[str, ...], names: tuple[str, ...], objective: Objective,
                 u_best: np.ndarray, fns: dict[str, Callable], groups: Any, evidence: str,
                 warn: bool, raised: np.ndarray | None
                 ) -> tuple[tuple[Any, Any, bool, float], float, str, dict[str, Any]]:
    """((Hessian, covariance, repaired?, Laplace log evidence), log evidence, its method,
    details) at the best point; ``evidence`` "none" when no Hessian was computed. No
    evidence at a point that is not an optimum (NaN). ``raised`` (the best point with the
    variances of the default start) is a second start of the evidence's joint mode."""
    if evidence == "none" or hessian is None:
        return (None, None, False, math.nan), math.nan, "none", {}
    bound_idx = [names.index(n) for n in at_bounds]
    laplace = (hessian, *_laplace(hessian, best, bound_idx, objective, u_best, warn))
    if not is_optimum(failure):
        laplace = (*laplace[:3], math.nan)
    if evidence != "laplace" and np.isfinite(best.log_posterior) and is_optimum(failure):
        return laplace, *_quadrature(fns, objective.space, groups, names, best.theta,
                                     laplace[3], evidence, raised)
    return laplace, laplace[3], "laplace", {}


def _quadrature(fns: dict[str, Callable], space: SearchSpace, groups: tuple[str, ...],
                names: tuple[str, ...], theta: np.ndarray,
                laplace: float, rule: str, raised: np.ndarray
                ) -> tuple[float, str, dict[str, Any]]:
    """(log evidence, method, details) by :func:`~._evidence.quadrature_evidence` (``rule``
    "quadrature" or "log-laplace"); the Laplace value when θ has no variance to integrate or
    the quadrature fails."""
    found = quadrature_evidence(fns["value_and_grad"], fns["hessian"], space, groups, names,
                                theta, EvidenceSettings(), other_starts=[raised], rule=rule)
    if found is None or not np.isfinite(found.log_evidence):
        return laplace, "laplace", {}
    return found.log_evidence, found.method, found.details


def _check_options(
    num_starts: Any, positive_floor: float, start_spread: float, evidence: str
) -> None:
    if evidence not in EVIDENCE_METHODS:
        raise ValueError(
            f"evidence must be one of {', '.join(map(repr, EVIDENCE_METHODS))}, got {evidence!r}"
        )
    if int(num_starts) != num_starts or num_starts < 1:
        raise ValueError(f"num_starts must be an integer ≥ 1, got {num_starts!r}")
    if not (positive_floor > 0 and math.isfinite(positive_floor)):
        raise ValueError(f"positive_floor must be a finite number > 0, got {positive_floor!r}")
    if not (start_spread >= 0 and math.isfinite(start_spread)):
        raise ValueError(f"start_spread must be a finite number ≥ 0, got {start_spread!r}")


def _starts(
    posterior: Any,
    objective: Objective,
    init: Any,
    seed: int,
    num_starts: int,
    spread: float,
    names: tuple[str, ...],
) -> list[np.ndarray]:
    """Start 0 (``init``, the data start or the default start), then ``num_starts − 1`` more
    ("Starting points" in the module docstring)."""
    default = default_start(posterior)
    partial = isinstance(init, Mapping)  # declared starts of some parameters: the rest read

    def read(smoother: str) -> Any:
        found = data_start(posterior, default, objective.is_finite, smoother=smoother)
        return found if found is not None and objective.is_finite(found.theta) else None

    found = read("spline") if init is None or partial else None
    if init is not None:
        first = as_theta(init, posterior, default if found is None else found.theta)
    else:
        first = default if found is None else found.theta
    if not objective.is_finite(first):
        where = "init" if init is not None else "the default start"
        raise ValueError(
            f"the log posterior is not finite at {where} "
            f"({', '.join(f'{n}={v:.4g}' for n, v in zip(names, first, strict=True))}); "
            "pass init=... at a point where the model can be evaluated"
        )
    root = jax.random.key(int(seed))
    spectral = read("spectral") if init is None and num_starts > 1 else None
    if spectral is not None and found is not None and (
            objective.log_density(spectral.theta) < objective.log_density(found.theta)):
        spectral = None  # it reads the data no better than the splines: the slot is theirs
    if spectral is not None:  # with the default start's variances, as the homotopy start
        spectral = homotopy_start(posterior, spectral.theta, default)
        spectral = spectral if objective.is_finite(spectral) else None
    if found is None:
        perturbed = num_starts if spectral is None else num_starts - 1
        return [first] + [
            perturbed_start(jax.random.fold_in(root, k), posterior, objective.space, first,
                            spread, objective.is_finite)
            for k in range(1, perturbed)
        ] + ([] if spectral is None else [spectral])
    starts = [first]
    homotopy = homotopy_start(posterior, first, default)
    if num_starts > 1 and objective.is_finite(homotopy):
        starts.append(homotopy)
    if init is None and num_starts > 2 and (rough := read("rough")) is not None:
        starts.append(rough.theta)
    if spectral is not None and len(starts) < num_starts:
        starts.append(spectral)
    while len(starts) < num_starts:
        key = jax.random.fold_in(root, len(starts))
        starts.append(scaled_start(key, objective.space, first, found.scale,
                                   objective.is_finite))
    return starts


def _laplace(
    hessian: np.ndarray,
    best: StartResult,
    bound_idx: list[int],
    objective: Objective,
    u_best: np.ndarray,
    warn: bool,
) -> tuple[np.ndarray, bool, float]:
    """(covariance, repaired?, log evidence) at the MAP (:mod:`symplid.inference.map._laplace`)."""
    theta, log_post = best.theta, best.log_posterior
    scans = [
        scan_from_bound(objective.log_density, theta, i, objective.space, u_best, log_post)
        for i in bound_idx
    ]
    covariance, repaired, log_evidence = laplace_covariance(hessian, log_post, bound_idx, scans)
    if covariance is None:
        if warn:
            warnings.warn(
                "the Hessian at the MAP has non-finite entries; the covariance falls back "
                "to a diagonal of (1% of |θ|)² and the evidence is NaN",
                MapConvergenceWarning,
                stacklevel=3,
            )
        covariance = np.diag((0.01 * np.maximum(np.abs(theta), 1e-8)) ** 2)
        repaired = True
    return covariance, repaired, log_evidence


def _warn_outcome(
    best: StartResult,
    failure: str,
    at_bounds: tuple[str, ...],
    names: tuple[str, ...],
    space: SearchSpace,
    u_best: np.ndarray,
) -> None:
    """:class:`BoundWarning` for a MAP on a bound; :class:`MapConvergenceWarning` when the
    search failed (:mod:`symplid.inference.map._checks`)."""
    if at_bounds:
        desc = []
        for n in at_bounds:
            i = names.index(n)
            lower_side = space.on_lower_side(u_best, i)
            bound = space.lower[i] if lower_side else space.upper[i]
            side = "lower" if lower_side else "upper"
            desc.append(f"{n} = {best.theta[i]:.3g} (its {side} bound is {bound:g})")
        warnings.warn(
            "the MAP sits on a bound: " + "; ".join(desc) + ". The data do not pull these "
            "parameters away from the bound (e.g. no detectable process noise); their Laplace "
            "variances are unreliable, and so is the Laplace evidence (the default evidence "
            "integrates the noise variances on their log scale and is not affected by theirs).",
            BoundWarning,
            stacklevel=3,
        )
    if failure:
        warnings.warn(failure_message(failure), MapConvergenceWarning, stacklevel=3)


__all__ = [
    "EVIDENCE_METHODS",
    "BoundWarning",
    "MapConvergenceWarning",
    "MapResult",
    "MultipleOptimaWarning",
    "StartResult",
    "default_start",
    "find_map",
]
