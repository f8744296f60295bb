"""The seed paper's experiment (Section IV): Hénon–Heiles learned with leapfrog against RK2.

``reproduce`` runs it end to end: the truth and the data, then for each propagator a full fit
(MAP, Hessian, DRAM with the paper's budget) in its own run folder, the predictions with
leapfrog at the fine step for 200 s from the true initial state, the paper's four figures,
``summary.json`` and a table beside the paper's numbers. The two fits run in parallel
processes (one per core).

Conventions: the paper's θ1..θ9 are the coefficients of −U; this library reports U's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from symplid import runtime
from symplid.dynamics._damping import with_damping
from symplid.dynamics._potentials import hamiltonian
from symplid.dynamics._systems import get_system
from symplid.inference._predict import predict_trajectory, prediction_horizon
from symplid.model._data import Observations
from symplid.model._simulate import simulate, true_trajectory
from symplid.sampling import draws_array
from symplid.studies._paper_calibration import cell_calibration, true_values
from symplid.studies._paper_cells import (
    CELL_KEYS,
    PAPER_MAP,
    PAPER_MODEL,
    PAPER_PRIORS,
    PAPER_SAMPLER,
    SWEEP_METRICS,
    cell_data,
    known_initial_state,
    system_defaults,
)
from symplid.studies._paper_figures import approach_predictions, draw_figures, figure_truth
from symplid.workflow._experiment import Experiment
from symplid.workflow._fit import SampledDraws, fit
from symplid.workflow._results import RunFolder
from symplid.workflow._settings import Settings, merge_overrides
from symplid.workflow._worker_pool import WorkerPool, post

__all__ = [
    "CELL_KEYS",
    "EXPERIMENT",
    "ApproachResult",
    "PaperConfig",
    "analyse_approach",
    "cell_data",
    "paper_settings",
    "reproduce",
    "run_cell",
    "truth_path",
]

# What the paper reports (Section IV, Figs 2–4), for the table printed beside ours.
PAPER = {
    "true_hamiltonian": 0.1227,
    "leapfrog": {"map_hamiltonian": 0.1219, "prediction_horizon_s": 150.0},
    "rk2": {"map_hamiltonian": 0.1211, "prediction_horizon_s": 20.0},
    "process_noise_ratio": 10.0,
}

APPROACHES = ("leapfrog", "rk2")
#: |q1 − q1_true| that ends a valid prediction (``docs/explanation/conventions.md``)
HORIZON_THRESHOLD = 0.1
QUICK = {"iterations": 3000, "burn_in": 1500, "chains": 2, "num_starts": 2, "num_paths": 20}
TRUTH_DT = 1e-3


@dataclasses.dataclass(frozen=True)
class PaperConfig:
    """Settings of one reproduction (defaults: the paper's budget, 4 chains)."""

    seed: int = 0
    chains: int = 4
    iterations: int = 200_000
    burn_in: int | None = None  # None: half the iterations, the paper's 100,000 of 200,000
    rk2: str = "rk2-midpoint"
    num_starts: int = 4
    num_paths: int = 100
    noise_std: float = 0.05
    num_obs: int = 20
    obs_interval: float = 5.0
    dt: float = 0.25
    order: int = 3
    t_end: float = 200.0
    prediction_dt: float = 0.01
    workers: int = 2

    @classmethod
    def quick(cls, **overrides: Any) -> PaperConfig:
        """A small budget for smoke tests (well under a minute on two cores)."""
        base = {
            "iterations": QUICK["iterations"],
            "burn_in": QUICK["burn_in"],
            "chains": QUICK["chains"],
            "num_starts": QUICK["num_starts"],
            "num_paths": QUICK["num_paths"],
        }
        base.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**base)

    @property
    def resolved_burn_in(self) -> int:
        return self.iterations // 2 if self.burn_in is None else self.burn_in

    def integrator(self, approach: str) -> str:
        return "leapfrog" if approach == "leapfrog" else self.rk2


def paper_data(config: PaperConfig) -> tuple[Observations, Any]:
    """The experiment's truth and data: 20 full-state observations, σ = 0.05, seeded."""

    system = get_system("henon-heiles")
    times = config.obs_interval * np.arange(1, config.num_obs + 1)
    obs = simulate(system, times=times, noise_std=config.noise_std, seed=config.seed)
    return obs, system


