"""Continue an interrupted run of :func:`~symplid.sampling.sample` where it stopped.

An interrupted run (Ctrl-C, SIGTERM, a ``callback`` raising ``KeyboardInterrupt``) keeps its
draws and, with ``sample(..., return_state=True)``, the chains' states after the last
finished chunk (:class:`~._api.SamplerCheckpoint`). Everything else a continuation needs is
in the draws' attributes: the method and every setting (``attrs["settings"]``: burn-in,
thinning, chunk size, the kernel's settings), the seed and the parameter names.

The continuation runs on the whole run's grid (:func:`~._run.run_chains` with ``start``): the
key of iteration t of chain c is still ``fold_in(chain_key[c], t)``, the burn-in and thinning
count from the run's first iteration and the chunks keep their length. A sampler whose state
is all of its memory (DRAM: position, running mean and covariance, proposal factor, counters;
NUTS: position, step size, mass matrix and both adaptation states) therefore continues
exactly: the interrupted draws followed by the continued ones **are** the draws of the
uninterrupted run, bit for bit (``tests/test_resume.py``).

A checkpoint is stored as plain arrays (:func:`checkpoint_arrays`: the state's leaves, its
tree structure as text, ``iterations_done``) and rebuilt against the kernel's own state
structure (``jax.eval_shape`` of its ``init_states``), which checks shapes and dtypes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from symplid.inference.samplers._registry import SAMPLERS, SamplerKernel, SamplerSpec
from symplid.sampling._api import (
    InterruptedInBurnIn,
    SamplerCheckpoint,
    built_kernel,
    check_posterior,
    draws_array,
    finished_draws,
    make_settings,
    to_inference_data,
)
from symplid.sampling._options import RunOptions, Targets
from symplid.sampling._run import ChainRun, run_chains

__all__ = ["checkpoint_arrays", "inference_data", "resume_sampling"]

_ITERATIONS, _TREEDEF, _LEAF, _MONITOR = "iterations_done", "treedef", "leaf_", "monitor_"


def checkpoint_arrays(checkpoint: SamplerCheckpoint) -> dict[str, np.ndarray]:
    """The checkpoint as named NumPy arrays (for ``numpy.savez``): the state's leaves
    ``leaf_0``…, its tree structure as text, ``iterations_done`` and the restart rule's
    arrays ``monitor_<name>`` (when the run restarts stuck chains)."""
    leaves, treedef = jax.tree.flatten(checkpoint.states)
    out = {f"{_LEAF}{i}": np.asarray(leaf) for i, leaf in enumerate(leaves)}
    out[_TREEDEF] = np.asarray(str(treedef))
    out[_ITERATIONS] = np.asarray(int(checkpoint.iterations_done))
    for name, value in (checkpoint.monitor or {}).items():
        out[f"{_MONITOR}{name}"] = np.asarray(value)
    return out


def inference_data(draws: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> Any:
    """ArviZ ``InferenceData`` of draws ``name -> (num_chains, kept, ...)`` (``theta`` and the
    sampler's statistics, as a :data:`~._run.ChunkSink` receives them) with the draws'
    attributes, laid out as :func:`~._api.sample` returns them."""
    names = tuple(str(n) for n in attrs["param_names"])
    run = ChainRun(dict(draws), None, int(attrs["iterations"]), True, 0.0)
    return to_inference_data(run, names, dict(attrs))


def _restore(arrays: Mapping[str, Any], template: Any) -> SamplerCheckpoint:
    """Rebuild the states from :func:`checkpoint_arrays` against the kernel's structure."""
    shapes, treedef = jax.tree.flatten(template)
    if str(np.asarray(arrays[_TREEDEF])) != str(treedef):
        raise ValueError("the stored sampler state does not fit this sampler (another "
                         "method or version wrote it)")
    leaves = []
    for i, shape in enumerate(shapes):
        leaf = np.asarray(arrays[f"{_LEAF}{i}"])
        if leaf.shape != shape.shape or leaf.dtype != shape.dtype:
            raise ValueError(f"stored sampler state entry {i} is {leaf.dtype}{leaf.shape}, "
                             f"the sampler expects {shape.dtype}{shape.shape}")
        leaves.append(jax.numpy.asarray(leaf))
    monitor = {k[len(_MONITOR):]: np.asarray(v) for k, v in arrays.items()
               if k.startswith(_MONITOR)}
    return SamplerCheckpoint(jax.tree.unflatten(treedef, leaves),
                             int(np.asarray(arrays[_ITERATIONS])), monitor or None)


def _state_template(spec: SamplerSpec, kernel: SamplerKernel, num_chains: int, d: int) -> Any:
    """The shapes and dtypes of the kernel's chain states, without computing them."""
    f64 = jax.numpy.float64
    thetas = jax.ShapeDtypeStruct((num_chains, d), f64)
    return jax.eval_shape(kernel.init_states, thetas, jax.ShapeDtypeStruct((d, d), f64))


def _old_draws(idata: Any, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    draws = {"theta": draws_array(idata)}
    stats = getattr(idata, "sample_stats", None)
    if stats is not None:
        draws.update({str(k): np.asarray(v.values) for k, v in stats.data_vars.items()})
    return draws


def resume_sampling(
    posterior: Any,
    idata: Any,
    checkpoint: SamplerCheckpoint | Mapping[str, Any],
    *,
    options: RunOptions | None = None,
):
    """Run the iterations an interrupted :func:`~._api.sample` run has left.

    Parameters
    ----------
    posterior
        The posterior the run sampled (same parameters, same log density).
    idata
        The interrupted run's draws (``attrs["interrupted"] = 1``), e.g. read back from
        netCDF; or, for a run interrupted in its burn-in (no draws yet), the ``attrs`` of
        its :class:`~._api.InterruptedInBurnIn`.
    checkpoint
        Its :class:`~._api.SamplerCheckpoint`, or the arrays of :func:`checkpoint_arrays`.
    options
        As for :func:`~._api.sample`, of which ``progress``, ``progress_label``,
        ``progress_position``, ``callback``, ``sink`` (it receives the new chunks only) and
        ``return_state`` are read; the rest is the run's own (its recorded settings).

    Returns
    -------
    arviz.InferenceData
        The whole run: the kept draws followed by the new ones, ``attrs["iterations"]`` the
        iterations done in all, ``sampling_seconds`` summed. Interrupted again, it is marked
        interrupted again and can be resumed again. A run without a fixed budget goes on
        checking its targets where it left off (:mod:`~._budget`).
    """
    options = RunOptions() if options is None else options
    attrs = dict(idata.attrs if hasattr(idata, "attrs") else idata)
    record = json.loads(attrs["settings"]) if isinstance(attrs["settings"], str) else dict(
        attrs["settings"])
    method = SAMPLERS.canonical(record["method"])
    spec = SAMPLERS[method]
    num_params, names = check_posterior(posterior, spec)
    if list(names) != [str(n) for n in attrs["param_names"]]:
        raise ValueError("the posterior's parameters are not those of the draws")
    kernel = _kernel(posterior, spec, method, record)
    if isinstance(checkpoint, Mapping):
        checkpoint = _restore(checkpoint, _state_template(spec, kernel, int(record["num_chains"]),
                                                          num_params))
    burn_in, thin = int(record["burn_in"]), int(record["thin"])
    total = burn_in + int(record["num_draws"]) * thin
    if checkpoint.iterations_done >= total:
        raise ValueError(f"the run is finished ({total:,} iterations per chain): nothing to "
                         "resume")
    if checkpoint.iterations_done != int(attrs["iterations"]):
        raise ValueError(f"the sampler state is at iteration {checkpoint.iterations_done:,} "
                         f"but the draws end at {int(attrs['iterations']):,}")
    _, run_key = jax.random.split(jax.random.key(int(record["seed"])), 2)
    # A run recorded before the rule existed ran without it.
    restart = bool(record.get("restart_stuck_chains", False))
    until = Targets(**record["targets"]) if "targets" in record else None
    old = _old_draws(idata, names) if hasattr(idata, "posterior") else {}
    run_options = RunOptions(
        chunk_size=int(record["chunk_size"]), chain_method=record["chain_method"],
        progress=options.progress, progress_label=options.progress_label or method.upper(),
        progress_position=options.progress_position, callback=options.callback,
        sink=options.sink, restart_stuck_chains=restart)
    run = run_chains(kernel.step, checkpoint.states, run_key, int(record["num_draws"]),
                     record=kernel.record, burn_in=burn_in, thin=thin, options=run_options,
                     until=until, start=checkpoint.iterations_done, monitor=checkpoint.monitor,
                     earlier=old.get("theta"))
    return _whole_run(run, old, attrs, names, kernel, restart, record, options.return_state)


def _kernel(posterior: Any, spec: SamplerSpec, method: str, record: dict) -> SamplerKernel:
    """The run's kernel, built from its recorded settings (or the one kept on the posterior)."""
    # a setting newer than the record: the value the run ran with, not today's default
    recorded = {**getattr(spec.settings_class, "RECORD_DEFAULTS", {}), **record["kernel"]}
    kernel_settings = make_settings(method, spec.settings_class, recorded)
    return built_kernel(posterior, spec, method, kernel_settings, int(record["burn_in"]))[1]


def _whole_run(run: ChainRun, old: dict[str, np.ndarray], attrs: dict[str, Any],
               names: tuple[str, ...], kernel: SamplerKernel, restart: bool, record: dict,
               return_state: bool) -> Any:
    """The interrupted run's draws followed by the continuation's, as ``InferenceData``."""
    draws = {k: np.concatenate([old[k], v], axis=1) if k in old else v
             for k, v in run.draws.items()} if run.draws else old
    elapsed = float(attrs.get("sampling_seconds", 0.0)) + run.elapsed
    attrs.update(iterations=int(run.iterations_done), interrupted=int(run.interrupted),
                 sampling_seconds=elapsed, **kernel.final_attrs(run.states))
    if restart:
        attrs["restarted_chains"] = list(run.restarted_chains)
    if run.budget is not None:
        attrs.update(stopped_by=run.budget["stopped_by"], budget=json.dumps(run.budget))
    checkpoint = SamplerCheckpoint(run.states, int(run.iterations_done), run.monitor)
    if not draws:  # interrupted again, still in the burn-in
        raise InterruptedInBurnIn(checkpoint, attrs)
    whole = finished_draws(ChainRun(draws, run.states, run.iterations_done, run.interrupted,
                                    elapsed, run.monitor, (), run.budget), record)
    result = to_inference_data(whole, names, attrs)
    if return_state:
        return result, checkpoint
    return result
