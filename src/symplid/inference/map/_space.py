"""The MAP search's own space: θ ↔ u, where L-BFGS-B moves.

The MAP is the only consumer of this space, so it lives with the MAP. It is one selection of
θ's :class:`~symplid.model._params.Reparameterisation` (the entries bounded below only, searched
as log(θ − a) with a floor) plus the log scale for positive ranges, which only the search uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
from jax import Array

from symplid.model._params import ParameterSpace, Reparameterisation

__all__ = ["BOX_MARGIN", "SearchSpace"]

#: How far inside [log a, log b] a ``log_box`` entry's bounds on u are moved, so that eᵘ never
#: rounds to just outside [a, b].
BOX_MARGIN = 1e-12


@dataclass(frozen=True, eq=False)
class SearchSpace:
    """θ ↔ u for the MAP search: u = log(θ − a) for parameters bounded below only (the
    ``log`` mask of its :class:`Reparameterisation`), with the bound u ≥ log(``floor``);
    u = log θ within [log a, log b] for a positive range 0 < a < b < ∞ (the ``log_box`` mask);
    the identity, within the bounds, for the others.

    Why log θ for a positive range: a log-uniform process variance spans eight decades
    (:mod:`symplid.model._variance_prior`). Searched as itself, its gradient is of order 1/a
    (about 1e9) next to coefficients of order one: L-BFGS-B's curvature pairs are then
    dominated by that one coordinate and it stops on "relative reduction" with the other
    parameters still moving, and a bound tolerance in θ (1e-8) would call anything below 1e-8
    "on the bound". On log θ the box is a plain box constraint of size one per decade, the
    prior's gradient there is 1, and the bound tolerance is relative.
    """

    reparameterisation: Reparameterisation
    floor: float

    @classmethod
    def of(cls, space: ParameterSpace, floor: float) -> SearchSpace:
        """The space the MAP search runs in for ``space`` (θ's layout), with ``floor``: the
        entries bounded below only go to the log scale."""
        return cls(space.reparameterisation(space.lower_only), float(floor))

    @property
    def lower(self) -> np.ndarray:
        return self.reparameterisation.lower

    @property
    def upper(self) -> np.ndarray:
        return self.reparameterisation.upper

    @property
    def log(self) -> np.ndarray:
        """Which entries are searched on the log scale (a bool mask)."""
        return self.reparameterisation.log_lower

    @property
    def log_box(self) -> np.ndarray:
        """Which entries are searched as log θ within [log a, log b] (0 < a < b < ∞)."""
        lo, hi = self.lower, self.upper
        with np.errstate(invalid="ignore"):
            return ~self.log & np.isfinite(lo) & np.isfinite(hi) & (lo > 0) & (hi > lo)

    def box_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounds of the ``log_box`` entries on u: log a and log b moved inside by 1e-12,
        so that eᵘ never rounds to just outside [a, b] (where the prior is −∞); NaN elsewhere."""
        box = self.log_box
        with np.errstate(divide="ignore", invalid="ignore"):
            lo = np.where(box, np.log(np.where(box, self.lower, 1.0)) + BOX_MARGIN, np.nan)
            hi = np.where(box, np.log(np.where(box, self.upper, 1.0)) - BOX_MARGIN, np.nan)
        return lo, hi

    @property
    def logarithmic(self) -> np.ndarray:
        """Which entries are searched on a log scale of either kind (``log`` or ``log_box``)."""
        return self.log | self.log_box

    def to_theta(self, u: Array) -> Array:
        u = jnp.asarray(u)
        theta = self.reparameterisation.from_unconstrained(u)
        box = self.log_box
        if not box.any():
            return theta
        return jnp.where(box, jnp.exp(jnp.where(box, u, 0.0)), theta)

    def to_u(self, theta: np.ndarray, floor: bool = True) -> np.ndarray:
        """θ ↦ u on the host; a logged entry on or below its bound goes to log(``floor``)
        (to −∞ or NaN with ``floor=False``); a ``log_box`` entry is clipped into [a, b]
        (not with ``floor=False``)."""
        theta = np.asarray(theta, dtype=float)
        box = self.log_box
        if floor:
            theta = np.where(self.log, np.maximum(theta, self.lower), theta)
            theta = np.where(box, np.clip(theta, self.lower, self.upper), theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.reparameterisation.to_unconstrained(theta)
            u = np.where(box, np.log(np.where(box, theta, 1.0)), u)
        if not floor:
            return u
        if box.any():
            lo, hi = self.box_bounds()
            u = np.where(box, np.clip(u, lo, hi), u)
        return np.where(self.log, np.maximum(u, math.log(self.floor)), u)

    def jacobian_diagonal(self, u: np.ndarray) -> np.ndarray:
        """∂θ_i/∂u_i entry by entry (eᵘ on both log scales, 1 for the others)."""
        u = np.asarray(u, dtype=float)
        out = np.asarray(self.reparameterisation.jacobian_diagonal(u), dtype=float)
        with np.errstate(over="ignore"):
            return np.where(self.log_box, np.exp(np.where(self.log_box, u, 0.0)), out)

    def bounds(self) -> list[tuple[float | None, float | None]]:
        """L-BFGS-B's bounds on u (None where unbounded)."""
        out: list[tuple[float | None, float | None]] = []
        box_lo, box_hi = self.box_bounds()
        for i, (lo, hi, lg) in enumerate(zip(self.lower, self.upper, self.log, strict=True)):
            if lg:
                out.append((math.log(self.floor), None))
            elif np.isfinite(box_lo[i]):
                out.append((float(box_lo[i]), float(box_hi[i])))
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
