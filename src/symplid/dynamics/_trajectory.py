"""The one trajectory solver: Ψ over observation gaps (eq. 14) and fixed-step trajectories.

Every path the library integrates goes through one loop, :func:`_advance` (``num_steps``
steps of one integrator, the force carried from step to step where the integrator has a
first-same-as-last form):

* :func:`propagate`: Ψ over one gap, for the propagator inside the likelihood (sigma points
  as a batch, coordinates first);
* :func:`solve_gaps`: the states at the end of a run of gaps of different lengths (the
  simulated truth at the observation times);
* :func:`solve`: every ``every``-th state of a fixed-step trajectory (predictions, the
  energies and paths drawn in figures); :func:`integrate` is its every-state form.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._integrators import (
    Dynamics,
    Integrator,
    get_integrator,
    require_separable,
)

Array = jax.Array
Carry = tuple[Array, ...]
"""``(q, p)``, or ``(q, p, ∂U(q))`` for an integrator with a first-same-as-last step (or
``(q, p, aux)`` for one with its own ``start``, e.g. Tao's extended phase space)."""

__all__ = ["integrate", "propagate", "solve", "solve_gaps", "substeps"]


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


# ---------------------------------------------------------------------------- the one loop
def _start(integrator: Integrator, dynamics: Dynamics, q: Array, p: Array) -> Carry:
    """The loop's carry at ``(q, p)``: with the force ∂U(q) when the integrator reuses it.

    An integrator with its own ``start`` carries what that returns instead (Tao's copies of
    the state); a separable-only integrator given a non-separable H stops here with a clear
    error.
    """
    if not integrator.nonseparable:
        require_separable(dynamics, f"the integrator {integrator.name!r}")
    if integrator.force_step is not None:
        if integrator.start is not None:
            return (q, p, integrator.start(dynamics, q, p))
        return (q, p, dynamics.grad_potential(q))
    return (q, p)


def _advance(
    integrator: Integrator,
    dynamics: Dynamics,
    carry: Carry,
    step_size: Array,
    num_steps: Array | int,
    max_steps: int | None,
    unroll: int | bool = 1,
    masked: bool = True,
) -> Carry:
    """``num_steps`` steps of ``step_size`` from ``carry`` (see :func:`_start`).

    With a static ``max_steps`` the loop has that many iterations and, when ``masked``, steps
    past ``num_steps`` leave the state unchanged (one compiled loop for gaps of any length, and
    reverse-mode differentiable). With ``max_steps=None`` the loop runs exactly ``num_steps``
    iterations (a traced bound: no wasted steps, forward-mode only).
    """
    if integrator.force_step is not None:
        # First-same-as-last: the force at the end of a step starts the next one.
        def advance(c: Carry) -> Carry:
            return integrator.force_step(dynamics, *c, step_size)
    else:

        def advance(c: Carry) -> Carry:
            return integrator.step(dynamics, *c, step_size)

    if max_steps is None:
        return jax.lax.fori_loop(0, num_steps, lambda _, c: advance(c), carry)

    def body(i, c: Carry) -> Carry:
        new = advance(c)
        if not masked:
            return new
        active = i < num_steps
        return tuple(jnp.where(active, a, b) for a, b in zip(new, c, strict=True))

    if max_steps == 1:
        return body(0, carry)
    return jax.lax.fori_loop(0, max_steps, body, carry, unroll=unroll)


def _coordinates_first(x: Array) -> tuple[Array, Array, int]:
    """``(q, p)`` of states ``x`` of shape ``(..., 2d)``, each moved to shape ``(d, ...)``."""
    x = jnp.asarray(x, dtype=float)
    d = x.shape[-1] // 2
    return jnp.moveaxis(x[..., :d], -1, 0), jnp.moveaxis(x[..., d:], -1, 0), d


def _stack_states(qs: Array, ps: Array) -> Array:
    """States ``(T, d, ...)`` twice → ``(..., T, 2d)``."""
    xs = jnp.concatenate([qs, ps], axis=1)  # (T, 2d, ...)
    return jnp.moveaxis(jnp.moveaxis(xs, 1, -1), 0, -2)


# ---------------------------------------------------------------------------- public API
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

    carry = _start(integrator, dynamics, q, p)
    carry = _advance(integrator, dynamics, carry, step_size, num_steps, max_steps, unroll, masked)
    return carry[0], carry[1]


def solve_gaps(
    integrator: Integrator | str,
    dynamics: Dynamics,
    x0: Array,
    step_sizes: Array,
    num_steps: Array,
    max_steps: int | None = None,
    unroll: int | bool = 1,
    masked: bool = True,
) -> Array:
    """The states at the end of consecutive gaps, gap k being ``num_steps[k]`` steps of
    ``step_sizes[k]`` (Ψ of eq. 14 applied gap after gap, without noise).

    Parameters
    ----------
    integrator
        An :class:`~._integrators.Integrator` or its name.
    dynamics
        ∂U/∂q and M⁻¹p (:func:`~._integrators.make_dynamics`); it must accept coordinates-first
        batches ``(d, ...)`` when ``x0`` has leading batch axes.
    x0
        Initial state ``(q, p)``, shape ``(2d,)`` or ``(..., 2d)`` (a batch sharing ``dynamics``).
    step_sizes, num_steps
        One entry per gap, shape ``(K,)`` (see :func:`substeps`).
    max_steps, unroll, masked
        As in :func:`propagate`; ``None`` (default) loops exactly ``num_steps[k]`` times per gap.

    Returns
    -------
    Array of shape ``(..., K, 2d)``: the state after each gap (``x0`` not included).
    """
    integrator = get_integrator(integrator)
    q, p, _ = _coordinates_first(x0)

    def gap(carry: Carry, inp: tuple[Array, Array]) -> tuple[Carry, tuple[Array, Array]]:
        h, n = inp
        carry = _advance(integrator, dynamics, carry, h, n, max_steps, unroll, masked)
        return carry, (carry[0], carry[1])

    inputs = (jnp.asarray(step_sizes, dtype=float), jnp.asarray(num_steps))
    _, (qs, ps) = jax.lax.scan(gap, _start(integrator, dynamics, q, p), inputs)
    return _stack_states(qs, ps)


def solve(
    integrator: Integrator | str,
    dynamics: Dynamics,
    x0: Array,
    step_size: Array | float,
    num_steps: int,
    every: int = 1,
    unroll: int | bool = 1,
) -> Array:
    """A fixed-step trajectory X_k = Ψ_h^k(X_0), stored every ``every`` steps (Section II-B.2).

    Parameters
    ----------
    integrator
        An :class:`~._integrators.Integrator` or its name.
    dynamics
        As in :func:`solve_gaps`.
    x0
        Initial state ``(q, p)``, shape ``(2d,)`` or ``(..., 2d)`` (a batch sharing ``dynamics``).
    step_size
        The step h (may be traced).
    num_steps
        Number of steps (static).
    every
        Store the states at steps ``0, every, 2·every, …`` and at the last step (static).
    unroll
        Unrolling of the inner loop of ``every`` steps.

    Returns
    -------
    Array of shape ``(..., T, 2d)`` with ``T = ⌈num_steps/every⌉ + 1``; ``x0`` comes first.
    """
    integrator = get_integrator(integrator)
    num_steps, every = _count(num_steps, "num_steps", 0), _count(every, "every", 1)
    q, p, _ = _coordinates_first(x0)
    full, rem = divmod(num_steps, every)

    def chunk(carry: Carry, _) -> tuple[Carry, tuple[Array, Array]]:
        carry = _advance(integrator, dynamics, carry, step_size, every, every, unroll, False)
        return carry, (carry[0], carry[1])

    carry, (qs, ps) = jax.lax.scan(chunk, _start(integrator, dynamics, q, p), None, length=full)
    qs, ps = [q[None], qs], [p[None], ps]
    if rem:  # the last, shorter stretch
        carry = _advance(integrator, dynamics, carry, step_size, rem, rem, unroll, False)
        qs.append(carry[0][None])
        ps.append(carry[1][None])
    return _stack_states(jnp.concatenate(qs), jnp.concatenate(ps))


def integrate(
    integrator: Integrator | str,
    dynamics: Dynamics,
    x0: Array,
    dt: float,
    num_steps: int,
) -> Array:
    """All states of ``num_steps`` fixed steps from ``x0 = (q, p)``, shape ``(num_steps+1, 2d)``.

    The every-state form of :func:`solve`.
    """
    return solve(integrator, dynamics, x0, dt, num_steps)


def _count(value: int, name: str, least: int) -> int:
    """``value`` as a static integer ≥ ``least``."""
    if int(value) != value or value < least:
        raise ValueError(f"{name} must be an integer ≥ {least}, got {value}")
    return int(value)