def paper_settings(config: PaperConfig, approach: str) -> Settings:
    """Run settings for one approach: the paper's priors and DRAM, known initial state."""
    system = get_system("henon-heiles")
    return merge_overrides(
        Settings(),
        {
            "seed": config.seed,
            "model.order": config.order,
            "model.integrator": config.integrator(approach),
            "model.dt": config.dt,
            **{f"model.{key}": value for key, value in PAPER_MODEL.items()},
            **{f"sampler.{key}": value for key, value in PAPER_SAMPLER.items()},
            **{f"map.{key}": value for key, value in PAPER_MAP.items()},
            **{f"priors.{key}": value for key, value in PAPER_PRIORS.items()},
            "initial_state.x0": [float(v) for v in system.initial_state],
            "map.num_starts": config.num_starts,
            "sampler.num_iterations": config.iterations,
            "sampler.burn_in": config.resolved_burn_in,
            "sampler.num_chains": config.chains,
            "prediction.dt": config.prediction_dt,
            "prediction.t_end": config.t_end,
            "prediction.num_paths": config.num_paths,
        },
    )


def _limit_threads() -> None:
    """One XLA thread per process: the parallelism is across processes."""
    runtime.limit_threads()


def _fit_one(args: tuple[PaperConfig, str, str, bool, int]) -> dict[str, Any]:
    """Fit one approach into ``out/approach`` (runs in a worker process).

    As soon as its sampler ends, the approach's draws and its prediction paths for the
    figures are posted to the parent (:func:`~symplid.workflow._worker_pool.post`), which draws
    the figures while this process summarises the draws and writes them; the return value is
    the fit's summary and timings (all in memory: the parent reads no file).
    """
    config, approach, out, progress, position = args
    _limit_threads()
    runtime.enable_compilation_cache()
    runtime.one_line_warnings()  # one line per warning, as in the parent process

    obs, system = paper_data(config)

    def sampled(done: SampledDraws) -> None:
        result = ApproachResult(approach, config.integrator(approach),
                                np.asarray(done.map_result.theta, dtype=float), done.draws,
                                done.param_names, {})  # its summary follows with the return
        post({"approach": approach, "result": result, "cores": runtime.own_cores(),
              "predictions": approach_predictions(result, system, config)})

    outcome = fit(
        obs,
        paper_settings(config, approach),
        out=Path(out) / approach,
        progress=progress,
        progress_label=f"DRAM {approach}",
        progress_position=position,
        overwrite=True,
        on_sampled=sampled,
    )
    return {"approach": approach, "timings": outcome.timings, "interrupted": outcome.interrupted,
            "summary": outcome.summary}


def fit_pool(config: PaperConfig, out: Path, progress: bool = True,
             workers: int | None = None) -> WorkerPool:
    """Both approaches' fits (:func:`_fit_one`), in parallel pinned processes when ``workers``
    > 1; a context manager that starts them (:class:`~symplid.workflow._worker_pool.WorkerPool`)."""
    workers = config.workers if workers is None else workers
    jobs = [(config, a, str(out), progress, i) for i, a in enumerate(APPROACHES)]
    return WorkerPool(_fit_one, jobs, workers)


#: The parameters that may follow the coefficients in θ (the first present ends them).
_AFTER_COEFFICIENTS = ("gamma", "process_var", "obs_var", "obs_rel_var")


@dataclasses.dataclass
class ApproachResult:
    """Everything the figures and the summary need from one approach."""

    name: str
    integrator: str
    map_theta: np.ndarray
    draws: np.ndarray  # (chain, draw, param)
    param_names: tuple[str, ...]
    fit_summary: dict[str, Any]

    @property
    def coefficients_map(self) -> np.ndarray:
        return self.map_theta[: self.num_coefficients]

    @property
    def num_coefficients(self) -> int:
        """The coefficients lead θ; the first of γ, Σ and the observation variance ends them
        (a model without process noise has no Σ)."""
        names = self.param_names
        return min(names.index(n) for n in _AFTER_COEFFICIENTS if n in names)

    @property
    def gamma_map(self) -> float | None:
        """The MAP damping rate of a damped fit (None for an undamped one)."""
        names = self.param_names
        return float(self.map_theta[names.index("gamma")]) if "gamma" in names else None

    @property
    def process_noise_draws(self) -> np.ndarray | None:
        """The process variance's draws (None for a model without process noise)."""
        if "process_var" not in self.param_names:
            return None
        return self.draws[..., self.param_names.index("process_var")].ravel()

    @property
    def coefficient_draws(self) -> np.ndarray:
        return self.draws[..., : self.num_coefficients].reshape(-1, self.num_coefficients)


