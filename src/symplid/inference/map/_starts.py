"""Starting points of the MAP search (see "Starting points" in :mod:`symplid.inference.map`)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.inference.map._result import MultipleOptimaWarning, Optimum, StartResult
from symplid.inference.map._space import SearchSpace

Array = jax.Array


def default_start(posterior: Any) -> np.ndarray:
    """The default first start of :func:`find_map` (see the module docstring)."""
    d = int(posterior.num_params)
    lower = np.asarray(posterior.lower, dtype=float)
    upper = np.asarray(posterior.upper, dtype=float)
    groups = tuple(getattr(posterior, "param_groups", ("",) * d))
    priors = getattr(posterior, "priors", None)
    data_var = _data_variance(posterior)
    start = np.empty(d)
    for i in range(d):
        if groups[i] == "process_var" and data_var is not None:
            v = data_var
        elif groups[i] == "obs_var" and data_var is not None:
            v = 0.1 * data_var
        elif groups[i] == "obs_rel_var":
            v = 0.1
        elif priors is not None:
            v = float(priors[i].median)
        else:
            v = 0.0 if not np.isfinite(lower[i]) or not np.isfinite(upper[i]) else np.nan
        start[i] = _inside(v, lower[i], upper[i])
    return start


def _inside(v: float, lo: float, hi: float) -> float:
    """v moved strictly inside [lo, hi] (a quarter of the width in, or a unit step)."""
    if np.isfinite(lo) and np.isfinite(hi):
        if not (lo < v < hi):
            v = 0.5 * (lo + hi)
    elif np.isfinite(lo) and not v > lo:
        v = lo + 1.0
    elif np.isfinite(hi) and not v < hi:
        v = hi - 1.0
    elif not np.isfinite(v):
        v = 0.0
    return float(v)


def _data_variance(posterior: Any) -> float | None:
    datasets = getattr(posterior, "datasets", None)
    if not datasets:
        return None
    with np.errstate(all="ignore"):
        values = [np.where(obs.mask, obs.values, np.nan) for obs in datasets]
        v = float(np.nanmean([np.nanvar(x, axis=0) for x in values]))
    return v if np.isfinite(v) and v > 0 else None


def _prior_std(posterior: Any, i: int, theta_i: float) -> float:
    priors = getattr(posterior, "priors", None)
    if priors is not None:
        s = float(priors[i].std)
        if np.isfinite(s) and s > 0:
            return s
    return max(1.0, abs(theta_i))


def as_theta(init: Any, posterior: Any, default: np.ndarray) -> np.ndarray:
    """``init`` as θ: an array, a ``{name: value}`` mapping (others default) or a MapResult."""
    names = tuple(posterior.param_names)
    if hasattr(init, "theta"):
        init = init.theta
    if isinstance(init, Mapping):
        unknown = [k for k in init if k not in names]
        if unknown:
            raise ValueError(
                f"init names unknown parameter(s) {', '.join(map(repr, unknown))}; "
                f"the parameters are {', '.join(names)}"
            )
        theta = default.copy()
        for k, v in init.items():
            theta[names.index(k)] = float(v)
    else:
        theta = np.asarray(init, dtype=float)
        if theta.shape != (len(names),):
            raise ValueError(
                f"init must have shape ({len(names)},) ({', '.join(names)}), got {theta.shape}"
            )
    lower, upper = np.asarray(posterior.lower), np.asarray(posterior.upper)
    outside = np.flatnonzero((theta < lower) | (theta > upper) | ~np.isfinite(theta))
    if outside.size:
        i = int(outside[0])
        raise ValueError(
            f"init: {names[i]} = {theta[i]:g} is outside its bounds [{lower[i]:g}, {upper[i]:g}]"
        )
    return theta


def perturbed_start(
    key: Array,
    posterior: Any,
    space: SearchSpace,
    base: np.ndarray,
    spread: float,
    is_finite: Callable[[np.ndarray], bool],
    max_halvings: int = 8,
) -> np.ndarray:
    """``base`` perturbed in the search space (module docstring of :mod:`.map`); a start with
    a non-finite log posterior is drawn again with half the step, up to ``max_halvings``
    times, then ``base`` itself is used."""
    d = base.shape[0]
    noise = np.asarray(jax.random.normal(key, (d,), dtype=jnp.float64))
    scale = np.array([_prior_std(posterior, i, base[i]) for i in range(d)])
    u_base = space.to_u(base)
    step = np.where(space.logarithmic, 1.0, spread * scale) * noise
    bounds = space.bounds()
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds])
    for _ in range(max_halvings + 1):
        u = np.clip(u_base + step, lo, hi)
        theta = np.asarray(space.to_theta(jnp.asarray(u)))
        if is_finite(theta):
            return theta
        step = 0.5 * step
    return base.copy()


OPTIMUM_LOG_POSTERIOR_TOL = 0.1
"""Starts whose log posteriors differ by more than this (nats) ended in different optima."""
OPTIMUM_SD_TOL = 1.0
"""... as did starts whose θ differ by more than this many Laplace standard deviations."""


def distinct_optima(
    results: Sequence[StartResult], covariance: np.ndarray | None, space: SearchSpace
) -> tuple[Optimum, ...]:
    """The distinct end points of the starts, best first.

    Only converged starts count (all starts with a finite log posterior when none
    converged): a start that stopped short is no optimum. Going down the log posterior, a
    start joins the first optimum that is within :data:`OPTIMUM_LOG_POSTERIOR_TOL` nats of it
    and within :data:`OPTIMUM_SD_TOL` Laplace standard deviations in every coordinate
    (``covariance``; without one, within 1e-2·max(1, |u|) in the search space u).
    """
    finite = [k for k, r in enumerate(results) if np.isfinite(r.log_posterior)]
    chosen = [k for k in finite if results[k].success] or finite
    chosen.sort(key=lambda k: -results[k].log_posterior)
    scale = None
    if covariance is not None:
        scale = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    groups: list[list[int]] = []
    for k in chosen:
        for group in groups:
            if _same_optimum(results[group[0]], results[k], scale, space):
                group.append(k)
                break
        else:
            groups.append([k])
    return tuple(
        Optimum(float(results[g[0]].log_posterior), np.asarray(results[g[0]].theta), tuple(g))
        for g in groups
    )


def _same_optimum(a: StartResult, b: StartResult, scale: np.ndarray | None,
                  space: SearchSpace) -> bool:
    if abs(a.log_posterior - b.log_posterior) > OPTIMUM_LOG_POSTERIOR_TOL:
        return False
    if scale is not None and np.all(np.isfinite(scale)) and np.all(scale > 0):
        return bool(np.all(np.abs(a.theta - b.theta) <= OPTIMUM_SD_TOL * scale))
    ua, ub = space.to_u(a.theta), space.to_u(b.theta)
    return bool(np.all(np.abs(ua - ub) <= 1e-2 * np.maximum(1.0, np.abs(ua))))


def warn_optima(optima: Sequence[Optimum], num_starts: int) -> None:
    """One line (:class:`MultipleOptimaWarning`) when the starts ended in several optima."""
    if len(optima) < 2:
        return
    values = ", ".join(f"{o.log_posterior:.2f}" for o in optima[:5])
    more = ", ..." if len(optima) > 5 else ""
    spread = optima[0].log_posterior - optima[-1].log_posterior
    warnings.warn(
        f"the {num_starts} MAP starts ended in {len(optima)} different optima (log posterior "
        f"{values}{more}; a spread of {spread:.2f} nats); the best is used",
        MultipleOptimaWarning,
        stacklevel=3,
    )




def scaled_start(
    key: Array,
    space: SearchSpace,
    base: np.ndarray,
    scale: np.ndarray,
    is_finite: Callable[[np.ndarray], bool],
    max_halvings: int = 8,
) -> np.ndarray:
    """``base`` perturbed on each parameter's own scale: θ_i + scale_i · N(0, 1) for a
    parameter searched as itself, θ_i · exp(N(0, 1)) for one searched on a log scale (the
    variances); redrawn with half the step while the log posterior is not finite."""
    d = base.shape[0]
    noise = np.asarray(jax.random.normal(key, (d,), dtype=jnp.float64))
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, np.maximum(np.abs(base), 1e-8))
    u_base = space.to_u(base)
    step = np.where(space.logarithmic, 1.0, scale) * noise
    bounds = space.bounds()
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds])
    for _ in range(max_halvings + 1):
        theta = np.asarray(space.to_theta(jnp.asarray(np.clip(u_base + step, lo, hi))))
        if is_finite(theta):
            return theta
        step = 0.5 * step
    return base.copy()


def homotopy_start(posterior: Any, base: np.ndarray, default: np.ndarray) -> np.ndarray:
    """``base`` with the variances of the default start (a process variance as large as the
    data's): the filter then follows the data whatever the dynamics, and the search lowers
    the process noise towards the deterministic fit (module docstring of :mod:`.map`)."""
    groups = np.asarray(getattr(posterior, "param_groups", ("",) * base.size))
    variance = np.isin(groups, ("process_var", "obs_var", "obs_rel_var"))
    return np.where(variance, default, base)


__all__ = [
    "OPTIMUM_LOG_POSTERIOR_TOL",
    "as_theta",
    "default_start",
    "distinct_optima",
    "homotopy_start",
    "perturbed_start",
    "scaled_start",
    "warn_optima",
]
