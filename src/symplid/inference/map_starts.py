"""Starting points of the MAP search (see "Starting points" in :mod:`symplid.inference.map`)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.model.params import SearchSpace

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
    step = np.where(space.log, 1.0, spread * scale) * noise
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


__all__ = ["as_theta", "default_start", "perturbed_start"]
