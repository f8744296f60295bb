"""Simulation-based calibration (SBC; Talts et al. 2018) of the fitting pipeline.

Where the model is right, a calibrated posterior gives every parameter a rank of the truth that
is uniform: draw θ̃ from the prior, simulate data from the model at θ̃, fit, and count how many
of L posterior draws fall below θ̃; over many replications the ranks are uniform on {0, …, L}
exactly when the fitted posterior is the posterior of the model and prior that made the data.
Any defect — in the likelihood (filter, propagator, process noise), the priors, the MAP or the
sampler — shows as ranks piling up somewhere.

The system (small, so that ≥ 100 replications fit in half an hour of one core): a 1-d
anharmonic oscillator, H = ½p² + U(q), U a quartic polynomial c[q1]·q + c[q1^2]·q² +
c[q1^3]·q³ + c[q1^4]·q⁴, known initial state (1, 0) at t = 0, ``num_obs`` full-state
observations ``obs_interval`` apart, learned with leapfrog at ``dt`` (the model's propagator
Ψ: ⌈gap/dt⌉ substeps per gap, eq. 14). Each replication (``seed``):

1. draws θ̃ = (c, Σ, Γ) from :data:`PRIORS` (a proper prior of realistic scale);
2. simulates the model itself, eq. (7): x_k = Ψ(x_{k−1}) + ξ_k, ξ_k ~ N(0, Σ I) once per gap,
   y_k = x_k + ε_k, ε_k ~ N(0, Γ I) — for ``likelihood = "none"`` (the deterministic
   likelihood, no Σ in θ) without ξ;
3. fits by the pipeline: the MAP (:func:`symplid.workflow._fit.find_map_for`, the
   deterministic path's homotopy included) and DRAM from it (``num_chains`` chains of
   ``iterations``, half burn-in; variances moved as log v);
4. records the rank of each θ̃_i among L = :data:`RANK_DRAWS` pooled draws thinned evenly
   (:func:`~symplid.studies._claims_stats.truth_rank`), and R-hat and ESS, so that
   replications whose chains did not converge can be reported apart.

:mod:`._sbc_report` tests the ranks (χ², ECDF bands) and draws them; :func:`run_sbc_study`
runs the replications on the sweep (resumable) and writes the report.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from symplid.dynamics._potentials import Polynomial
from symplid.inference._diagnostics import summary as diagnostics_summary
from symplid.model._data import Observations
from symplid.model._posterior import Posterior
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import LogNormal, LogUniform, Normal, Prior
from symplid.model._simulate import true_trajectory
from symplid.sampling import RunOptions, draws_array, sample
from symplid.studies._claims_stats import RANK_DRAWS, truth_rank
from symplid.workflow._experiment import Experiment
from symplid.workflow._fit import build_model, find_map_for
from symplid.workflow._settings import Settings, merge_overrides
from symplid.workflow._validate import Spec

__all__ = [
    "BUDGETS",
    "CELL_KEYS",
    "EXPERIMENT",
    "LIKELIHOODS",
    "PRIORS",
    "SAMPLERS",
    "THIN_DRAWS",
    "X0",
    "draw_truth",
    "fit_replication",
    "rank_metrics",
    "run_cell",
    "run_sbc_study",
    "sbc_spec",
    "simulate_model",
]

#: The likelihoods calibrated: the filter with process noise once per gap, and without.
LIKELIHOODS = ("gap", "none")
#: The known initial state (q, p) at t = 0.
X0 = (1.0, 0.0)
#: The prior every replication draws its truth from and every fit uses (by θ's names):
#: a softening/stiffening quartic well around the harmonic U = ½q², process variances over
#: three decades, observation noise of sd ≈ 0.05.
PRIORS: dict[str, Prior] = {
    "c[q1]": Normal(0.0, 0.05),
    "c[q1^2]": Normal(0.5, 0.05),
    "c[q1^3]": Normal(0.0, 0.05),
    "c[q1^4]": Normal(0.1, 0.03),
    "process_var": LogUniform(1e-5, 1e-2),
    "obs_var": LogNormal(math.log(2.5e-3), 0.5),
}
#: The samplers calibrated, both started from the MAP: DRAM (the paper's, in θ) and NUTS.
SAMPLERS = ("dram", "nuts")
#: Sampler budgets: iterations per chain (half burn-in) and chains; NUTS (whose draws are far
#: less autocorrelated) ``nuts_draws`` kept per chain after ``nuts_warmup`` adaptation steps.
BUDGETS: dict[str, dict[str, int]] = {
    "full": {"iterations": 4000, "chains": 2, "num_starts": 2, "nuts_warmup": 400,
             "nuts_draws": 300},
    "quick": {"iterations": 400, "chains": 2, "num_starts": 1, "nuts_warmup": 100,
              "nuts_draws": 100},
}
#: Draws behind the second, ESS-matched rank (``sbc.<name>.rank_thin``): a converged chain
#: (ESS ≥ :data:`~symplid.studies._sbc_report.ESS_MIN` = 50) thinned to 49 draws is one draw
#: per autocorrelation time or more, so these draws are about independent (Talts et al.
#: 2018, §5: ranks of autocorrelated draws are not uniform, even from the right posterior).
THIN_DRAWS = 49

CELL_KEYS: dict[str, Spec] = {
    "seed": Spec(int, 0, "replication: seed of the truth, the data and the fit", minimum=0,
                 setting="seed"),
    "likelihood": Spec(str, "gap", "process noise once per gap, or none (deterministic)",
                       choices=LIKELIHOODS),
    "sampler": Spec(str, "dram", "sampler started from the MAP", choices=SAMPLERS),
    "num_obs": Spec(int, 20, "full-state observations", minimum=2),
    "obs_interval": Spec(float, 1.0, "time between observations", minimum=0.0, strict=True),
    "dt": Spec(float, 0.1, "learning step (eq. 14)", minimum=0.0, strict=True),
    "budget": Spec(str, "full", "sampler budget", choices=tuple(BUDGETS)),
}


def _param_names(likelihood: str) -> list[str]:
    return [n for n in PRIORS if likelihood != "none" or n != "process_var"]


def draw_truth(seed: int, likelihood: str = "gap") -> dict[str, float]:
    """θ̃ of replication ``seed``: each parameter from its prior in :data:`PRIORS`."""
    key = jax.random.fold_in(jax.random.key(seed), 0)
    return {name: float(prior.sample(jax.random.fold_in(key, i)))
            for i, (name, prior) in enumerate(PRIORS.items())
            if name in _param_names(likelihood)}


def simulate_model(truth: Mapping[str, float], cell: Mapping[str, Any]) -> Observations:
    """Data from the model of eq. (7) at ``truth``: Ψ over each gap (leapfrog at ``dt``),
    then N(0, Σ I) added to the state (when ``truth`` has a process variance) and
    N(0, Γ I) to the observation."""
    potential = Polynomial(1, 4)
    coefficients = [truth[f"c[{n}]"] for n in potential.param_names]
    times = float(cell["obs_interval"]) * np.arange(1, int(cell["num_obs"]) + 1)
    rng = np.random.default_rng([int(cell["seed"]), 1])
    state, previous, states = np.asarray(X0, dtype=float), 0.0, []
    for t in times:
        state = true_trajectory(potential, coefficients, state, [t], dt=float(cell["dt"]),
                                t0=previous)[0]
        if "process_var" in truth:
            state = state + math.sqrt(truth["process_var"]) * rng.standard_normal(2)
        states.append(state)
        previous = float(t)
    values = np.asarray(states) + math.sqrt(truth["obs_var"]) * rng.standard_normal((len(times),
                                                                                     2))
    return Observations(times=times, values=values, names=("q1", "p1"))


def _settings(cell: Mapping[str, Any]) -> Settings:
    budget = BUDGETS[str(cell["budget"])]
    return merge_overrides(Settings(), {
        "seed": int(cell["seed"]), "model.order": 4, "model.integrator": "leapfrog",
        "model.dt": float(cell["dt"]), "model.noise": "isotropic",
        "model.standardise": "off", "model.process_noise_per": str(cell["likelihood"]),
        "initial_state.x0": list(X0), "map.num_starts": budget["num_starts"],
        "map.evidence": "laplace",
    })


def fit_replication(cell: Mapping[str, Any], obs: Observations) -> tuple[Any, np.ndarray, Any]:
    """The pipeline's fit of one replication: posterior (priors :data:`PRIORS`), MAP, then
    the cell's sampler (DRAM or NUTS) from it.

    Returns ``(posterior, draws (chain, draw, param), diagnostics table)``.
    """
    settings = _settings(cell)
    model = build_model(settings, obs)
    names = _param_names(str(cell["likelihood"]))
    posterior = Posterior(model, obs, prior=PriorSpec(overrides={n: PRIORS[n] for n in names}),
                          x0=np.asarray(X0), P0=settings.initial_state.p0_var, t0=0.0)
    if list(posterior.param_names) != names:
        raise RuntimeError(f"θ is {posterior.param_names}, the study's priors name {names}")
    budget = BUDGETS[str(cell["budget"])]
    method = str(cell.get("sampler", "dram"))
    if method == "nuts":
        kept, burn_in = budget["nuts_draws"], budget["nuts_warmup"]
    else:
        kept = burn_in = budget["iterations"] // 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a replication's warnings are its metrics
        result = find_map_for(settings, posterior)
        idata = sample(posterior, method, num_draws=kept, num_chains=budget["chains"],
                       burn_in=burn_in, init=result, seed=int(cell["seed"]),
                       options=RunOptions(progress=False))
        table = diagnostics_summary(idata, show=False, warn=False)
    return posterior, draws_array(idata), table


def run_cell(cell: dict[str, Any]) -> dict[str, Any]:
    """One replication: draw θ̃, simulate, fit, rank (flat metrics, ``sbc.<name>.rank``)."""
    start = time.perf_counter()
    truth = draw_truth(int(cell["seed"]), str(cell["likelihood"]))
    obs = simulate_model(truth, cell)
    posterior, draws, table = fit_replication(cell, obs)
    metrics = rank_metrics(posterior.param_names, draws, truth, table)
    metrics["wall_time_s"] = time.perf_counter() - start
    return metrics


def rank_metrics(names: Any, draws: np.ndarray, truth: Mapping[str, float],
                 table: Any) -> dict[str, Any]:
    """A replication's flat metrics: per parameter of θ (``names``, the last axis of
    ``draws``), the rank of its truth among :data:`~symplid.studies._claims_stats.RANK_DRAWS`
    and :data:`THIN_DRAWS` thinned draws, the truth, R-hat and the smaller of bulk and tail
    ESS (from the diagnostics ``table``); and the largest R-hat and smallest ESS of all."""
    metrics: dict[str, Any] = {"rank_draws": RANK_DRAWS, "thin_draws": THIN_DRAWS}
    for i, name in enumerate(names):
        metrics[f"sbc.{name}.rank"] = truth_rank(draws[..., i], truth[name], RANK_DRAWS)
        metrics[f"sbc.{name}.rank_thin"] = truth_rank(draws[..., i], truth[name], THIN_DRAWS)
        metrics[f"sbc.{name}.truth"] = truth[name]
        metrics[f"sbc.{name}.rhat"] = float(table.loc[name, "r_hat"])
        metrics[f"sbc.{name}.ess"] = float(min(table.loc[name, "ess_bulk"],
                                               table.loc[name, "ess_tail"]))
    metrics["rhat_max"] = float(np.nanmax(table["r_hat"].to_numpy(dtype=float)))
    metrics["ess_min"] = float(np.nanmin(table[["ess_bulk", "ess_tail"]].to_numpy(dtype=float)))
    return metrics


#: The study's experiment (listed in :data:`symplid.studies.STUDIES`).
EXPERIMENT = Experiment(
    "sbc",
    CELL_KEYS,
    run_cell,
    metrics=("rhat_max", "ess_min", "wall_time_s"),
    description="simulation-based calibration of MAP + DRAM on a 1-d anharmonic "
    "oscillator simulated from the model (with and without process noise)",
)


def sbc_spec(replications: int = 100, likelihoods: tuple[str, ...] = LIKELIHOODS,
             budget: str = "full", samplers: tuple[str, ...] = ("dram",)) -> Any:
    """The study's sweep: ``replications`` seeds for each sampler and likelihood (all of the
    first sampler's first likelihood first, so an interrupted study can be reported on
    what finished)."""
    from symplid.workflow._sweep import sweep_spec_from_dict

    if isinstance(replications, bool) or not isinstance(replications, int) or replications < 1:
        raise ValueError(f"replications must be a positive integer, got {replications!r}")
    unknown = [v for v in likelihoods if v not in LIKELIHOODS]
    if unknown or not likelihoods:
        raise ValueError(f"likelihoods must be among {', '.join(LIKELIHOODS)}, got "
                         f"{', '.join(likelihoods) or 'none'}")
    bad = [m for m in samplers if m not in SAMPLERS]
    if bad or not samplers:
        raise ValueError(f"samplers must be among {', '.join(SAMPLERS)}, got "
                         f"{', '.join(samplers) or 'none'}")
    cells = [{"sampler": m, "likelihood": v, "seed": s} for m in samplers for v in likelihoods
             for s in range(replications)]
    name = "sbc" + (f" ({budget})" if budget != "full" else "")
    return sweep_spec_from_dict({"base": {"budget": budget},
                                 "sweep": {"name": name, "experiment": "sbc", "cells": cells}},
                                source="sbc study", experiment=EXPERIMENT)


def run_sbc_study(out_dir: Any, *, replications: int = 100,
                  likelihoods: tuple[str, ...] = LIKELIHOODS, budget: str = "full",
                  samplers: tuple[str, ...] = ("dram",), workers: int | None = None,
                  progress: bool = True,
                  report_only: bool = False) -> dict[str, Any]:
    """Run the replications on the sweep (resumable) into ``out_dir``, then write
    ``report.md``, ``sbc.json`` and ``figures/`` (:mod:`._sbc_report`). ``report_only``:
    report the replications the folder holds, run nothing."""
    from symplid.studies._sbc_report import write_sbc_report
    from symplid.workflow._sweep import run_sweep

    spec = sbc_spec(replications, likelihoods, budget, samplers)
    table = None
    if not report_only:
        table = run_sweep(spec, out_dir, None, workers, progress=progress, figures=False,
                          experiment=EXPERIMENT)
    return write_sbc_report(out_dir, table, budget={"name": budget, **BUDGETS[budget]})
