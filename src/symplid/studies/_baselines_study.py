"""The baselines study: the UKF posterior against the least-squares objectives, on equal data.

The paper argues (Section I) that treating noisy observations as exact states, as HNN's loss
(eq. 1) and least squares through one integrator step (its refs 13–14) do, needs much more data
than its marginal-likelihood posterior (Theorem 1). This experiment measures it on Hénon–Heiles
(eq. 15): ``num_obs`` full-state observations spread evenly over ``t_span`` = 100 s (so more
points are denser; 20 is the paper's schedule), noise σ = 0.05, for every data ``seed``, fitted
by every ``method`` with every ``potential`` family:

* ``ukf-leapfrog``, ``ukf-rk2``: the UKF posterior (eq. 8) with the leapfrog or RK2 (midpoint)
  propagator at the learning step ``dt`` (eq. 14), the run settings' priors (the family's
  default: Laplace(0, 10) on the polynomial's coefficients, Normal(0, 1) on an MLP's weights),
  known initial state. **Budget**: MAP and Laplace only, no MCMC: the polynomial by multistart
  L-BFGS-B (``num_starts``) and the exact Hessian, the MLP by Adam then L-BFGS and the
  Gauss–Newton covariance (:func:`symplid.workflow._fit.find_map_for`). The intervals are
  the linearised Laplace ones, θ ~ N(θ*, Σ) pushed through the first-order expansion
  (exact for the polynomial, whose H is linear in its coefficients).
* ``hnn``, ``euler``, ``rk4``, ``leapfrog-ls``: the point estimates of
  :func:`symplid.inference._baselines.fit`, one integrator step per gap as their authors use
  them (``leapfrog-ls`` is the objective ``"leapfrog"``).

The potential families are ``"polynomial"`` (the cubic of eq. 13, which holds the truth) and
``"mlp"`` (:class:`~symplid.dynamics._neural.MLPPotential`, ``width`` × ``depth``).

Metrics of a cell (:func:`score`):

* ``hamiltonian_rel_error``: |H_θ(x0) − H(x0)| / H(x0) at the true initial state, with the
  learned U shifted so that U(0) = 0 (an MLP's U has an arbitrary constant; the polynomial and
  the truth have none, so for them nothing changes);
* ``coefficient_error``: the largest absolute error of the nine coefficients (polynomial only);
* ``potential_rmse``: the RMS error of U_θ(q) − U_θ(0) against the true U along the true path
  over the data's time span (both families);
* ``prediction_horizon_s``: the first time |q1 − q1_true| > ``horizon_tol`` of the learned
  model integrated by leapfrog at ``prediction_dt`` from the true initial state (the paper's
  measure, Fig. 3), up to ``t_end``;
* for the Bayesian methods, ``h_covered`` (1 when the true H(x0) is inside the 95 %
  interval H* ± 1.96·√(gᵀΣg), g = ∂H(x0)/∂θ) and ``coefficient_coverage`` (the fraction of true
  coefficients inside their 95 % Laplace intervals; polynomial only).

The table, the figure and the numbers that decide the comparison are in
:mod:`._baselines_report`; :func:`run_baselines_study` runs the sweep and writes them.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from symplid.dynamics._potentials import Polynomial
from symplid.dynamics._systems import get_system
from symplid.inference import _baselines as baselines
from symplid.inference._measures import prediction_horizon
from symplid.inference._predict import predict_trajectory
from symplid.model._data import Observations
from symplid.model._simulate import simulate
from symplid.studies._baselines_methods import METHODS, REFERENCE, Method
from symplid.studies._baselines_report import (
    deciding_numbers,
    format_report,
    plot_error_vs_size,
)
from symplid.studies._paper import truth_path
from symplid.workflow._experiment import Experiment
from symplid.workflow._fit import build_model, build_posterior, find_map_for
from symplid.workflow._model_builder import build_model_family
from symplid.workflow._sweep import cell_settings
from symplid.workflow._validate import Spec

__all__ = [
    "BUDGETS",
    "CELL_KEYS",
    "EXPERIMENT",
    "METHODS",
    "METRICS",
    "Method",
    "baselines_spec",
    "cell_data",
    "fit_method",
    "run_baselines_study",
    "run_cell",
    "score",
    "study_from_options",
    "write_study_report",
]

SYSTEM = "henon-heiles"


POTENTIALS = ("polynomial", "mlp")

#: The keys of a cell (table-column order). ``budget`` ``"quick"`` shrinks every iterative
#: solver for smoke tests (:data:`BUDGETS`).
CELL_KEYS: dict[str, Spec] = {
    "seed": Spec(int, 0, "seed of the data noise (and of the MAP starts)", minimum=0,
                 setting="seed"),
    "num_obs": Spec(int, 20, "observations, evenly spread over t_span", minimum=2),
    "method": Spec(str, REFERENCE, "how the potential is learned", choices=METHODS),
    "potential": Spec(str, "polynomial", "potential family", choices=POTENTIALS,
                      setting="model.potential"),
    "width": Spec(int, 16, "MLP units per hidden layer", minimum=1, setting="model.width"),
    "depth": Spec(int, 2, "MLP hidden layers", minimum=0, setting="model.depth"),
    "noise_std": Spec(float, 0.05, "observation-noise standard deviation", minimum=0.0,
                      strict=True),
    "t_span": Spec(float, 100.0, "the observations cover (0, t_span]", minimum=0.0, strict=True),
    "dt": Spec(float, 0.25, "UKF learning step (eq. 14)", minimum=0.0, strict=True,
               setting="model.dt"),
    "budget": Spec(str, "full", "solver budget", choices=("full", "quick")),
    "horizon_tol": Spec(float, 0.1, "a prediction is valid while |q1 − q1_true| ≤ this",
                        minimum=0.0, strict=True),
    "t_end": Spec(float, 200.0, "end of the predictions", minimum=0.0, strict=True),
    "prediction_dt": Spec(float, 0.01, "step of the predictions", minimum=0.0, strict=True),
}
#: Solver budgets: UKF MAP starts (polynomial), Adam and L-BFGS steps (MLP posterior), L-BFGS
#: iterations of the baselines with an MLP (the polynomial's baselines run to convergence).
BUDGETS: dict[str, dict[str, int]] = {
    "full": {"num_starts": 2, "adam_steps": 800, "lbfgs_steps": 200, "baseline_maxiter": 1000},
    "quick": {"num_starts": 1, "adam_steps": 60, "lbfgs_steps": 20, "baseline_maxiter": 60},
}
#: The metrics drawn by the generic sweep figures.
METRICS = (
    "hamiltonian_rel_error",
    "coefficient_error",
    "potential_rmse",
    "prediction_horizon_s",
    "h_covered",
    "coefficient_coverage",
)


def _base_settings(cell: Mapping[str, Any]) -> dict[str, Any]:
    """Known initial state (the system's), the method's propagator, the budget's MAP search;
    NUTS named for the neural family only so that the settings validate (no MCMC is run)."""
    system = get_system(SYSTEM)
    budget = BUDGETS[cell.get("budget", "full")]
    method = METHODS.get_entry(cell.get("method", REFERENCE))
    out: dict[str, Any] = {
        "initial_state": {"mode": "known", "x0": [float(v) for v in system.initial_state]},
        "map": {k: budget[k] for k in ("num_starts", "adam_steps", "lbfgs_steps")},
        "model": {"integrator": method.integrator or "leapfrog"},
    }
    if cell.get("potential") == "mlp":
        out["sampler"] = {"method": "nuts"}
    return out


def cell_data(cell: Mapping[str, Any]) -> Observations:
    """``num_obs`` full-state observations at t_span/n, 2·t_span/n, …, t_span, seeded."""
    n = int(cell.get("num_obs", 20))
    span = float(cell.get("t_span", 100.0))
    times = np.linspace(span / n, span, n)
    return simulate(get_system(SYSTEM), times=times, noise_std=float(cell.get("noise_std", 0.05)),
                    seed=int(cell.get("seed", 0)))


def fit_method(cell: Mapping[str, Any], data: Observations) -> tuple[Any, np.ndarray,
                                                                      np.ndarray | None]:
    """Fit one cell: ``(potential, coefficients, their Laplace covariance or None)``."""
    settings = cell_settings(cell, experiment=EXPERIMENT)
    method = METHODS.get_entry(cell["method"])
    potential = build_model_family(get_system(SYSTEM).dim, settings.model)
    if not method.bayesian:
        budget = BUDGETS[cell.get("budget", "full")]
        maxiter = 10_000 if isinstance(potential, Polynomial) else budget["baseline_maxiter"]
        return potential, baselines.fit(potential, data, method.objective, maxiter=maxiter), None
    model = build_model(settings, data)
    posterior = build_posterior(settings, data, model)
    result = find_map_for(settings, posterior)
    nc = potential.num_params
    cov = None if result.covariance is None else np.asarray(result.covariance)[:nc, :nc]
    return model.hamiltonian, np.asarray(result.theta[:nc], dtype=float), cov


def _energy(potential: Any, coefficients: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """H(x0) with U shifted to U(0) = 0, for one coefficient vector or a stack of them."""
    import jax
    import jax.numpy as jnp

    d = potential.dim
    q0, p0 = jnp.asarray(x0[:d]), jnp.asarray(x0[d:])

    def one(c):
        return 0.5 * jnp.sum(p0**2) + potential.value(q0, c) - potential.value(jnp.zeros(d), c)

    return np.asarray(jax.vmap(one)(jnp.atleast_2d(jnp.asarray(coefficients))))


def _energy_gradient(potential: Any, coefficients: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """∂H(x0)/∂θ of the shifted energy of :func:`_energy`."""
    import jax
    import jax.numpy as jnp

    d = potential.dim

    def h(c):
        return potential.value(jnp.asarray(x0[:d]), c) - potential.value(jnp.zeros(d), c)

    return np.asarray(jax.grad(h)(jnp.asarray(coefficients, dtype=float)))


@functools.lru_cache(maxsize=4)
def _truth(t_end: float, prediction_dt: float) -> tuple[np.ndarray, np.ndarray]:
    return truth_path(get_system(SYSTEM), t_end, prediction_dt)


def score(cell: Mapping[str, Any], potential: Any, coef: np.ndarray,
          cov: np.ndarray | None) -> dict[str, Any]:
    """The metrics of a fitted cell (module docstring)."""
    system = get_system(SYSTEM)
    x0 = np.asarray(system.initial_state, dtype=float)
    h_true = float(_energy(system.potential, system.coefficients, x0)[0])
    h = float(_energy(potential, coef, x0)[0])
    t_end, pdt = float(cell.get("t_end", 200.0)), float(cell.get("prediction_dt", 0.01))
    truth_times, truth = _truth(t_end, pdt)
    out: dict[str, Any] = {
        "learned_hamiltonian": h,
        "hamiltonian_rel_error": abs(h - h_true) / h_true,
        "coefficient_error": np.nan,
        "potential_rmse": _potential_rmse(potential, coef, system, truth_times, truth,
                                          float(cell.get("t_span", 100.0))),
        "h_covered": np.nan,
        "coefficient_coverage": np.nan,
    }
    polynomial = isinstance(potential, Polynomial) and potential.num_params == len(
        system.coefficients)
    if polynomial:
        out["coefficient_error"] = float(np.max(np.abs(coef - system.coefficients)))
    times, path = predict_trajectory(potential, coef, x0, t_end, dt=pdt)
    on_grid = np.stack([np.interp(times, truth_times, col) for col in truth.T], axis=1)
    out["prediction_horizon_s"] = float(
        prediction_horizon(times, path, on_grid, float(cell.get("horizon_tol", 0.1)), 0))
    if cov is not None:
        # the linearised Laplace interval H* ± 1.96·√(gᵀΣg), g = ∂H(x0)/∂θ: exact for the
        # polynomial (H is linear in its coefficients), the usual predictive for a network
        # (draws of the weights pushed through the network scatter far beyond the data)
        g = _energy_gradient(potential, coef, x0)
        sd = float(np.sqrt(max(g @ cov @ g, 0.0)))
        out["h_covered"] = float(abs(h - h_true) <= 1.96 * sd)
        if polynomial:
            inside = np.abs(coef - system.coefficients) <= 1.96 * np.sqrt(np.diag(cov))
            out["coefficient_coverage"] = float(np.mean(inside))
    return out


def _potential_rmse(potential, coef, system, truth_times, truth, span: float) -> float:
    """RMS of (U_θ(q) − U_θ(0)) − U(q) over the true path on (0, span]."""
    import jax.numpy as jnp

    d = system.dim
    keep = truth_times <= span
    q = jnp.asarray(truth[keep, :d].T)
    zero = potential.value(jnp.zeros(d), jnp.asarray(coef))
    learned = np.asarray(potential.value(q, jnp.asarray(coef)) - zero)
    true = np.asarray(system.potential.value(q, jnp.asarray(system.coefficients)))
    return float(np.sqrt(np.mean((learned - true) ** 2)))


def run_cell(cell: dict[str, Any]) -> dict[str, Any]:
    """One cell: simulate, fit by the cell's method and potential, score (flat metrics)."""
    start = time.perf_counter()
    data = cell_data(cell)
    try:
        potential, coef, cov = fit_method(cell, data)
    except FloatingPointError as err:  # a diverged baseline: a result, not a failed cell
        return {"diverged": 1.0, "error_message": str(err)[:200],
                "hamiltonian_rel_error": np.inf, "prediction_horizon_s": 0.0,
                "wall_time_s": time.perf_counter() - start}
    metrics = score(cell, potential, coef, cov)
    metrics["diverged"] = 0.0
    metrics["num_coefficients"] = int(potential.num_params)
    metrics["wall_time_s"] = time.perf_counter() - start
    return metrics


def baselines_spec(
    seeds: int = 10,
    sizes: tuple[int, ...] = (20, 50, 200, 1000),
    potentials: tuple[str, ...] = POTENTIALS,
    methods: tuple[str, ...] | None = None,
    *,
    mlp_seeds: int | None = None,
    quick: bool = False,
) -> Any:
    """The study's sweep: seeds × sizes × methods for each potential family.

    ``mlp_seeds`` (default ``seeds``) gives the MLP cells fewer seeds, the costly part;
    ``quick`` uses the ``"quick"`` solver budget (:data:`BUDGETS`) and predicts to 50 s.
    """
    from symplid.workflow._sweep import sweep_spec_from_dict

    for name, value in (("seeds", seeds), ("mlp_seeds", mlp_seeds)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)
                                  or value < 1):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    methods = tuple(methods) if methods else tuple(METHODS.names())
    cells = []
    for potential in potentials:
        n_seeds = seeds if potential != "mlp" or mlp_seeds is None else mlp_seeds
        cells += [{"potential": potential, "seed": s, "num_obs": int(n), "method": m}
                  for n in sizes for s in range(n_seeds) for m in methods]
    # The deciding numbers need every baseline cell but the posterior at the smallest size
    # only: those run first, so that an interrupted study (a long one on a busy machine) can
    # be reported on them (--report-only); the other posterior cells follow, size by size.
    first = min(int(n) for n in sizes)
    cells.sort(key=lambda c: (c["potential"] != potentials[0],
                              METHODS.get_entry(c["method"]).bayesian and c["num_obs"] > first))
    base: dict[str, Any] = {"budget": "quick" if quick else "full"}
    if quick:
        base["t_end"] = 50.0
    name = "baselines" + (" (quick)" if quick else "")
    return sweep_spec_from_dict({"base": base, "sweep": {"name": name, "experiment": "baselines",
                                                         "cells": cells}},
                                source="baselines study", experiment=EXPERIMENT)


