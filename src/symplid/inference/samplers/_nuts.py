"""The No-U-Turn sampler (BlackJAX's kernel) with Stan's window adaptation built in.

BlackJAX's NUTS kernel takes its step size and inverse mass matrix as arguments; here they
travel inside the chain state (:class:`NUTSState`), together with the state of the window
adaptation, so that the transition has the common signature
``step(rng_key, state) -> (state, info)``:

* during the first ``num_warmup`` iterations the step adapts the step size (dual averaging)
  and the inverse mass matrix (Welford estimates over Stan's doubling slow windows) after
  every NUTS transition, exactly as ``blackjax.window_adaptation`` does but one iteration
  at a time, from BlackJAX's public building blocks (``build_schedule``,
  ``dual_averaging_adaptation``, ``mass_matrix_adaptation``);
* at the last warm-up iteration the step size becomes the dual-averaging average, and from
  then on the parameters stay fixed: plain NUTS.

Warm-up and sampling are therefore the same compiled function: the chunked runner
(:func:`symplid.sampling._run.run_chains`) treats warm-up as burn-in, so one compilation
serves both, the progress bar moves during warm-up, and Ctrl-C works there too. Each chain
adapts its own parameters.

Everything runs in the *unconstrained* space of the posterior
(``log_density_unconstrained``, Jacobian included); :mod:`symplid.sampling._api` maps the
draws back.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

if TYPE_CHECKING:  # BlackJAX is imported on first use: it takes a second or two to load.
    from blackjax.adaptation.mass_matrix import MassMatrixAdaptationState
    from blackjax.adaptation.step_size import DualAveragingAdaptationState
    from blackjax.mcmc.hmc import HMCState
    from blackjax.mcmc.nuts import NUTSInfo

Array = jax.Array
LogDensityFn = Callable[[Array], Array]

__all__ = ["NUTSSettings", "NUTSState", "build_kernel", "init"]


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
    """One NUTS chain.

    Attributes
    ----------
    hmc
        BlackJAX's state (position, log density, its gradient).
    step_size, inverse_mass_matrix
        The parameters the next transition uses.
    iteration
        Transitions taken so far (warm-up included).
    step_size_adaptation, mass_adaptation
        States of the dual averaging and of the Welford mass-matrix estimate (unused after
        warm-up).
    """

    hmc: HMCState
    step_size: Array
    inverse_mass_matrix: Array
    iteration: Array
    step_size_adaptation: DualAveragingAdaptationState
    mass_adaptation: MassMatrixAdaptationState


def _adaptation(settings: NUTSSettings):
    from blackjax.adaptation.mass_matrix import mass_matrix_adaptation
    from blackjax.adaptation.step_size import dual_averaging_adaptation

    mass = mass_matrix_adaptation(is_diagonal_matrix=not settings.dense_mass)
    step_size = dual_averaging_adaptation(settings.target_acceptance_rate)
    return mass, step_size


def _as_mass(inverse_mass_matrix: Array, dense: bool) -> Array:
    matrix = jnp.asarray(inverse_mass_matrix, dtype=jnp.float64)
    if dense:
        return matrix if matrix.ndim == 2 else jnp.diag(matrix)
    return jnp.diag(matrix) if matrix.ndim == 2 else matrix


def init(position: Array, logdensity_fn: LogDensityFn, inverse_mass_matrix: Array,
         settings: NUTSSettings | None = None, step_size: float | None = None) -> NUTSState:
    """Initial NUTS state.

    Parameters
    ----------
    position
        Starting point, shape ``(d,)``, in the space of ``logdensity_fn``.
    logdensity_fn
        Log density (unconstrained space).
    inverse_mass_matrix
        Initial inverse mass matrix, e.g. the Laplace covariance mapped to the unconstrained
        space; a vector is read as a diagonal. With ``dense_mass=False`` only its diagonal
        is used.
    settings
        NUTS settings.
    step_size
        Initial step size (default ``settings.initial_step_size``).
    """
    import blackjax

    settings = NUTSSettings() if settings is None else settings
    position = jnp.asarray(position, dtype=jnp.float64)
    if position.ndim != 1:
        raise ValueError(f"position must be a 1-D array, got shape {position.shape}")
    mass = _as_mass(inverse_mass_matrix, settings.dense_mass)
    expected = (position.size,) * (2 if settings.dense_mass else 1)
    if mass.shape != expected:
        raise ValueError(f"inverse_mass_matrix must have shape {expected}, got {mass.shape}")
    step_size = settings.initial_step_size if step_size is None else step_size
    (mass_init, _, _), (step_init, _, _) = _adaptation(settings)
    return NUTSState(
        hmc=blackjax.nuts.init(position, logdensity_fn),
        step_size=jnp.asarray(step_size, dtype=jnp.float64),
        inverse_mass_matrix=mass,
        iteration=jnp.asarray(0, dtype=jnp.int64),
        step_size_adaptation=step_init(jnp.asarray(step_size, dtype=jnp.float64)),
        mass_adaptation=mass_init(position.size, mass),
    )


def build_kernel(
    logdensity_fn: LogDensityFn, settings: NUTSSettings | None = None, num_warmup: int = 0
) -> Callable[[Array, NUTSState], tuple[NUTSState, NUTSInfo]]:
    """Build ``step(rng_key, state) -> (state, info)``: NUTS, adapting while warming up.

    Parameters
    ----------
    logdensity_fn
        Log density (unconstrained space).
    settings
        NUTS settings.
    num_warmup
        Number of warm-up (adaptation) iterations, counted by ``state.iteration``; 0 keeps
        the state's step size and mass matrix fixed throughout.

    Returns
    -------
    Callable
        The transition. Its info is BlackJAX's :class:`~blackjax.mcmc.nuts.NUTSInfo`
        (``is_divergent``, ``acceptance_rate``, ``num_integration_steps``, ...).
    """
    import blackjax
    from blackjax.adaptation.window_adaptation import build_schedule

    settings = NUTSSettings() if settings is None else settings
    if int(num_warmup) != num_warmup or num_warmup < 0:
        raise ValueError(f"num_warmup must be an integer >= 0, got {num_warmup!r}")
    num_warmup = int(num_warmup)
    kernel = blackjax.nuts.build_kernel(divergence_threshold=settings.divergence_threshold)
    (_, mass_update, mass_final), (step_init, step_update, step_final) = _adaptation(settings)
    schedule = jnp.asarray(build_schedule(num_warmup), dtype=jnp.int64).reshape(-1, 2)

    def adapt(state: NUTSState, acceptance_rate: Array) -> NUTSState:
        t = jnp.minimum(state.iteration - 1, num_warmup - 1)  # the transition just taken
        slow, window_end = schedule[t, 0] == 1, schedule[t, 1] == 1
        last = state.iteration == num_warmup
        acceptance_rate = jnp.where(jnp.isfinite(acceptance_rate), acceptance_rate, 0.0)

        step_state = step_update(state.step_size_adaptation, acceptance_rate)
        mass_state = lax.cond(slow, lambda m: mass_update(m, state.hmc.position),
                              lambda m: m, state.mass_adaptation)
        # End of a slow window: new mass matrix, dual averaging restarted from its average.
        mass_state = lax.cond(window_end, mass_final, lambda m: m, mass_state)
        step_state = lax.cond(window_end, lambda s: step_init(step_final(s)), lambda s: s,
                              step_state)
        step_size = jnp.where(last, step_final(step_state), jnp.exp(step_state.log_step_size))
        return state._replace(
            step_size=step_size,
            inverse_mass_matrix=mass_state.inverse_mass_matrix,
            step_size_adaptation=step_state,
            mass_adaptation=mass_state,
        )

    def step(rng_key: Array, state: NUTSState) -> tuple[NUTSState, NUTSInfo]:
        hmc_state, info = kernel(
            rng_key,
            state.hmc,
            logdensity_fn,
            state.step_size,
            state.inverse_mass_matrix,
            max_num_doublings=settings.max_num_doublings,
        )
        new_state = state._replace(hmc=hmc_state, iteration=state.iteration + 1)
        if num_warmup > 0:
            new_state = lax.cond(state.iteration < num_warmup,
                                 lambda s: adapt(s, info.acceptance_rate), lambda s: s,
                                 new_state)
        return new_state, info

    return step
