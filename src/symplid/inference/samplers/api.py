"""``sample``: posterior draws by DRAM or NUTS, returned as ArviZ ``InferenceData``.

Layout of the result
--------------------
* ``posterior``: **one variable per parameter**, named by ``posterior.param_names``
  (``q1``, ``q1^2``, ..., ``process_var``, ``obs_var``), each shaped ``(chain, draw)``.
  ``az.summary`` then prints one row per parameter under its own name, which reads better
  than ``theta[0]``..``theta[10]``. :func:`draws_array` stacks them back into
  ``(chain, draw, num_params)`` in the posterior's order.
* ``sample_stats``: ``lp`` (log posterior density over θ, in the constrained space, for both
  samplers) and, for DRAM, ``accepted``, ``stage1_accepted``, ``stage2_attempted``,
  ``stage2_accepted``; for NUTS, ``acceptance_rate``, ``diverging``, ``n_steps``,
  ``tree_depth``, ``energy`` and ``step_size``.
* ``attrs`` (of the ``InferenceData``): ``method``, ``seed``, ``settings`` (a JSON string of
  every setting, defaults included), ``param_names``, ``map_theta``, ``map_log_posterior``,
  ``hessian`` and ``map_covariance`` (nested lists), ``initial_positions`` (one row per
  chain), ``iterations`` (per chain, burn-in
  included), ``interrupted`` (0/1), ``sampling_seconds``, and for DRAM
  ``dram_adapted_covariance`` (each chain's final running covariance, nested lists). All
  survive ``to_netcdf``.

Starting points
---------------
Chains start from overdispersed points around the MAP, ``θ̂ + s·L z`` with ``L Lᵀ`` the MAP
covariance, ``z ~ N(0, I)`` and ``s = init_spread`` (2 by default), a point being redrawn
until its log density is finite (up to 100 times; then the chain starts at the MAP and a
warning says so). ``init_spread=0`` starts every chain at the MAP, as in the paper.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid.inference.diagnostics import import_arviz
from symplid.inference.samplers import dram, nuts
from symplid.inference.samplers.registry import SAMPLERS
from symplid.inference.samplers.run import ChainRun, ChunkReport, run_chains

__all__ = ["draws_array", "overdispersed_starts", "sample"]
#: Chain layout used when ``sample(chain_method=None)``.
DEFAULT_CHAIN_METHOD = {"dram": "vectorized", "nuts": "sequential"}
_POSTERIOR_ATTRIBUTES = ("num_params", "param_names", "log_density")
_UNCONSTRAINED_ATTRIBUTES = ("to_unconstrained", "from_unconstrained",
                             "log_density_unconstrained")


def _check_posterior(posterior: Any, method: str) -> tuple[int, tuple[str, ...]]:
    needed = _POSTERIOR_ATTRIBUTES + (_UNCONSTRAINED_ATTRIBUTES if method == "nuts" else ())
    missing = [name for name in needed if not hasattr(posterior, name)]
    if missing:
        raise TypeError(
            f"posterior lacks {', '.join(missing)}: sample() needs an object with "
            f"{', '.join(needed)} (e.g. symplid.Posterior)"
        )
    num_params = int(posterior.num_params)
    names = tuple(str(name) for name in posterior.param_names)
    if len(names) != num_params:
        raise ValueError(
            f"posterior.param_names has {len(names)} names but num_params is {num_params}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"posterior.param_names must be unique, got {names}")
    return num_params, names


def _check_map(init: Any, num_params: int, batch_logdensity: Callable,
               num_chains: int) -> tuple[np.ndarray, np.ndarray]:
    for name in ("theta", "covariance"):
        if not hasattr(init, name):
            raise TypeError(
                f"init lacks .{name}: pass the result of symplid.find_map (an object with "
                ".theta and .covariance)"
            )
    theta = np.asarray(init.theta, dtype=np.float64)
    cov = np.asarray(init.covariance, dtype=np.float64)
    if theta.shape != (num_params,):
        raise ValueError(f"init.theta must have shape ({num_params},), got {theta.shape}")
    if cov.shape != (num_params, num_params):
        raise ValueError(
            f"init.covariance must have shape ({num_params}, {num_params}), got {cov.shape}"
        )
    if not np.all(np.isfinite(cov)):
        raise ValueError("init.covariance contains non-finite entries")
    try:
        np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        raise ValueError("init.covariance is not positive definite") from None
    # Same batch shape as the starting points: one compilation serves both.
    value = float(batch_logdensity(jnp.tile(jnp.asarray(theta), (num_chains, 1)))[0])
    if not np.isfinite(value):
        raise ValueError(f"the log density at init.theta is not finite ({value})")
    return theta, 0.5 * (cov + cov.T)


def overdispersed_starts(
    rng_key: jax.Array,
    batch_logdensity: Callable[[jax.Array], jax.Array],
    center: np.ndarray,
    cov: np.ndarray,
    num_chains: int,
    spread: float = 2.0,
    max_tries: int = 100,
) -> np.ndarray:
    """Starting points ``center + spread·L z`` with a finite log density, one per chain.

    Parameters
    ----------
    rng_key
        Key for the draws (round ``r`` uses ``fold_in(rng_key, r)``).
    batch_logdensity
        Log density over the parameters, vectorised over a leading axis
        (e.g. ``jax.jit(jax.vmap(posterior.log_density))``).
    center, cov
        The MAP and its covariance (``L`` is the Cholesky factor of ``cov``).
    num_chains
        Number of starting points.
    spread
        Multiplier of ``L z``; 0 puts every chain at ``center``.
    max_tries
        Rounds of redrawing before a chain falls back to ``center`` (with a warning).

    Returns
    -------
    numpy.ndarray
        Shape ``(num_chains, d)``.
    """
    center = np.asarray(center, dtype=np.float64)
    starts = np.tile(center, (num_chains, 1))
    if spread == 0:
        return starts
    chol = np.linalg.cholesky(cov)
    pending = np.ones(num_chains, dtype=bool)
    for attempt in range(max_tries):
        z = np.asarray(jax.random.normal(jax.random.fold_in(rng_key, attempt),
                                         (num_chains, center.size)))
        candidates = center + spread * z @ chol.T
        finite = np.isfinite(np.asarray(batch_logdensity(jnp.asarray(candidates))))
        take = pending & finite
        starts[take] = candidates[take]
        pending &= ~take
        if not pending.any():
            return starts
    warnings.warn(
        f"{int(pending.sum())} chain(s) found no start with a finite log density within "
        f"{max_tries} draws at init_spread={spread}; they start at the MAP",
        UserWarning,
        stacklevel=3,
    )
    return starts


def _make_settings(method: str, settings: Any):
    cls = dram.DRAMSettings if method == "dram" else nuts.NUTSSettings
    if settings is None:
        return cls()
    if isinstance(settings, cls):
        return settings
    if isinstance(settings, dict):
        known = {field.name for field in dataclasses.fields(cls)}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise ValueError(
                f"unknown {method} setting(s) {unknown}; known: {sorted(known)}"
            )
        return cls(**settings)
    raise TypeError(
        f"settings must be None, a dict or a {cls.__name__}, got {type(settings).__name__}"
    )


def sample(
    posterior: Any,
    method: str = "dram",
    num_samples: int = 10_000,
    num_chains: int = 4,
    seed: int = 0,
    init: Any = None,
    *,
    burn_in: int | None = None,
    thin: int = 1,
    settings: Any = None,
    init_spread: float = 2.0,
    initial_positions: Any = None,
    chunk_size: int = 5000,
    chain_method: str | None = None,
    progress: bool = True,
    callback: Callable[[ChunkReport], None] | None = None,
    progress_label: str | None = None,
    progress_position: int | None = None,
):
    """Draw from a posterior with DRAM or NUTS.

    Parameters
    ----------
    posterior
        Any object with ``num_params``, ``param_names`` and ``log_density(theta)``
        (jit/vmap-able, −∞ outside the support); NUTS also needs ``to_unconstrained``,
        ``from_unconstrained`` and ``log_density_unconstrained`` (Jacobian included).
    method
        ``"dram"`` (the paper's sampler, in the constrained space) or ``"nuts"`` (BlackJAX,
        in the unconstrained space, draws mapped back).
    num_samples
        Draws kept per chain (after burn-in and thinning).
    num_chains
        Number of chains.
    seed
        Integer seed; the whole run is a deterministic function of it.
    init
        The MAP result (``.theta``, ``.covariance``; ``.hessian`` and ``.log_posterior`` are
        recorded when present). ``None`` runs ``symplid.find_map(posterior, seed=seed)``.
    burn_in
        DRAM: iterations discarded first (default ``num_samples·thin``, i.e. half the run, as
        the paper's 100,000 of 200,000). NUTS: window-adaptation steps (default 1000).
    thin
        Keep every ``thin``-th iteration after burn-in.
    settings
        Sampler settings: a :class:`~symplid.inference.samplers.dram.DRAMSettings` /
        :class:`~symplid.inference.samplers.nuts.NUTSSettings` or a dict of their fields.
    init_spread
        Overdispersion of the starting points (module docstring); 0 starts at the MAP.
    initial_positions
        Explicit starting points ``(num_chains, d)`` (overrides ``init_spread``).
    chunk_size
        Iterations per compiled chunk; the progress bar moves once per chunk.
    chain_method
        ``"vectorized"`` (``vmap``) or ``"sequential"`` (``lax.map``) over chains; ``None``
        picks the default of the method (:data:`DEFAULT_CHAIN_METHOD`). NUTS defaults to
        sequential: vectorised, every chain waits for the deepest tree of the batch, and
        the batched ``while`` loops take about twice as long to compile.
    progress
        Show progress bars.
    progress_label, progress_position
        Text and line of the progress bar (several processes sampling at once each get
        their own line).
    callback
        Called after every chunk with a :class:`~.run.ChunkReport`; raising
        ``KeyboardInterrupt`` there stops the run like Ctrl-C.

    Returns
    -------
    arviz.InferenceData
        See the module docstring for the layout. A run stopped by ``KeyboardInterrupt``
        returns the draws made so far with ``attrs["interrupted"] = 1`` and a
        :class:`~symplid.inference.samplers.run.SamplingInterrupted` warning.
    """
    method = SAMPLERS.canonical(method)
    num_params, names = _check_posterior(posterior, method)
    for name, value, low in (("num_samples", num_samples, 1), ("num_chains", num_chains, 1),
                             ("thin", thin, 1)):
        if int(value) != value or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    if burn_in is None:
        burn_in = int(num_samples) * int(thin) if method == "dram" else 1000
    if int(burn_in) != burn_in or burn_in < 0:
        raise ValueError(f"burn_in must be an integer >= 0, got {burn_in!r}")
    if int(seed) != seed:
        raise ValueError(f"seed must be an integer, got {seed!r}")
    if not (np.isfinite(init_spread) and init_spread >= 0):
        raise ValueError(f"init_spread must be a finite number >= 0, got {init_spread}")
    kernel_settings = _make_settings(method, settings)
    if chain_method is None:
        chain_method = DEFAULT_CHAIN_METHOD[method]

    parts = _kernel_parts(posterior, method, kernel_settings,
                          int(burn_in) if method == "nuts" else 0)
    if init is None:
        from symplid.inference.map import find_map

        init = find_map(posterior, seed=seed)
    theta_map, cov_map = _check_map(init, num_params, parts.batch_logdensity, int(num_chains))

    init_key, run_key = jax.random.split(jax.random.key(int(seed)), 2)
    if initial_positions is None:
        starts = overdispersed_starts(init_key, parts.batch_logdensity, theta_map, cov_map,
                                      int(num_chains), float(init_spread))
    else:
        starts = np.asarray(initial_positions, dtype=np.float64)
        if starts.shape != (num_chains, num_params):
            raise ValueError(
                f"initial_positions must have shape ({num_chains}, {num_params}), "
                f"got {starts.shape}"
            )

    common = dict(thin=int(thin), chunk_size=int(chunk_size),
                  chain_method=chain_method, progress=progress, callback=callback)
    if method == "dram":
        states = parts.init_states(jnp.asarray(starts), jnp.asarray(cov_map))
        extra_attrs: dict[str, Any] = {}
    else:
        cov_z = _unconstrained_covariance(posterior, theta_map, cov_map)
        z_starts = np.asarray(jax.vmap(posterior.to_unconstrained)(jnp.asarray(starts)))
        if not np.all(np.isfinite(z_starts)):
            raise ValueError(
                "a NUTS starting point lies on a bound of the parameters (its unconstrained "
                "value is infinite); use init_spread > 0 or move initial_positions inside"
            )
        states = parts.init_states(jnp.asarray(starts), jnp.asarray(cov_z))
        extra_attrs = {"unconstrained_map_covariance": cov_z.tolist()}
    run = run_chains(parts.step, states, run_key, int(num_samples), record=parts.record,
                     burn_in=int(burn_in), desc=progress_label or method.upper(),
                     position=progress_position, **common)
    if method == "dram":
        extra_attrs["dram_adapted_covariance"] = np.asarray(run.states.cov).tolist()
    else:
        extra_attrs["nuts_step_size"] = np.asarray(run.states.step_size).tolist()
        extra_attrs["nuts_inverse_mass_matrix"] = np.asarray(
            run.states.inverse_mass_matrix).tolist()
    if not run.draws:
        raise KeyboardInterrupt("sampling was interrupted before any draw was kept")

    record_settings = {
        "method": method, "num_samples": int(num_samples), "num_chains": int(num_chains),
        "seed": int(seed), "burn_in": int(burn_in), "thin": int(thin),
        "init_spread": float(init_spread), "chunk_size": int(chunk_size),
        "chain_method": chain_method,
        "explicit_initial_positions": initial_positions is not None,
        "kernel": dataclasses.asdict(kernel_settings),
    }
    attrs = {
        "method": method,
        "seed": int(seed),
        "settings": json.dumps(record_settings),
        "param_names": list(names),
        "map_theta": theta_map.tolist(),
        "map_covariance": cov_map.tolist(),
        "initial_positions": np.asarray(starts).tolist(),
        "iterations": int(run.iterations_done),
        "interrupted": int(run.interrupted),
        "sampling_seconds": float(run.elapsed),
        **extra_attrs,
    }
    if getattr(init, "hessian", None) is not None:
        attrs["hessian"] = np.asarray(init.hessian, dtype=np.float64).tolist()
    if getattr(init, "log_posterior", None) is not None:
        attrs["map_log_posterior"] = float(init.log_posterior)
    return _to_inference_data(run, names, attrs)


#: Cap on each variance of the Laplace covariance pushed to the unconstrained space.
MAX_UNCONSTRAINED_VARIANCE = 4.0


def _unconstrained_covariance(posterior, theta_map, cov_map) -> np.ndarray:
    """Laplace covariance pushed to the unconstrained space: ``J Σ Jᵀ``, ``J = ∂z/∂θ``.

    Near a bound the push-forward is meaningless: a variance whose MAP sits at 1e-14 with a
    Laplace standard deviation of 1e-6 would get a log-scale variance of 1e16. Each
    unconstrained variance is therefore capped at :data:`MAX_UNCONSTRAINED_VARIANCE` (a
    factor e² either way on a log scale) by rescaling its row and column, which keeps the
    correlations; a coordinate whose push-forward is not finite (MAP exactly on a bound)
    gets the cap and no correlation. The window adaptation of NUTS refines all of this.
    """
    jac = np.asarray(jax.jacfwd(posterior.to_unconstrained)(jnp.asarray(theta_map)))
    broken = ~np.all(np.isfinite(jac), axis=1)
    jac = np.where(broken[:, None], 0.0, jac)
    cov_z = jac @ cov_map @ jac.T
    cov_z = 0.5 * (cov_z + cov_z.T)
    cov_z[broken, :] = 0.0
    cov_z[:, broken] = 0.0
    cov_z[broken, broken] = MAX_UNCONSTRAINED_VARIANCE
    variance = np.diag(cov_z)
    shrink = np.sqrt(np.minimum(1.0, MAX_UNCONSTRAINED_VARIANCE / np.maximum(variance, 1e-300)))
    cov_z = shrink[:, None] * cov_z * shrink[None, :]
    try:
        np.linalg.cholesky(cov_z)
    except np.linalg.LinAlgError:
        cov_z = np.diag(np.maximum(np.diag(cov_z), 1e-12))
    return cov_z


class _KernelParts(NamedTuple):
    """Compiled pieces of one sampler on one posterior, reused across ``sample`` calls."""

    batch_logdensity: Callable
    init_states: Callable
    step: Callable
    record: Callable


def _kernel_parts(posterior: Any, method: str, settings: Any, num_warmup: int) -> _KernelParts:
    """The kernel pieces, cached for hashable posteriors so that a second run on the same
    posterior with the same settings does not compile again (see :func:`_build_parts`)."""
    try:
        hash(posterior)
    except TypeError:
        return _build_parts.__wrapped__(posterior, method, settings, num_warmup)
    return _build_parts(posterior, method, settings, num_warmup)


@functools.lru_cache(maxsize=8)
def _build_parts(posterior: Any, method: str, settings: Any, num_warmup: int) -> _KernelParts:
    # A small cache: it keeps at most 8 posteriors alive.
    batch_logdensity = jax.jit(jax.vmap(posterior.log_density))
    if method == "dram":
        logdensity_fn = posterior.log_density

        @jax.jit
        def init_from_values(thetas, cov, values):
            return jax.vmap(
                lambda p, value: dram.init(p, logdensity_fn, cov, settings, logdensity=value)
            )(thetas, values)

        def init_dram(thetas, cov):
            # The log densities come from the batch function, already compiled for the starts.
            return init_from_values(thetas, cov, batch_logdensity(thetas))

        def record_dram(state: dram.DRAMState, info: dram.DRAMInfo) -> dict[str, jax.Array]:
            return {
                "theta": state.position,
                "lp": state.logdensity,
                "accepted": info.is_accepted,
                "stage1_accepted": info.stage1_accepted,
                "stage2_attempted": info.stage2_attempted,
                "stage2_accepted": info.stage2_accepted,
            }

        return _KernelParts(batch_logdensity, init_dram,
                            dram.build_kernel(logdensity_fn, settings), record_dram)

    logdensity_z = posterior.log_density_unconstrained
    from_z = posterior.from_unconstrained
    to_z = posterior.to_unconstrained

    @jax.jit
    def init_nuts(thetas, cov_z):
        return jax.vmap(lambda t: nuts.init(to_z(t), logdensity_z, cov_z, settings))(thetas)

    def record_nuts(state: nuts.NUTSState, info) -> dict[str, jax.Array]:
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

    return _KernelParts(batch_logdensity, init_nuts,
                        nuts.build_kernel(logdensity_z, settings, num_warmup), record_nuts)


def _to_inference_data(run: ChainRun, names: tuple[str, ...], attrs: dict):
    az = import_arviz()
    theta = run.draws["theta"]
    posterior = {name: theta[..., i] for i, name in enumerate(names)}
    stats = {name: value for name, value in run.draws.items() if name != "theta"}
    return az.from_dict(posterior=posterior, sample_stats=stats, attrs=attrs)


def draws_array(idata) -> np.ndarray:
    """Posterior draws of a :func:`sample` result stacked as ``(chain, draw, num_params)``.

    The last axis follows ``idata.attrs["param_names"]``, the posterior's own order.
    """
    names = list(idata.attrs["param_names"])
    return np.stack([idata.posterior[name].values for name in names], axis=-1)
