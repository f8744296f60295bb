"""The sampler registry: every MCMC method :func:`~symplid.sampling.sample` can run.

A sampler is registered once, as a :class:`SamplerSpec`: its settings class, how its chains
are laid out by default, whether it moves in the unconstrained space of the posterior, how
long its default burn-in is, and a ``build`` function that returns the pieces the runner
needs (:class:`SamplerKernel`: ``init_states``, ``step``, ``record`` and ``final_attrs``).
``sample``, the settings file, the command line and the sweeps read the names from
:data:`SAMPLERS`, so a sampler registered from anywhere (a test, a notebook) is usable at once::

    SAMPLERS.register("my-mh", SamplerSpec(MySettings, build_my_mh))

``build(posterior, settings, num_warmup, batch_logdensity)`` receives the posterior, an
instance of the settings class, the number of warm-up iterations (the burn-in when the
sampler ``adapts_during_burn_in``, else 0) and the posterior's log density vectorised over
chains (compiled already for the starting points). The kernel it returns must follow the
BlackJAX convention ``step(rng_key, state) -> (state, info)`` for **one** chain;
``init_states(thetas, cov)`` gets the starting points ``(num_chains, d)`` in θ and the MAP
covariance (pushed to the unconstrained space when ``unconstrained``) and returns the states
stacked over chains; ``record(state, info)`` returns the arrays kept per draw, among them
``"theta"`` (θ, constrained) and ``"lp"`` (log density of θ); ``final_attrs(states)`` the
JSON-ready attributes stored with the draws.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid._registry import Registry
from symplid.inference.samplers import dram, nuts
from symplid.inference.samplers._dram import DRAMSettings
from symplid.inference.samplers._nuts import NUTSSettings
from symplid.model._backends import LIKELIHOOD_BACKENDS
from symplid.model._params import (
    POSITIVE_GROUPS,
    USER_GROUP,
    ParameterSpace,
    pushforward_covariance,
)

Array = jax.Array


class DataStep:
    """A step that reads data: ``fn(data, rng_key, state) -> (state, info)``, called as
    ``step(rng_key, state)``.

    The runner (:func:`symplid.sampling.run_chains`) passes ``data`` to the compiled chunk as
    an argument, so that the chunk's program does not hold the data as constants: the same
    kernel on another data set of the same shape (another seed of a sweep) is then the same
    program, which JAX's persistent compilation cache serves instead of compiling again.
    """

    def __init__(self, fn: Callable[[Any, jax.Array, Any], tuple[Any, Any]], data: Any):
        self.fn, self.data = fn, data

    def __call__(self, rng_key: jax.Array, state: Any) -> tuple[Any, Any]:
        return self.fn(self.data, rng_key, state)


class SamplerKernel(NamedTuple):
    """The pieces of one sampler built for one posterior and one set of settings."""

    init_states: Callable[[Array, Array], Any]
    step: Callable[[Array, Any], tuple[Any, Any]]
    record: Callable[[Any, Any], dict[str, Array]]
    final_attrs: Callable[[Any], dict[str, Any]]
    covariance_at: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    """For a sampler in θ that moves some coordinates on another scale: the MAP covariance
    (θ̂, Σ) ↦ the covariance ``init_states`` gets (None: Σ itself)."""


def half_the_run(num_draws: int, thin: int) -> int:
    """Default burn-in of as many iterations as are kept (the paper's 100,000 of 200,000)."""
    return int(num_draws) * int(thin)


def fixed_warmup(num_draws: int, thin: int) -> int:
    """Default burn-in of 1000 warm-up (adaptation) iterations."""
    return 1000


def adaptation_length(num_params: int) -> int:
    """DRAM's first burn-in without a fixed budget: max(2000, 500 d) iterations, so that the
    adaptive covariance has seen some hundred states per parameter (its d(d+1)/2 entries
    settle at about that) before a draw is kept; the budget extends it while the chains
    disagree (:mod:`~symplid.sampling._budget`)."""
    return max(2000, 500 * int(num_params))


def warmup_length(num_params: int) -> int:
    """NUTS' first burn-in without a fixed budget: its 1000 window-adaptation steps."""
    return 1000


@dataclass(frozen=True)
class SamplerSpec:
    """Everything :func:`~symplid.sampling.sample` needs to know about a sampler.

    Parameters
    ----------
    settings_class
        A (frozen, hashable) dataclass of the kernel's static settings; ``sample(settings=)``
        takes an instance or a dict of its fields.
    build
        ``build(posterior, settings, num_warmup, batch_logdensity) -> SamplerKernel``.
    default_chain_method
        ``"vectorized"`` or ``"sequential"`` (see :func:`symplid.sampling.run_chains`).
    unconstrained
        Whether the chains move in the unconstrained space (the posterior must then have
        ``to_unconstrained``, ``from_unconstrained`` and ``log_density_unconstrained``).
    adapts_during_burn_in
        Whether the kernel adapts during the burn-in (then ``build`` gets it as
        ``num_warmup``; otherwise 0, and one compiled kernel serves every burn-in).
    default_burn_in
        ``(num_draws, thin) -> burn_in`` when ``sample(burn_in=None)`` with a fixed budget.
    first_burn_in
        ``num_params -> burn_in`` when ``sample(burn_in=None, num_draws=None)``: the burn-in
        before the budget's first check (:mod:`~symplid.sampling._budget`).
    resolve
        ``resolve(settings, posterior, num_chains, chain_method) -> settings``: fills the
        settings left to the run (``None``: none are).
    description
        One line for help texts.
    """

    settings_class: type
    build: Callable[[Any, Any, int, Callable], SamplerKernel]
    default_chain_method: str = "vectorized"
    unconstrained: bool = False
    adapts_during_burn_in: bool = False
    default_burn_in: Callable[[int, int], int] = half_the_run
    first_burn_in: Callable[[int], int] = adaptation_length
    resolve: Callable[[Any, Any, int, str], Any] | None = None
    description: str = ""


class LogScale:
    """θ ↔ w with the entries :func:`log_scale_entries` picks (those bounded below only) as
    w = log(θ − a), the rest as is, and the log density of w (log π(θ(w)) + Σ w over those
    entries: the log-Jacobian). By default the variances and the damping rate, and a user
    model's parameters whose prior is a law of log θ. The map, and with it the mask of the
    entries on the log scale, is the posterior's one
    :class:`~symplid.model._params.Reparameterisation` for DRAM
    (:meth:`~symplid.model._params.ParameterSpace.log_scale`)."""

    def __init__(self, posterior: Any, settings: DRAMSettings | None = None) -> None:
        space = ParameterSpace.of(posterior)
        chosen = log_scale_entries(space, settings or DRAMSettings())
        self.reparameterisation = space.log_scale(chosen)
        self.mask = self.reparameterisation.transformed  # the bounded-below-only ones
        self._log_density = posterior.log_density

    def to_theta(self, w: Array) -> Array:
        return self.reparameterisation.from_unconstrained(jnp.asarray(w))

    def to_w(self, theta: Array) -> Array:
        return self.reparameterisation.to_unconstrained(jnp.asarray(theta))

    def log_jacobian(self, w: Array) -> Array:
        return self.reparameterisation.log_abs_det_jacobian(jnp.asarray(w))

    def log_density(self, w: Array) -> Array:
        return self._log_density(self.to_theta(w)) + self.log_jacobian(w)


def log_scale_entries(space: ParameterSpace, settings: DRAMSettings) -> np.ndarray:
    """The entries DRAM's settings put on a log scale (the bounds then keep those bounded
    below only): the variances and the damping rate with ``variance_scale = "log"``; a user
    model's parameters with ``parameter_scale = "log"``, or with ``"prior"`` those whose
    prior is a law of log θ (:attr:`~symplid.model._priors.Prior.log_scale`)."""
    def chosen(group: str, prior: Any) -> bool:
        if group in POSITIVE_GROUPS:
            return settings.variance_scale == "log"
        if group != USER_GROUP or settings.parameter_scale == "natural":
            return False
        return settings.parameter_scale == "log" or bool(getattr(prior, "log_scale", False))
    return np.array([chosen(g, p) for g, p in zip(space.groups, space.priors, strict=True)],
                    dtype=bool)


def build_dram(posterior: Any, settings: DRAMSettings, num_warmup: int,
               batch_logdensity: Callable) -> SamplerKernel:
    """DRAM in θ, from the MAP covariance (the paper's sampler); with
    ``variance_scale = "log"`` the variances move as log(v − a), and a user model's
    parameters by ``parameter_scale`` (:class:`LogScale`)."""
    scale: LogScale | None = LogScale(posterior, settings)
    on_log_scale = [str(n) for n, m in zip(posterior.param_names, scale.mask, strict=True) if m]
    if not on_log_scale:
        scale = None
    logdensity_fn = posterior.log_density if scale is None else scale.log_density
    to_theta = (lambda w: w) if scale is None else scale.to_theta

    @jax.jit
    def init_from_values(positions, cov, values):
        return jax.vmap(
            lambda p, value: dram.init(p, logdensity_fn, cov, settings, logdensity=value)
        )(positions, values)

    def init_states(thetas, cov):
        # The log densities come from the batch function, already compiled for the starts.
        values = batch_logdensity(thetas)
        if scale is None:
            return init_from_values(thetas, cov, values)
        ws = scale.to_w(thetas)
        return init_from_values(ws, cov, values + scale.log_jacobian(ws))

    def record(state: dram.DRAMState, info: dram.DRAMInfo) -> dict[str, Array]:
        jacobian = 0.0 if scale is None else scale.log_jacobian(state.position)
        return {
            "theta": to_theta(state.position),
            "lp": state.logdensity - jacobian,
            "accepted": info.is_accepted,
            "stage1_accepted": info.stage1_accepted,
            "stage2_attempted": info.stage2_attempted,
            "stage2_accepted": info.stage2_accepted,
        }

    def final_attrs(states: dram.DRAMState) -> dict[str, Any]:
        return {"dram_adapted_covariance": np.asarray(states.cov).tolist(),
                "dram_variance_scale": settings.variance_scale,
                "dram_parameter_scale": settings.parameter_scale,
                "dram_log_scale": list(on_log_scale)}

    covariance_at = None if scale is None else (
        lambda theta, cov: pushforward_covariance(scale.to_w, theta, cov))
    return SamplerKernel(init_states, _dram_step(posterior, settings, scale), record,
                         final_attrs, covariance_at)


def resolve_dram(settings: DRAMSettings, posterior: Any, num_chains: int,
                 chain_method: str) -> DRAMSettings:
    """The settings left to the run (``None``), from the chains and the likelihood backend.

    * ``paired_stages``: paired when the chains are vectorised and their two stages fill the
      backend's batch (``2 × num_chains ≥ batch_width > 1``: four chains on the compiled
      kernel), where one batch of both stages costs less than the stage-by-stage calls.
    * ``linalg``: ``"fused"`` when the backend is a custom call (each stretch of the step
      between its likelihood calls compiled as one kernel), else unrolled.
    """
    backend = _backend(posterior)
    width = int(getattr(backend, "batch_width", 1))
    changes: dict[str, Any] = {}
    if settings.paired_stages is None:
        changes["paired_stages"] = bool(settings.delayed_rejection
                                        and chain_method == "vectorized"
                                        and 1 < width <= 2 * num_chains)
    if settings.linalg is None:
        changes["linalg"] = "fused" if getattr(backend, "custom_call", False) else "unrolled"
    return dataclasses.replace(settings, **changes)


def _backend(posterior: Any) -> Any:
    """The likelihood backend of ``posterior``'s model (None if it has none)."""
    try:
        name = posterior.model.likelihood_backend
    except AttributeError:
        return None
    return LIKELIHOOD_BACKENDS.get_entry(name)


def _dram_step(posterior: Any, settings: DRAMSettings, scale: LogScale | None) -> Callable:
    """DRAM's transition (in θ, or in w with the variances on a log scale); one that takes
    the observations as an argument (:class:`DataStep`) when the posterior offers
    ``log_density_with`` and ``data``, so that the compiled chunk is the same program for
    every data set of the same shape."""
    with_data = getattr(posterior, "log_density_with", None)
    data = getattr(posterior, "data", None)
    if with_data is None or data is None:
        return dram.build_kernel(
            posterior.log_density if scale is None else scale.log_density, settings)
    log_density = jax.jit(with_data)  # a nested program, as posterior.log_density is

    def density(observations, x):
        if scale is None:
            return log_density(observations, x)
        return log_density(observations, scale.to_theta(x)) + scale.log_jacobian(x)

    def step(observations, rng_key, state):
        kernel = dram.build_kernel(lambda x: density(observations, x), settings)
        return kernel(rng_key, state)

    return DataStep(step, data)


def build_nuts(posterior: Any, settings: NUTSSettings, num_warmup: int,
               batch_logdensity: Callable) -> SamplerKernel:
    """NUTS (BlackJAX) in z = to_unconstrained(θ), adapting during the warm-up."""
    logdensity_z = posterior.log_density_unconstrained
    from_z = posterior.from_unconstrained
    to_z = posterior.to_unconstrained

    @jax.jit
    def init_states(thetas, cov_z):
        return jax.vmap(lambda t: nuts.init(to_z(t), logdensity_z, cov_z, settings))(thetas)

    def record(state: nuts.NUTSState, info) -> dict[str, Array]:
        z = state.hmc.position
        log_det = jnp.linalg.slogdet(jax.jacfwd(from_z)(z))[1]
        return {
            "theta": from_z(z),
            "lp": state.hmc.logdensity - log_det,
            "acceptance_rate": info.acceptance_rate,
            "diverging": info.is_divergent,
            "n_steps": info.num_integration_steps,
            "tree_depth": info.num_trajectory_expansions,
            "energy": info.energy,
            "step_size": state.step_size,
        }

    def final_attrs(states: nuts.NUTSState) -> dict[str, Any]:
        return {
            "nuts_step_size": np.asarray(states.step_size).tolist(),
            "nuts_inverse_mass_matrix": np.asarray(states.inverse_mass_matrix).tolist(),
        }

    return SamplerKernel(init_states, nuts.build_kernel(logdensity_z, settings, num_warmup),
                         record, final_attrs)


SAMPLERS: Registry[SamplerSpec] = Registry("sampler")
"""Sampler name → its :class:`SamplerSpec` (DRAM, the paper's; NUTS through BlackJAX)."""
SAMPLERS.register(
    "dram",
    SamplerSpec(DRAMSettings, build_dram, resolve=resolve_dram,
                description="delayed-rejection adaptive Metropolis (the paper's), in θ "
                "(variances optionally on a log scale)"),
)
SAMPLERS.register(
    "nuts",
    SamplerSpec(NUTSSettings, build_nuts, default_chain_method="sequential", unconstrained=True,
                adapts_during_burn_in=True, default_burn_in=fixed_warmup,
                first_burn_in=warmup_length,
                description="the No-U-Turn sampler (BlackJAX), in the unconstrained space"),
)

__all__ = [
    "SAMPLERS",
    "DataStep",
    "LogScale",
    "SamplerKernel",
    "SamplerSpec",
    "adaptation_length",
    "build_dram",
    "build_nuts",
    "fixed_warmup",
    "half_the_run",
    "warmup_length",
]
