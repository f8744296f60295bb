"""The commands that make or read one run: reproduce, simulate, fit, predict, report.

The commands parse their options and print; what they do is :mod:`symplid.workflow`
(:mod:`~symplid.workflow._fit_command`, :mod:`~symplid.workflow._run_tools`, ...). Every user
mistake ends with one line on stderr and exit code 2 (:func:`~symplid.cli._errors.user_errors`);
Ctrl-C (exit code 130) and SIGTERM (143) keep whatever the sampler had drawn and say
"interrupted".
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import click

from symplid.cli._errors import Interrupted, user_errors
from symplid.cli._options import (
    LazyChoice,
    RegistryOption,
    config_option,
    integrator_registry,
    no_progress_option,
    noise_model_names,
    potential_registry,
    quiet_option,
    rk2_variants,
    sampler_registry,
    sets_option,
)
from symplid.workflow._commandline import UserError, floats, model_text, time_or_word
from symplid.workflow._fit_command import (
    diagnostics_lines,
    fit_result_line,
    report_after_fit,
    run_fit,
    simulate_to_file,
)

__all__ = ["fit", "predict", "report", "reproduce", "simulate"]


# ----------------------------------------------------------------------------- reproduce
@click.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("runs/paper"),
    show_default=True,
    help="Run folder to write.",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Seed of the data noise and of the sampler.",
)
@click.option(
    "--chains",
    type=click.IntRange(min=1),
    default=None,
    help="Chains per approach [default: 4; 2 with --quick].",
)
@click.option(
    "--iterations",
    type=click.IntRange(min=2),
    default=None,
    help="DRAM iterations per chain, burn-in included [default: 200000].",
)
@click.option(
    "--burn-in",
    type=click.IntRange(min=0),
    default=None,
    help="Iterations discarded per chain [default: half of --iterations].",
)
@click.option(
    "--rk2",
    type=LazyChoice(rk2_variants),
    default="midpoint",
    show_default=True,
    help="The non-symplectic RK2 variant.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=2,
    show_default=True,
    help="Processes (the two approaches run in parallel).",
)
@click.option("--quick", is_flag=True, help="A small budget for a smoke test (under a minute).")
@no_progress_option
@user_errors
def reproduce(out, seed, chains, iterations, burn_in, rk2, workers, quick, no_progress) -> None:
    """The paper's Hénon–Heiles experiment: leapfrog against RK2, all figures and a table."""
    from symplid.studies._paper import PaperConfig
    from symplid.studies._paper import reproduce as run

    overrides = {
        "seed": seed,
        "chains": chains,
        "iterations": iterations,
        "burn_in": burn_in,
        "rk2": f"rk2-{rk2}",
        "workers": workers,
    }
    if quick:
        config = PaperConfig.quick(**overrides)
    else:
        config = PaperConfig(**{k: v for k, v in overrides.items() if v is not None})
    if config.resolved_burn_in >= config.iterations:
        raise UserError(
            f"--burn-in ({config.resolved_burn_in}) must be below --iterations "
            f"({config.iterations})"
        )
    summary = run(out, config, progress=not no_progress, echo=click.echo)
    lf, rk = summary["leapfrog"], summary["rk2"]
    click.echo(
        f"H: true {summary['true_hamiltonian']:.4f}, leapfrog {lf['map_hamiltonian']:.4f}, "
        f"RK2 {rk['map_hamiltonian']:.4f}; process noise ratio "
        f"{summary['process_noise_ratio']:.1f}; valid predictions {lf['prediction_horizon_s']:.0f}"
        f" s vs {rk['prediction_horizon_s']:.0f} s; {summary['wall_time_s']:.0f} s"
    )


# ----------------------------------------------------------------------------- simulate
@click.command(epilog="SYSTEM is one of the registered systems (symplid.SYSTEMS).")
@click.argument("system", type=str)
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="Data file to write (.csv or .npz).",
)
@click.option(
    "--t-end",
    type=float,
    default=None,
    help="Last observation time [default: the system's schedule].",
)
@click.option(
    "--num-obs",
    type=click.IntRange(min=1),
    default=None,
    help="Number of equally spaced observations up to --t-end.",
)
@click.option(
    "--times", type=str, default=None, help="Explicit observation times, comma-separated."
)
@click.option(
    "--noise-std",
    type=click.FloatRange(min=0),
    default=None,
    help="Observation noise standard deviation [default: the system's, 0.05].",
)
@click.option(
    "--seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Seed of the observation noise (and of --missing).",
)
@click.option(
    "--observation",
    type=click.Choice(["full", "positions"]),
    default=None,
    help="Observe the full state, or the positions only [default: the system's; the "
    "double pendulum's angles, the full state otherwise].",
)
@click.option("--observation-noise", type=LazyChoice(noise_model_names), default="additive",
              show_default=True, help="Observation noise (multiplicative: y = h(x)(1 + ε)).")
@click.option("--rel-std", type=click.FloatRange(min=0), default=0.05, show_default=True,
              help="Standard deviation of the relative noise ε of multiplicative noise.")
