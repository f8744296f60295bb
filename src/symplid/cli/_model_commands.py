"""The commands that choose a model: compare (rank candidates by their evidence) and discover
(which terms of a library the data need).

What they do is :mod:`symplid.workflow._compare` and :mod:`symplid.workflow._discover`; here
are their options and their printed lines.
"""

from __future__ import annotations

from pathlib import Path

import click

from symplid.cli._errors import user_errors
from symplid.cli._options import config_option, no_progress_option, sets_option
from symplid.workflow._commandline import (
    UserError,
    compare_candidates,
    floats,
    settings_from_options,
)

__all__ = ["compare", "discover"]


# ----------------------------------------------------------------------------- compare
@click.command()
@click.argument("data", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder for compare.csv and compare.txt.",
)
@config_option("Settings file (TOML) shared by every candidate.")
@click.option(
    "--orders",
    type=str,
    default=None,
    help="Polynomial orders, e.g. 2..5 or 2,3,5 [default: 2..5 for the polynomial family; "
    "another family, or a user's model, is one candidate].",
)
@click.option(
    "--integrators",
    type=str,
    default=None,
    help="Comma-separated propagators [default: the settings' one].",
)
@click.option(
    "--damping",
    is_flag=True,
    help="Every candidate without and with a learned damping rate γ (is damping needed?).",
)
@click.option(
    "--process-noise",
    is_flag=True,
    help="Every candidate with process noise and without (model.process_noise_per = none: "
    "one integrated path, no filter): does the model need Σ?",
)
@click.option("--x0", type=str, default=None, help="Known initial state q1..qd,p1..pd.")
@click.option("--learn-initial-state", is_flag=True, help="Learn x0 with θ.")
@click.option("--candidates", type=str, default=None,
              help="Comma-separated settings files, one whole model each (e.g. two of your "
              "own): rank them instead of polynomial orders.")
@sets_option
@no_progress_option
@user_errors
def compare(
    data, out, config, orders, integrators, damping, process_noise, x0, learn_initial_state,
    candidates, sets, no_progress,
) -> None:
    """Rank polynomial orders (propagators, damping, process noise), or whole models
    (--candidates), for DATA by the log evidence (Gaussian in the coefficients, the noise
    variances integrated on their log scale)."""
    from symplid.io import read_observations
    from symplid.workflow._compare import compare_models, format_table
    from symplid.workflow._compare_candidates import candidate_orders
    from symplid.workflow._driven import read_data_for

    overrides = {
        "initial_state.x0": floats(x0, "--x0"),
        "initial_state.mode": "learned" if learn_initial_state else None,
    }
    names = [n.strip() for n in integrators.split(",")] if integrators else None
    if candidates is not None:
        obs = read_observations(data)
        table = compare_candidates(obs, candidates, config, orders, overrides, sets, names,
                                   out, not no_progress, [False, True] if damping else None)
        best = table.iloc[0]
        click.echo(format_table(table))
        click.echo(f"best: {best['model']} with {best['integrator']}"
                   + (f"; table in {out}" if out is not None else ""))
        return
    settings, source = settings_from_options(config, overrides, sets)
    obs = read_data_for(data, settings)  # a driven model's inputs with the data
    table = compare_models(
        obs,
        settings,
        orders=candidate_orders(settings, orders),
        integrators=names,
        out=out,
        progress=not no_progress,
        source=source,
        dampings=[False, True] if damping else None,
        process_noises=_with_and_without_noise(settings) if process_noise else None,
    )
    click.echo(format_table(table))
    best = table.iloc[0]
    click.echo(
        f"best: order {best['order']} with {best['integrator']}"
        + (f", damped (γ = {best['gamma']:.3g})" if best["damping"] else "")
        + (", no process noise" if best["process_noise"] == "none" else "")
        + (f"; table in {out}" if out is not None else "")
    )


# ----------------------------------------------------------------------------- discover
@click.command()
@click.argument("data", type=click.Path(path_type=Path))
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder for terms.csv, subsets.csv, summary.json, report.md (and fit/).",
)
@config_option("Settings file (TOML): integrator, dt, noise, priors, initial state.")
@click.option("--order", type=click.IntRange(min=1), default=None,
              help="The library: every monomial of U up to this order [default: model.order].")
@click.option("--terms", type=str, default=None,
              help="The library: your own terms, e.g. 'q1^2, q1^4, cos(q1)' (each gets a "
              "coefficient with the coefficients' prior).")
@click.option("--x0", type=str, default=None, help="Known initial state q1..qd,p1..pd.")
@click.option("--learn-initial-state", is_flag=True, help="Learn x0 with θ.")
@click.option("--size-prior", type=click.Choice(["beta-binomial", "uniform"]),
              default="beta-binomial", show_default=True,
              help="Prior over subsets: every size equally likely, or every subset.")
@click.option("--max-fits", type=click.IntRange(min=1), default=None,
              help="Stop the search after this many fits [default: until it converges].")
@click.option("--fit/--no-fit", "fit_chosen", default=False, show_default=True,
              help="Fit the chosen model fully (sampler, report) into OUT/fit.")
@sets_option
@no_progress_option
@user_errors
def discover(data, out, config, order, terms, x0, learn_initial_state, size_prior, max_fits,
             fit_chosen, sets, no_progress) -> None:
    """Which terms of a library DATA need: each term's inclusion probability, the best
    subsets by their evidence, and the chosen model's coefficients with 95 % intervals."""
    from symplid.io import read_observations
    from symplid.workflow._discover import discover as run_discover
    from symplid.workflow._discover import format_terms
    from symplid.workflow._term_library import LibraryError

    if fit_chosen and out is None:
        raise UserError("--fit writes the chosen model's run into OUT/fit: give --out")
    obs = read_observations(data)
    overrides = {
        "initial_state.x0": floats(x0, "--x0"),
        "initial_state.mode": "learned" if learn_initial_state else None,
    }
    settings, source = settings_from_options(config, overrides, sets)
    try:
        found = run_discover(obs, settings, terms=terms, order=order, out=out,
                             fit_chosen=fit_chosen, size_prior=size_prior, max_fits=max_fits,
                             progress=not no_progress, source=source)
    except LibraryError as err:
        raise UserError(str(err)) from None
    click.echo(format_terms(found.table))
    click.echo(f"chosen: {' + '.join(found.chosen) or '(none)'} ({found.search.num_fits} "
               f"fits)" + (f"; files in {out}" if out is not None else ""))
    if found.search.stopped == "max_fits":
        click.echo("symplid: the search stopped at --max-fits before it converged: the "
                   "inclusion probabilities cover the subsets it visited", err=True)


def _with_and_without_noise(settings) -> list[str]:
    """``compare --process-noise``: the settings' process noise (``gap`` if it is none)
    beside none."""
    per = settings.model.process_noise_per
    return ["gap" if per == "none" else per, "none"]
