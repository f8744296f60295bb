"""The No-U-Turn sampler through BlackJAX, in the shape of the other samplers.

BlackJAX's NUTS kernel takes its step size and inverse mass matrix as arguments; here they
travel inside the chain state (:class:`NUTSState`) so that the transition has the common
signature ``step(rng_key, state) -> (state, info)`` and each chain keeps the parameters its
own window adaptation found. Everything runs in the *unconstrained* space of the posterior
(``log_density_unconstrained``, Jacobian included); mapping the draws back is the caller's
job (:mod:`symplid.samplers.api` does it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import blackjax
import jax
import jax.numpy as jnp
from blackjax.adaptation.base import get_filter_adapt_info_fn
from blackjax.mcmc.hmc import HMCState
from blackjax.mcmc.nuts import NUTSInfo

Array = jax.Array
LogDensityFn = Callable[[Array], Array]

__all__ = ["NUTSSettings", "NUTSState", "build_kernel", "init", "warmup"]


@dataclass(frozen=True)
class NUTSSettings:
    """Static settings of NUTS and its window adaptation.

    Parameters
    ----------
    dense_mass
        Adapt a dense inverse mass matrix (``True``) or only its diagonal. The posteriors of
        this library have strongly correlated coefficients, hence dense by default.
    target_acceptance_rate
        Target of the dual-averaging step-size adaptation.
    max_num_doublings
        Maximum tree depth.
    divergence_threshold
        Energy error above which a transition counts as divergent.
    initial_step_size
        Step size the adaptation starts from.
    """

    dense_mass: bool = True
    target_acceptance_rate: float = 0.8
    max_num_doublings: int = 10
    divergence_threshold: float = 1000.0
    initial_step_size: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 < self.target_acceptance_rate < 1.0:
            raise ValueError(
                f"target_acceptance_rate must lie in (0, 1), got {self.target_acceptance_rate}"
            )
        if int(self.max_num_doublings) != self.max_num_doublings or self.max_num_doublings < 1:
            raise ValueError(
                f"max_num_doublings must be an integer >= 1, got {self.max_num_doublings}"
            )
        if not self.divergence_threshold > 0:
            raise ValueError(
                f"divergence_threshold must be > 0, got {self.divergence_threshold}"
            )
        if not self.initial_step_size > 0:
            raise ValueError(f"initial_step_size must be > 0, got {self.initial_step_size}")


class NUTSState(NamedTuple):
    """One NUTS chain: BlackJAX's state and the chain's tuned parameters."""

    hmc: HMCState
    step_size: Array
    inverse_mass_matrix: Array


def _initial_mass(inverse_mass_matrix: Array, dense: bool) -> Array:
    matrix = jnp.asarray(inverse_mass_matrix, dtype=jnp.float64)
    if dense:
        return matrix if matrix.ndim == 2 else jnp.diag(matrix)
    return jnp.diag(matrix) if matrix.ndim == 2 else matrix


def warmup(
    rng_key: Array,
    position: Array,
    logdensity_fn: LogDensityFn,
    num_steps: int,
    inverse_mass_matrix: Array,
    settings: NUTSSettings | None = None,
) -> NUTSState:
    """Stan-style window adaptation of the step size and inverse mass matrix for one chain.

    Parameters
    ----------
    rng_key
        Key of this chain's adaptation.
    position
        Starting point in the space of ``logdensity_fn``.
    logdensity_fn
        Log density (unconstrained space).
    num_steps
        Number of adaptation steps (discarded draws).
    inverse_mass_matrix
        Initial inverse mass matrix, e.g. the Laplace covariance mapped to the unconstrained
        space; a vector is read as a diagonal.
    settings
        NUTS settings.

    Returns
    -------
    NUTSState
        The last adaptation state with the tuned step size and inverse mass matrix.
        ``vmap`` over ``rng_key`` and ``position`` adapts several chains at once.
    """
    settings = NUTSSettings() if settings is None else settings
    adaptation = blackjax.window_adaptation(
        blackjax.nuts,
        logdensity_fn,
        is_mass_matrix_diagonal=not settings.dense_mass,
        initial_inverse_mass_matrix=_initial_mass(inverse_mass_matrix, settings.dense_mass),
        initial_step_size=settings.initial_step_size,
        target_acceptance_rate=settings.target_acceptance_rate,
        adaptation_info_fn=get_filter_adapt_info_fn(),
        max_num_doublings=settings.max_num_doublings,
    )
    result, _ = adaptation.run(rng_key, position, num_steps=int(num_steps))
    return NUTSState(
        result.state,
        jnp.asarray(result.parameters["step_size"]),
        jnp.asarray(result.parameters["inverse_mass_matrix"]),
    )


def init(position: Array, logdensity_fn: LogDensityFn, step_size: float,
         inverse_mass_matrix: Array) -> NUTSState:
    """A NUTS state at ``position`` with fixed (already tuned) parameters."""
    return NUTSState(
        blackjax.nuts.init(jnp.asarray(position, dtype=jnp.float64), logdensity_fn),
        jnp.asarray(step_size, dtype=jnp.float64),
        jnp.asarray(inverse_mass_matrix, dtype=jnp.float64),
    )


def build_kernel(
    logdensity_fn: LogDensityFn, settings: NUTSSettings | None = None
) -> Callable[[Array, NUTSState], tuple[NUTSState, NUTSInfo]]:
    """Build ``step(rng_key, state) -> (state, info)`` for NUTS (BlackJAX's kernel).

    The info is BlackJAX's :class:`~blackjax.mcmc.nuts.NUTSInfo` (``is_divergent``,
    ``acceptance_rate``, ``num_integration_steps``, ``energy``, ...).
    """
    settings = NUTSSettings() if settings is None else settings
    kernel = blackjax.nuts.build_kernel(divergence_threshold=settings.divergence_threshold)

    def step(rng_key: Array, state: NUTSState) -> tuple[NUTSState, NUTSInfo]:
        hmc_state, info = kernel(
            rng_key,
            state.hmc,
            logdensity_fn,
            state.step_size,
            state.inverse_mass_matrix,
            max_num_doublings=settings.max_num_doublings,
        )
        return NUTSState(hmc_state, state.step_size, state.inverse_mass_matrix), info

    return step
