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
of its own (``symplid.inference.map``): parameters bounded below alone are searched as
log(θ − a), with a floor; parameters in a positive range 0 < a < b < ∞ (a log-uniform
variance) as log θ within [log a, log b]; the others as themselves within their bounds, which
L-BFGS-B handles directly.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import cached
from symplid.model._prior_spec import log_density_sum
from symplid.model._priors import Prior

Array = jax.Array

POSITIVE_GROUPS = ("damping", "process_var", "obs_var", "obs_rel_var")
"""Groups bounded below by 0 whatever their prior: the damping rate and the variances."""

USER_GROUP = "parameters"
"""The group of a user model's declared parameters (``[model.parameters]``) and of a
generalised force's: DRAM moves those bounded below only on the scale of their prior, or on
one chosen for them (``DRAMSettings.parameter_scale``)."""

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


def _compiled_on_arrays(method: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
    """``method(self, x)`` as one compiled program, kept on ``self``, when ``x`` is a concrete
    JAX array: run eagerly, each of its dozen array operations would be a program of its own,
    compiled again in every process. NumPy arrays and tracers (inside a trace) go through it
    as they are, so a traced program is unchanged."""

    @functools.wraps(method)
    def run(self: Any, x: Any) -> Any:
        if isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer):
            key = ("bijector", method.__name__)
            return cached(self, key, lambda: jax.jit(functools.partial(method, self)))(x)
        return method(self, x)

    return run


def _without_programs(owner: Any) -> dict[str, Any]:
    """``owner``'s state for pickling, without its compiled programs (a process compiles its
    own)."""
    return {k: v for k, v in vars(owner).items() if k != "_symplid_compiled"}


