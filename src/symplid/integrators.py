"""One-step integrators for separable Hamiltonians, and the propagator over a gap (eq. 14).

Every integrator has one call signature::

    q_next, p_next = integrator.step(dynamics, q, p, dt)

where ``dynamics`` bundles ∂U/∂q and the velocity map p ↦ M⁻¹p. Integrators are declared as
data, each with its order and whether it is symplectic:

* symplectic compositions: a tuple of leapfrog weights (leapfrog = ``(1,)``; Yoshida's
  fourth-order method = ``(w1, w0, w1)``), each leapfrog sub-step written in the integer-step
  form of eqs (5)–(6);
* explicit Runge–Kutta methods: a Butcher tableau (forward Euler, RK2 midpoint and Heun, RK4).

To add an integrator, add one entry to :data:`INTEGRATORS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array


class Dynamics(NamedTuple):
    """The right-hand side of Hamilton's equations (3) for H = ½pᵀM⁻¹p + U(q).

    ``grad_potential(q)`` is ∂U/∂q and ``velocity(p)`` is M⁻¹p, so q̇ = velocity(p) and
    ṗ = −grad_potential(q).
    """

    grad_potential: Callable[[Array], Array]
    velocity: Callable[[Array], Array]


def make_dynamics(potential, coefficients: Array, inv_mass: Array | None = None) -> Dynamics:
    """Bind a potential's coefficients and the inverse mass matrix into :class:`Dynamics`."""
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


def leapfrog_step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
    """Leapfrog (Störmer–Verlet) at integer steps, eqs (5)–(6), with a mass matrix M.

    q⁺ = q + Δt M⁻¹p − ½Δt² M⁻¹∂U(q);  p⁺ = p − ½Δt (∂U(q) + ∂U(q⁺)).
    """
    g = dynamics.grad_potential(q)
    q_next = q + dt * dynamics.velocity(p) - 0.5 * dt * dt * dynamics.velocity(g)
    p_next = p - 0.5 * dt * (g + dynamics.grad_potential(q_next))
    return q_next, p_next


def leapfrog_force_step(
    dynamics: Dynamics, q: Array, p: Array, force: Array, dt: Array
) -> tuple[Array, Array, Array]:
    """Eqs (5)–(6) with ``force = ∂U(q)`` given; returns the new state and ∂U(q⁺)."""
    q_next = q + dt * dynamics.velocity(p) - 0.5 * dt * dt * dynamics.velocity(force)
    force_next = dynamics.grad_potential(q_next)
    p_next = p - 0.5 * dt * (force + force_next)
    return q_next, p_next, force_next


def symplectic_composition(weights: tuple[float, ...]) -> tuple[StepFn, ForceStepFn]:
    """A step made of leapfrog sub-steps of sizes ``w_i·Δt`` (symmetric composition).

    Returns the plain step and its first-same-as-last form.
    """
    weights = tuple(float(w) for w in weights)

    def force_step(
        dynamics: Dynamics, q: Array, p: Array, force: Array, dt: Array
    ) -> tuple[Array, Array, Array]:
        for w in weights:
            q, p, force = leapfrog_force_step(dynamics, q, p, force, w * dt)
        return q, p, force

    def step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        q, p, _ = force_step(dynamics, q, p, dynamics.grad_potential(q), dt)
        return q, p

    return step, force_step


def symplectic_integrator(
    name: str, order: int, weights: tuple[float, ...], description: str
) -> Integrator:
    step, force_step = symplectic_composition(weights)
    return Integrator(name, order, True, step, description, force_step)


def runge_kutta(a: tuple[tuple[float, ...], ...], b: tuple[float, ...]) -> StepFn:
    """An explicit Runge–Kutta step from its Butcher tableau (strictly lower-triangular ``a``)."""
    a_np = np.asarray(a, dtype=float)
    b_np = np.asarray(b, dtype=float)
    stages = len(b_np)
    if a_np.shape != (stages, stages) or np.any(np.triu(a_np) != 0):
        raise ValueError("an explicit Butcher tableau needs a strictly lower-triangular a")

    def step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        kq: list[Array] = []
        kp: list[Array] = []
        for i in range(stages):
            qi, pi = q, p
            for j in range(i):
                if a_np[i, j] != 0.0:
                    qi = qi + dt * a_np[i, j] * kq[j]
                    pi = pi + dt * a_np[i, j] * kp[j]
            kq.append(dynamics.velocity(pi))
            kp.append(-dynamics.grad_potential(qi))
        for i in range(stages):
            if b_np[i] != 0.0:
                q = q + dt * b_np[i] * kq[i]
                p = p + dt * b_np[i] * kp[i]
        return q, p

    return step


_CBRT2 = 2.0 ** (1.0 / 3.0)
_YOSHIDA_W1 = 1.0 / (2.0 - _CBRT2)
_YOSHIDA_W0 = -_CBRT2 / (2.0 - _CBRT2)

