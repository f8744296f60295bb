"""What a one-step method advances, and what a one-step method is.

:class:`Dynamics` (a separable H = T(p) + U(q)) and :class:`GeneralDynamics` (any H(q, p))
are the right-hand sides of Hamilton's equations (3) that an integrator's ``step`` takes;
:class:`Integrator` is the record of one method. The methods themselves and their registry
are :mod:`symplid.dynamics._integrators` (separable) and :mod:`symplid.dynamics._nonseparable`
(any H), which both build on this module.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from symplid.dynamics._schemes import Scheme
from symplid.dynamics._separable import has_kinetic

Array = jax.Array

__all__ = [
    "Dynamics",
    "ForceStepFn",
    "GeneralDynamics",
    "Integrator",
    "StepFn",
    "as_general",
    "make_dynamics",
]


class Dynamics(NamedTuple):
    """The right-hand side of Hamilton's equations (3) for a separable H = T(p) + U(q).

    ``grad_potential(q)`` is ∂U/∂q and ``velocity(p)`` is ∂T/∂p (M⁻¹p for the quadratic
    T = ½pᵀM⁻¹p of eq. 2), so q̇ = velocity(p) and ṗ = −grad_potential(q). ``linear`` says
    that ``velocity`` is linear in p (a quadratic T): leapfrog then uses the integer-step form
    of eqs (5)–(6); otherwise its kick–drift–kick form (:mod:`symplid.dynamics._separable`).
    """

    grad_potential: Callable[[Array], Array]
    velocity: Callable[[Array], Array]
    linear: bool = True


class GeneralDynamics(NamedTuple):
    """Hamilton's equations (3) for any H(q, p): q̇ = ∂H/∂p, ṗ = −∂H/∂q.

    ``grad_q(q, p)`` is ∂H/∂q and ``grad_p(q, p)`` is ∂H/∂p, for one point ``(d,)`` or a batch
    ``(d, ...)``. What a non-separable Hamiltonian gives the integrators.
    """

    grad_q: Callable[[Array, Array], Array]
    grad_p: Callable[[Array, Array], Array]


def as_general(dynamics: Dynamics | GeneralDynamics) -> GeneralDynamics:
    """``dynamics`` as :class:`GeneralDynamics` (a separable one is a special case)."""
    if isinstance(dynamics, GeneralDynamics):
        return dynamics
    return GeneralDynamics(
        lambda q, p: dynamics.grad_potential(q), lambda q, p: dynamics.velocity(p)
    )


def make_dynamics(
    potential, coefficients: Array, inv_mass: Array | None = None
) -> Dynamics | GeneralDynamics:
    """Bind a potential's coefficients and the inverse mass matrix into :class:`Dynamics`.

    For a whole Hamiltonian H(q, p; θ) (an object with ``grad_q`` and ``grad_p``, see
    :mod:`symplid.dynamics._hamiltonians`) the result is :class:`GeneralDynamics`; a constant
    mass matrix does not apply to it (M belongs inside H).
    """
    if hasattr(potential, "grad_q") and hasattr(potential, "grad_p"):
        if inv_mass is not None:
            raise ValueError("a constant mass matrix applies to a separable H only; "
                             "write the mass into the Hamiltonian")
        return GeneralDynamics(
            lambda q, p: potential.grad_q(q, p, coefficients),
            lambda q, p: potential.grad_p(q, p, coefficients),
        )
    if has_kinetic(potential):  # H = T(p) + U(q) with its own T
        if inv_mass is not None:
            raise ValueError("a constant mass matrix applies to H = ½pᵀM⁻¹p + U(q) only; the "
                             "model's own kinetic energy T(p) replaces it")
        return Dynamics(lambda q: potential.gradient(q, coefficients),
                        lambda p: potential.velocity(p, coefficients), linear=False)
    if inv_mass is None:
        velocity = _identity
    else:
        inv_mass = jnp.asarray(inv_mass)

        def velocity(p: Array) -> Array:
            return jnp.tensordot(inv_mass, p, axes=1)  # works for p of shape (d, ...)

    return Dynamics(lambda q: potential.gradient(q, coefficients), velocity)


def _identity(p: Array) -> Array:
    return p


StepFn = Callable[[Dynamics, Array, Array, Array], tuple[Array, Array]]
ForceStepFn = Callable[[Dynamics, Array, Array, Array, Array], tuple[Array, Array, Array]]


@dataclass(frozen=True)
class Integrator:
    """A one-step method: its name, its order of accuracy, whether it is symplectic."""

    name: str
    order: int
    symplectic: bool
    step: StepFn
    description: str = ""
    force_step: ForceStepFn | None = None
    """Optional ``(dynamics, q, p, ∂U(q), dt) -> (q⁺, p⁺, ∂U(q⁺))``: the same step, reusing the
    force at the start (first-same-as-last), so a run of steps costs one force per step."""
    scheme: Scheme | None = None
    """The method as data, for compiled backends and damped forms: a
    :class:`~symplid.dynamics._schemes.Composition` (leapfrog sub-steps of ``w·Δt``) or a
    :class:`~symplid.dynamics._schemes.ButcherTableau`; None when the step is only a function.
    A scheme is checked against ``order`` when the integrator is made."""
    nonseparable: bool = False
    """Whether ``step`` also accepts :class:`~symplid.dynamics._integrators.GeneralDynamics` (a
    non-separable H)."""
    start: Callable[[GeneralDynamics, Array, Array], Array] | None = None
    """Optional ``(dynamics, q, p) -> aux``: what ``force_step`` carries in its third slot at
    the start of a run, when that is not the force ∂U(q) (Tao's copies of the state)."""

    def __post_init__(self) -> None:
        if self.scheme is not None:
            self.scheme.check_order(self.order)
