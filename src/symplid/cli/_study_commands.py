"""``symplid sweep`` and ``symplid study``: many fits, on Dask, and the named studies (paper
claims, baselines, SBC, shift decomposition).

Each study command runs a study of :mod:`symplid.studies` (imported when the command runs, so
that the rest of the command line never loads them) and, like every command, ends a user
mistake with one line and exit code 2 (:func:`symplid.cli._errors.user_errors`).
"""

from __future__ import annotations

from pathlib import Path

import click

from symplid.cli._errors import user_errors
from symplid.cli._options import (
    baselines_study_options,
    no_progress_option,
    sbc_defaults_study_options,
    sbc_study_options,
    shift_study_options,
)

__all__ = ["study", "sweep"]


# ----------------------------------------------------------------------------- sweep
@click.command()
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Sweep folder (a rerun skips the finished cells).",
)
@click.option(
    "--scheduler",
    type=str,
    default=None,
    help="A dask.distributed scheduler address [default: a local cluster].",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Local worker processes [default: one per core].",
)
@no_progress_option
@user_errors
def sweep(spec, out, scheduler, workers, no_progress) -> None:
    """Run a sweep (SPEC: a TOML grid or list of cells) on Dask; one full fit per cell."""
    from symplid.studies import register_studies
    from symplid.workflow._experiment import EXPERIMENTS
    from symplid.workflow._sweep import run_sweep
    from symplid.workflow._sweep_spec import get_experiment, named_experiment, read_sweep_file

    register_studies(EXPERIMENTS)  # the studies a spec may name, "paper" the default
    data = read_sweep_file(spec)
    experiment = get_experiment(named_experiment(data, str(spec)), str(spec))
    table = run_sweep(spec, out, scheduler=scheduler, workers=workers, progress=not no_progress,
                      experiment=experiment)
    counts = table["status"].value_counts().to_dict() if "status" in table else {}
    done = ", ".join(f"{v} {k}" for k, v in counts.items())
    click.echo(f"{out}: {len(table)} cells ({done}); results.csv and results.parquet")


@click.group()
def study() -> None:
    """Named studies: sweeps with their own analysis."""


@study.command("paper-claims")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Study folder (a rerun skips the finished cells).")
@click.option("--seeds", type=click.IntRange(min=1), default=20, show_default=True)
@click.option("--budget", default="paper", show_default=True,
              help="Sampler budget per cell: paper (4 × 200,000 DRAM), quick, or iterations.")
@click.option("--variants", default="all", show_default=True,
              help="all, none (the paper's setting), or variant names separated by commas.")
@click.option("--quick", is_flag=True, hidden=True, help="Same as --budget quick.")
@click.option("--no-variants", is_flag=True, hidden=True, help="Same as --variants none.")
@click.option("--scheduler", type=str, default=None,
              help="A Dask scheduler address (tcp://host:8786) [default: a local cluster].")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local worker processes [default: one per core].")
@click.option("--update-readme", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Rewrite the claims block of this README from claims.json.")
@click.option("--report-only", is_flag=True,
              help="Run nothing: judge the cells OUT holds (cells not run yet are pending).")
@no_progress_option
@user_errors
def paper_claims(out, seeds, budget, variants, quick, no_variants, scheduler, workers,
                 update_readme, report_only, no_progress) -> None:
    """How often the paper's claims hold over many data seeds, per variant; calibration."""
    from symplid.studies._paper_study import run_paper_claims

    if update_readme is not None:  # before the study: not an error after its success line
        from symplid.studies._claims_readme import check_readme

        check_readme(update_readme)
    claims = run_paper_claims(
        out,
        seeds=seeds,
        budget="quick" if quick else budget,
        scheduler=scheduler,
        workers=workers,
        variants="none" if no_variants else variants,
        progress=not no_progress,
        report_only=report_only,
    )
    click.echo(f"{out}: claims.json, report.md and figures/")
    if update_readme is not None:
        from symplid.studies._claims_readme import update_readme as write_block

        write_block(update_readme, claims, Path(out))
        click.echo(f"{update_readme}: claims block rewritten from {out}/claims.json")


@study.command("baselines")
@baselines_study_options
@user_errors
def baselines_study(out, no_progress, **options) -> None:
    """The UKF posterior against HNN and one-step least squares over data sizes (a sweep)."""
    from symplid.studies._baselines_study import study_from_options

    click.echo(study_from_options(out, progress=not no_progress, **options))


@study.command("sbc")
@sbc_study_options
def sbc_study(out, replications, likelihoods, budget, samplers, workers, report_only,
              no_progress) -> None:
    """Simulation-based calibration: ranks of prior-drawn truths among posterior draws."""
    from symplid.studies._sbc import run_sbc_study

    chosen = tuple(v.strip() for v in likelihoods.split(",") if v.strip())
    methods = tuple(v.strip() for v in samplers.split(",") if v.strip())
    run_sbc_study(out, replications=replications, likelihoods=chosen, budget=budget,
                  samplers=methods, workers=workers, progress=not no_progress,
                  report_only=report_only)
    click.echo(f"{out}: report.md, sbc.json, results.csv and figures/")


@study.command("sbc-defaults")
@sbc_defaults_study_options
def sbc_defaults_study(out, replications, workers, report_only, no_progress) -> None:
    """Simulation-based calibration of the defaults: a user's damped pendulum, fitted as
    `symplid fit` fits it with nothing but its priors given."""
    from symplid.studies._sbc_defaults import run_sbc_defaults

    run_sbc_defaults(out, replications=replications, workers=workers,
                     progress=not no_progress, report_only=report_only)
    click.echo(f"{out}: report.md, sbc.json, results.csv and figures/")


@study.command("shift")
@shift_study_options
def shift_study(**options) -> None:
    """Split each coefficient's shift into discretisation, noise draws, process noise, rest."""
    from symplid.studies._shift import study_from_options

    click.echo(study_from_options(echo=click.echo, **options))
