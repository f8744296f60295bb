"""Synthetic data: integrate a system finely and observe it with Gaussian noise.

The paper's truth is leapfrog with Δt = 1e-3 and 20 full-state observations at t = 5, 10, …,
100 with noise standard deviation 0.05 (Section IV); those are the defaults for
``henon-heiles``. A damped system (γ > 0) is integrated by the damped form of the same
integrator (for leapfrog the conformally symplectic splitting, :mod:`symplid.dynamics._damping`)
at the same fine step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import jit_for
from symplid.dynamics._damping import bind_dynamics, with_damping
from symplid.dynamics._integrators import get_integrator
from symplid.dynamics._potentials import Potential, inverse_mass
from symplid.dynamics._systems import System, get_system
from symplid.dynamics._trajectory import solve_gaps, substeps
from symplid.filters._noise import get_observation_noise
from symplid.model._data import Observations

__all__ = ["simulate", "state_names", "true_trajectory"]


def state_names(dim: int, observation: str = "full") -> tuple[str, ...]:
    q = tuple(f"q{i + 1}" for i in range(dim))
    p = tuple(f"p{i + 1}" for i in range(dim))
    return q + p if observation == "full" else q


def _trajectory(potential, integrator, coefficients, gamma, x0, step_sizes, num_steps, inv_mass):
    """States at the end of every gap: :func:`~symplid.dynamics._trajectory.solve_gaps`."""
    dynamics = bind_dynamics(integrator, potential, coefficients, inv_mass, gamma)
    return solve_gaps(integrator, dynamics, x0, step_sizes, num_steps)


def true_trajectory(
    potential: Potential,
    coefficients,
    x0,
    times,
    dt: float = 1e-3,
    integrator: str = "leapfrog",
    t0: float = 0.0,
    mass=None,
    damping: float = 0.0,
) -> np.ndarray:
    """States ``(n, 2d)`` at ``times`` from ``x0`` at ``t0``, by ⌈gap/dt⌉ equal steps per gap.

    With ``damping`` = γ > 0 the damped system ṗ = −∂U/∂q − γM⁻¹p is integrated by the
    damped form of ``integrator``.
    """
    times = np.asarray(times, dtype=float)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (2 * potential.dim,):
        raise ValueError(f"x0 must have shape ({2 * potential.dim},), got {x0.shape}")
    num_steps, step_sizes = substeps(np.diff(np.concatenate([[t0], times])), dt)
    inv_mass = inverse_mass(mass, potential.dim)
    integ = get_integrator(integrator)
    params = np.asarray(coefficients, dtype=float)
    if damping:
        integ = with_damping(integ)
    xs = jit_for(potential, _trajectory, integ)(
        jnp.asarray(params),
        jnp.asarray(float(damping)),
        jnp.asarray(x0),
        jnp.asarray(step_sizes),
        jnp.asarray(num_steps),
        inv_mass,
    )
    return np.asarray(xs)


def simulate(
    system: System | str,
    times=None,
    noise_std: float | None = None,
    seed: int = 0,
    x0=None,
    dt: float = 1e-3,
    observation: str | None = None,
    integrator: str | None = None,
    observation_noise: str = "additive",
    rel_std: float = 0.05,
) -> Observations:
    """Noisy observations of a named system.

    Parameters
    ----------
    system
        A :class:`~symplid.dynamics._systems.System` or its name (``"henon-heiles"``, ...).
    times
        Observation times (default: the system's schedule, for Hénon–Heiles 5, 10, …, 100).
    noise_std
        Standard deviation of the Gaussian observation noise (default: the system's, 0.05).
    seed
        Seed of the noise (``jax.random.key(seed)``).
    x0
        Initial state at t = 0 (default: the system's).
    dt
        Step of the fine "truth" integration.
    observation
        ``"full"`` or ``"positions"`` (default: the system's; ``"positions"`` for the double
        pendulum, ``"full"`` otherwise).
    integrator
        The truth's integrator (default: the system's; leapfrog for a separable H).
    observation_noise
        A noise model of :data:`~symplid.filters._noise.OBSERVATION_NOISE`: ``"additive"``
        (y = h(x) + σ·e, the paper's), ``"multiplicative"`` (y = h(x)∘(1 + ``rel_std``·e′))
        or ``"both"``.
    rel_std
        Standard deviation of the relative noise ε of multiplicative noise.
    """
    if isinstance(system, str):
        system = get_system(system)
    if times is None:
        times = system.obs_interval * np.arange(1, system.num_obs + 1)
    noise_std = system.noise_std if noise_std is None else float(noise_std)
    if noise_std < 0:
        raise ValueError("noise_std must be ≥ 0")
    x0 = system.initial_state if x0 is None else np.asarray(x0, dtype=float)
    observation = system.observation if observation is None else observation
    if observation not in ("full", "positions"):
        raise ValueError("observation must be 'full' or 'positions'")
    integrator = system.truth_integrator if integrator is None else integrator
    states = true_trajectory(
        system.potential, system.coefficients, x0, times, dt, integrator, damping=system.damping
    )
    clean = states if observation == "full" else states[:, : system.dim]
    noise_model = get_observation_noise(observation_noise)
    if rel_std < 0:
        raise ValueError("rel_std must be ≥ 0")
    key = jax.random.key(seed)
    noise = np.asarray(jax.random.normal(key, clean.shape, dtype=jnp.float64))
    if noise_model.multiplicative:
        relative = np.asarray(jax.random.normal(jax.random.fold_in(key, 1), clean.shape))
        values = noise_model.sample(
            clean, noise_std**2, float(rel_std) ** 2, np.stack([relative, noise])
        )
    else:
        values = clean + noise_std * noise
    return Observations(
        np.asarray(times, dtype=float), values, state_names(system.dim, observation)
    )