def load_approach(out: Path, approach: str, integrator: str) -> ApproachResult:
    """Read one approach's run folder back (``reproduce`` has its results in memory: this is
    for a folder written earlier)."""

    folder = RunFolder(out / approach, "r", allow_incomplete=True)
    map_info = folder.read_map()
    idata = folder.read_posterior()
    names = tuple(map_info["param_names"])
    return ApproachResult(
        approach,
        integrator,
        np.asarray(map_info["theta"], dtype=float),
        draws_array(idata),
        names,
        folder.read_summary(),
    )


#: The keys of an approach's summary taken from its fit's summary (None where it has none).
FIT_FIGURES = ("acceptance_rate", "rhat_max", "ess_min", "restarted_chains")


def analyse_approach(
    result: ApproachResult,
    system,
    truth_times: np.ndarray,
    truth: np.ndarray,
    t_end: float,
    prediction_dt: float,
    threshold: float = HORIZON_THRESHOLD,
    prediction_integrator: str = "leapfrog",
) -> dict[str, Any]:
    """The summary numbers of one approach (the keys of ``summary.json``).

    H is evaluated at the true initial state under the learned potential (the learned model's
    energy along its own leapfrog path from there); the horizon is the first time the MAP
    path, integrated by leapfrog (or ``prediction_integrator``: a non-separable system needs
    another) at ``prediction_dt``, leaves the truth by ``threshold`` in q1.
    """

    x0 = system.initial_state
    h_true = float(hamiltonian(system.potential, system.coefficients, x0))
    h_map = float(hamiltonian(system.potential, result.coefficients_map, x0))
    params, integrator = result.coefficients_map, prediction_integrator
    if result.gamma_map is not None:  # a damped fit predicts with its γ
        params = np.append(params, result.gamma_map)
        integrator = with_damping(prediction_integrator)
    times, path = predict_trajectory(
        system.potential, params, x0, t_end, dt=prediction_dt, integrator=integrator
    )
    truth_on_grid = np.stack([np.interp(times, truth_times, col) for col in truth.T], axis=1)
    horizon = prediction_horizon(times, path, truth_on_grid, threshold, 0)
    damping = {} if result.gamma_map is None else {"gamma_map": result.gamma_map}
    return {
        **damping,
        "integrator": result.integrator,
        "map_hamiltonian": h_map,
        "hamiltonian_rel_error": abs(h_map - h_true) / h_true,
        **_process_noise(result),
        "prediction_horizon_s": float(horizon),
        **_fit_figures(result.fit_summary),
        "map": dict(zip(result.param_names, result.map_theta.tolist(), strict=True)),
    }


def _process_noise(result: ApproachResult) -> dict[str, float | None]:
    """The process variance's MAP, median and central 95 % interval (all None for a model
    without process noise, ``model.process_noise_per = "none"``: it has no such parameter)."""
    noise = result.process_noise_draws
    if noise is None:
        return dict.fromkeys(("process_noise_map", "process_noise_median",
                              "process_noise_q025", "process_noise_q975"))
    return {
        "process_noise_map": float(result.map_theta[result.param_names.index("process_var")]),
        "process_noise_median": float(np.median(noise)),
        "process_noise_q025": float(np.quantile(noise, 0.025)),
        "process_noise_q975": float(np.quantile(noise, 0.975)),
    }