class Reparameterisation:
    """θ = D·f(z) entry by entry: the one map between θ and the space a method moves in.

    Each selected entry goes through the bijector its bounds ``(a, b)`` give (module
    docstring: a + eᶻ, b − eᶻ, a + (b − a)·σ(z), or z when unbounded); the others are the
    identity. D is an optional diagonal scale (1 by default). Every consumer of θ that moves in
    another space takes one of these, and differs only in what it selects:

    * NUTS and the Laplace push-forward: every entry (:meth:`ParameterSpace.reparameterisation`);
    * the MAP search: the entries bounded below only (its search space,
      ``symplid.inference.map``), u = log(θ − a);
    * DRAM: those of them its settings put on a log scale, by default the entries of
      :data:`POSITIVE_GROUPS` and the user's parameters with a log-normal prior
      (:meth:`ParameterSpace.log_scale`; its mask, :attr:`transformed`, is DRAM's);
    * standardisation (``symplid.workflow._scaling``): no entry, D the unit factors
      (:meth:`linear`).

    The methods follow their input: NumPy in, NumPy out; JAX (traced, batched) in, JAX out.

    Parameters
    ----------
    lower, upper
        Bounds of θ (±∞ when unbounded), broadcast to the length of ``select``.
    select
        Boolean mask of the entries mapped by their bijector (None: all).
    scale
        The diagonal D (None: ones).
    """

    def __init__(self, lower: Any, upper: Any, select: Any = None, scale: Any = None) -> None:
        lower, upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        size = max(lower.size, upper.size, 0 if select is None else np.size(select),
                   0 if scale is None else np.size(scale))
        self.lower = np.broadcast_to(lower, (size,)).copy()
        self.upper = np.broadcast_to(upper, (size,)).copy()
        chosen = np.ones(size, bool) if select is None else np.asarray(select, dtype=bool)
        lo_f, hi_f = np.isfinite(self.lower), np.isfinite(self.upper)
        self.lower_only = lo_f & ~hi_f
        self.log_lower = chosen & self.lower_only  # θ = a + eᶻ
        self.log_upper = chosen & ~lo_f & hi_f  # θ = b − eᶻ
        self.logit = chosen & lo_f & hi_f  # θ = a + (b − a)·σ(z)
        self._lo = np.where(lo_f, self.lower, 0.0)
        self._hi = np.where(hi_f, self.upper, 0.0)
        self.scale = None if scale is None else np.asarray(scale, dtype=float).reshape(size)

    @classmethod
    def linear(cls, scale: Any) -> Reparameterisation:
        """θ = D·z for the diagonal ``scale`` D, no bounds (a change of units)."""
        scale = np.asarray(scale, dtype=float)
        return cls(np.full(scale.shape, -np.inf), np.full(scale.shape, np.inf), scale=scale)

    @property
    def size(self) -> int:
        return self.lower.size

    def __getstate__(self) -> dict[str, Any]:
        return _without_programs(self)

    @property
    def transformed(self) -> np.ndarray:
        """Which entries go through a bijector other than the identity (a bool mask)."""
        return self.log_lower | self.log_upper | self.logit

    @_compiled_on_arrays
    def from_unconstrained(self, z: Any) -> Any:
        """z ↦ θ = D·f(z)."""
        xp = _array_module(z)
        one_sided = self.log_lower | self.log_upper
        ez = xp.exp(xp.where(one_sided, z, 0.0))
        theta = xp.where(self.log_lower, self._lo + ez, z)
        theta = xp.where(self.log_upper, self._hi - ez, theta)
        width = self._hi - self._lo
        theta = xp.where(self.logit, self._lo + width * _sigmoid(xp, z), theta)
        return theta if self.scale is None else theta * self.scale

    @_compiled_on_arrays
    def to_unconstrained(self, theta: Any) -> Any:
        """θ ↦ z, the inverse of :meth:`from_unconstrained` (±∞ on a bound, NaN beyond it)."""
        xp = _array_module(theta)
        if self.scale is not None:
            theta = theta / self.scale
        lo, hi = self._lo, self._hi
        z = xp.where(self.log_lower, xp.log(xp.where(self.log_lower, theta - lo, 1.0)), theta)
        z = xp.where(self.log_upper, xp.log(xp.where(self.log_upper, hi - theta, 1.0)), z)
        u = xp.where(self.logit, (theta - lo) / np.where(self.logit, hi - lo, 1.0), 0.5)
        z = xp.where(self.logit, xp.log(u) - xp.log1p(-u), z)
        return z

    @_compiled_on_arrays
    def log_abs_det_jacobian(self, z: Any) -> Any:
        """log |det ∂θ/∂z|, a sum over the entries (along the last axis)."""
        xp = _array_module(z)
        terms = xp.where(self.log_lower | self.log_upper, z, 0.0)
        width = np.where(self.logit, self.upper - self.lower, 1.0)
        logistic = np.log(width) - _softplus(xp, z) - _softplus(xp, -z)
        terms = xp.where(self.logit, logistic, terms)
        total = xp.sum(terms, axis=-1)
        return total if self.scale is None else total + float(np.sum(np.log(np.abs(self.scale))))

    @_compiled_on_arrays
    def jacobian_diagonal(self, z: Any) -> Any:
        """∂θ_i/∂z_i, entry by entry (the Jacobian is diagonal): D·(eᶻ, −eᶻ, (b − a)·σ(1 − σ)
        or 1)."""
        xp = _array_module(z)
        ez = xp.exp(xp.where(self.log_lower | self.log_upper, z, 0.0))
        out = xp.where(self.log_lower, ez, 1.0)
        out = xp.where(self.log_upper, -ez, out)
        sig = _sigmoid(xp, z)
        out = xp.where(self.logit, (self._hi - self._lo) * sig * (1.0 - sig), out)
        return out if self.scale is None else out * self.scale

    def __repr__(self) -> str:
        return f"Reparameterisation({int(self.transformed.sum())} of {self.size} entries mapped)"


def _array_module(x: Any) -> Any:
    """``jax.numpy`` for a JAX array (or tracer), else NumPy."""
    return jnp if isinstance(x, jax.Array) else np


def _sigmoid(xp: Any, z: Any) -> Any:
    if xp is jnp:
        return jax.nn.sigmoid(z)
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(z)))


