"""Separable Hamiltonians H = T(p; θ) + U(q; θ) with any kinetic energy T.

Hamilton's equations (3) of a separable H read q̇ = ∂T/∂p, ṗ = −∂U/∂q. The Störmer–Verlet
(leapfrog) step in its kick–drift–kick form needs nothing else,

    p½ = p − ½Δt ∂U(q),   q⁺ = q + Δt ∂T(p½),   p⁺ = p½ − ½Δt ∂U(q⁺),

and is explicit, symmetric, second order and symplectic for **any** T, not only the quadratic
½pᵀM⁻¹p of eq. (2) (each of the three maps is the exact flow of a Hamiltonian that depends on
q or on p alone, so their composition is symplectic). Yoshida's compositions of leapfrog
steps inherit this. :class:`SeparablePotential` carries U and T: it is a potential for every
part of the library that reads U(q) (the report's U(q) band, the compiled-kernel check), and
its :meth:`~SeparablePotential.velocity` replaces M⁻¹p in
:func:`~symplid.dynamics._integrators.make_dynamics`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from symplid.dynamics._potentials import has_kinetic, over_points

Array = jax.Array

__all__ = ["SeparablePotential", "has_kinetic"]


@dataclass(frozen=True, eq=False)
class SeparablePotential:
    """H = T(p; θ) + U(q; θ) from two JAX functions of one point.

    Parameters
    ----------
    potential_fn
        ``U(q, params) -> scalar`` for ``q`` of shape ``(dim,)``.
    kinetic_fn
        ``T(p, params) -> scalar`` for ``p`` of shape ``(dim,)``.
    dim, num_params
        Number of coordinates d and of parameters (both functions read the same vector).
    names
        The parameters' names (default ``c1..cN``).

    Examples
    --------
    A relativistic-like kinetic energy T = √(1 + p²) − 1 in a harmonic well:

    >>> H = SeparablePotential(lambda q, c: 0.5 * c[0] * q[0] ** 2,
    ...                        lambda p, c: jnp.sqrt(1 + p[0] ** 2) - 1, dim=1, num_params=1)
    >>> float(H.velocity(jnp.array([0.0]), jnp.array([1.0]))[0])
    0.0
    """

    potential_fn: Callable[[Array, Array], Array]
    kinetic_fn: Callable[[Array, Array], Array]
    dim: int
    num_params: int
    names: tuple[str, ...] | None = None
    parameter_group: ClassVar[str] = "parameters"  # named parameters with their own priors

    def __post_init__(self) -> None:
        if not callable(self.potential_fn) or not callable(self.kinetic_fn):
            raise TypeError("potential_fn(q, params) and kinetic_fn(p, params) must be callables")
        if self.dim < 1 or self.num_params < 0:
            raise ValueError("dim must be ≥ 1 and num_params ≥ 0")
        if self.names is not None:
            object.__setattr__(self, "names", tuple(str(n) for n in self.names))
            if len(self.names) != self.num_params:
                raise ValueError(f"{len(self.names)} names given for {self.num_params} "
                                 "parameters")

    @property
    def param_names(self) -> tuple[str, ...]:
        if self.names is not None:
            return self.names
        return tuple(f"c{m + 1}" for m in range(self.num_params))

    def _scalar(self, fn: Callable[[Array, Array], Array], params: Array):
        params = jnp.asarray(params, dtype=float)
        return lambda x: jnp.asarray(fn(x, params), dtype=float).reshape(())

    def value(self, q: Array, params: Array) -> Array:
        """U(q); ``q`` of shape ``(dim,)`` or ``(dim, ...)`` with trailing batch axes."""
        return over_points(self._scalar(self.potential_fn, params), jnp.asarray(q, dtype=float))

    def gradient(self, q: Array, params: Array) -> Array:
        """∂U/∂q by ``jax.grad``; the shape of ``q``."""
        grad = jax.grad(self._scalar(self.potential_fn, params))
        return over_points(grad, jnp.asarray(q, dtype=float))

    def kinetic(self, p: Array, params: Array) -> Array:
        """T(p); ``p`` of shape ``(dim,)`` or ``(dim, ...)``."""
        return over_points(self._scalar(self.kinetic_fn, params), jnp.asarray(p, dtype=float))

    def velocity(self, p: Array, params: Array) -> Array:
        """q̇ = ∂T/∂p by ``jax.grad``; the shape of ``p``."""
        grad = jax.grad(self._scalar(self.kinetic_fn, params))
        return over_points(grad, jnp.asarray(p, dtype=float))