def run_baselines_study(out_dir: Any, *, scheduler: Any = None, workers: int | None = None,
                        progress: bool = True, **spec_options: Any) -> dict[str, Any]:
    """Run the study (resumable) into ``out_dir``, then :func:`write_study_report`.

    ``spec_options`` go to :func:`baselines_spec`. Returns the content of ``decision.json``.
    """
    from symplid.workflow._sweep import run_sweep

    spec = baselines_spec(**spec_options)
    start = time.perf_counter()
    table = run_sweep(spec, out_dir, scheduler, workers, progress=progress, figures=False,
                      experiment=EXPERIMENT)
    return write_study_report(out_dir, table, wall_time_s=time.perf_counter() - start,
                              quick=bool(spec_options.get("quick")))


def write_study_report(out_dir: Any, table: Any = None, *, wall_time_s: float | None = None,
                       quick: bool = False) -> dict[str, Any]:
    """``report.md``, ``decision.json`` and ``figures/`` of a study folder from its finished
    cells (``table``: default, the folder's results, pending cells left out), so an
    interrupted study can be reported on what it has."""
    import os
    from pathlib import Path

    from symplid.workflow._results import write_json
    from symplid.workflow._sweep import load_results

    out = Path(out_dir)
    table = load_results(out) if table is None else table
    budget: dict[str, Any] = dict(BUDGETS["quick" if quick else "full"])
    budget["posterior"] = "MAP + Laplace (no MCMC)"
    decision = {"deciding": deciding_numbers(table), "budget": budget,
                "cells": len(table), "ok": int((table["status"] == "ok").sum()),
                "failed": int((table["status"] == "failed").sum()),
                "pending": int((table["status"] == "pending").sum()),
                "wall_time_s": wall_time_s}
    write_json(decision, out / "decision.json")
    plot_error_vs_size(table, out / "figures")
    tmp = out / ".report.md.tmp"
    tmp.write_text(format_report(table, budget), encoding="utf-8")
    os.replace(tmp, out / "report.md")
    return decision