@click.option("--x0", type=str, default=None, help="Initial state q1..qd,p1..pd (comma-separated).")
@click.option(
    "--missing",
    type=click.FloatRange(0, 1, max_open=True),
    default=0.0,
    show_default=True,
    help="Fraction of values to blank out at random (NaN).",
)
@click.option("--force", "force", type=str, default=None,
              help="Drive the system: a force in q, p, u1, t and numbers (e.g. '0.8*u1 - "
              "0.1*p1'); the file gets an input column u1 on a 5× denser grid.")
@click.option("--input", "signal", type=str, default="multisine", show_default=True,
              help="The input u1 of --force: multisine, chirp, steps, or a CSV t,u1.")
@click.option("--input-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Seed of the input's random phases or levels.")
@click.option("--input-amplitude", type=float, default=1.0, show_default=True,
              help="RMS (multisine) or amplitude of the input.")
@user_errors
def simulate(system, out, t_end, num_obs, times, noise_std, seed, observation, observation_noise,
             rel_std, x0, missing, force, signal, input_seed, input_amplitude) -> None:
    """Noisy observations of a named SYSTEM (see --help for the names)."""
    if force is not None:
        from symplid.workflow._driven import simulate_driven

        if times or x0 or missing or observation_noise != "additive":
            raise UserError("--force simulates on a regular grid from the system's x0 with "
                            "additive noise: drop --times, --x0, --missing, --observation-noise")
        click.echo(simulate_driven(system, out, force, signal, input_seed, input_amplitude,
                                   t_end, num_obs, noise_std, seed, observation))
        return
    click.echo(simulate_to_file(system, out, t_end, num_obs, times, noise_std, seed,
                                observation, x0, missing, observation_noise, rel_std))


