"""What the command line needs besides its commands: one-line errors, option types, parsing.

Kept apart from :mod:`symplid.cli` (the commands only). Every user mistake becomes one line on
stderr and exit code 2 (:func:`user_errors`, :class:`OneLineErrors` for click's own usage
errors); Ctrl-C and SIGTERM become "interrupted" and exit code 128 + the signal's number.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

__all__ = [
    "EXIT_INTERRUPTED",
    "EXIT_USER_ERROR",
    "Interrupted",
    "LazyChoice",
    "OneLineErrors",
    "RegistryOption",
    "UserError",
    "baselines_study_options",
    "converged",
    "floats",
    "integrator_registry",
    "potential_registry",
    "rk2_variants",
    "sampler_registry",
    "settings_from_options",
    "time_or_word",
    "user_errors",
]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class UserError(click.ClickException):
    exit_code = EXIT_USER_ERROR

    def show(self, file=None) -> None:
        click.echo(f"symplid: error: {self.format_message()}", err=True)


class Interrupted(Exception):
    """A command that was interrupted but kept (and reported) what it had done."""


def user_errors(fn: Callable) -> Callable:
    """Turn the library's validation errors into one line and exit code 2; Ctrl-C and SIGTERM
    into "interrupted" and exit code 128 + the signal's number."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from symplid.model.data import DataError
        from symplid.workflow.interrupts import terminate_as_interrupt
        from symplid.workflow.settings import SettingsError

        with terminate_as_interrupt() as signals:
            try:
                return fn(*args, **kwargs)
            except (DataError, SettingsError, FileNotFoundError, FileExistsError) as err:
                raise UserError(str(err)) from None
            except (ValueError, NotADirectoryError) as err:  # the library's argument checks
                raise UserError(str(err)) from None
            except KeyboardInterrupt:
                click.echo("symplid: interrupted", err=True)
                sys.exit(128 + signals[-1] if signals else EXIT_INTERRUPTED)
            except Interrupted:  # the command said so in its result line
                sys.exit(128 + signals[-1] if signals else EXIT_INTERRUPTED)

    return wrapper


class OneLineErrors(click.Group):
    """A group whose usage errors (a bad option value, a missing argument) are one line, like
    every other error, instead of click's usage block."""

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            result = super().main(*args, standalone_mode=False, **kwargs)
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
        sys.exit(result if isinstance(result, int) else 0)


# Registries are read when a help text or a value needs them: importing symplid (and JAX) at
# import time would make `symplid --help` slow.
def integrator_registry() -> Any:
    from symplid.dynamics.integrators import INTEGRATORS

    return INTEGRATORS


def potential_registry() -> Any:
    from symplid.dynamics.families import POTENTIAL_FAMILIES

    return POTENTIAL_FAMILIES


def sampler_registry() -> Any:
    from symplid.inference.samplers import SAMPLERS

    return SAMPLERS


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


def rk2_variants() -> tuple[str, ...]:
    """The registered RK2 integrators, by variant (``rk2-midpoint`` → ``midpoint``)."""
    return tuple(n[4:] for n in integrator_registry().names() if n.startswith("rk2-"))


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


def floats(text: str | None, name: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise UserError(f"{name} must be numbers separated by commas, got {text!r}") from None


def converged(summary: dict[str, Any]) -> bool:
    from symplid.inference.diagnostics import ESS_THRESHOLD, RHAT_THRESHOLD

    return summary["rhat_max"] <= RHAT_THRESHOLD and summary["ess_min"] >= ESS_THRESHOLD


def time_or_word(text: str | None, name: str) -> float | str | None:
    """A time option: a number, or a word such as "first" (checked by the settings)."""
    if text is None:
        return None
    try:
        return float(text)
    except ValueError:
        return text.strip()


def settings_from_options(config: Path | None, overrides: dict[str, Any], sets: tuple[str, ...]):
    """Settings from the defaults, then ``config``, then the options and ``--set`` pairs."""
    from symplid.workflow.settings import Settings, load_settings, merge_overrides, parse_override

    settings = load_settings(config) if config is not None else Settings()
    source = str(config) if config is not None else "command line"
    for text in sets:
        key, value = parse_override(text)
        overrides[key] = value
    return merge_overrides(settings, overrides, source="command line"), source


