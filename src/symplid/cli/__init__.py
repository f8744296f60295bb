"""The ``symplid`` command line, the only part of the package that uses click.

:func:`main` is the group (:mod:`~symplid.cli.group`); the commands are in
:mod:`~symplid.cli.run_commands` (reproduce, simulate, fit, predict, report),
:mod:`~symplid.cli.model_commands` (compare, discover) and :mod:`~symplid.cli.study_commands`
(sweep, study); the option types and shared options in :mod:`~symplid.cli.options`; one-line
errors and exit codes in :mod:`~symplid.cli.errors`. What the commands do is
:mod:`symplid.workflow` (click-free). ``python -m symplid.cli`` runs it too.
"""

from __future__ import annotations

from symplid.cli.group import main

__all__ = ["main"]
