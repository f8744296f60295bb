"""From settings and data to a finished run: model, posterior, MAP, sampler, predictions.

This is the layer the command line, the paper's experiment and the sweeps share. Each step is
a function of plain inputs, so a notebook can run them one at a time:

>>> settings = resolve_for_data(Settings(...), obs)         # doctest: +SKIP
>>> model = build_model(settings, obs)                       # doctest: +SKIP
>>> posterior = build_posterior(settings, obs, model)        # doctest: +SKIP
>>> outcome = fit(obs, settings, out="runs/mine")            # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from symplid._stopping import check as check_stop
from symplid.inference._diagnostics import prefetch_arviz
from symplid.inference.map import (
    MapConvergenceWarning,
    MapFailedError,
    failure_message,
    filter_start,
    find_map,
    half_normal_start,
)
from symplid.inference.samplers import SAMPLERS
from symplid.io._chunks import remove_chunks
from symplid.model._data import Observations
from symplid.sampling import InterruptedInBurnIn, RunOptions, Targets, sample
from symplid.workflow._auto import auto_notes
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._fit_files import FitOutcome, chunk_sink, save_burn_in, save_run
from symplid.workflow._mode_watch import (
    MAX_REFINDS,
    HigherModeFound,
    mode_watch,
    refound_record,
)
from symplid.workflow._model_builder import model_family
from symplid.workflow._plan import ModelPlan
from symplid.workflow._results import RunFolder
from symplid.workflow._scaling import scaling_for
from symplid.workflow._sensitivity import sensitivity_checks
from symplid.workflow._settings import Settings
from symplid.workflow._settings_schema import SamplerSettings, map_start
from symplid.workflow._step_size import StepChoice, choose_step, step_check, step_line

__all__ = ["SampledDraws", "build_model", "build_posterior", "find_map_for", "fit"]


@dataclass(frozen=True)
class SampledDraws:
    """What ``fit(on_sampled=...)`` receives as soon as the chains end, before their draws are
    made ``InferenceData``, summarised and written (all in the data's units)."""

    map_result: Any
    draws: np.ndarray
    """The kept draws of θ, ``(chain, draw, param)``."""
    param_names: tuple[str, ...]


def find_map_for(settings: Settings, posterior, start: np.ndarray | None = None) -> Any:
    """The MAP and its Laplace covariance, by the path the model's family calls for.

    ``start`` (θ in the posterior's coordinates), given, is the one start of a polynomial's
    search: the MAP found at the same settings already (``model.dt = "auto"``,
    :mod:`symplid.workflow._step_size`), only polished and given its Laplace covariance.

    A polynomial (or any family with few coefficients): bounded quasi-Newton from
    ``settings.map.num_starts`` seeded starts and the exact Hessian (without process noise,
    ``model.process_noise_per = "none"``, the first start is the MAP with process noise:
    :func:`~symplid.inference.map._homotopy.filter_start`; with a log-uniform prior on Σ, the MAP
    under the half-normal one: :func:`~symplid.inference.map._homotopy.half_normal_start`). A
    neural family
    (:attr:`~symplid.dynamics._families.Family.neural`, e.g. ``"mlp"``): Adam then L-BFGS and
    the Gauss–Newton covariance (:func:`~symplid.inference.map._neural.find_map_neural`),
    returned as a :class:`~symplid.inference.map._result.MapResult`.
    """

    m = settings.map
    if not model_family(settings.model).neural:
        # without process noise: start from the filter's MAP (symplid.inference.map._homotopy);
        # otherwise from a user model's declared starts, if any
        declared = map_start(settings)  # every likelihood's search starts from it
        init = None if start is not None else filter_start(
            posterior, seed=m.seed, num_starts=m.num_starts, init=declared)
        if init is None and start is None:  # a log-uniform Σ: from the half-normal MAP
            init = half_normal_start(posterior, seed=m.seed, num_starts=m.num_starts,
                                     init=declared)
        num_starts = m.num_starts if start is None else 1
        # a failed search is raised by the caller in one line: its warnings would only repeat
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = find_map(posterior, seed=m.seed, num_starts=num_starts,
                              evidence=m.evidence,
                              init=start if start is not None else
                              declared if init is None else init)
        for w in caught if not result.failure else ():
            if not issubclass(w.category, MapConvergenceWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return result
    from symplid.inference.map import find_map_neural

    start = time.perf_counter()
    ggn = (posterior.model.observation_matrix is not None and not posterior.learn_initial_state
           and all(t is not None for t in posterior.t0))
    result = find_map_neural(
        posterior, adam_steps=m.adam_steps, learning_rate=m.learning_rate,
        lbfgs_steps=m.lbfgs_steps, polish="scipy", laplace="ggn" if ggn else "hessian",
    )
    return result.to_map_result(time.perf_counter() - start, m.seed)


def _dynamic_names(posterior: Any) -> tuple[str, ...]:
    """The names of a user model's declared parameters (``[model.parameters]``: those a MAP
    start can be declared for; a built-in family has none)."""
    return tuple(str(n) for n, g in zip(posterior.param_names, posterior.param_groups,
                                        strict=True) if g == "parameters")


def sample_for(
    settings: Settings,
    posterior,
    map_result,
    progress: bool = True,
    progress_label: str | None = None,
    progress_position: int = 0,
    return_state: bool = False,
    sink: Any = None,
    on_draws: Callable[[np.ndarray], None] | None = None,
    callback: Callable[[Any], None] | None = None,
) -> Any:
    """Run the sampler of ``settings.sampler`` from the MAP; returns ArviZ ``InferenceData``
    (and the chains' final states with ``return_state``, see ``symplid.sample``); ``sink``
    receives each chunk's draws (:func:`chunk_sink`), ``on_draws`` the kept draws as soon as
    the chains end, ``callback`` a report after each chunk (``symplid.sample``)."""

    s = settings.sampler
    # The [sampler] section's method-specific keys go to the samplers whose settings class
    # declares them (DRAM's γ and adaptation start); no branch on the method's name.
    accepted = {f.name for f in dataclasses.fields(SAMPLERS[s.method].settings_class)}
    offered = {"gamma": s.gamma, "adapt_start": max(1, s.adapt_start),
               "variance_scale": s.variance_scale, "parameter_scale": s.parameter_scale}
    options_for_kernel = {key: value for key, value in offered.items() if key in accepted}
    # The settings count every iteration (burn-in included, as the paper's 200,000 with
    # 100,000 discarded); the sampler counts the draws it keeps. "auto": no fixed number.
    options = RunOptions(chunk_size=s.chunk_size, progress=progress,
                         progress_label=progress_label, progress_position=progress_position,
                         sink=sink, on_draws=on_draws, return_state=return_state,
                         callback=callback,
                         restart_stuck_chains=s.restart_stuck_chains, targets=_targets_of(s))
    return sample(posterior, method=s.method, num_draws=s.num_draws, num_chains=s.num_chains,
                  seed=s.seed, init=map_result, burn_in=s.resolved_burn_in, thin=s.thin,
                  settings=options_for_kernel, options=options)


def _targets_of(sampler: SamplerSettings) -> Targets:
    """The targets and caps of the ``[sampler]`` section (read by ``num_iterations =
    "auto"``)."""
    return Targets(ess_bulk=sampler.target_ess, ess_tail=sampler.target_ess,
                   rhat=sampler.target_rhat, max_iterations=sampler.max_iterations,
                   max_seconds=sampler.max_seconds or None)


def fit(
    obs: Observations,
    settings: Settings,
    out: str | Path | None = None,
    progress: bool = True,
    source: str = "settings",
    progress_label: str | None = None,
    overwrite: bool = False,
    progress_position: int = 0,
    warn: bool = False,
    status: Callable[[str], None] | None = None,
    on_sampled: Callable[[SampledDraws], None] | None = None,
) -> FitOutcome:
    """The whole fit: MAP, Hessian, sampler and the run folder (when ``out`` is given).

    The run folder is marked incomplete until every file is written; the sampler streams each
    chunk's draws and the chains' state to ``draws/`` as it goes (:func:`chunk_sink`), so a
    killed run keeps them. A sampler stopped by a signal (:mod:`symplid.workflow._interrupts`:
    at its next chunk) or by Ctrl-C keeps the draws it made: they are saved, with the signals
    held while the files are written, and the folder is marked ``interrupted`` (readers refuse
    it with a message that says what to do); a stop asked for during the MAP search comes at
    its next evaluation (:mod:`symplid._stopping`). A
    failure or an interruption before sampling records its reason in the marker; a MAP
    search that failed (:mod:`symplid.inference.map._checks`) raises
    :class:`~symplid.inference.map._checks.MapFailedError` before any sampling. ``warn``
    issues :class:`~symplid.inference._diagnostics.ConvergenceWarning` for R-hat and ESS.
    Between the MAP and the sampler, with ``map.sensitivity`` (the default), the MAP is refitted
    at dt/2 and with the other process-noise model (:mod:`symplid.workflow._sensitivity`;
    ``FitOutcome.diagnostics``, ``diagnostics.json``); a refit that fails is recorded as not
    available, never raised;
    ``status`` receives a one-line message before the (silent) MAP search and compilation;
    ``on_sampled`` receives the MAP and the kept draws (:class:`SampledDraws`) as soon as the
    chains end, before the draws are made ``InferenceData``, summarised and written: a caller
    can use them meanwhile.
    """

    prefetch_arviz()  # ArviZ's seconds of import pass during the MAP search
    plan = ModelPlan.from_settings(settings, obs, source)  # the run's one model
    given, settings = settings, plan.settings
    for note in auto_notes(given, settings, obs) if status is not None else ():
        status(note)
    folder = RunFolder(out, "w", overwrite=overwrite) if out is not None else None
    try:
        return _fit(obs, plan, folder, progress, progress_label, progress_position, warn,
                    status, on_sampled)
    except BaseException as err:
        if folder is not None and not folder.is_complete and not _marked(folder):
            what = "interrupted before any draw was kept" if isinstance(
                err, KeyboardInterrupt) else f"{type(err).__name__}: {err}"
            folder.fail(what)
        raise
    finally:
        if folder is not None:
            folder.release()  # the run folder's lock (symplid.io._files.FolderLock)


def _marked(folder: RunFolder) -> bool:
    reason = folder.incomplete_reason or ""
    return reason.startswith((RunFolder.INTERRUPTED, "failed"))


def _fit(obs, plan, folder, progress, progress_label, progress_position, warn,
         status, on_sampled=None) -> FitOutcome:
    settings, timings = plan.settings, {}
    if folder is not None:
        folder.write_settings(settings)
        folder.write_data(obs)
    check_stop()  # a safe point: nothing compiled yet
    step = _learning_step(settings, obs, folder, timings, status, plan)
    settings = settings if step is None else step.settings
    if status is not None and step is None:
        status(f"MAP search from {settings.map.num_starts} starts (the first fit compiles the "
               "filter: this can take a minute)...")
    start = time.perf_counter()
    # model.standardise: the fit runs on q/a, p/a and is reported in the data's units.
    scaling = scaling_for(settings, obs)
    fit_settings = settings if scaling is None else scaling.settings(settings)
    fit_obs = obs if scaling is None else scaling.observations(obs)
    if step is not None and step.posterior is not None:  # the search's, at the chosen step
        posterior = step.posterior
        model = posterior.model
    else:
        model = plan.model(fit_settings, fit_obs)
        posterior = build_posterior(fit_settings, fit_obs, model)
    map_fit = find_map_for(settings, posterior, _warm_start(step, scaling, posterior))
    groups, refound = posterior.param_groups, []
    while True:  # the MAP searched again where the chains climb above it (.mode_watch)
        check_stop()  # a safe point between the phases (symplid._stopping)
        if getattr(map_fit, "failure", ""):  # stop before sampling (inference.map._checks)
            raise MapFailedError(failure_message(map_fit.failure, "settings",
                                                 _dynamic_names(posterior)))
        map_result = map_fit if scaling is None else scaling.map_result(map_fit, groups, obs)
        timings["map_s"] = timings.get("map_s", 0.0) + time.perf_counter() - start
        if folder is not None:
            folder.write_map(map_result)
        diagnostics = _diagnostics(plan, settings, obs, posterior, map_result, folder,
                                   timings, status, step)
        start, handing_over = time.perf_counter(), [0.0]  # the caller's time: not sampling
        watch = mode_watch(map_fit.log_posterior) if len(refound) < MAX_REFINDS else None
        try:
            idata, checkpoint = sample_for(settings, posterior, map_fit, progress,
                                           progress_label, progress_position,
                                           return_state=True,
                                           sink=None if folder is None else chunk_sink(folder),
                                           on_draws=_draws_hook(on_sampled, map_result,
                                                                posterior, scaling, groups,
                                                                handing_over),
                                           callback=watch)
            break
        except HigherModeFound as found:
            start = time.perf_counter()  # the search again is the MAP's time
            map_fit = _search_again(settings, posterior, folder, found, status)
            refound.append(refound_record(found, map_fit.log_posterior))
        except InterruptedInBurnIn as stop:
            if folder is not None:
                save_burn_in(folder, settings, stop)
            raise
    timings["sampler_s"] = time.perf_counter() - start - handing_over[0]
    if scaling is not None:
        idata = scaling.inference_data(idata, groups, obs)
        model = plan.model(settings, obs)
        posterior = build_posterior(settings, obs, model)
    outcome = FitOutcome(settings, obs, model, posterior, map_result, idata, timings=timings,
                         standardised_scale=None if scaling is None else scaling.scale,
                         diagnostics=diagnostics, plan=plan,
                         learning_step=None if step is None else step.record,
                         map_refound=tuple(refound))
    return save_run(folder, outcome, checkpoint, warn)


def _search_again(settings: Settings, posterior, folder: RunFolder | None,
                  found: HigherModeFound, status: Callable[[str], None] | None) -> Any:
    """The MAP searched again from the highest point the chains visited
    (:mod:`symplid.workflow._mode_watch`); the first attempt's chunk files are removed."""
    if status is not None:
        status(f"the chains climbed above the MAP (log π {found.map_log_posterior:.2f} → "
               f"{found.log_posterior:.2f}): searching the MAP again from there...")
    if folder is not None:
        remove_chunks(folder.file(RunFolder.CHUNKS))
    return find_map_for(settings, posterior, found.theta)


def _draws_hook(on_sampled, map_result, posterior, scaling, groups,
                spent: list[float]) -> Callable[[np.ndarray], None] | None:
    """The sampler's ``on_draws`` that hands ``on_sampled`` the draws in the data's units (the
    seconds ``on_sampled`` takes are added to ``spent[0]``)."""
    if on_sampled is None:
        return None
    factors = None if scaling is None else np.asarray(scaling.reparameterisation(groups).scale)
    names = tuple(posterior.param_names)

    def hand_over(theta: np.ndarray) -> None:
        draws = theta if factors is None else theta * factors
        start = time.perf_counter()
        on_sampled(SampledDraws(map_result, draws, names))
        spent[0] += time.perf_counter() - start

    return hand_over


def _learning_step(settings, obs, folder, timings, status, plan) -> StepChoice | None:
    """``model.dt = "auto"``: the step chosen from the data (:mod:`symplid.workflow._step_size`),
    the run folder's settings rewritten with it; None for a given dt."""
    if settings.model.dt != "auto":
        return None
    start = time.perf_counter()
    step = choose_step(settings, obs, search=find_map_for, status=status, plan=plan)
    timings["learning_step_s"] = time.perf_counter() - start
    if folder is not None:
        folder.write_settings(step.settings)
    if status is not None:
        status(f"learning step: {step_line(step.record)}")
    check_stop()  # a safe point between the phases
    return step


def _warm_start(step: StepChoice | None, scaling, posterior) -> np.ndarray | None:
    """The MAP at the chosen step (data units) as a start in the fit's coordinates."""
    if step is None or step.theta is None:
        return None
    if scaling is None:
        return step.theta
    return scaling.reparameterisation(posterior.param_groups).to_unconstrained(step.theta)


def _diagnostics(plan, settings, obs, posterior, map_result, folder, timings,
                 status, step: StepChoice | None = None) -> dict[str, Any] | None:
    """The MAP-level sensitivity checks between the MAP and the sampler
    (:mod:`symplid.workflow._sensitivity`, with ``map.sensitivity``), saved as
    ``diagnostics.json`` (a step chosen by ``model.dt = "auto"`` has had its step-size check: the
    search's last halving, no refit). A check that fails is recorded as not
    available; a stop asked for meanwhile ends the run here, its MAP kept
    (:mod:`symplid._stopping`)."""
    if not settings.map.sensitivity:
        return None
    if status is not None:
        half = "" if step is not None else "at dt/2 and "  # "auto": the search's own halving
        status(f"sensitivity checks: the MAP refitted {half}with the other process-noise "
               "model (map.sensitivity = false skips them)...")
    start = time.perf_counter()
    checks = sensitivity_checks(settings, obs, posterior, map_result, plan=plan,
                                step_size=None if step is None else step_check(step.record))
    timings["diagnostics_s"] = time.perf_counter() - start
    if folder is not None:
        folder.write_json(RunFolder.DIAGNOSTICS, checks)
    check_stop()  # a safe point between the phases
    return checks
