"""Simulation-based calibration of the defaults: a user's model fitted as ``symplid fit`` fits it.

:mod:`._sbc` calibrates the pipeline at fixed choices (a known dt, a fixed budget, the data
made by the fit's own propagator). This study calibrates what a user who changes nothing gets:
each replication is one call of :func:`symplid.workflow.fit` with **every default** of
:class:`~symplid.workflow.Settings` — the learning step chosen from the data (``model.dt =
"auto"``), the MAP's data-driven starts, the sensitivity checks, the evidence, DRAM until every
parameter's bulk and tail ESS reach 400 and R-hat 1.01 (``num_iterations = "auto"``) — on data
that the fit's propagator did not make.

The model is the one a user would write (:data:`MODEL`): a damped pendulum from the command
line's expression language,

    H = ½p² + k(1 − cos q),   ṗ = −∂H/∂q − γp,

positions only, its initial state learned. Its settings give what no default can, the priors
(a proper prior is what makes SBC meaningful, and the defaults' half-normal(1) variances would
draw noise ten times the signal): k log-normal around 4 (a period of about 3 s), γ
half-normal(0.05), both noise variances log-normal around 10⁻³, and the initial state
N((1, 0), 0.3² I) — the learned initial state's prior centred on a given ``initial_state.x0``,
not on the data, so that the truth can be drawn from it.

Each replication (``seed``):

1. draws θ̃ = (k, γ, Σ, Γ, x0) from those priors (:func:`draw_truth`, the priors' own
   ``sample``);
2. simulates eq. (7) with the *exact* flow: SciPy's DOP853 (tolerance 1e-11) over each gap, then
   ξ_k ~ N(0, Σ I) added to (q, p) once per gap (``model.process_noise_per = "gap"``, the
   default), and y_k = q_k + ε_k, ε_k ~ N(0, Γ) (:func:`simulate_data`);
3. fits with :func:`symplid.workflow.fit` and the settings of :data:`MODEL` (no run folder);
4. records the rank of each θ̃_i among :data:`~symplid.studies._claims_stats.RANK_DRAWS` pooled
   draws, R-hat and ESS, the step chosen, and what ended the sampling (the targets or the cap).

Where the defaults are right — the step's bias below the posterior's spread, the unscented
filter's Gaussian approximation good enough, the sampler run to its targets — the ranks are
uniform; :mod:`._sbc_report` tests them, converged replications and the rest apart.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from symplid.inference._diagnostics import summary as diagnostics_summary
from symplid.model._data import Observations
from symplid.sampling import draws_array
from symplid.studies._sbc import rank_metrics
from symplid.workflow._experiment import Experiment
from symplid.workflow._settings import Settings, settings_from_dict
from symplid.workflow._settings_schema import prior_spec
from symplid.workflow._validate import Spec

__all__ = [
    "CELL_KEYS",
    "EXPERIMENT",
    "MODEL",
    "draw_truth",
    "run_cell",
    "run_sbc_defaults",
    "sbc_defaults_spec",
    "settings_for",
    "simulate_data",
]

#: The study's model file, as a settings table: the expression, the damping, the priors and
#: the learned initial state's centre. Every other key keeps its default (a test checks it).
MODEL: dict[str, Any] = {
    "model": {
        "potential": "k*(1 - cos(q1))",
        "damping": True,
        "parameters": {"k": {"prior": "log-normal", "mu": math.log(4.0), "sigma": 0.25}},
    },
    "initial_state": {"mode": "learned", "x0": [1.0, 0.0]},
    "priors": {
        "variances": {"prior": "log-normal", "mu": math.log(1e-3), "sigma": 1.0},
        "initial_state": {"prior": "normal", "loc": 0.0, "scale": 0.3},
        "damping": {"prior": "half-normal", "scale": 0.05},
    },
}
#: Tolerance of the DOP853 flow that makes the data.
FLOW_TOLERANCE = 1e-11

CELL_KEYS: dict[str, Spec] = {
    "seed": Spec(int, 0, "replication: seed of the truth, the data and the fit", minimum=0,
                 setting="seed"),
    "num_obs": Spec(int, 25, "observed positions", minimum=2),
    "obs_interval": Spec(float, 0.8, "time between observations (the first at one interval)",
                         minimum=0.0, strict=True),
}


def settings_for(seed: int) -> Settings:
    """The settings of replication ``seed``: :data:`MODEL`, every other key its default."""
    return settings_from_dict({**MODEL, "seed": int(seed)}, source="sbc-defaults model")


def draw_truth(seed: int) -> dict[str, float]:
    """θ̃ of replication ``seed``, by θ's names, each entry drawn from its prior in
    :data:`MODEL` (the learned initial state: its centre plus an offset from its prior)."""
    settings = settings_for(seed)
    spec = prior_spec(settings)
    priors = {"k": spec.overrides["k"], "gamma": spec.damping,
              "process_var": spec.process_var, "obs_var": spec.obs_var}
    key = jax.random.fold_in(jax.random.key(seed), 0)
    truth = {name: float(prior.sample(jax.random.fold_in(key, i)))
             for i, (name, prior) in enumerate(priors.items())}
    centre = settings.initial_state.x0
    for j, name in enumerate(("q1", "p1")):
        offset = settings.priors.initial_state.sample(jax.random.fold_in(key, len(priors) + j))
        truth[f"x0[0].{name}"] = centre[j] + float(offset)
    return truth


def simulate_data(truth: Mapping[str, float], cell: Mapping[str, Any]) -> Observations:
    """Positions from eq. (7) at ``truth`` with the exact flow of q̇ = p, ṗ = −k sin q − γp
    (DOP853 over each gap), N(0, Σ I) added to the state once per gap, N(0, Γ) to q."""
    from scipy.integrate import solve_ivp

    k, gamma = truth["k"], truth["gamma"]

    def field(_t: float, x: np.ndarray) -> list[float]:
        return [x[1], -k * math.sin(x[0]) - gamma * x[1]]

    times = float(cell["obs_interval"]) * np.arange(1, int(cell["num_obs"]) + 1)
    rng = np.random.default_rng([int(cell["seed"]), 1])
    state = np.array([truth["x0[0].q1"], truth["x0[0].p1"]])
    previous, positions = 0.0, []
    for t in times:
        flow = solve_ivp(field, (previous, float(t)), state, method="DOP853",
                         rtol=FLOW_TOLERANCE, atol=FLOW_TOLERANCE)
        state = flow.y[:, -1] + math.sqrt(truth["process_var"]) * rng.standard_normal(2)
        positions.append(state[0] + math.sqrt(truth["obs_var"]) * rng.standard_normal())
        previous = float(t)
    return Observations(times=times, values=np.asarray(positions)[:, None], names=("q1",))


def run_cell(cell: dict[str, Any]) -> dict[str, Any]:
    """One replication: draw θ̃, simulate, fit with the defaults, rank (flat metrics,
    ``sbc.<name>.rank``), with the chosen step and what ended the sampling."""
    from symplid.workflow._fit import fit

    start = time.perf_counter()
    seed = int(cell["seed"])
    truth = draw_truth(seed)
    obs = simulate_data(truth, cell)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a replication's warnings are its metrics
        outcome = fit(obs, settings_for(seed), progress=False)
        table = diagnostics_summary(outcome.idata, show=False, warn=False)
    names = list(outcome.posterior.param_names)
    if sorted(names) != sorted(truth):
        raise RuntimeError(f"θ is {names}, the study draws {sorted(truth)}")
    metrics = rank_metrics(names, draws_array(outcome.idata), truth, table)
    metrics["dt"] = float(outcome.settings.model.dt)
    metrics["reached_target"] = float(outcome.idata.attrs.get("stopped_by") == "target")
    metrics["iterations"] = float(outcome.idata.attrs.get("iterations", math.nan))
    metrics["wall_time_s"] = time.perf_counter() - start
    return metrics


#: The study's experiment (listed in :data:`symplid.studies.STUDIES`).
EXPERIMENT = Experiment(
    "sbc-defaults",
    CELL_KEYS,
    run_cell,
    metrics=("rhat_max", "ess_min", "dt", "wall_time_s"),
    description="simulation-based calibration of symplid fit's defaults on a user's damped "
    "pendulum (positions only, learned x0, data from the exact flow)",
)


def sbc_defaults_spec(replications: int = 100) -> Any:
    """The study's sweep: one cell per replication (seeds 0 … ``replications`` − 1)."""
    from symplid.workflow._sweep import sweep_spec_from_dict

    if isinstance(replications, bool) or not isinstance(replications, int) or replications < 1:
        raise ValueError(f"replications must be a positive integer, got {replications!r}")
    cells = [{"seed": s} for s in range(replications)]
    return sweep_spec_from_dict({"sweep": {"name": "sbc-defaults", "experiment": "sbc-defaults",
                                           "cells": cells}},
                                source="sbc-defaults study", experiment=EXPERIMENT)


def run_sbc_defaults(out_dir: Any, *, replications: int = 100, workers: int | None = None,
                     progress: bool = True, report_only: bool = False) -> dict[str, Any]:
    """Run the replications on the sweep (resumable) into ``out_dir``, then write
    ``report.md``, ``sbc.json`` and ``figures/`` (:mod:`._sbc_report`); ``report_only``:
    report what the folder holds, run nothing."""
    from symplid.studies._sbc_report import write_sbc_report
    from symplid.workflow._sweep import run_sweep

    spec = sbc_defaults_spec(replications)
    table = None
    if not report_only:
        table = run_sweep(spec, out_dir, None, workers, progress=progress, figures=False,
                          experiment=EXPERIMENT)
    sampler = settings_for(0).sampler
    words = (f"the defaults, {sampler.method.upper()} with {sampler.num_chains} chains "
             f"{sampler.budget_words()}")
    return write_sbc_report(out_dir, table, budget={"name": "defaults", "words": words},
                            title="Simulation-based calibration of the defaults")