def study_from_options(out: Any, *, seeds: int, mlp_seeds: int | None, sizes: str,
                       potentials: str, quick: bool, report_only: bool, workers: int | None,
                       progress: bool) -> str:
    """``symplid study baselines``: run (or only report) the study; returns the line to print."""
    from symplid.workflow._commandline import floats

    if report_only:
        d = write_study_report(out, quick=quick)
        return f"{out}: report.md from {d['ok']} finished cells ({d['pending']} pending)"
    run_baselines_study(
        out, workers=workers, progress=progress, seeds=seeds, mlp_seeds=mlp_seeds, quick=quick,
        sizes=tuple(int(n) for n in floats(sizes, "--sizes") or ()),
        potentials=tuple(p.strip() for p in potentials.split(",") if p.strip()),
    )
    return f"{out}: report.md, decision.json, results.csv and figures/"


def _figures(table: Any, folder: Any, settings: list[str]) -> Mapping[str, Any]:
    return plot_error_vs_size(table, folder)


EXPERIMENT = Experiment(
    "baselines",
    CELL_KEYS,
    run_cell,
    metrics=METRICS,
    figures=_figures,
    description="Hénon–Heiles: the UKF posterior against HNN and one-step least squares, "
    "over data sizes, seeds and potential families",
    base_settings=_base_settings,
)
