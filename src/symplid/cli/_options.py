"""The command line's option types and shared options.

Registries are read when a help text or a value needs them: importing symplid (and JAX) at
import time would make ``symplid --help`` slow. The options that several commands share
(``--config``, ``--set``, ``--no-progress``) and the option lists of the named studies are
written once here.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from symplid.cli._errors import user_errors

__all__ = [
    "LazyChoice",
    "RegistryOption",
    "baselines_study_options",
    "config_option",
    "integrator_registry",
    "no_progress_option",
    "noise_model_names",
    "potential_registry",
    "quiet_option",
    "rk2_variants",
    "sampler_registry",
    "sbc_defaults_study_options",
    "sbc_study_options",
    "sets_option",
    "shift_study_options",
]


def integrator_registry() -> Any:
    from symplid.dynamics._integrators import INTEGRATORS

    return INTEGRATORS


def potential_registry() -> Any:
    from symplid.dynamics._families import POTENTIAL_FAMILIES

    return POTENTIAL_FAMILIES


def sampler_registry() -> Any:
    from symplid.inference.samplers import SAMPLERS

    return SAMPLERS


def noise_model_names() -> tuple[str, ...]:
    """The registered observation-noise models (``--observation-noise``)."""
    from symplid.filters._noise import OBSERVATION_NOISE

    return OBSERVATION_NOISE.names()


def rk2_variants() -> tuple[str, ...]:
    """The registered RK2 integrators, by variant (``rk2-midpoint`` → ``midpoint``)."""
    return tuple(n[4:] for n in integrator_registry().names() if n.startswith("rk2-"))


class RegistryOption(click.Option):
    """An option whose help lists a registry's names (``{choices}``), read when shown."""

    def __init__(self, *args: Any, registry: Callable[[], Any], **kwargs: Any) -> None:
        self.registry = registry
        super().__init__(*args, **kwargs)

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        record = super().get_help_record(ctx)
        if record is None:
            return None
        return record[0], record[1].replace("{choices}", ", ".join(self.registry().names()))


class LazyChoice(click.Choice):
    """A ``click.Choice`` whose choices are computed when first needed."""

    def __init__(self, load: Callable[[], tuple[str, ...]]) -> None:
        self._load = load
        super().__init__((), case_sensitive=True)

    @property
    def choices(self) -> tuple[str, ...]:
        return tuple(self._load())

    @choices.setter
    def choices(self, value: Any) -> None:  # set by click.Choice.__init__; computed instead
        pass


# ----------------------------------------------------------------------------- shared options
def no_progress_option(fn: Callable) -> Callable:
    return click.option("--no-progress", is_flag=True, help="No progress bars.")(fn)


def quiet_option(fn: Callable) -> Callable:
    """``--no-progress`` of a command that draws no progress bar (predict, report): accepted so
    that one script can pass it to every command."""
    return click.option("--no-progress", is_flag=True,
                        help="Accepted for scripts that pass it to every command; this command "
                        "draws no progress bar.")(fn)


def config_option(help_text: str) -> Callable[[Callable], Callable]:
    return click.option("--config", "config", type=click.Path(dir_okay=False, path_type=Path),
                        default=None, help=help_text)


def sets_option(fn: Callable) -> Callable:
    return click.option(
        "--set", "sets", multiple=True, metavar="KEY=VALUE",
        help="Any setting, e.g. --set priors.coefficients.scale=5 (repeatable).",
    )(fn)


# ----------------------------------------------------------------------------- studies
def baselines_study_options(fn: Any) -> Any:
    """The options of ``symplid study baselines`` (listed as ``--help`` shows them)."""
    options = [
        click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True),
        click.option("--seeds", type=click.IntRange(min=1), default=10, show_default=True),
        click.option("--mlp-seeds", type=click.IntRange(min=1), default=None,
                     help="Seeds of the MLP cells [default: --seeds]."),
        click.option("--sizes", default="20,50,200,1000", show_default=True),
        click.option("--potentials", default="polynomial,mlp", show_default=True),
        click.option("--quick", is_flag=True, help="Tiny solver budgets (a smoke test)."),
        click.option("--report-only", is_flag=True,
                     help="Write the report of the cells OUT holds (an interrupted study)."),
        click.option("--workers", type=click.IntRange(min=1), default=None),
        click.option("--no-progress", is_flag=True),
    ]
    for option in reversed(options):
        fn = option(fn)
    return fn


def _replication_options(fn: Any, *own: Any) -> Any:
    """An SBC study's options (``--out``, ``--replications``, then ``own``, then
    ``--workers``, ``--report-only``, ``--no-progress``), and its user errors as one line
    (:func:`~symplid.cli._errors.user_errors`)."""
    options = [
        click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
                     help="Study folder (a rerun skips the finished replications)."),
        click.option("--replications", type=click.IntRange(min=1), default=100,
                     show_default=True),
        *own,
        click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Local worker processes [default: one per core]."),
        click.option("--report-only", is_flag=True,
                     help="Run nothing: report the replications OUT holds."),
        no_progress_option,
    ]
    fn = user_errors(fn)
    for option in reversed(options):
        fn = option(fn)
    return fn


def sbc_study_options(fn: Any) -> Any:
    """The options of ``symplid study sbc``."""
    return _replication_options(
        fn,
        click.option("--likelihoods", default="gap,none", show_default=True,
                     help="gap (process noise once per gap), none (deterministic), or both."),
        click.option("--budget", type=click.Choice(["full", "quick"]), default="full",
                     show_default=True, help="Sampler budget per replication."),
        click.option("--samplers", default="dram", show_default=True,
                     help="dram, nuts, or both (dram,nuts): each runs every replication from "
                     "the MAP."),
    )


def sbc_defaults_study_options(fn: Any) -> Any:
    """The options of ``symplid study sbc-defaults`` (nothing to choose but the
    replications: the fits take every default)."""
    return _replication_options(fn)


def shift_study_options(fn: Any) -> Any:
    """The options of ``symplid study shift``, and its user errors as one line
    (:func:`~symplid.cli._errors.user_errors`)."""
    options = [
        click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
                     help="Study folder (decomposition.json, report.md, figures/, parts/)."),
        click.option("--cells", type=click.Path(exists=True, file_okay=False, path_type=Path),
                     default=None, help="A paper-claims study folder: the posterior shifts, "
                     "Σ's per-seed values and the remainders [default: parts (a)–(c) only]."),
        click.option("--budget", type=click.Choice(["full", "quick"]), default="full",
                     show_default=True, help="Rows, steps and seeds decomposed."),
        click.option("--report-only", is_flag=True,
                     help="Run nothing: report the parts OUT holds (the others as pending)."),
    ]
    fn = user_errors(fn)
    for option in reversed(options):
        fn = option(fn)
    return fn