def _softplus(xp: Any, z: Any) -> Any:
    return jax.nn.softplus(z) if xp is jnp else np.logaddexp(0.0, z)


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
        self._bijector = Reparameterisation(self.lower, self.upper)

    def __getstate__(self) -> dict[str, Any]:
        return _without_programs(self)

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

    @property
    def lower_only(self) -> np.ndarray:
        """Which parameters are bounded below only (a bool mask): those searched, and moved
        by DRAM, on the scale log(θ − a)."""
        return self._bijector.lower_only

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
    def reparameterisation(self, select: Any = None) -> Reparameterisation:
        """The map z ↦ θ by each parameter's bounds, on the entries ``select`` picks (a
        boolean mask; None: all) and the identity on the others (:class:`Reparameterisation`)."""
        return Reparameterisation(self.lower, self.upper, select)

    def log_scale(self, chosen: Any = None) -> Reparameterisation:
        """DRAM's map: the entries ``chosen`` picks (a boolean mask; None: those of
        :data:`POSITIVE_GROUPS`, the variances and the damping rate) that are bounded below
        only, as log(θ − a); the others as they are. Which entries move on the log scale is
        the result's :attr:`~Reparameterisation.transformed` mask (none: DRAM moves in θ)."""
        if chosen is None:
            chosen = [g in POSITIVE_GROUPS for g in self.groups]
        chosen = np.asarray(chosen, dtype=bool)
        return self.reparameterisation(chosen & self.lower_only)

    def from_unconstrained(self, z: Array) -> Array:
        """z ∈ ℝᵈ ↦ θ: a + eᶻ, b − eᶻ, a + (b − a)·σ(z) or z, by each parameter's bounds."""
        return self._bijector.from_unconstrained(jnp.asarray(z, dtype=float))

    def to_unconstrained(self, theta: Array) -> Array:
        """θ ↦ z, the inverse of :meth:`from_unconstrained` (±∞ on a bound)."""
        return self._bijector.to_unconstrained(jnp.asarray(theta, dtype=float))

    def log_abs_det_jacobian(self, z: Array) -> Array:
        """log |det ∂θ/∂z| of :meth:`from_unconstrained` (a sum over the parameters)."""
        return self._bijector.log_abs_det_jacobian(jnp.asarray(z, dtype=float))

    def pushforward_covariance(self, theta: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """A covariance of θ at ``theta`` pushed to z (see :func:`pushforward_covariance`)."""
        jacobian = cached(self, ("space", "jacobian"),
                          lambda: jax.jit(jax.jacfwd(self._bijector.to_unconstrained)))
        return pushforward_covariance(self.to_unconstrained, theta, cov, jacobian)


def pushforward_covariance(
    to_unconstrained: Callable[[Array], Array], theta: np.ndarray, cov: np.ndarray,
    jacobian: Callable[[Array], Array] | None = None,
) -> np.ndarray:
    """A covariance of θ pushed to the unconstrained space: ``J Σ Jᵀ``, ``J = ∂z/∂θ``.

    Near a bound the push-forward is meaningless: a variance whose MAP sits at 1e-14 with a
    Laplace standard deviation of 1e-6 would get a log-scale variance of 1e16. Each
    unconstrained variance is therefore capped at :data:`MAX_UNCONSTRAINED_VARIANCE` (a
    factor e² either way on a log scale) by rescaling its row and column, which keeps the
    correlations; a coordinate whose push-forward is not finite (θ exactly on a bound)
    gets the cap and no correlation. The window adaptation of NUTS refines all of this.
    ``jacobian`` (θ ↦ ∂z/∂θ, e.g. compiled once by the caller) replaces
    ``jax.jit(jax.jacfwd(to_unconstrained))``.
    """
    jacobian = jax.jit(jax.jacfwd(to_unconstrained)) if jacobian is None else jacobian
    jac = np.asarray(jacobian(jnp.asarray(theta, dtype=float)))
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
    "MAX_UNCONSTRAINED_VARIANCE",
    "POSITIVE_GROUPS",
    "USER_GROUP",
    "ParameterProperties",
    "ParameterSpace",
    "Reparameterisation",
    "pushforward_covariance",
]
