"""A prior restricted to bounds and renormalised: what ``lower``/``upper`` of a declared
parameter (``[model.parameters]``) make of its prior.

For a base prior with density π and distribution function F, bounded to [a, b],

    π_ab(x) = π(x) / (F(b) − F(a))   on [a, b],   0 elsewhere,

so the log evidence of a model with bounded parameters stays a proper marginal likelihood.
F and its inverse are those of :data:`CDFS` (normal, laplace, half-normal, log-normal,
uniform, log-uniform); draws are F⁻¹ of a uniform on [F(a), F(b)].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtr, ndtri

from symplid.model._priors import (
    HalfNormal,
    Laplace,
    LogNormal,
    LogUniform,
    Normal,
    Prior,
    Uniform,
)

Array = jax.Array

__all__ = ["CDFS", "Truncated", "bounded"]


def _laplace_cdf(p: Laplace, x: Array) -> Array:
    z = (x - p.loc) / p.scale
    return jnp.where(z < 0, 0.5 * jnp.exp(jnp.minimum(z, 0.0)),
                     1.0 - 0.5 * jnp.exp(-jnp.maximum(z, 0.0)))


def _laplace_quantile(p: Laplace, u: Array) -> Array:
    return p.loc - p.scale * jnp.sign(u - 0.5) * jnp.log1p(-2.0 * jnp.abs(u - 0.5))


#: Family → (F(prior, x), F⁻¹(prior, u)) in JAX.
CDFS: dict[type, tuple[Callable[[Any, Array], Array], Callable[[Any, Array], Array]]] = {
    Normal: (lambda p, x: ndtr((x - p.loc) / p.scale), lambda p, u: p.loc + p.scale * ndtri(u)),
    Laplace: (_laplace_cdf, _laplace_quantile),
    HalfNormal: (lambda p, x: jnp.where(x > 0, 2.0 * ndtr(jnp.maximum(x, 0.0) / p.scale) - 1.0,
                                        0.0),
                 lambda p, u: p.scale * ndtri(0.5 + 0.5 * u)),
    LogNormal: (lambda p, x: jnp.where(
                    x > 0, ndtr((jnp.log(jnp.where(x > 0, x, 1.0)) - p.mu) / p.sigma), 0.0),
                lambda p, u: jnp.exp(p.mu + p.sigma * ndtri(u))),
    Uniform: (lambda p, x: jnp.clip((x - p.low) / (p.high - p.low), 0.0, 1.0),
              lambda p, u: p.low + (p.high - p.low) * u),
    LogUniform: (lambda p, x: jnp.clip(
                     jnp.log(jnp.clip(x, p.low, p.high) / p.low) / math.log(p.high / p.low),
                     0.0, 1.0),
                 lambda p, u: p.low * jnp.exp(math.log(p.high / p.low) * u)),
}


@dataclass(frozen=True)
class Truncated(Prior):
    """``base`` restricted to ``[lower, upper]`` and renormalised (module docstring)."""

    base: Prior
    lower: float = -math.inf
    upper: float = math.inf
    family: ClassVar[str] = "truncated"
    _cdfs: tuple[float, float] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if type(self.base) not in CDFS:
            raise ValueError(f"bounds cannot be put on a {self.base.family!r} prior (bounded: "
                             f"{', '.join(c.family for c in CDFS)})")
        object.__setattr__(self, "lower", float(self.lower))
        object.__setattr__(self, "upper", float(self.upper))
        if not self.lower < self.upper:
            raise ValueError(f"lower ({self.lower:g}) must be less than upper ({self.upper:g})")
        with jax.ensure_compile_time_eval():  # numbers fixed once, never traced
            object.__setattr__(self, "_cdfs", (self._cdf(self.lower), self._cdf(self.upper)))
        if not self.mass > 1e-12:
            raise ValueError(f"the bounds [{self.lower:g}, {self.upper:g}] leave the prior "
                             f"{self.base} no probability")

    def _cdf(self, x: float) -> float:
        if x == math.inf:
            return 1.0
        if x == -math.inf:
            return 0.0
        return float(CDFS[type(self.base)][0](self.base, jnp.asarray(x, dtype=float)))

    @property
    def mass(self) -> float:
        """F(upper) − F(lower): the base prior's probability inside the bounds."""
        return self._cdfs[1] - self._cdfs[0]

    @property
    def log_scale(self) -> bool:  # type: ignore[override]
        """The base family's: bounds do not change the scale a law is written on."""
        return self.base.log_scale

    @property
    def support(self) -> tuple[float, float]:
        lo, hi = self.base.support
        return (max(lo, self.lower), min(hi, self.upper))

    def log_density(self, x: Array) -> Array:
        x = jnp.asarray(x, dtype=float)
        value = self.base.log_density(x) - math.log(self.mass)
        return jnp.where(self._inside(x), value, -jnp.inf)

    def quantile(self, u: Array) -> Array:
        """F⁻¹ of the truncated law."""
        lo = self._cdfs[0]
        inverse = CDFS[type(self.base)][1]
        x = inverse(self.base, lo + jnp.asarray(u, dtype=float) * self.mass)
        lo_s, hi_s = self.support
        return jnp.clip(x, lo_s, hi_s)

    def sample(self, key: Array, shape: tuple[int, ...] = ()) -> Array:
        return self.quantile(jax.random.uniform(key, shape, dtype=jnp.float64))

    def _moments(self) -> tuple[float, float]:
        u = (np.arange(4000) + 0.5) / 4000  # the quantile grid: mean and sd to ~1e-4
        x = np.asarray(self.quantile(jnp.asarray(u)))
        return float(np.mean(x)), float(np.std(x))

    @property
    def mean(self) -> float:
        return self._moments()[0]

    @property
    def std(self) -> float:
        return self._moments()[1]

    @property
    def median(self) -> float:
        return float(self.quantile(0.5))

    def to_dict(self) -> dict[str, Any]:
        out = self.base.to_dict()
        out |= {k: v for k, v in (("lower", self.lower), ("upper", self.upper))
                if math.isfinite(v)}
        return out


def bounded(prior: Prior, lower: float = -math.inf, upper: float = math.inf) -> Prior:
    """``prior`` within ``[lower, upper]``: itself when the bounds contain its support, else
    :class:`Truncated`."""
    lo, hi = prior.support
    if lower <= lo and upper >= hi:
        return prior
    return Truncated(prior, float(lower), float(upper))
