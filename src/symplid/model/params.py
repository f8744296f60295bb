"""The parameter space of θ: each entry's name, group, prior, bounds and bijector.

One :class:`ParameterSpace` describes θ for everything that moves through it: the posterior
(bounds, prior, unconstrained density), the MAP search (:meth:`ParameterSpace.search`), the
Laplace approximation and NUTS (:meth:`ParameterSpace.pushforward_covariance`). The idea is
dynamax's ``ParameterProperties``: a parameter carries its own constraint, so a sampler that
needs the whole real line takes a few lines.

Bijectors (unconstrained z ↦ θ), chosen by each parameter's bounds ``(a, b)``:

=============  ==============  =======================  ==============================
bounds         bijector        θ = f(z)                 log |df/dz|
=============  ==============  =======================  ==============================
(−∞, ∞)        ``identity``    z                        0
(a, ∞)         ``log``         a + eᶻ                   z
(−∞, b)        ``log-upper``   b − eᶻ                   z
(a, b)         ``logit``       a + (b − a)·σ(z)         log(b − a) − softplus(z) − softplus(−z)
=============  ==============  =======================  ==============================

The variances and the damping rate γ (groups :data:`POSITIVE_GROUPS`) are bounded below by 0
whatever their prior, so they get the ``log`` bijector. The MAP search uses a gentler space
(:class:`SearchSpace`): only parameters bounded below alone are searched on a log scale, with a
floor; the others are searched as themselves within their bounds, which L-BFGS-B handles
directly.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.model.priors import Prior, log_density_sum

Array = jax.Array

POSITIVE_GROUPS = ("damping", "process_var", "obs_var", "obs_rel_var")
"""Groups bounded below by 0 whatever their prior: the damping rate and the variances."""

LOG_SCALE_GROUPS = (*POSITIVE_GROUPS, "parameters")
"""Groups whose parameters, when bounded below only, DRAM moves on a log scale: the positive
groups and the declared parameters of a user's model (``[model.parameters]``)."""

MAX_UNCONSTRAINED_VARIANCE = 4.0
"""Cap on each variance of a covariance pushed to the unconstrained space."""

BIJECTORS = ("identity", "log", "log-upper", "logit")


@dataclass(frozen=True)
class ParameterProperties:
    """One entry of θ: its name, group, prior (None when unknown) and bounds."""

    name: str
    group: str
    prior: Prior | None
    lower: float
    upper: float

    @property
    def bijector(self) -> str:
        """The map from the real line onto ``(lower, upper)`` (module docstring)."""
        lo, hi = math.isfinite(self.lower), math.isfinite(self.upper)
        return ("identity", "log-upper", "log", "logit")[2 * lo + hi]


