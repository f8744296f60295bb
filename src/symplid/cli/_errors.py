"""One-line errors and exit codes of the ``symplid`` command line.

Every user mistake becomes one line on stderr and exit code 2 (:func:`user_errors` for the
library's validation errors, :class:`OneLineErrors` for click's own usage errors); Ctrl-C,
SIGTERM and SIGHUP become "interrupted" and exit code 128 + the signal's number; a full disk
or a file-size limit is one line and exit code 1 (not the user's fault). The mistakes
themselves are plain exceptions of the layers below
(:class:`symplid.workflow._commandline.UserError`, :class:`~symplid.model._data.DataError`, ...):
only this module turns them into click's exits.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any

import click

__all__ = [
    "EXIT_INTERRUPTED",
    "EXIT_USER_ERROR",
    "CommandError",
    "EnvironmentFault",
    "Interrupted",
    "OneLineErrors",
    "user_errors",
]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class CommandError(click.ClickException):
    """A mistake of the user, shown as ``symplid: error: ...`` with exit code 2."""

    exit_code = EXIT_USER_ERROR

    def show(self, file=None) -> None:
        click.echo(f"symplid: error: {self.format_message()}", err=True)


class EnvironmentFault(CommandError):
    """One line like a user error, but exit code 1: the disk failed, not the user."""

    exit_code = 1


class Interrupted(Exception):
    """A command that was interrupted but kept (and reported) what it had done."""


def user_errors(fn: Callable) -> Callable:
    """Turn the library's validation errors into one line and exit code 2, a failing disk
    into one line and exit code 1; Ctrl-C, SIGTERM and SIGHUP into a stop at the next safe
    point (:func:`symplid.workflow._interrupts.supervised`), "interrupted" and exit code 128 +
    the signal's number (also when the command finished before reaching a safe point)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from symplid import _stopping as stopping
        from symplid.io._files import StorageError
        from symplid.model._data import DataError
        from symplid.runtime import MissingExtraError
        from symplid.workflow._interrupts import supervised
        from symplid.workflow._settings import SettingsError

        def exit_code() -> int:
            signum = stopping.requested()
            return EXIT_INTERRUPTED if signum is None else 128 + signum

        with supervised():
            try:
                stopping.check()  # a safe point: a signal during the imports stops here
                result = fn(*args, **kwargs)
                _exit_if_stopped()  # no safe point came after the signal
                return result
            except (DataError, SettingsError, FileNotFoundError, FileExistsError) as err:
                raise CommandError(str(err)) from None
            except MissingExtraError as err:  # e.g. a sweep without the "sweeps" extra
                raise CommandError(str(err)) from None
            except (ValueError, NotADirectoryError) as err:  # argument checks, UserError
                raise CommandError(str(err)) from None
            except StorageError as err:  # a full disk, a file-size limit: not the user's
                raise EnvironmentFault(str(err)) from None
            except KeyboardInterrupt as err:
                click.echo(f"symplid: interrupted{_burn_in_words(err)}", err=True)
                sys.exit(exit_code())
            except Interrupted:  # the command said so in its result line
                sys.exit(exit_code())

    return wrapper


def _burn_in_words(stop: BaseException) -> str:
    """What the one line of a stop in the burn-in adds: where, and that ``--resume`` goes on."""
    if not hasattr(stop, "checkpoint"):
        return ""
    done = stop.checkpoint.iterations_done
    where = (f" in the burn-in after {done:,} iterations per chain" if done
             else " before the sampler's first iteration")
    return f"{where}; the chains' state is kept: continue with 'symplid fit --resume'"


class OneLineErrors(click.Group):
    """A group whose usage errors (a bad option value, a missing argument) are one line, like
    every other error, instead of click's usage block.

    The signal handlers (:func:`symplid.workflow._interrupts.supervised`) are installed first,
    before the group's callback and the commands import JAX: a signal during the imports is
    recorded (not raised inside a library's callback, where JAX swallowed it, nor left to
    SIGHUP's default, which killed the process without a word) and obeyed when the command
    starts (:func:`user_errors`).
    """

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        from symplid import _stopping as stopping
        from symplid.workflow._interrupts import supervised

        try:
            with supervised():
                result = self._one_line_main(*args, **kwargs)
                _exit_if_stopped()  # a command without a safe point (--help, --version)
            sys.exit(result if isinstance(result, int) else 0)
        except SystemExit as done:
            if not stopping.abandoned():
                raise
            # A compilation the stop did not wait for still runs in its thread: the files
            # are written, so end here rather than tear the interpreter down under it.
            sys.stdout.flush()
            sys.stderr.flush()
            code = done.code
            os._exit(code if isinstance(code, int) else 0 if code is None else 1)

    def _one_line_main(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().main(*args, standalone_mode=False, **kwargs)
        except click.UsageError as err:
            where = f" (see '{err.ctx.command_path} --help')" if err.ctx is not None else ""
            message = " ".join(err.format_message().split())
            click.echo(f"symplid: error: {message}{where}", err=True)
            sys.exit(EXIT_USER_ERROR)
        except click.ClickException as err:
            err.show()
            sys.exit(err.exit_code)
        except click.exceptions.Abort:
            click.echo("symplid: interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)


def _exit_if_stopped() -> None:
    """Exit with 128 + the signal's number, after one line, when a stop was requested."""
    from symplid import _stopping as stopping

    signum = stopping.requested()
    if signum is not None:
        click.echo("symplid: interrupted (the command finished first; its results are kept)",
                   err=True)
        sys.exit(128 + signum)
