"""``sample``: posterior draws by any registered sampler, returned as ArviZ ``InferenceData``.

The samplers are those of :data:`~symplid.inference.samplers._registry.SAMPLERS` (DRAM and NUTS
ship); ``sample`` knows nothing of any one of them: each :class:`~._registry.SamplerSpec` says
what is particular to it.

Layout of the result
--------------------
* ``posterior``: **one variable per parameter**, named by ``posterior.param_names``
  (``c[q1]``, ``c[q1^2]``, ..., ``process_var``, ``obs_var``), each shaped ``(chain, draw)``.
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
  included), ``interrupted`` (0/1), ``sampling_seconds``, ``restarted_chains`` (the chains
  restarted at the end of the burn-in, see ``restart_stuck_chains``: one dict each with
  ``chain``, ``from_chain``, ``lp_median``, ``best_lp_median``), and the sampler's own
  (``final_attrs``):
  for DRAM ``dram_adapted_covariance`` (each chain's final running covariance, nested
  lists, in the coordinates the chain moves in: log(θ − a) for the entries named in
  ``dram_log_scale``, by default the variances), ``dram_variance_scale`` and
  ``dram_parameter_scale`` (the settings that chose them); for NUTS
  ``unconstrained_map_covariance``, ``nuts_step_size`` and ``nuts_inverse_mass_matrix``.
  All survive ``to_netcdf``.

Starting points
---------------
Chains start from overdispersed points around the MAP, ``θ̂ + s·L z`` with ``L Lᵀ`` the MAP
covariance, ``z ~ N(0, I)`` and ``s = init_spread`` (2 by default), a point being redrawn
until its log density is finite (up to 100 times; then the chain starts at the MAP and a
warning says so). ``init_spread=0`` starts every chain at the MAP, as in the paper.

Overdispersed starts let R-hat see a chain that has not found the bulk of the posterior, but
on a rugged likelihood such a chain can settle in a secondary mode of negligible mass and
spoil the run. With ``restart_stuck_chains`` (the default) a chain whose log density at the
end of the burn-in stays far below the best chain's is restarted from a good chain's state
before any draw is kept (:mod:`~symplid.sampling._restart` states and argues the
rule); R-hat and ESS are computed on the kept draws as before.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

from symplid._compiled import cached_or_built
from symplid._saved_programs import identity_of, mark
from symplid.inference._diagnostics import import_arviz
from symplid.inference.map import find_map
from symplid.inference.samplers._registry import SAMPLERS, SamplerKernel, SamplerSpec
from symplid.sampling._budget import kept_after_burn_in
from symplid.sampling._options import RunOptions, Targets
from symplid.sampling._run import ChainRun, run_chains
from symplid.sampling._starts import chain_starts

__all__ = [
    "InterruptedInBurnIn",
    "SamplerCheckpoint",
    "built_kernel",
    "check_posterior",
    "draws_array",
    "finished_draws",
    "make_settings",
    "sample",
    "to_inference_data",
]


class SamplerCheckpoint(NamedTuple):
    """Where a run's chains stand: their states (stacked over chains) after
    ``iterations_done`` iterations per chain (burn-in included), and the arrays of the rule
    that restarts stuck chains (``monitor``: :meth:`~._restart.BurnInMonitor.arrays`; None
    when the run does not restart them)."""

    states: Any
    iterations_done: int
    monitor: dict[str, np.ndarray] | None = None


class InterruptedInBurnIn(KeyboardInterrupt):
    """Sampling was interrupted before any draw was kept (during the burn-in). It carries the
    chains' ``checkpoint`` and the run's ``attrs`` (the attributes its draws would have had),
    from which :func:`~._resume.resume_sampling` can continue."""

    def __init__(self, checkpoint: SamplerCheckpoint, attrs: dict[str, Any]) -> None:
        super().__init__("sampling was interrupted before any draw was kept")
        self.checkpoint, self.attrs = checkpoint, attrs


_POSTERIOR_ATTRIBUTES = ("num_params", "param_names", "log_density")
_UNCONSTRAINED_ATTRIBUTES = ("to_unconstrained", "from_unconstrained",
                             "log_density_unconstrained")


def sample(
    posterior: Any,
    method: str = "dram",
    num_draws: int | None = None,
    num_chains: int = 4,
    seed: int = 0,
    init: Any = None,
    *,
    burn_in: int | None = None,
    thin: int = 1,
    settings: Any = None,
    options: RunOptions | None = None,
):
    """Draw from a posterior with a registered sampler (DRAM, NUTS, ...).

    Parameters
    ----------
    posterior
        Any object with ``num_params``, ``param_names`` and ``log_density(theta)`` (−∞
        outside the support); NUTS also needs ``to_unconstrained``, ``from_unconstrained``
        and ``log_density_unconstrained`` (Jacobian included).
    method
        A name of :data:`~symplid.inference.samplers.SAMPLERS`: ``"dram"`` (the paper's, in
        θ) or ``"nuts"`` (BlackJAX, in the unconstrained space, draws mapped back).
    num_draws
        Draws kept per chain after burn-in and thinning: a fixed budget. ``None`` (default):
        until every parameter's bulk and tail ESS and R-hat meet ``options.targets``, or a
        cap (:mod:`~._budget`); ``attrs["stopped_by"]`` says which.
    num_chains, seed
        Number of chains; integer seed (the run is a deterministic function of it).
    init
        The MAP result (``.theta``, ``.covariance``; ``.hessian`` and ``.log_posterior`` are
        recorded when present). ``None`` runs ``symplid.find_map(posterior, seed=seed)``.
    burn_in
        Iterations discarded first; by default, with a fixed budget DRAM ``num_draws·thin``
        (the paper's ratio), NUTS 1000 warm-up steps; else the sampler's first burn-in
        (the sampler's ``SamplerSpec.first_burn_in``), extended while the chains disagree.
    thin
        Keep every ``thin``-th iteration after burn-in.
    settings
        The sampler's settings (:class:`~._dram.DRAMSettings`, :class:`~._nuts.NUTSSettings`)
        or a dict of their fields.
    options
        How the chains run (:class:`~._options.RunOptions`): starting points, chunks, progress,
        sink and callback, restarts, targets, ``return_state`` (also return the chains'
        :class:`SamplerCheckpoint`, which :func:`~._resume.resume_sampling` continues).

    Returns
    -------
    arviz.InferenceData
        Laid out as the module docstring says; a run stopped by ``KeyboardInterrupt``: the
        draws so far, ``attrs["interrupted"] = 1`` and a :class:`~._run.SamplingInterrupted`.
    """
    options = RunOptions() if options is None else options
    method, spec = SAMPLERS.canonical(method), SAMPLERS[method]
    num_params, names = check_posterior(posterior, spec)
    plan = _plan(spec, num_draws, num_params, num_chains, thin, burn_in, seed, options.targets)
    kernel_settings, chain_method = _run_settings(spec, method, settings, options.chain_method,
                                                  posterior, int(num_chains))
    batch_logdensity, kernel = built_kernel(posterior, spec, method, kernel_settings,
                                             plan.burn_in)
    init = find_map(posterior, seed=seed) if init is None else init
    theta_map, cov_map, starts, states, extra_attrs, run_key = chain_starts(
        posterior, spec, kernel, batch_logdensity, init, num_params, int(seed),
        int(num_chains), float(options.init_spread), options.initial_positions)
    record_settings = _recorded_settings(method, plan, int(num_chains), int(seed), int(thin),
                                         options, chain_method, kernel_settings)
    make_attrs = functools.partial(_attrs, method, seed, record_settings, names, theta_map,
                                   cov_map, starts)
    if hasattr(options.sink, "begin"):  # the attributes of the run before its first iteration
        options.sink.begin(make_attrs(ChainRun({}, states, 0, True, 0.0),
                                      {**extra_attrs, **kernel.final_attrs(states)}, init))
    run = run_chains(kernel.step, states, run_key, plan.num_draws, record=kernel.record,
                     burn_in=plan.burn_in, thin=int(thin), until=plan.until,
                     options=dataclasses.replace(options, chain_method=chain_method,
                                                 progress_label=options.progress_label
                                                 or method.upper()))
    extra_attrs.update(kernel.final_attrs(run.states))
    return _finished(run, names, make_attrs(run, extra_attrs, init), options.return_state,
                     options.on_draws)


class _Plan(NamedTuple):
    """The run's sizes: the (first) burn-in, the draws to keep (at most, with targets) and
    the targets of a budget set by the answer (None: a fixed budget)."""

    burn_in: int
    num_draws: int
    until: Targets | None


def _plan(spec: SamplerSpec, num_draws: int | None, num_params: int, num_chains: int,
          thin: int, burn_in: int | None, seed: int, targets: Targets) -> _Plan:
    """Validate the run's sizes and settle its budget: fixed (``num_draws``) or set by the
    answer (``targets``, capped at ``targets.max_iterations``)."""
    for name, value in (("num_chains", num_chains), ("thin", thin)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if int(seed) != seed:
        raise ValueError(f"seed must be an integer, got {seed!r}")
    if num_draws is not None and (int(num_draws) != num_draws or num_draws < 1):
        raise ValueError(f"num_draws must be an integer >= 1 or None, got {num_draws!r}")
    if burn_in is None:
        burn_in = (spec.default_burn_in(int(num_draws), int(thin)) if num_draws is not None
                   else spec.first_burn_in(num_params))
    if int(burn_in) != burn_in or burn_in < 0:
        raise ValueError(f"burn_in must be an integer >= 0, got {burn_in!r}")
    if num_draws is not None:
        return _Plan(int(burn_in), int(num_draws), None)
    cap = (int(targets.max_iterations) - int(burn_in)) // int(thin)
    if cap < 1:
        raise ValueError(f"the cap of {targets.max_iterations:,} iterations per chain leaves "
                         f"no draw after the burn-in of {int(burn_in):,}")
    return _Plan(int(burn_in), cap, targets)


def _recorded_settings(method: str, plan: _Plan, num_chains: int, seed: int, thin: int,
                       options: RunOptions, chain_method: str,
                       kernel_settings: Any) -> dict[str, Any]:
    """The run's settings as its attributes record them (all a continuation needs)."""
    record = {
        "method": method, "num_draws": plan.num_draws, "num_chains": num_chains, "seed": seed,
        "burn_in": plan.burn_in, "thin": thin, "init_spread": float(options.init_spread),
        "chunk_size": int(options.chunk_size), "chain_method": chain_method,
        "explicit_initial_positions": options.initial_positions is not None,
        "restart_stuck_chains": bool(options.restart_stuck_chains),
        "kernel": dataclasses.asdict(kernel_settings),
    }
    if plan.until is not None:
        record["targets"] = plan.until.as_dict()
    return record


def _finished(run: ChainRun, names: tuple[str, ...], attrs: dict[str, Any],
              return_state: bool, on_draws: Callable[[np.ndarray], None] | None = None) -> Any:
    """The run's ``InferenceData`` (and checkpoint with ``return_state``), the draws first
    handed to ``on_draws``; a run stopped in its burn-in raises :class:`InterruptedInBurnIn`."""
    checkpoint = SamplerCheckpoint(run.states, int(run.iterations_done), run.monitor)
    if not run.draws:
        raise InterruptedInBurnIn(checkpoint, attrs)
    run = finished_draws(run, json.loads(attrs["settings"]))
    if on_draws is not None:
        on_draws(np.asarray(run.draws["theta"]))
    idata = to_inference_data(run, names, attrs)
    return (idata, checkpoint) if return_state else idata


def finished_draws(run: ChainRun, record: dict[str, Any]) -> ChainRun:
    """A run with a budget set by the answer, finished: its draws after the extended burn-in
    (:mod:`~._budget`). An interrupted run keeps every draw since the first burn-in, which its
    continuation needs; a fixed budget's draws are the run's."""
    if run.budget is None or run.interrupted:
        return run
    draws = kept_after_burn_in(run.draws, run.monitor, int(record["burn_in"]),
                               int(record["thin"]))
    return run._replace(draws=draws)


def built_kernel(posterior: Any, spec: Any, method: str, kernel_settings: Any,
                  burn_in: int) -> tuple[Any, SamplerKernel]:
    """The posterior's batched log density and the sampler's kernel, built once per
    posterior and settings (kept on the posterior): a run and its continuation
    (:func:`~._resume.resume_sampling`) share them."""
    batch_logdensity = cached_or_built(
        posterior, "batch-log-density", lambda: _batch_log_density(posterior)
    )
    num_warmup = burn_in if spec.adapts_during_burn_in else 0
    kernel: SamplerKernel = cached_or_built(
        posterior, ("sampler", method, kernel_settings, num_warmup),
        lambda: _marked(spec.build(posterior, kernel_settings, num_warmup, batch_logdensity),
                        posterior, method, kernel_settings, num_warmup),
    )
    return batch_logdensity, kernel


def _marked(kernel: SamplerKernel, posterior: Any, *static: Any) -> SamplerKernel:
    """``kernel`` with its step and record given the identity of what they close over (the
    posterior's and the sampler's settings), so that the chunk's program is saved
    (:mod:`symplid._saved_programs`); a posterior without one leaves them unmarked."""
    identity = identity_of(posterior)
    if identity is not None:
        mark(kernel.step, ("step", identity, *map(repr, static)))
        mark(kernel.record, ("record", identity, *map(repr, static)))
    return kernel


# ----------------------------------------------------------------------------- checks
def check_posterior(posterior: Any, spec: SamplerSpec) -> tuple[int, tuple[str, ...]]:
    """θ's size and names, after checking the posterior has what ``spec``'s sampler reads."""
    needed = _POSTERIOR_ATTRIBUTES + (_UNCONSTRAINED_ATTRIBUTES if spec.unconstrained else ())
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


def _run_settings(spec: SamplerSpec, method: str, settings: Any, chain_method: str | None,
                  posterior: Any, num_chains: int) -> tuple[Any, str]:
    """The kernel's settings, with what the sampler leaves to the run resolved, and the chain
    layout."""
    kernel_settings = make_settings(method, spec.settings_class, settings)
    chain_method = spec.default_chain_method if chain_method is None else chain_method
    if spec.resolve is not None:
        kernel_settings = spec.resolve(kernel_settings, posterior, num_chains, chain_method)
    return kernel_settings, chain_method


def make_settings(method: str, cls: type, settings: Any) -> Any:
    """The sampler's settings: ``cls()``, an instance of ``cls``, or one built from a dict."""
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


def _batch_log_density(posterior: Any) -> Callable[[jax.Array], jax.Array]:
    """``θ[n] ↦ log density[n]``, compiled; with the observations as an argument of the
    program when the posterior offers ``log_density_with`` and ``data`` (the same program for
    every data set of the same shape, so the persistent compilation cache serves it)."""
    with_data = getattr(posterior, "log_density_with", None)
    data = getattr(posterior, "data", None)
    if with_data is None or data is None:
        return jax.jit(jax.vmap(posterior.log_density))
    batched = jax.jit(jax.vmap(with_data, in_axes=(None, 0)))
    return lambda thetas: batched(data, thetas)


def _attrs(method: str, seed: int, record_settings: dict, names: tuple[str, ...],
           theta_map: np.ndarray, cov_map: np.ndarray, starts: np.ndarray, run: ChainRun,
           extra: dict[str, Any], init: Any) -> dict[str, Any]:
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
        "restarted_chains": list(run.restarted_chains),
        "stopped_by": "fixed budget" if run.budget is None else run.budget["stopped_by"],
        **extra,
    }
    if run.budget is not None:  # JSON: netCDF keeps no nested attributes
        attrs["budget"] = json.dumps(run.budget)
    if getattr(init, "hessian", None) is not None:
        attrs["hessian"] = np.asarray(init.hessian, dtype=np.float64).tolist()
    if getattr(init, "log_posterior", None) is not None:
        attrs["map_log_posterior"] = float(init.log_posterior)
    return attrs


def to_inference_data(run: ChainRun, names: tuple[str, ...], attrs: dict):
    """A run's draws as ArviZ ``InferenceData`` (layout: the module docstring)."""
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
