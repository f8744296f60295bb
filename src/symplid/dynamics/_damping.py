"""Dissipation: the damped Hamiltonian flow and its two propagators.

The damped Hamiltonian system adds a friction force to Hamilton's equations (3)::

    q̇ = ∂H/∂p = M⁻¹p,    ṗ = −∂H/∂q − γ M⁻¹p,    γ ≥ 0,

so that dH/dt = −γ pᵀM⁻²p ≤ 0. Its part ṗ = −γM⁻¹p has the exact flow

    φ_t(q, p) = (q, exp(−γ t M⁻¹) p),

and the Hamiltonian part is the one the library already integrates (eqs 5–6, 14). Two ways
to propagate the damped system are offered, both built from a registered integrator:

* **conformally symplectic splitting** (symplectic compositions: leapfrog, yoshida4): every
  leapfrog sub-step of size w·h is wrapped in exact damping half-flows,
  φ_{wh/2} ∘ LF_{wh} ∘ φ_{wh/2}. For leapfrog this is "damping half-flow, one leapfrog step,
  damping half-flow"; each wrapped sub-step is symmetric, so a symmetric composition keeps its
  order (Yoshida's stays fourth order). With M ∝ I the step map J satisfies
  JᵀΩJ = e^{−γh}Ω (Ω the symplectic form): it contracts phase-space volume exactly as the
  true flow does, the defining property of a conformally symplectic method. With γ = 0 it is
  the undamped integrator exactly (e⁰ = 1).
* **damped Runge–Kutta** (explicit tableaus: euler, rk2-midpoint, rk2-heun, rk4): the
  integrator's Butcher tableau applied to the whole damped vector field, the
  non-structure-preserving baseline.

For a mass matrix M that is not a multiple of the identity, the friction −γM⁻¹p is Rayleigh
damping (proportional to the velocity, with the damping matrix γM⁻¹); the splitting then uses
the exact matrix exponential exp(−γtM⁻¹) and the conformal identity above holds only for
M ∝ I.

A damped integrator steps :class:`DampedDynamics` (∂U/∂q, M⁻¹p and γ) and keeps the common
signature ``integrator.step(dynamics, q, p, dt)``; the parameters of the propagator (θ_Ψ of
eq. 7) are then the potential's coefficients and γ, each given by name (:func:`bind_dynamics`:
where they sit in θ is the model's layout, :mod:`symplid.model._layout`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from symplid._compiled import cached
from symplid.dynamics._integrators import (
    Dynamics,
    ForceStepFn,
    GeneralDynamics,
    Integrator,
    StepFn,
    get_integrator,
    leapfrog_force_step,
    make_dynamics,
    runge_kutta,
)
from symplid.dynamics._schemes import ButcherTableau, Composition

Array = jax.Array

__all__ = [
    "DampedDynamics",
    "DampedIntegrator",
    "bind_dynamics",
    "conformal_composition",
    "damped_dynamics",
    "damped_runge_kutta",
    "is_damped",
    "with_damping",
]


class DampedDynamics(NamedTuple):
    """The damped right-hand side: ∂U/∂q, p ↦ M⁻¹p, the rate γ and the exact damping flow.

    ``damp(p, t)`` is exp(−γ t M⁻¹) p (``p`` of shape ``(d,)`` or ``(d, ...)``); the friction
    force is −γ·``velocity(p)``. The first two fields are those of
    :class:`~symplid.dynamics._integrators.Dynamics`, so an undamped step accepts it too.
    """

    grad_potential: Callable[[Array], Array]
    velocity: Callable[[Array], Array]
    gamma: Array
    damp: Callable[[Array, Array], Array]


def damped_dynamics(
    dynamics: Dynamics, gamma: Array | float, inv_mass: Any = None
) -> DampedDynamics:
    """Add the friction −γM⁻¹p to ``dynamics`` (``inv_mass`` = M⁻¹, identity when None).

    The flow exp(−γtM⁻¹) is e^{−γt} for M = I, and otherwise uses the eigenvectors of the
    symmetric M⁻¹ = V diag(λ) Vᵀ: exp(−γtM⁻¹) p = V (e^{−γtλ} ⊙ Vᵀp), exact for any SPD M.
    """
    gamma = jnp.asarray(gamma, dtype=float)
    if inv_mass is None:

        def damp(p: Array, t: Array) -> Array:
            return jnp.exp(-gamma * t) * p

    else:
        rates, basis = jnp.linalg.eigh(jnp.asarray(inv_mass, dtype=float))

        def damp(p: Array, t: Array) -> Array:
            decay = jnp.exp(-gamma * t * rates).reshape(rates.shape + (1,) * (p.ndim - 1))
            return jnp.tensordot(basis, decay * jnp.tensordot(basis.T, p, axes=1), axes=1)

    return DampedDynamics(dynamics.grad_potential, dynamics.velocity, gamma, damp)


# ---------------------------------------------------------------------------- the two steps
def conformal_composition(weights: tuple[float, ...]) -> tuple[StepFn, ForceStepFn]:
    """The conformally symplectic step: each leapfrog sub-step of size ``w·h`` of a
    symmetric composition wrapped in exact damping half-flows φ_{wh/2} (module docstring).

    Returns the plain step and its first-same-as-last form (the damping changes p only, so
    the force ∂U(q) at the end of a step still starts the next one).
    """
    weights = tuple(float(w) for w in weights)

    def force_step(
        dynamics: DampedDynamics, q: Array, p: Array, force: Array, dt: Array
    ) -> tuple[Array, Array, Array]:
        for w in weights:
            h = w * dt
            p = dynamics.damp(p, 0.5 * h)
            q, p, force = leapfrog_force_step(dynamics, q, p, force, h)  # type: ignore[arg-type]
            p = dynamics.damp(p, 0.5 * h)
        return q, p, force

    def step(dynamics: DampedDynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        q, p, _ = force_step(dynamics, q, p, dynamics.grad_potential(q), dt)
        return q, p

    return step, force_step  # type: ignore[return-value]


def damped_runge_kutta(a: tuple[tuple[float, ...], ...], b: tuple[float, ...]) -> StepFn:
    """An explicit Runge–Kutta step of q̇ = M⁻¹p, ṗ = −∂U/∂q − γM⁻¹p from a Butcher tableau:
    the tableau's own step (:func:`~symplid.dynamics._integrators.runge_kutta`) on the
    right-hand side with the friction folded into ∂H/∂q."""
    rk_step = runge_kutta(a, b)

    def step(dynamics: DampedDynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        rhs = GeneralDynamics(
            grad_q=lambda qi, pi: (dynamics.grad_potential(qi)
                                   + dynamics.gamma * dynamics.velocity(pi)),
            grad_p=lambda qi, pi: dynamics.velocity(pi),
        )
        return rk_step(rhs, q, p, dt)

    return step  # type: ignore[return-value]


# ---------------------------------------------------------------------------- integrators
@dataclass(frozen=True)
class DampedIntegrator(Integrator):
    """A registered integrator made to propagate the damped system; steps :class:`DampedDynamics`.

    ``base`` is the undamped integrator it was built from. ``symplectic`` is False (the
    splitting is *conformally* symplectic: :attr:`conformal`); ``scheme`` is None, so a
    backend that reads schemes does not mistake it for its base.
    """

    base: Integrator | None = None
    conformal: bool = False


def with_damping(integrator: str | Integrator) -> DampedIntegrator:
    """The damped form of a registered integrator (built once per integrator, then reused).

    A symplectic composition becomes the conformally symplectic splitting, an explicit
    Runge–Kutta method the damped Runge–Kutta step. A damped integrator is returned as is.

    Raises
    ------
    ValueError
        For an integrator given only as a step function (no composition weights or tableau).
    """
    integrator = get_integrator(integrator)
    if isinstance(integrator, DampedIntegrator):
        return integrator
    return cached(integrator, ("with_damping",), lambda: _build(integrator))


def _build(base: Integrator) -> DampedIntegrator:
    if base.scheme is None:
        raise ValueError(
            f"the integrator {base.name!r} cannot be damped: it is a step function without "
            "composition weights or a Butcher tableau"
        )
    if isinstance(base.scheme, Composition):
        step, force_step = conformal_composition(base.scheme.weights)
        text = f"conformally symplectic {base.name}: exact damping half-flows around each sub-step"
        return DampedIntegrator(f"damped-{base.name}", base.order, False, step, text,
                                force_step=force_step, base=base, conformal=True)
    if isinstance(base.scheme, ButcherTableau):
        step = damped_runge_kutta(base.scheme.a, base.scheme.b)
        text = f"{base.name} applied to the damped vector field (not structure preserving)"
        return DampedIntegrator(f"damped-{base.name}", base.order, False, step, text,
                                base=base, conformal=False)
    raise ValueError(f"the integrator {base.name!r} has a scheme of unknown kind "
                     f"{type(base.scheme).__name__}")


def is_damped(integrator: Any) -> bool:
    """Whether ``integrator`` steps the damped system (its θ_Ψ ends with γ)."""
    return isinstance(integrator, DampedIntegrator)


def bind_dynamics(
    integrator: Integrator, potential: Any, params: Array, inv_mass: Any = None,
    gamma: Array | float | None = None,
) -> Dynamics | DampedDynamics:
    """The dynamics ``integrator`` steps, from the potential's (or H's) parameters ``params``
    and, for a damped integrator, the damping rate ``gamma`` (θ's ``damping`` block, which the
    model's layout places: :meth:`~symplid.model._statespace.HamiltonianModel.damping_rate`).
    """
    if not is_damped(integrator):
        return make_dynamics(potential, params, inv_mass)
    if gamma is None:
        raise TypeError("a damped integrator needs the damping rate: bind_dynamics(..., gamma=)")
    return damped_dynamics(make_dynamics(potential, params, inv_mass), gamma, inv_mass)