INTEGRATORS: dict[str, Integrator] = {
    "leapfrog": symplectic_integrator("leapfrog", 2, (1.0,), "Störmer–Verlet, eqs (5)–(6)"),
    "yoshida4": symplectic_integrator(
        "yoshida4",
        4,
        (_YOSHIDA_W1, _YOSHIDA_W0, _YOSHIDA_W1),
        "Yoshida's 4th-order composition of three leapfrog steps",
    ),
    "euler": Integrator("euler", 1, False, runge_kutta(((0.0,),), (1.0,)), "forward Euler"),
    "rk2-midpoint": Integrator(
        "rk2-midpoint",
        2,
        False,
        runge_kutta(((0.0, 0.0), (0.5, 0.0)), (0.0, 1.0)),
        "explicit midpoint (the paper's non-symplectic RK2)",
    ),
    "rk2-heun": Integrator(
        "rk2-heun", 2, False, runge_kutta(((0.0, 0.0), (1.0, 0.0)), (0.5, 0.5)), "Heun's method"
    ),
    "rk4": Integrator(
        "rk4",
        4,
        False,
        runge_kutta(
            (
                (0.0, 0.0, 0.0, 0.0),
                (0.5, 0.0, 0.0, 0.0),
                (0.0, 0.5, 0.0, 0.0),
                (0.0, 0.0, 1.0, 0.0),
            ),
            (1 / 6, 1 / 3, 1 / 3, 1 / 6),
        ),
        "classical Runge–Kutta",
    ),
}

ALIASES = {"rk2": "rk2-midpoint", "verlet": "leapfrog", "stormer-verlet": "leapfrog"}


def get_integrator(name: str | Integrator) -> Integrator:
    """Look up an integrator by name (``'leapfrog'``, ``'rk2-midpoint'``, ...)."""
    if isinstance(name, Integrator):
        return name
    key = str(name).lower()
    key = ALIASES.get(key, key)
    if key not in INTEGRATORS:
        raise ValueError(
            f"unknown integrator {name!r}; choose one of {', '.join(sorted(INTEGRATORS))}"
        )
    return INTEGRATORS[key]


def substeps(gaps: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Number of equal substeps ⌈gap/dt⌉ per gap and their size gap/⌈gap/dt⌉ (eq. 14).

    A relative tolerance of 1e-9 keeps ``gap = 5, dt = 0.25`` at exactly 20 steps despite
    rounding in the observation times.
    """
    gaps = np.asarray(gaps, dtype=float)
    if dt <= 0 or not np.isfinite(dt):
        raise ValueError(f"dt must be a positive number, got {dt}")
    if np.any(gaps <= 0):
        raise ValueError("observation times must be strictly increasing and after t0")
    n = np.maximum(np.ceil(gaps / dt * (1.0 - 1e-9)), 1).astype(np.int64)
    return n, gaps / n


def propagate(
    integrator: Integrator,
    dynamics: Dynamics,
    q: Array,
    p: Array,
    step_size: Array,
    num_steps: Array,
    max_steps: int,
    unroll: int | bool = 1,
    masked: bool = True,
) -> tuple[Array, Array]:
    """Ψ over one observation gap: ``num_steps`` steps of ``step_size`` (eq. 14).

    ``q`` and ``p`` have shape ``(d,)`` or ``(d, ...)`` (a batch of points, coordinates first).
    ``max_steps`` is static (the largest ``num_steps`` over the data), so one compiled
    function serves every gap: steps past ``num_steps`` leave the state unchanged. When every
    gap has the same number of steps, pass ``masked=False`` to skip that test.
    """

    if integrator.force_step is not None:
        # First-same-as-last: the force at the end of a step starts the next one.
        def advance(carry):
            return integrator.force_step(dynamics, *carry, step_size)

        carry = (q, p, dynamics.grad_potential(q))
    else:

        def advance(carry):
            return integrator.step(dynamics, *carry, step_size)

        carry = (q, p)

    def body(i, carry):
        new = advance(carry)
        if not masked:
            return new
        active = i < num_steps
        return tuple(jnp.where(active, a, b) for a, b in zip(new, carry, strict=True))

    if max_steps == 1:
        carry = body(0, carry)
    else:
        carry = jax.lax.fori_loop(0, max_steps, body, carry, unroll=unroll)
    return carry[0], carry[1]


def integrate(
    integrator: Integrator | str,
    dynamics: Dynamics,
    x0: Array,
    dt: float,
    num_steps: int,
) -> Array:
    """All states of ``num_steps`` fixed steps from ``x0 = (q, p)``, shape ``(num_steps+1, 2d)``."""
    integrator = get_integrator(integrator)
    x0 = jnp.asarray(x0, dtype=float)
    d = x0.shape[-1] // 2

    def body(x, _):
        q, p = integrator.step(dynamics, x[:d], x[d:], dt)
        x_next = jnp.concatenate([q, p])
        return x_next, x_next

    _, xs = jax.lax.scan(body, x0, None, length=int(num_steps))
    return jnp.concatenate([x0[None], xs])
