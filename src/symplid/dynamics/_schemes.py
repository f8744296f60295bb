"""One-step methods as data: a composition of leapfrog sub-steps, or a Butcher tableau.

An :class:`~symplid.dynamics._onestep.Integrator` whose method is one of these carries it in its
``scheme``; the compiled likelihood kernel and the damped forms (:mod:`symplid.dynamics._damping`)
read the numbers from there instead of from the step function. Each record checks itself when it
is made: its shape, and the order conditions of the order it is declared to have, so a typo in
a weight or a tableau fails at import, not as a silently first-order method.

Order conditions checked (Hairer, Lubich & Wanner, *Geometric Numerical Integration*, II.4 and
III.1; Butcher's conditions for Runge–Kutta methods):

* a **symmetric composition** Ψ = Φ_{w_s Δt} ∘ … ∘ Φ_{w_1 Δt} of leapfrog (eqs 5–6, itself
  symmetric and of order 2) has order 2 when Σ w_i = 1 and w is a palindrome, and order 4 when
  also Σ w_i³ = 0 (Yoshida's triple jump, Suzuki's fractal); higher orders are not checked;
* an **explicit Runge–Kutta** method with c_i = Σ_j a_ij has order p ≤ 4 when its b, c and A
  satisfy the 1, 2, 4 and 8 rooted-tree conditions of orders 1–4.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ButcherTableau", "Composition", "Scheme"]

#: How far an order condition may miss its value (the weights are given to double precision).
_TOL = 1e-10


def _rows(a: object) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(x) for x in row) for row in a)  # type: ignore[union-attr]


@dataclass(frozen=True)
class Composition:
    """Leapfrog sub-steps of sizes w_i·Δt in turn (eqs 5–6 composed): symmetric, Σ w_i = 1."""

    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        w = tuple(float(x) for x in self.weights)
        object.__setattr__(self, "weights", w)
        if not w:
            raise ValueError("a composition needs at least one weight")
        if abs(sum(w) - 1.0) > _TOL:
            raise ValueError(f"the weights of a composition must sum to 1, not {sum(w)!r}")
        if any(abs(x - y) > _TOL for x, y in zip(w, reversed(w), strict=True)):
            raise ValueError("the weights of a composition must be symmetric (a palindrome)")

    def check_order(self, order: int) -> None:
        """Raise ValueError unless the composition has (at least) ``order`` ≤ 4."""
        if order > 4:
            return
        if order >= 3 and abs(sum(x**3 for x in self.weights)) > _TOL:
            raise ValueError(f"a composition of order {order} needs Σ w³ = 0 "
                             f"(here {sum(x**3 for x in self.weights)!r})")


@dataclass(frozen=True)
class ButcherTableau:
    """An explicit Runge–Kutta method: a strictly lower-triangular ``a`` and weights ``b``."""

    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "a", _rows(self.a))
        object.__setattr__(self, "b", tuple(float(x) for x in self.b))
        a = np.asarray(self.a, dtype=float)
        if a.shape != (len(self.b), len(self.b)) or np.any(np.triu(a) != 0):
            raise ValueError("an explicit Butcher tableau needs a strictly lower-triangular "
                             "s×s matrix a and s weights b")

    @property
    def c(self) -> np.ndarray:
        """The nodes c_i = Σ_j a_ij."""
        return np.asarray(self.a, dtype=float).sum(axis=1)

    def order_residuals(self) -> dict[int, float]:
        """The largest miss of the order conditions of each order 1–4."""
        a, b, c = np.asarray(self.a, dtype=float), np.asarray(self.b, dtype=float), self.c
        conditions = {
            1: [b.sum() - 1.0],
            2: [b @ c - 1 / 2],
            3: [b @ c**2 - 1 / 3, b @ a @ c - 1 / 6],
            4: [b @ c**3 - 1 / 4, (b * c) @ a @ c - 1 / 8, b @ a @ c**2 - 1 / 12,
                b @ a @ a @ c - 1 / 24],
        }
        return {k: float(np.max(np.abs(v))) for k, v in conditions.items()}

    def check_order(self, order: int) -> None:
        """Raise ValueError unless the tableau has (at least) ``order`` ≤ 4."""
        for k, miss in self.order_residuals().items():
            if k <= order and miss > _TOL:
                raise ValueError(f"the tableau misses an order-{k} condition by {miss:.3g}, "
                                 f"so it is not of order {order}")


Scheme = Composition | ButcherTableau
"""A method as data; an :class:`~symplid.dynamics._onestep.Integrator` given only as a step
function has ``scheme = None``."""
