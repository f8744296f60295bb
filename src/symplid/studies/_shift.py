"""The shift study: where the paper-claims posteriors' coefficient shift comes from.

The paper-claims study (:mod:`._paper_study`) finds the 95 % intervals of some coefficients
missing the truth more often than 5 %, and the cause a mean shift of the posterior rather than
a too-narrow width. This study splits each coefficient's shift at the paper's Hénon–Heiles
setting (σ 0.05, 20 full-state observations every 5 s, learning step dt, process noise once per
gap) into four parts, each a difference of point fits (:mod:`._shift_fits`) that the study
recomputes:

(a) **discretisation** D: the noise-free fit (the least-squares maximum of the deterministic
    likelihood on noise-free data, the observation variance held at σ², no prior) minus the
    truth, for dt ∈ :data:`DISCRETISATION_DTS`; the learned propagator's own error (∝ dt² for
    leapfrog and RK2, ∝ dt⁴ for yoshida4);
(b) **noise draws** N: the MAP of the deterministic likelihood (Σ = 0,
    ``model.process_noise_per = "none"``, :mod:`symplid.model._deterministic`) on the study's
    own data seeds (0..19), averaged, minus truth and D: what the 20 reused noise draws add.
    The same average over ``fresh`` new seeds (from :data:`FRESH_SEED`) says whether the
    estimator itself is biased by the noise (it is not, when N_fresh is within its standard
    error of 0) or the 20 draws happen to lean one way;
(c) **process noise** S: the MAP of the filter's posterior with Σ held fixed (its prior is then
    a constant; everything else of the posterior is the paper's) minus the deterministic MAP,
    on the same data, averaged over the seeds. Σ is held at each seed's own posterior median
    (``"median"``, the decomposition's value), at each seed's MAP value of Σ (``"map"``,
    usually the search's floor 1e-14) and at :data:`SIGMA_TYPICAL` (``"typical"``);
(d) the **remainder** R: the posterior's shift (the 95 % interval midpoint minus the truth,
    read from the paper-claims study's cells, not resampled) minus D + N + S: what the
    posterior adds to the fixed-Σ mode (integrating over Σ, its skewness).

Shifts are reported in the coefficient's units and in posterior standard deviations (the
interval's width / 3.92, averaged over the seeds). Cells whose chains did not converge
(R-hat above :data:`~._paper_calibration.RHAT_FAILED`) are left out of every average and
listed apart. :func:`run_shift_study` writes ``decomposition.json``, ``report.md`` and the
figures (:mod:`._shift_report`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from symplid.dynamics._integrators import INTEGRATORS
from symplid.dynamics._systems import get_system
from symplid.model._data import Observations
from symplid.model._simulate import simulate
from symplid.studies import _paper as paper
from symplid.studies._paper_calibration import RHAT_FAILED, true_values
from symplid.studies._paper_cells import cell_data
from symplid.studies._shift_fits import ConditionalMode, ModeFit, stack_data
from symplid.workflow._experiment import Experiment
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._sweep_spec import cell_settings
from symplid.workflow._validate import Spec

__all__ = [
    "BUDGETS",
    "CELL_KEYS",
    "DISCRETISATION_DTS",
    "EXPERIMENT",
    "FRESH_SEED",
    "ROWS",
    "SIGMA_OPTIONS",
    "SIGMA_TYPICAL",
    "STUDY_SEEDS",
    "decompose_row",
    "discretisation",
    "posterior_totals",
    "read_cells",
    "row_posterior",
    "run_cell",
    "run_shift_study",
    "study_from_options",
]

#: The (integrator, dt) rows decomposed: those the paper-claims study fitted at the paper's
#: σ, schedule and process noise.
ROWS: tuple[tuple[str, float], ...] = (
    ("leapfrog", 0.25), ("yoshida4", 0.25), ("rk2-midpoint", 0.25),
    ("leapfrog", 0.5), ("leapfrog", 0.1), ("rk2-midpoint", 0.5), ("rk2-midpoint", 0.1),
)
#: The learning steps of the noise-free fits (part a), for every integrator of :data:`ROWS`.
DISCRETISATION_DTS: tuple[float, ...] = (0.5, 0.25, 0.1, 0.05)
#: The paper-claims study's data seeds.
STUDY_SEEDS = 20
#: The first fresh data seed (disjoint from the study's).
FRESH_SEED = 1000
#: A typical posterior median of Σ at the paper's setting (leapfrog, dt 0.25).
SIGMA_TYPICAL = 1.4e-5
#: The values Σ is held at in part (c); the first is the decomposition's.
SIGMA_OPTIONS = ("median", "map", "typical")
#: Run sizes: rows, noise-free steps, study seeds and fresh seeds.
BUDGETS: dict[str, dict[str, Any]] = {
    "full": {"rows": ROWS, "dts": DISCRETISATION_DTS, "seeds": STUDY_SEEDS, "fresh": 200},
    "quick": {"rows": (("leapfrog", 0.25),), "dts": (0.5, 0.25), "seeds": 2, "fresh": 3},
}
_NOISE_STD = 0.05


def row_posterior(integrator: str, dt: float, obs: Observations, likelihood: str) -> Any:
    """The paper's posterior (priors, known initial state) for ``obs`` with this propagator,
    with process noise once per gap (``"gap"``) or without (``"none"``)."""
    cell = {"integrator": integrator, "dt": dt, "order": 3, "noise_std": _NOISE_STD,
            "model.process_noise_per": likelihood}
    settings = cell_settings(cell, experiment=paper.EXPERIMENT)
    return build_posterior(settings, obs, build_model(settings, obs))


def _data(seed: int, noise_std: float = _NOISE_STD) -> Observations:
    if noise_std == 0.0:
        system = get_system("henon-heiles")
        times = system.obs_interval * np.arange(1, system.num_obs + 1)
        return simulate(system, times=times, noise_std=0.0, seed=0)
    return cell_data({"seed": seed, "noise_std": noise_std})[1]


def _truth(posterior: Any) -> np.ndarray:
    system = get_system("henon-heiles")
    values = true_values(system, posterior.model, _NOISE_STD)
    return np.array([values.get(n, np.nan) for n in posterior.param_names])


def _coefficients(posterior: Any) -> list[int]:
    return [i for i, g in enumerate(posterior.param_groups) if g == "coefficients"]


# ----------------------------------------------------------------------------- the cells
def read_cells(folder: str | Path) -> dict[tuple[str, float], dict[int, dict[str, Any]]]:
    """The paper-claims cells at the paper's σ, schedule and process noise, by (integrator,
    dt) and seed: each coefficient's interval midpoint and posterior sd (width / 3.92), the
    MAP and median of Σ, R-hat and ESS."""
    from symplid.workflow._sweep_results import load_results

    table = load_results(folder)
    if "priors.process_var" in table:  # the paper's prior on Σ only (not the log-uniform variant)
        prior = table["priors.process_var"]
        table = table[prior.isna() | (prior == "variances")]
    table = table[(table["status"] == "ok") & (table["noise_std"] == _NOISE_STD)
                  & (table["num_obs"] == 20) & (table["model.process_noise_per"] == "gap")]
    cells: dict[tuple[str, float], dict[int, dict[str, Any]]] = {}
    names = [c[len("calibration."):-len(".q025")] for c in table.columns
             if c.startswith("calibration.c[") and c.endswith(".q025")]
    for _, row in table.iterrows():
        low = np.array([row[f"calibration.{n}.q025"] for n in names], dtype=float)
        high = np.array([row[f"calibration.{n}.q975"] for n in names], dtype=float)
        cells.setdefault((str(row["integrator"]), float(row["dt"])), {})[int(row["seed"])] = {
            "names": names, "midpoint": 0.5 * (low + high), "sd": (high - low) / 3.92,
            "sigma_map": float(row["process_noise_map"]),
            "sigma_median": float(row["process_noise_median"]),
            "rhat_max": float(row["rhat_max"]), "ess_min": float(row["ess_min"]),
        }
    return cells


# ----------------------------------------------------------------------------- part (a)
def discretisation(integrator: str, dt: float) -> tuple[dict[str, float], ModeFit]:
    """Part (a): the noise-free least-squares fit minus the truth, by coefficient, and the fit.

    The deterministic likelihood of noise-free data, Γ held at σ² (on noise-free data its
    maximum is at Γ → 0; holding it changes the objective by a factor, not the coefficients'
    maximiser), no prior; started at the truth.
    """
    posterior = row_posterior(integrator, dt, _data(0, 0.0), "none")
    truth = _truth(posterior)
    fit = ConditionalMode(posterior).fit(truth, fixed=("obs_var",), prior=False)
    index = _coefficients(posterior)
    names = [posterior.param_names[i] for i in index]
    return dict(zip(names, map(float, fit.theta[index] - truth[index]), strict=True)), fit


# ----------------------------------------------------------------------------- parts (b)–(d)
def _deterministic_fits(integrator: str, dt: float, seeds: Sequence[int]) -> tuple:
    """The noise-free fit and the deterministic MAPs on ``seeds``, in one compiled call."""
    datasets = [_data(0, 0.0), *(_data(s) for s in seeds)]
    posteriors = [row_posterior(integrator, dt, obs, "none") for obs in datasets]
    truth = _truth(posteriors[0])
    fitter = ConditionalMode(posteriors[0])
    fits = fitter.fit_many([truth] * len(datasets), stack_data(posteriors),
                           [("obs_var",)] + [()] * len(seeds), [False] + [True] * len(seeds))
    return truth, fits[0], fits[1:], posteriors[0]


def _sigma_fits(integrator: str, dt: float, seeds: Sequence[int],
                det: Mapping[int, np.ndarray], sigmas: Mapping[str, Mapping[int, float]]
                ) -> dict[str, dict[int, ModeFit]]:
    """The filter's MAP on each seed's data with Σ held at each option's value (started at
    the seed's deterministic MAP), in one compiled call."""
    posteriors = {s: row_posterior(integrator, dt, _data(s), "gap") for s in seeds}
    first = posteriors[seeds[0]]
    k = list(first.param_groups).index("process_var")
    jobs = [(o, s) for o in sigmas for s in seeds]
    starts = [np.insert(det[s], k, sigmas[o][s]) for o, s in jobs]
    fits = ConditionalMode(first).fit_many(
        starts, stack_data([posteriors[s] for _, s in jobs]), [("process_var",)] * len(jobs),
        [True] * len(jobs))
    out: dict[str, dict[int, ModeFit]] = {o: {} for o in sigmas}
    for (o, s), fit in zip(jobs, fits, strict=True):
        out[o][s] = fit
    return out


