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
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from symplid.dynamics.families import build_family
from symplid.inference.diagnostics import summary as diagnostics_summary
from symplid.inference.map import find_map
from symplid.inference.samplers import SAMPLERS, draws_array, sample
from symplid.io import observation_layout
from symplid.model.data import Observations
from symplid.model.posterior import Posterior
from symplid.model.statespace import HamiltonianModel
from symplid.workflow.interrupts import deferred_interrupts
from symplid.workflow.results import RunFolder
from symplid.workflow.settings import Settings, resolve_for_data


def build_model(settings: Settings, obs: Observations) -> HamiltonianModel:
    """The state-space model of eq. (7) that ``settings.model`` describes, for these data."""

    m = settings.model
    layout = observation_layout(obs)
    observation = layout.kind if m.observation == "auto" else m.observation
    return HamiltonianModel(
        build_family(layout.dim, m),
        integrator=m.integrator,
        binding=m.binding or None,
        dt=m.dt,
        observation=observation,
        process_noise_per=m.process_noise_per,
        noise=m.noise,
        mass=list(m.mass) if m.mass else None,
        alpha=m.alpha,
        beta=m.beta,
        kappa=m.kappa,
        jitter=m.jitter,
    )


def build_posterior(settings: Settings, obs: Observations, model: HamiltonianModel):
    """The posterior of ``settings`` (priors, initial state) for ``model`` and ``obs``."""

    init = settings.initial_state
    learned = init.mode == "learned"
    x0 = np.asarray(init.x0, dtype=float) if init.x0 else None
    return Posterior(
        model,
        obs,
        prior=settings.priors.prior_spec(learned),
        x0=x0,
        P0=init.p0_var,
        t0=None if init.at_first_observation else init.t0,  # None: at the first observation
        learn_initial_state=learned,  # its prior is the "initial_state" group above
    )


@dataclass
class FitOutcome:
    """What :func:`fit` produced (the same content as the run folder, in memory)."""

    settings: Settings
    data: Observations
    model: HamiltonianModel
    posterior: Any
    map_result: Any
    idata: Any = None
    summary: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    interrupted: bool = False


def find_map_for(settings: Settings, posterior) -> Any:
    """MAP by bounded quasi-Newton from ``settings.map.num_starts`` seeded starts."""

    return find_map(posterior, seed=settings.map.seed, num_starts=settings.map.num_starts)


def sample_for(
    settings: Settings,
    posterior,
    map_result,
    progress: bool = True,
    progress_label: str | None = None,
    progress_position: int = 0,
) -> Any:
    """Run the sampler of ``settings.sampler`` from the MAP; returns ArviZ ``InferenceData``."""

    s = settings.sampler
    # The [sampler] section's method-specific keys go to the samplers whose settings class
    # declares them (DRAM's γ and adaptation start); no branch on the method's name.
    accepted = {f.name for f in dataclasses.fields(SAMPLERS[s.method].settings_class)}
    offered = {"gamma": s.gamma, "adapt_start": max(1, s.adapt_start)}
    options = {key: value for key, value in offered.items() if key in accepted}
    # The settings count every iteration (burn-in included, as the paper's 200,000 with
    # 100,000 discarded); the sampler counts the draws it keeps.
    return sample(
        posterior,
        method=s.method,
        num_draws=s.num_draws,
        num_chains=s.num_chains,
        seed=s.seed,
        init=map_result,
        burn_in=s.burn_in,
        thin=s.thin,
        settings=options,
        progress=progress,
        progress_label=progress_label,
        progress_position=progress_position,
    )


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
) -> FitOutcome:
    """The whole fit: MAP, Hessian, sampler and the run folder (when ``out`` is given).

    The run folder is marked incomplete until every file is written. A sampler interrupted
    with Ctrl-C (or SIGTERM, see :mod:`symplid.workflow.interrupts`) keeps the draws it made:
    they are saved, with SIGINT and SIGTERM held while the files are written, and the folder
    is marked ``interrupted`` (readers refuse it with a message that says what to do). A
    failure or an interruption before sampling records its reason in the marker. ``warn``
    issues :class:`~symplid.inference.diagnostics.ConvergenceWarning` for R-hat and ESS;
    ``status`` receives a one-line message before the (silent) MAP search and compilation.
    """

    settings = resolve_for_data(settings, obs, source)
    folder = RunFolder(out, "w", overwrite=overwrite) if out is not None else None
    try:
        return _fit(obs, settings, folder, progress, progress_label, progress_position, warn,
                    status)
    except BaseException as err:
        if folder is not None and not folder.is_complete and not _marked(folder):
            what = "interrupted before any draw was kept" if isinstance(
                err, KeyboardInterrupt) else f"{type(err).__name__}: {err}"
            folder.fail(what)
        raise


