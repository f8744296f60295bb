"""The one trajectory solver: Ψ over observation gaps (eq. 14) and fixed-step trajectories.

Every path the library integrates goes through here: the propagator inside the likelihood
(:func:`propagate`, sigma points as a batch), simulation of the truth, predictions and the
energies drawn in figures (:func:`integrate`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics.integrators import Dynamics, Integrator, get_integrator

Array = jax.Array


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