def _not_converged(noise_free: ModeFit, det: Mapping[int, ModeFit],
                   sigma: Mapping[str, Mapping[int, ModeFit]]) -> list[dict[str, Any]]:
    """The fits whose Newton decrement stayed above the tolerance (with the decrement)."""
    fits = [("noise-free", None, noise_free), *(("deterministic", s, f) for s, f in det.items()),
            *((f"sigma={o}", s, f) for o, by in sigma.items() for s, f in by.items())]
    return [{"fit": kind, "seed": seed, "decrement": fit.decrement}
            for kind, seed, fit in fits if not fit.converged]


def _mean_se(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = values.shape[0]
    se = values.std(axis=0, ddof=1) / np.sqrt(n) if n > 1 else np.full(values.shape[1], np.nan)
    return values.mean(axis=0), se


def decompose_row(integrator: str, dt: float, seeds: int = STUDY_SEEDS, fresh: int = 200,
                  cells: Mapping[int, Mapping[str, Any]] | None = None,
                  echo: Callable[[str], None] = print) -> dict[str, Any]:
    """Parts (a)–(d) of one (integrator, dt) row; ``cells`` (:func:`read_cells`, this row's)
    give the posterior's shift and Σ's per-seed values, without them the parts (a)–(c) with
    Σ at :data:`SIGMA_TYPICAL` only."""
    start = time.perf_counter()
    excluded = sorted(s for s, c in (cells or {}).items()
                      if s < seeds and not c["rhat_max"] <= RHAT_FAILED)
    study = [s for s in range(seeds) if s not in excluded and (cells is None or s in cells)]
    fresh_seeds = list(range(FRESH_SEED, FRESH_SEED + fresh))
    truth, noise_free, det_fits, posterior = _deterministic_fits(integrator, dt,
                                                                 study + fresh_seeds)
    index = _coefficients(posterior)
    names = [posterior.param_names[i] for i in index]
    det = {s: f.theta for s, f in zip(study + fresh_seeds, det_fits, strict=True)}
    sigmas: dict[str, dict[int, float]] = {"typical": dict.fromkeys(study, SIGMA_TYPICAL)}
    if cells is not None:
        sigmas = {"median": {s: cells[s]["sigma_median"] for s in study},
                  "map": {s: max(cells[s]["sigma_map"], 1e-14) for s in study}, **sigmas}
    sigma_fits = _sigma_fits(integrator, dt, study, det, sigmas)
    echo(f"  {integrator} dt {dt}: {len(study)} seeds, {fresh} fresh, "
         f"{time.perf_counter() - start:.0f} s")

    disc = noise_free.theta[index] - truth[index]
    reused = np.array([det[s][index] for s in study]) - truth[index] - disc
    fresh_shift = np.array([det[s][index] for s in fresh_seeds]) - truth[index] - disc
    k = next(iter(sigma_fits))  # process_var follows the coefficients: same indices
    parts = {"discretisation": disc, "noise_reused": _mean_se(reused)[0]}
    parts["noise_fresh"], fresh_se = _mean_se(fresh_shift)
    sigma_parts = {o: _mean_se(np.array([fits[s].theta[index] - det[s][index]
                                         for s in study]))[0] for o, fits in sigma_fits.items()}
    parts["sigma"] = sigma_parts[k]
    row: dict[str, Any] = {
        "integrator": integrator, "dt": dt, "seeds": study, "excluded_seeds": excluded,
        "fresh": fresh, "sigma_option": k, "noise_free_converged": noise_free.converged,
        "fits_not_converged": _not_converged(noise_free, dict(zip(study + fresh_seeds,
                                                                  det_fits, strict=True)),
                                             sigma_fits),
        "coefficients": {},
    }
    sd = None
    if cells is not None:
        midpoints = np.array([cells[s]["midpoint"] for s in study])
        sd = np.array([cells[s]["sd"] for s in study]).mean(axis=0)
        parts["total"] = (midpoints - truth[index]).mean(axis=0)
        parts["remainder"] = parts["total"] - disc - parts["noise_reused"] - parts["sigma"]
    for j, name in enumerate(names):
        entry = {"truth": float(truth[index][j]),
                 **{p: float(v[j]) for p, v in parts.items()},
                 "noise_fresh_se": float(fresh_se[j]),
                 "sigma_options": {o: float(v[j]) for o, v in sigma_parts.items()}}
        if sd is not None:
            entry["posterior_sd"] = float(sd[j])
        row["coefficients"][name] = entry
    row["wall_time_s"] = time.perf_counter() - start
    return row


# ----------------------------------------------------------------------------- the study
def run_shift_study(out_dir: str | Path, cells: str | Path | None = None,
                    budget: str = "full", echo: Callable[[str], None] = print,
                    compute: bool = True) -> dict[str, Any]:
    """Decompose every row of the budget (:data:`BUDGETS`) and write ``decomposition.json``,
    ``report.md`` and ``figures/`` into ``out_dir`` (:mod:`._shift_report`). ``cells``: a
    paper-claims study folder, for the totals, Σ's per-seed values and the remainders.

    Each finished row and noise-free fit is kept in ``out_dir/parts/`` at once, so that an
    interrupted study resumes where it stopped (a rerun with the same budget and cells skips
    them); ``decomposition.json`` is rewritten after each, with what is finished so far.
    ``compute=False`` computes nothing: it reports the parts the folder holds, the others
    listed as ``pending``.
    """
    from symplid.studies._shift_report import write_shift_report

    if budget not in BUDGETS:
        raise ValueError(f"budget must be one of {', '.join(BUDGETS)}, got {budget!r}")
    plan = BUDGETS[budget]
    out = Path(out_dir)
    table = read_cells(cells) if cells is not None else {}
    tag = f"{budget}-{'cells' if cells is not None else 'nocells'}"
    rows: list[dict[str, Any]] = []
    noise_free: dict[str, dict[str, dict[str, Any]]] = {}
    integrators = list(dict.fromkeys(i for i, _ in plan["rows"]))
    jobs = [("row", i, dt) for i, dt in plan["rows"]]
    jobs += [("noise-free", i, dt) for i in integrators for dt in plan["dts"]
             if (i, dt) not in plan["rows"]]
    pending: list[str] = []
    for kind, integrator, dt in jobs:
        path = out / "parts" / f"{tag}-{kind}-{integrator}-{dt:g}.json"
        if not compute and not path.is_file():
            pending.append(f"{kind} {integrator} dt {dt:g}")
            continue
        part = _part(path, lambda k=kind, i=integrator, d=dt: _job(k, i, d, plan,
                                                                   table if cells else None,
                                                                   echo))
        if kind == "row":
            rows.append(part)
            noise_free.setdefault(integrator, {})[str(dt)] = {
                **{n: c["discretisation"] for n, c in part["coefficients"].items()},
                "converged": part["noise_free_converged"]}
        else:
            noise_free.setdefault(integrator, {})[str(dt)] = part
        _write(out, budget, plan, cells, rows, noise_free, pending)
    _write(out, budget, plan, cells, rows, noise_free, pending,
           posterior_totals(table, plan["seeds"]) if cells is not None else {})
    return write_shift_report(out)


def study_from_options(out: Path, cells: Path | None, budget: str, report_only: bool,
                       echo: Callable[[str], None] = print) -> str:
    """``symplid study shift``: run (or, ``report_only``, report) the study; its last line."""
    from symplid.workflow._commandline import UserError

    if report_only and not (Path(out) / "parts").is_dir():
        raise UserError(f"{out} holds no finished parts (parts/) to report on")
    run_shift_study(out, cells=cells, budget=budget, echo=echo, compute=not report_only)
    return f"{out}: decomposition.json, report.md and figures/"


def _job(kind: str, integrator: str, dt: float, plan: Mapping[str, Any],
         table: Mapping[tuple[str, float], Any] | None, echo: Callable[[str], None]
         ) -> dict[str, Any]:
    if kind == "row":
        return decompose_row(integrator, dt, plan["seeds"], plan["fresh"],
                             None if table is None else table.get((integrator, float(dt))),
                             echo)
    shifts, fit = discretisation(integrator, dt)
    echo(f"  {integrator} dt {dt}: noise-free fit")
    return {**shifts, "converged": fit.converged}


def _part(path: Path, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """The JSON at ``path`` if a run before this one left it, else ``compute()`` stored there."""
    from symplid.workflow._results import read_json, write_json

    if path.is_file():
        return read_json(path)
    value = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(value, path)
    return value


def posterior_totals(table: Mapping[tuple[str, float], Mapping[int, Mapping[str, Any]]],
                     seeds: int = STUDY_SEEDS) -> dict[str, dict[str, dict[str, Any]]]:
    """Every (integrator, dt) of the cells (:func:`read_cells`): each coefficient's
    posterior shift (interval midpoint − truth) and posterior sd averaged over the converged
    seeds below ``seeds``, for the fit of the shift against dt² (no fits needed)."""
    posterior = row_posterior("leapfrog", 0.25, _data(0, 0.0), "none")
    truth = dict(zip(posterior.param_names, _truth(posterior), strict=True))
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (integrator, dt), by_seed in sorted(table.items(), key=lambda kv: (kv[0][0],
                                                                           -kv[0][1])):
        ok = [c for s, c in by_seed.items() if s < seeds and c["rhat_max"] <= RHAT_FAILED]
        if not ok:
            continue
        names = ok[0]["names"]
        shift = (np.array([c["midpoint"] for c in ok])
                 - np.array([truth[n] for n in names])).mean(axis=0)
        sd = np.array([c["sd"] for c in ok]).mean(axis=0)
        out.setdefault(integrator, {})[f"{dt:g}"] = {
            "seeds": len(ok), **{n: {"total": float(m), "posterior_sd": float(d)}
                                 for n, m, d in zip(names, shift, sd, strict=True)}}
    return out


def _write(out: Path, budget: str, plan: Mapping[str, Any], cells: Any,
           rows: list[dict[str, Any]], noise_free: Mapping[str, Any],
           pending: Sequence[str] = (), totals: Mapping[str, Any] | None = None) -> None:
    from symplid.workflow._results import write_json

    by_dt = {i: dict(sorted(v.items(), key=lambda kv: -float(kv[0])))
             for i, v in noise_free.items()}
    result = {"setting": {"system": "henon-heiles", "noise_std": _NOISE_STD, "num_obs": 20,
                          "obs_interval": 5.0, "process_noise_per": "gap"},
              "budget": {"name": budget, "seeds": plan["seeds"], "fresh": plan["fresh"],
                         "fresh_seed": FRESH_SEED, "sigma_typical": SIGMA_TYPICAL,
                         "rhat_failed": RHAT_FAILED},
              "cells": None if cells is None else str(cells),
              "rows": rows, "discretisation": by_dt, "pending": list(pending),
              "posterior_totals": dict(totals or {})}
    out.mkdir(parents=True, exist_ok=True)
    write_json(result, out / "decomposition.json")


# ----------------------------------------------------------------------------- on the sweep
#: The keys of a cell of the ``"shift"`` experiment: one row of the decomposition.
CELL_KEYS: dict[str, Spec] = {
    "integrator": Spec(str, "leapfrog", "learning propagator", choices=INTEGRATORS),
    "dt": Spec(float, 0.25, "learning step (eq. 14)", minimum=0.0, strict=True),
    "seeds": Spec(int, STUDY_SEEDS, "the paper-claims study's seeds 0..seeds-1", minimum=1),
    "fresh": Spec(int, 200, "fresh data seeds for part (b)", minimum=2),
    "cells": Spec(str, "", "a paper-claims study folder (empty: no totals)"),
}


def run_cell(cell: dict[str, Any]) -> dict[str, Any]:
    """One row on the sweep (:func:`decompose_row`), as flat metrics
    ``shift.<coefficient>.<part>``."""
    cells = read_cells(cell["cells"]).get((str(cell["integrator"]), float(cell["dt"]))) \
        if cell.get("cells") else None
    row = decompose_row(str(cell["integrator"]), float(cell["dt"]), int(cell["seeds"]),
                        int(cell["fresh"]), cells, echo=lambda _: None)
    metrics: dict[str, Any] = {f"shift.{name}.{part}": value
                               for name, c in row["coefficients"].items()
                               for part, value in c.items() if isinstance(value, float)}
    metrics["fits_not_converged"] = len(row["fits_not_converged"])
    metrics["excluded_seeds"] = len(row["excluded_seeds"])
    metrics["wall_time_s"] = row["wall_time_s"]
    return metrics


#: The study's experiment (listed in :data:`symplid.studies.STUDIES`): a sweep over rows.
EXPERIMENT = Experiment(
    "shift",
    CELL_KEYS,
    run_cell,
    metrics=("fits_not_converged", "wall_time_s"),
    description="the paper-claims coefficient shift split into discretisation, noise "
    "draws, process noise and remainder, one (integrator, dt) row per cell",
)