def _marked(folder: RunFolder) -> bool:
    reason = folder.incomplete_reason or ""
    return reason.startswith((RunFolder.INTERRUPTED, "failed"))


def _fit(obs, settings, folder, progress, progress_label, progress_position, warn,
         status) -> FitOutcome:
    timings: dict[str, float] = {}
    if folder is not None:
        folder.write_settings(settings)
        folder.write_data(obs)
    if status is not None:
        status(f"MAP search from {settings.map.num_starts} starts (the first fit compiles the "
               "filter: this can take a minute)...")
    start = time.perf_counter()
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    map_result = find_map_for(settings, posterior)
    timings["map_s"] = time.perf_counter() - start
    if folder is not None:
        folder.write_map(map_result)
    start = time.perf_counter()
    idata = sample_for(settings, posterior, map_result, progress, progress_label, progress_position)
    timings["sampler_s"] = time.perf_counter() - start
    with deferred_interrupts():  # a second Ctrl-C must not lose the draws the first kept
        interrupted = bool(idata.attrs.get("interrupted", False)) if idata is not None else False
        table = diagnostics_summary(idata, show=False, warn=warn and not interrupted)
        summary = fit_summary(posterior, map_result, idata, table)
        summary["timings"] = timings
        summary["interrupted"] = interrupted
        if interrupted:
            summary["iterations_done"] = int(idata.attrs.get("iterations", 0))
        outcome = FitOutcome(
            settings, obs, model, posterior, map_result, idata, summary, timings, interrupted
        )
        if folder is not None:
            folder.write_posterior(idata)
            folder.write_summary(summary)
            if interrupted:
                folder.mark_interrupted(
                    f"after {summary['iterations_done']:,} of "
                    f"{settings.sampler.num_iterations:,} iterations per chain (the draws "
                    "made so far are in posterior.nc)"
                )
            else:
                folder.finish(required=("settings.toml", "data.csv", "map.json", "posterior.nc"))
    return outcome


def fit_summary(posterior, map_result, idata, table=None) -> dict[str, Any]:
    """A JSON-ready digest of a fit: MAP, posterior quantiles, convergence and acceptance."""

    names = list(posterior.param_names)
    out: dict[str, Any] = {
        "param_names": names,
        "map": dict(zip(names, np.asarray(map_result.theta).tolist(), strict=True)),
        "map_log_posterior": float(map_result.log_posterior),
        "log_evidence_laplace": float(map_result.log_evidence),
    }
    if idata is None:
        return out
    draws = draws_array(idata)  # (chain, draw, param)
    flat = draws.reshape(-1, draws.shape[-1])
    q = np.quantile(flat, [0.025, 0.5, 0.975], axis=0)
    out["posterior"] = {
        name: {"q025": q[0, i], "median": q[1, i], "q975": q[2, i], "mean": flat[:, i].mean()}
        for i, name in enumerate(names)
    }
    stats = idata.sample_stats
    for key in ("acceptance_rate", "accepted"):
        if key in stats:
            out["acceptance_rate"] = float(np.asarray(stats[key]).mean())
            break
    if table is not None:
        out["rhat_max"] = float(np.nanmax(table["r_hat"].to_numpy()))
        out["ess_min"] = float(np.nanmin(table["ess_bulk"].to_numpy()))
    return out