def truth_path(system, t_end: float, prediction_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The true trajectory on the prediction grid (leapfrog at dt = 1e-3, Section IV; the
    system's own truth integrator for a non-separable one, its damped form for a damped
    system)."""

    n = round(t_end / prediction_dt)
    times = prediction_dt * np.arange(1, n + 1)
    states = true_trajectory(
        system.potential, system.coefficients, system.initial_state, times, TRUTH_DT,
        system.truth_integrator, damping=system.damping,
    )
    return np.concatenate([[0.0], times]), np.concatenate([system.initial_state[None], states])


def reproduce(
    out: str | Path,
    config: PaperConfig | None = None,
    progress: bool = True,
    echo: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the paper's experiment end to end into ``out``; returns ``summary.json``'s content."""

    config = config or PaperConfig()
    out = Path(out)
    start = time.perf_counter()
    folder = RunFolder(out, "w", overwrite=True, identity="config.json")  # an earlier reproduce
    # the workers start first: they load while this process makes the data
    with contextlib.ExitStack() as stack, fit_pool(config, out, progress) as pool:
        obs, system = paper_data(config)
        folder.write_data(obs)
        folder.write_json("config.json", dataclasses.asdict(config))
        echo(
            f"Hénon–Heiles, seed {config.seed}: {config.num_obs} observations, σ = "
            f"{config.noise_std}; {config.chains} chains × {config.iterations:,} DRAM "
            f"iterations per approach ({config.resolved_burn_in:,} burn-in)"
        )
        sampled, analysed, truth_times, truth, prepared = {}, {}, None, None, None
        for done in pool.messages():  # each approach's draws, as soon as its sampler ends
            sampled[done["approach"]] = done
            if truth is None:  # not before: the workers have both cores until one ends
                # from now on on the core of the fit that is done sampling, not the other's
                stack.enter_context(runtime.cores_for_a_while(done["cores"]))
                truth_times, truth = truth_path(system, config.t_end, config.prediction_dt)
                prepared = figure_truth(system, truth_times, truth, config)
            if len(sampled) < len(APPROACHES):  # the other one samples: analyse this one
                analysed[done["approach"]] = analyse_approach(
                    done["result"], system, truth_times, truth, config.t_end,
                    config.prediction_dt)
        results = {a: sampled[a]["result"] for a in APPROACHES}
        # the figures and the last analysis, while the workers summarise and write their draws
        draw_figures(folder, results, system, obs, truth_times, truth, config, progress,
                     predictions={a: sampled[a]["predictions"] for a in APPROACHES},
                     prepared=prepared)
        for name in [a for a in APPROACHES if a not in analysed]:
            analysed[name] = analyse_approach(results[name], system, truth_times, truth,
                                              config.t_end, config.prediction_dt)
        fitted = {done["approach"]: done for done in pool.results()}
    h_true = hamiltonian(system.potential, system.coefficients, system.initial_state)
    summary: dict[str, Any] = {"true_hamiltonian": float(h_true)}
    for name in APPROACHES:  # the analysis with the fits' convergence figures filled in
        summary[name] = {**analysed[name], **_fit_figures(fitted[name]["summary"])}
    summary["process_noise_ratio"] = (
        summary["rk2"]["process_noise_median"] / summary["leapfrog"]["process_noise_median"]
    )
    summary["seed"] = config.seed
    summary["wall_time_s"] = time.perf_counter() - start
    table = comparison_table(summary)
    folder.write_summary(summary, table)
    folder.write_report(report_text(summary, table, config))
    folder.finish(required=("data.csv", "summary.json"))
    echo(table)
    echo(f"Run folder: {out}  (wall time {summary['wall_time_s']:.0f} s)")
    return summary


def _fit_figures(fit_summary: dict[str, Any]) -> dict[str, Any]:
    """The figures of an approach's summary that come from its fit's summary."""
    return {key: fit_summary.get(key) for key in FIT_FIGURES}


def comparison_table(summary: dict[str, Any]) -> str:
    """This run's numbers beside the paper's (Section IV)."""
    lf, rk = summary["leapfrog"], summary["rk2"]
    rows = [
        ("true H", f"{summary['true_hamiltonian']:.4f}", f"{PAPER['true_hamiltonian']:.4f}"),
        ("MAP H, leapfrog", f"{lf['map_hamiltonian']:.4f}", "0.1219"),
        ("MAP H, RK2", f"{rk['map_hamiltonian']:.4f}", "0.1211"),
        ("|ΔH|/H, leapfrog", f"{lf['hamiltonian_rel_error']:.2%}", "0.7%"),
        ("|ΔH|/H, RK2", f"{rk['hamiltonian_rel_error']:.2%}", "1.3%"),
        ("process noise median, leapfrog", f"{lf['process_noise_median']:.2e}", ""),
        ("process noise median, RK2", f"{rk['process_noise_median']:.2e}", ""),
        ("process noise RK2 / leapfrog", f"{summary['process_noise_ratio']:.1f}", "≈ 10"),
        ("valid prediction, leapfrog [s]", f"{lf['prediction_horizon_s']:.1f}", "≈ 150"),
        ("valid prediction, RK2 [s]", f"{rk['prediction_horizon_s']:.1f}", "≈ 20"),
        ("acceptance, leapfrog / RK2", _pair(lf, rk, "acceptance_rate", "{:.2f}"), ""),
        ("max R-hat, leapfrog / RK2", _pair(lf, rk, "rhat_max", "{:.3f}"), ""),
        ("min bulk ESS, leapfrog / RK2", _pair(lf, rk, "ess_min", "{:.0f}"), ""),
    ]
    width = max(len(r[0]) for r in rows)
    lines = [f"{'':<{width}}  {'this run':>14}  {'paper':>8}"]
    lines += [f"{a:<{width}}  {b:>14}  {c:>8}" for a, b, c in rows]
    return "\n".join(lines)


def _pair(a: dict, b: dict, key: str, fmt: str) -> str:
    def one(d: dict) -> str:
        v = d.get(key)
        return "n/a" if v is None else fmt.format(v)

    return f"{one(a)} / {one(b)}"


def report_text(summary: dict[str, Any], table: str, config: PaperConfig) -> str:
    """``report.md`` of a reproduction: the table and the four figures."""
    return f"""# Hénon–Heiles: leapfrog against RK2 ({config.rk2})

Seed {config.seed}; {config.chains} chains × {config.iterations:,} DRAM iterations per approach,
the first {config.resolved_burn_in:,} discarded; wall time {summary["wall_time_s"]:.0f} s.
Coefficients are those of U (the paper's θ1..θ9 are those of −U).

```
{table}
```

![Phase portraits](figures/fig1_phase_portraits.png)

![Hamiltonians](figures/fig2_hamiltonians.png)

![q1 with posterior bands](figures/fig3_trajectories.png)

![Process-noise posteriors](figures/fig4_process_noise.png)

Per-approach runs (settings, data, MAP, Hessian, posterior) are in `leapfrog/` and `rk2/`.
"""


def sweep_figures(table: Any, folder: str | os.PathLike, settings: list[str]) -> dict[str, Path]:
    """One figure per metric, the propagators in the paper's colours."""
    from symplid.plotting import COLORS  # matplotlib only where figures are drawn
    from symplid.plotting._sweep import plot_sweep

    metrics = [m for m in SWEEP_METRICS if m in table.columns] or None
    colors = {"leapfrog": COLORS["leapfrog"], PaperConfig.rk2: COLORS["rk2"]}
    return plot_sweep(
        table, folder, metrics, settings=settings, hue="integrator", colors=colors
    )


def run_cell(cell: dict[str, Any]) -> dict[str, Any]:
    """One cell of a sweep: simulate, fit (MAP + sampler), predict; returns flat metrics.

    ``cell`` holds the keys of :data:`CELL_KEYS` (and dotted run settings); the metrics are
    those of ``summary.json`` for one approach, plus the true H and the wall time.
    """

    start = time.perf_counter()
    system, obs = cell_data(cell)
    from symplid.workflow._sweep import cell_settings  # the sweep (and its figures) only here

    settings = cell_settings(cell, experiment=EXPERIMENT)
    outcome = fit(obs, settings, out=None, progress=False)
    integrator = settings.model.integrator
    result = ApproachResult(
        integrator,
        integrator,
        np.asarray(outcome.map_result.theta, dtype=float),
        draws_array(outcome.idata),
        tuple(outcome.posterior.param_names),
        outcome.summary,
    )
    p = settings.prediction
    truth_times, truth = _cached_truth_path(cell.get("system", "henon-heiles"), p.t_end, p.dt)
    metrics = analyse_approach(
        result,
        system,
        truth_times,
        truth,
        p.t_end,
        p.dt,
        float(cell.get("horizon_tol", HORIZON_THRESHOLD)),
        p.integrator,
    )
    metrics.pop("map")
    metrics["true_hamiltonian"] = float(
        hamiltonian(system.potential, system.coefficients, system.initial_state)
    )
    truth_theta = true_values(system, outcome.model, float(cell_data_noise(cell, system)))
    metrics["calibration"] = cell_calibration(result.param_names, result.draws, truth_theta)
    if outcome.learning_step is not None:  # dt = "auto": the step the fit chose
        metrics["learning_dt"] = float(outcome.learning_step["dt"])
        metrics["learning_step_s"] = outcome.timings.get("learning_step_s")
    metrics["map_s"] = outcome.timings.get("map_s")
    metrics["sampler_s"] = outcome.timings.get("sampler_s")
    metrics["wall_time_s"] = time.perf_counter() - start
    return metrics


def cell_data_noise(cell: dict[str, Any], system: Any) -> float:
    """The observation-noise σ of a cell (the system's when the cell leaves it out)."""
    return float(cell.get("noise_std", system.noise_std))


@functools.lru_cache(maxsize=8)
def _cached_truth_path(name: str, t_end: float, prediction_dt: float):
    """:func:`truth_path` once per system and grid in a worker process (every seed of a sweep
    shares the truth: only the data's noise differs)."""
    times, states = truth_path(get_system(name), t_end, prediction_dt)
    times.setflags(write=False)
    states.setflags(write=False)
    return times, states


EXPERIMENT = Experiment(
    "paper",
    CELL_KEYS,
    run_cell,
    metrics=SWEEP_METRICS,
    figures=sweep_figures,
    description="The seed paper's Hénon–Heiles fit (Section IV), one data set and "
    "propagator per cell",
    defaults=system_defaults,
    base_settings=known_initial_state,
    renamed={"num_samples": "num_iterations"},
)
