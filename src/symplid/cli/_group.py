"""The ``symplid`` group: its options, its callback, and the list of its commands.

A command is written in one of the command modules (:mod:`~symplid.cli._run_commands`,
:mod:`~symplid.cli._model_commands`, :mod:`~symplid.cli._study_commands`) and added here, in one
place.
"""

from __future__ import annotations

import click

from symplid import __version__
from symplid.cli._errors import OneLineErrors
from symplid.cli._model_commands import compare, discover
from symplid.cli._run_commands import fit, predict, report, reproduce, simulate
from symplid.cli._study_commands import study, sweep

__all__ = ["main"]


@click.group(
    cls=OneLineErrors,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100},
)
@click.version_option(version=__version__, prog_name="symplid")  # no importlib.metadata
def main() -> None:
    """Bayesian identification of Hamiltonian dynamics from sparse, noisy data.

    A symplectic integrator inside a UKF marginal likelihood, MAP and DRAM/NUTS posterior
    sampling, and predictions with uncertainty. Start with `symplid reproduce --quick`.

    Compiled code is cached in ~/.cache/symplid/jax (SYMPLID_CACHE_DIR=off disables it).
    """
    from symplid import runtime

    runtime.enable_compilation_cache()
    runtime.one_line_warnings()
    runtime.limit_blas_threads()  # small LAPACK calls, thousands a fit: no thread pool


for _command in (reproduce, simulate, fit, predict, report, compare, discover, sweep, study):
    main.add_command(_command)