class ParameterSpace:
    """θ as a vector of :class:`ParameterProperties`, with vectorised transforms.

    Parameters
    ----------
    properties
        One entry per parameter of θ, in order.

    Attributes
    ----------
    names, groups, priors
        Tuples over θ's entries (``priors`` holds None where a parameter has no prior).
    lower, upper
        Bounds as NumPy arrays (±∞ when unbounded).
    """

    def __init__(self, properties: Sequence[ParameterProperties]) -> None:
        self.properties: tuple[ParameterProperties, ...] = tuple(properties)
        self.names = tuple(p.name for p in self.properties)
        self.groups = tuple(p.group for p in self.properties)
        self.priors = tuple(p.prior for p in self.properties)
        self.lower = np.array([p.lower for p in self.properties], dtype=float)
        self.upper = np.array([p.upper for p in self.properties], dtype=float)
        lo_f, hi_f = np.isfinite(self.lower), np.isfinite(self.upper)
        self._lower_only, self._upper_only = lo_f & ~hi_f, ~lo_f & hi_f
        self._both = lo_f & hi_f
        self._lo = np.where(lo_f, self.lower, 0.0)
        self._hi = np.where(hi_f, self.upper, 0.0)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_priors(
        cls, names: Sequence[str], groups: Sequence[str], priors: Sequence[Prior]
    ) -> ParameterSpace:
        """Bounds from the priors' supports, and 0 below every variance and damping rate."""
        props = []
        for name, group, prior in zip(names, groups, priors, strict=True):
            lo, hi = prior.support
            if group in POSITIVE_GROUPS:
                lo = max(lo, 0.0)
            if not lo < hi:
                raise ValueError(f"the prior of {name!r} ({prior}) gives it no positive values")
            props.append(ParameterProperties(str(name), str(group), prior, lo, hi))
        return cls(props)

    @classmethod
    def of(cls, posterior: Any) -> ParameterSpace:
        """The space of a posterior: its ``space``, or one read from ``param_names``, ``lower``
        and ``upper`` (and ``param_groups``, ``priors`` when present)."""
        space = getattr(posterior, "space", None)
        if isinstance(space, ParameterSpace):
            return space
        names = tuple(str(n) for n in posterior.param_names)
        d = len(names)
        groups = tuple(getattr(posterior, "param_groups", ("",) * d))
        priors = tuple(getattr(posterior, "priors", None) or (None,) * d)
        lower = np.asarray(posterior.lower, dtype=float)
        upper = np.asarray(posterior.upper, dtype=float)
        return cls(
            [
                ParameterProperties(n, g, p, float(lo), float(hi))
                for n, g, p, lo, hi in zip(names, groups, priors, lower, upper, strict=True)
            ]
        )

    def with_bounds(self, lower: Any, upper: Any) -> ParameterSpace:
        """The same parameters with other bounds."""
        lower = np.broadcast_to(np.asarray(lower, dtype=float), (self.size,))
        upper = np.broadcast_to(np.asarray(upper, dtype=float), (self.size,))
        return ParameterSpace(
            [
                dataclasses.replace(p, lower=float(lo), upper=float(hi))
                for p, lo, hi in zip(self.properties, lower, upper, strict=True)
            ]
        )

    # ------------------------------------------------------------------ description
    @property
    def size(self) -> int:
        return len(self.properties)

    def __len__(self) -> int:
        return self.size

    @property
    def bijectors(self) -> tuple[str, ...]:
        return tuple(p.bijector for p in self.properties)

    def indices(self, group: str) -> np.ndarray:
        """Positions of the parameters of ``group`` in θ."""
        return np.array([i for i, g in enumerate(self.groups) if g == group], dtype=int)

    def __repr__(self) -> str:
        pairs = zip(self.names, self.bijectors, strict=True)
        return f"ParameterSpace({', '.join(f'{n}: {b}' for n, b in pairs)})"

    # ------------------------------------------------------------------ bounds and prior
    def in_bounds(self, theta: Array) -> Array:
        return jnp.all((theta >= self.lower) & (theta <= self.upper), axis=-1)

    def log_prior(self, theta: Array) -> Array:
        """Σ log π_i(θ_i); −∞ outside the bounds, never NaN."""
        lp = log_density_sum(self.priors, theta)
        lp = jnp.where(self.in_bounds(theta), lp, -jnp.inf)
        return jnp.where(jnp.isnan(lp), -jnp.inf, lp)

    def interior_point(self) -> np.ndarray:
        """A point strictly inside the bounds (prior medians, pulled inside when needed)."""
        out = np.empty(self.size)
        for i, p in enumerate(self.priors):
            lo, hi = self.lower[i], self.upper[i]
            v = p.median
            if np.isfinite(lo) and np.isfinite(hi):
                v = min(max(v, lo + 0.25 * (hi - lo)), hi - 0.25 * (hi - lo))
            elif np.isfinite(lo):
                v = max(v, lo + max(p.std, 1e-3))
            elif np.isfinite(hi):
                v = min(v, hi - max(p.std, 1e-3))
            out[i] = v
        return out

    # ------------------------------------------------------------------ bijectors
    def from_unconstrained(self, z: Array) -> Array:
        """z ∈ ℝᵈ ↦ θ: a + eᶻ, b − eᶻ, a + (b − a)·σ(z) or z, by each parameter's bounds."""
        z = jnp.asarray(z, dtype=float)
        lower_only, upper_only, both = self._lower_only, self._upper_only, self._both
        ez = jnp.exp(jnp.where(lower_only | upper_only, z, 0.0))
        theta = jnp.where(lower_only, self._lo + ez, z)
        theta = jnp.where(upper_only, self._hi - ez, theta)
        return jnp.where(both, self._lo + (self._hi - self._lo) * jax.nn.sigmoid(z), theta)

    def to_unconstrained(self, theta: Array) -> Array:
        """θ ↦ z, the inverse of :meth:`from_unconstrained` (±∞ on a bound)."""
        theta = jnp.asarray(theta, dtype=float)
        lower_only, upper_only, both = self._lower_only, self._upper_only, self._both
        lo, hi = self._lo, self._hi
        width = np.where(both, hi - lo, 1.0)
        z = jnp.where(lower_only, jnp.log(jnp.where(lower_only, theta - lo, 1.0)), theta)
        z = jnp.where(upper_only, jnp.log(jnp.where(upper_only, hi - theta, 1.0)), z)
        u = jnp.where(both, (theta - lo) / width, 0.5)
        return jnp.where(both, jnp.log(u) - jnp.log1p(-u), z)

    def log_abs_det_jacobian(self, z: Array) -> Array:
        """log |det ∂θ/∂z| of :meth:`from_unconstrained` (a sum over the parameters)."""
        z = jnp.asarray(z, dtype=float)
        width = np.where(self._both, self.upper - self.lower, 1.0)
        terms = jnp.where(self._lower_only | self._upper_only, z, 0.0)
        logistic = np.log(width) - jax.nn.softplus(z) - jax.nn.softplus(-z)
        terms = jnp.where(self._both, logistic, terms)
        return jnp.sum(terms, axis=-1)

    def pushforward_covariance(self, theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """A covariance of θ at ``theta`` pushed to z (see :func:`pushforward_covariance`)."""
        return pushforward_covariance(self.to_unconstrained, theta, cov)

    # ------------------------------------------------------------------ the MAP search
    def search(self, floor: float) -> SearchSpace:
        """The space the MAP search runs in (:class:`SearchSpace`), with ``floor``."""
        return SearchSpace(self.lower, self.upper, self._lower_only.copy(), float(floor))


@dataclass(frozen=True, eq=False)
class SearchSpace:
    """θ ↔ u for the MAP search: u = log(θ − a) for parameters bounded below only (``log``),
    with the bound u ≥ log(``floor``); the identity, within the bounds, for the others."""

    lower: np.ndarray
    upper: np.ndarray
    log: np.ndarray  # bool mask
    floor: float

    def to_theta(self, u: Array) -> Array:
        lo = np.where(self.log, self.lower, 0.0)
        return jnp.where(self.log, lo + jnp.exp(jnp.where(self.log, u, 0.0)), u)

    def to_u(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            logged = np.log(np.maximum(theta - np.where(self.log, self.lower, 0.0), 0.0))
        return np.where(self.log, np.maximum(logged, math.log(self.floor)), theta)

    def bounds(self) -> list[tuple[float | None, float | None]]:
        """L-BFGS-B's bounds on u (None where unbounded)."""
        out: list[tuple[float | None, float | None]] = []
        for lo, hi, lg in zip(self.lower, self.upper, self.log, strict=True):
            if lg:
                out.append((math.log(self.floor), None))
            else:
                out.append(
                    (float(lo) if np.isfinite(lo) else None, float(hi) if np.isfinite(hi) else None)
                )
        return out

    def at_bounds(self, u: np.ndarray, tol: float = 1e-8) -> np.ndarray:
        """Which entries of u sit on one of their bounds (within ``tol`` relative)."""
        hits = np.zeros(u.shape[0], dtype=bool)
        for i, (lo, hi) in enumerate(self.bounds()):
            for b in (lo, hi):
                if b is not None and abs(u[i] - b) <= tol * max(1.0, abs(b)):
                    hits[i] = True
        return hits

    def on_lower_side(self, u: np.ndarray, i: int) -> bool:
        """Whether entry i of u sits on its lower bound (else on its upper one)."""
        lo = self.bounds()[i][0]
        return lo is not None and abs(u[i] - lo) <= 1e-8 * max(1.0, abs(lo))


def pushforward_covariance(
    to_unconstrained: Callable[[Array], Array], theta: np.ndarray, cov: np.ndarray
) -> np.ndarray:
    """A covariance of θ pushed to the unconstrained space: ``J Σ Jᵀ``, ``J = ∂z/∂θ``.

    Near a bound the push-forward is meaningless: a variance whose MAP sits at 1e-14 with a
    Laplace standard deviation of 1e-6 would get a log-scale variance of 1e16. Each
    unconstrained variance is therefore capped at :data:`MAX_UNCONSTRAINED_VARIANCE` (a
    factor e² either way on a log scale) by rescaling its row and column, which keeps the
    correlations; a coordinate whose push-forward is not finite (θ exactly on a bound)
    gets the cap and no correlation. The window adaptation of NUTS refines all of this.
    """
    jac = np.asarray(jax.jacfwd(to_unconstrained)(jnp.asarray(theta)))
    broken = ~np.all(np.isfinite(jac), axis=1)
    jac = np.where(broken[:, None], 0.0, jac)
    cov_z = jac @ cov @ jac.T
    cov_z = 0.5 * (cov_z + cov_z.T)
    cov_z[broken, :] = 0.0
    cov_z[:, broken] = 0.0
    cov_z[broken, broken] = MAX_UNCONSTRAINED_VARIANCE
    variance = np.diag(cov_z)
    shrink = np.sqrt(np.minimum(1.0, MAX_UNCONSTRAINED_VARIANCE / np.maximum(variance, 1e-300)))
    cov_z = shrink[:, None] * cov_z * shrink[None, :]
    try:
        np.linalg.cholesky(cov_z)
    except np.linalg.LinAlgError:
        cov_z = np.diag(np.maximum(np.diag(cov_z), 1e-12))
    return cov_z


__all__ = [
    "BIJECTORS",
    "LOG_SCALE_GROUPS",
    "MAX_UNCONSTRAINED_VARIANCE",
    "POSITIVE_GROUPS",
    "ParameterProperties",
    "ParameterSpace",
    "SearchSpace",
    "pushforward_covariance",
]