# ----------------------------------------------------------------------------- fit
@click.command()
@click.argument("data", nargs=-1, type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Run folder to write (must not exist, or be empty)  [required]")
@config_option("Settings file (TOML); command-line options override it.")
@click.option("--order", type=click.IntRange(min=1), default=None, help="Polynomial order of U.")
@click.option("--potential", cls=RegistryOption, registry=potential_registry, default=None,
              help="U(q): a family ({choices}; model.width, model.depth for mlp), an "
              "expression in q1.. ('k*(1 - cos(q1))') or FILE.py:U; its parameters in "
              "[model.parameters].")
@click.option("--hamiltonian", type=str, default=None,
              help="A whole H(q, p): an expression in q1.., p1.. or FILE.py:H (a JAX function "
              "H(q, p, params)); its parameters in [model.parameters].")
@click.option("--integrator", cls=RegistryOption, registry=integrator_registry, default=None,
              help="Learning propagator: {choices}.")
@click.option("--dt", type=str, default=None,
              help='Learning step: a number, or "auto" (the default: chosen from the data by '
                   'step doubling).')
@click.option("--damping", is_flag=True, default=None,
              help="Learn a damping rate γ (ṗ = −∂U/∂q − γM⁻¹p; model.damping = true).")
@click.option("--observation-noise", type=LazyChoice(noise_model_names), default=None,
              help="Observation-noise model [default: additive].")
@click.option("--method", cls=RegistryOption, registry=sampler_registry, default=None,
              help="Sampler: {choices}.")
@click.option("--iterations", type=click.IntRange(min=1), default=None,
              help="A fixed budget: iterations per chain, burn-in included (draws kept: "
              "iterations − burn-in) [default: until every parameter's ESS ≥ 400 and R-hat ≤ "
              "1.01, at most 200000; sampler.target_ess, target_rhat, max_iterations, "
              "max_seconds].")
@click.option("--samples", type=click.IntRange(min=1), default=None, hidden=True)
@click.option("--burn-in", type=click.IntRange(min=0), default=None,
              help="Iterations discarded per chain [default: half of --iterations; without "
              "it the sampler's own, extended while the chains disagree].")
@click.option("--chains", type=click.IntRange(min=1), default=None, help="Independent chains.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seed of the MAP starts and of the sampler [default: 0].")
@click.option("--x0", type=str, default=None,
              help="Known initial state q1..qd,p1..pd (several DATA: one such group per file, "
              "or one for all).")
@click.option("--learn-initial-state", is_flag=True, help="Learn x0 with θ.")
@click.option("--t0", type=str, default=None,
              help='Time of the initial state: a number, or "first" (the first observation '
              "time) [default: 0].")
@click.option("--time-unit", type=str, default=None,
              help="Unit of the data's times, on the figures' axes [default: s].")
@sets_option
@click.option("--holdout", type=click.FloatRange(0, 1, min_open=True, max_open=True),
              default=None, help="Hold out the last FRACTION of the observation times: fit on "
              "the rest, then score the forecast on them (summary.json: holdout).")
@click.option("--holdout-after", type=float, default=None,
              help="Hold out the observations after time T (instead of --holdout).")
@click.option("--overwrite", is_flag=True, help="Replace an existing run folder.")
@click.option("--resume", is_flag=True,
              help="Continue the interrupted run in --out (its own settings and data).")
@click.option("--report/--no-report", default=True, show_default=True,
              help="Write report.md and the figures when the fit finishes (as symplid report).")
@no_progress_option
@user_errors
def fit(data, out, config, order, potential, hamiltonian, integrator, dt, damping,
        observation_noise, method, iterations, samples, burn_in, chains, seed, x0,
        learn_initial_state, t0, time_unit, holdout, holdout_after, sets, overwrite, resume,
        report, no_progress) -> None:
    """Fit a Hamiltonian to DATA (CSV or NPZ) and write a run folder.

    Without --iterations the sampler runs until every parameter's bulk and tail ESS reach
    400 and its R-hat is at most 1.01 (or a cap), and says which ended it. Several DATA files,
    or a `trajectory` column in one, are several trajectories of the same system: they share
    θ, each has its own initial state. Ctrl-C (or SIGTERM, SIGHUP) during sampling keeps the
    draws made so far, marks the run "interrupted" and exits with code 130 (143, 129); the
    draws also go to RUN/draws/ chunk by chunk, so a killed run keeps them too.
    `symplid fit --resume --out RUN` continues either.
    """
    if samples is not None:
        if iterations is not None:  # refused before the warning: one line
            raise UserError("--samples and --iterations are the same option; give --iterations")
        warnings.warn("--samples is deprecated; use --iterations",
                      FutureWarning, stacklevel=1)
        iterations = samples
    overrides = {
        "model.order": order,
        "model.potential": model_text(potential),
        "model.hamiltonian": model_text(hamiltonian),
        "model.integrator": integrator,
        "model.dt": time_or_word(dt, "--dt"),
        "model.damping": True if damping else None,
        "model.observation_noise": observation_noise,
        "sampler.method": method,
        "sampler.num_iterations": iterations,
        "sampler.burn_in": burn_in,
        "sampler.num_chains": chains,
        "seed": seed,
        "initial_state.x0": floats(x0, "--x0"),
        "initial_state.mode": "learned" if learn_initial_state else None,
        "initial_state.t0": time_or_word(t0, "--t0"),
        "plots.time_unit": time_unit,
    }
    start = time.perf_counter()
    outcome, heldout = run_fit(data, out, config, overrides, sets, (holdout, holdout_after),
                               overwrite, resume, no_progress, status=_status)
    click.echo(fit_result_line(out, outcome, time.perf_counter() - start))
    _echo_lines(diagnostics_lines(out, outcome))  # the MAP-level sensitivity checks
    if outcome.interrupted:
        raise Interrupted
    if report:
        click.echo(report_after_fit(out, outcome.plan))
    if heldout is not None:
        from symplid.workflow._forecasting import score_holdout

        h = score_holdout(out, heldout, outcome.plan)
        click.echo(
            f"{out}: held out {h['num_times']} times from t = {h['t_start']:g}: RMSE "
            f"{h['rmse']:.4g}, 95 % band coverage {h['coverage_95']:.0%}, log predictive "
            f"density {h['log_predictive_density']:.2f}"
        )


# ----------------------------------------------------------------------------- predict
@click.command()
@click.argument("run", type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--t-end",
    type=float,
    default=None,
    help="Predict up to this time [default: the run's prediction.t_end].",
)
@click.option("--dt", type=float, default=None, help="Prediction step [default: the run's].")
@click.option(
    "--num-paths",
    type=click.IntRange(min=0),
    default=None,
    help="Posterior sample paths for the band (0: MAP path only) [default: the run's].",
)
@click.option(
    "--from",
    "start",
    type=click.Choice(["start", "end"]),
    default="start",
    show_default=True,
    help="start: paths from the initial state; end: a forecast from each draw's filtered "
    "state at the last observation, with process noise (forecast.npz).",
)
@click.option("--inputs", "inputs", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="A driven run's future inputs: a CSV t,u1,… to --t-end.")
@quiet_option
@user_errors
def predict(run, t_end, dt, num_paths, start, inputs, no_progress) -> None:
    """Predict from a finished run: MAP path and posterior band, or a forecast from the end of
    the data (--from end), saved with a figure."""
    if start == "end":
        from symplid.workflow._forecasting import forecast_run

        if dt is not None or num_paths is not None:
            raise UserError("--from end forecasts one point per data gap; drop --dt/--num-paths")
        click.echo(forecast_run(run, t_end=t_end))
        return
    from symplid.workflow._run_tools import predict_run

    result = predict_run(run, t_end=t_end, dt=dt, num_paths=num_paths, inputs=inputs)
    click.echo(result)


# ----------------------------------------------------------------------------- report
@click.command()
@click.argument("run", type=click.Path(file_okay=False, path_type=Path))
@quiet_option
@user_errors
def report(run, no_progress) -> None:
    """Write report.md (tables and figures) for a finished run."""
    from symplid.workflow._run_tools import report_run

    click.echo(report_run(run))
    _echo_lines(diagnostics_lines(run))  # the fit's sensitivity checks, as report.md shows them


def _status(text: str) -> None:
    """A status line of the fit (what it is doing), on stderr."""
    click.echo(f"symplid: {text}", err=True)


def _echo_lines(lines: list[str]) -> None:
    for line in lines:
        click.echo(line)
