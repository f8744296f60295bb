"""The ``symplid`` command line, the only part of the package that uses click.

:func:`main` is the group (:mod:`~symplid.cli._group`); the commands are in
:mod:`~symplid.cli._run_commands` (reproduce, simulate, fit, predict, report),
:mod:`~symplid.cli._model_commands` (compare, discover) and :mod:`~symplid.cli._study_commands`
(sweep, study); the option types and shared options in :mod:`~symplid.cli._options`; one-line
errors and exit codes in :mod:`~symplid.cli._errors`. What the commands do is
:mod:`symplid.workflow` (click-free). ``python -m symplid.cli`` runs it too.
"""

from __future__ import annotations

from symplid.cli._group import main

__all__ = ["main"]
