"""What the command line needs besides its commands: one-line errors, option types, parsing.

Kept apart from :mod:`symplid.cli` (the commands only). Every user mistake becomes one line on
stderr and exit code 2 (:func:`user_errors`, :class:`OneLineErrors` for click's own usage
errors); Ctrl-C, SIGTERM and SIGHUP become "interrupted" and exit code 128 + the signal's
number; a full disk or a file-size limit is one line and exit code 1 (not the user's fault).
"""

from __future__ import annotations

import functools
import os
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
    "compare_candidates",
    "config_option",
    "converged",
    "floats",
    "integrator_registry",
    "model_text",
    "no_progress_option",
    "noise_model_names",
    "potential_registry",
    "quiet_option",
    "rk2_variants",
    "sampler_registry",
    "sbc_study_options",
    "sets_option",
    "settings_from_options",
    "shift_study_options",
    "time_or_word",
    "user_errors",
]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class UserError(click.ClickException):
    exit_code = EXIT_USER_ERROR

    def show(self, file=None) -> None:
        click.echo(f"symplid: error: {self.format_message()}", err=True)


class EnvironmentFault(UserError):
    """One line like a user error, but exit code 1: the disk failed, not the user."""

    exit_code = 1


class Interrupted(Exception):
    """A command that was interrupted but kept (and reported) what it had done."""


def user_errors(fn: Callable) -> Callable:
    """Turn the library's validation errors into one line and exit code 2, a failing disk
    into one line and exit code 1; Ctrl-C, SIGTERM and SIGHUP into a stop at the next safe
    point (:func:`symplid.workflow.interrupts.supervised`), "interrupted" and exit code 128 +
    the signal's number (also when the command finished before reaching a safe point)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from symplid import stopping
        from symplid.io.files import StorageError
        from symplid.model.data import DataError
        from symplid.runtime import MissingExtraError
        from symplid.workflow.interrupts import supervised
        from symplid.workflow.settings import SettingsError

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
                raise UserError(str(err)) from None
            except MissingExtraError as err:  # e.g. a sweep without the "sweeps" extra
                raise UserError(str(err)) from None
            except (ValueError, NotADirectoryError) as err:  # the library's argument checks
                raise UserError(str(err)) from None
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

    The signal handlers (:func:`symplid.workflow.interrupts.supervised`) are installed first,
    before the group's callback and the commands import JAX: a signal during the imports is
    recorded (not raised inside a library's callback, where JAX swallowed it, nor left to
    SIGHUP's default, which killed the process without a word) and obeyed when the command
    starts (:func:`user_errors`).
    """

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        from symplid import stopping
        from symplid.workflow.interrupts import supervised

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
    from symplid import stopping

    signum = stopping.requested()
    if signum is not None:
        click.echo("symplid: interrupted (the command finished first; its results are kept)",
                   err=True)
        sys.exit(128 + signum)


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


def noise_model_names() -> tuple[str, ...]:
    """The registered observation-noise models (``--observation-noise``)."""
    from symplid.filters.noise import OBSERVATION_NOISE

    return OBSERVATION_NOISE.names()


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


def sbc_study_options(fn: Any) -> Any:
    """The options of ``symplid study sbc``, and its user errors as one line
    (:func:`user_errors`)."""
    options = [
        click.option("--out", type=click.Path(file_okay=False, path_type=Path), required=True,
                     help="Study folder (a rerun skips the finished replications)."),
        click.option("--replications", type=click.IntRange(min=1), default=100,
                     show_default=True),
        click.option("--likelihoods", default="gap,none", show_default=True,
                     help="gap (process noise once per gap), none (deterministic), or both."),
        click.option("--budget", type=click.Choice(["full", "quick"]), default="full",
                     show_default=True, help="Sampler budget per replication."),
        click.option("--samplers", default="dram", show_default=True,
                     help="dram, nuts, or both (dram,nuts): each runs every replication from "
                     "the MAP."),
        click.option("--workers", type=click.IntRange(min=1), default=None),
        click.option("--report-only", is_flag=True,
                     help="Run nothing: report the replications OUT holds."),
        no_progress_option,
    ]
    fn = user_errors(fn)
    for option in reversed(options):
        fn = option(fn)
    return fn


def shift_study_options(fn: Any) -> Any:
    """The options of ``symplid study shift``, and its user errors as one line
    (:func:`user_errors`)."""
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


def settings_from_options(config: Path | None, overrides: dict[str, Any], sets: tuple[str, ...],
                          base: Any = None):
    """Settings from the defaults (or ``base``), then ``config``, then the options and
    ``--set`` pairs."""
    from symplid.workflow.settings import Settings, load_settings, merge_overrides, parse_override

    if base is not None and config is not None:
        settings = _merged_file(base, config)
    elif config is not None:
        settings = load_settings(config)
    else:
        settings = base if base is not None else Settings()
    source = str(config) if config is not None else "command line"
    for text in sets:
        key, value = parse_override(text)
        overrides[key] = value
    return merge_overrides(settings, overrides, source="command line"), source




# ----------------------------------------------------------------------------- shared options
def no_progress_option(fn: Callable) -> Callable:
    return click.option("--no-progress", is_flag=True, help="No progress bars.")(fn)


def compare_candidates(obs: Any, files: str, config: Path | None, orders: str | None,
                       overrides: dict[str, Any], sets: tuple[str, ...], integrators: Any,
                       out: Path | None, progress: bool, dampings: Any) -> Any:
    """``symplid compare --candidates a.toml,b.toml``: each file is one whole model, labelled
    by its name; the options and ``--set`` apply to every one."""
    from symplid.workflow.compare_candidates import compare_settings

    if config is not None or orders is not None:
        raise UserError("--candidates gives each model its own settings file; drop --config "
                        "and --orders")
    paths = [Path(p.strip()) for p in files.split(",") if p.strip()]
    if len(paths) < 2:
        raise UserError(f"--candidates needs two settings files or more, got {files!r}")
    twice = [str(p) for k, p in enumerate(paths) if p.resolve() in
             {q.resolve() for q in paths[:k]}]
    if twice:
        raise UserError(f"--candidates names {twice[0]} twice; give each model once")
    stems = [p.stem for p in paths]
    labels = stems if len(set(stems)) == len(stems) else [str(p) for p in paths]
    pairs = [(label, settings_from_options(p, dict(overrides), sets)[0])
             for label, p in zip(labels, paths, strict=True)]
    return compare_settings(obs, pairs, integrators, out, progress, dampings)


def quiet_option(fn: Callable) -> Callable:
    """``--no-progress`` of a command that draws no progress bar (predict, report): accepted so
    that one script can pass it to every command."""
    return click.option("--no-progress", is_flag=True,
                        help="Accepted for scripts that pass it to every command; this command "
                        "draws no progress bar.")(fn)


def model_text(text: str | None) -> str | None:
    """``--potential``/``--hamiltonian``: ``FILE.py:NAME`` becomes ``file:FILE.py:NAME``; a family
    name or an expression is passed on as written."""
    if text is None:
        return None
    path, sep, name = text.strip().rpartition(":")
    if sep and path.endswith(".py") and not text.strip().startswith("file:"):
        return f"file:{path}:{name}"
    return text


def config_option(help_text: str) -> Callable[[Callable], Callable]:
    return click.option("--config", "config", type=click.Path(dir_okay=False, path_type=Path),
                        default=None, help=help_text)


def sets_option(fn: Callable) -> Callable:
    return click.option(
        "--set", "sets", multiple=True, metavar="KEY=VALUE",
        help="Any setting, e.g. --set priors.coefficients.scale=5 (repeatable).",
    )(fn)


def _merged_file(base: Any, config: Path) -> Any:
    """``base`` with the keys of the settings file ``config`` replaced (the others kept)."""
    import tomllib

    from symplid.workflow.settings import (
        settings_from_dict,
        settings_to_dict,
        upgrade_prior_keys,
    )

    try:
        given = tomllib.loads(Path(config).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as err:
        raise UserError(f"{config}: {err}") from None

    def merge(into: dict, extra: dict) -> dict:
        for key, value in extra.items():
            if isinstance(value, dict) and isinstance(into.get(key), dict):
                merge(into[key], value)
            else:
                into[key] = value
        return into

    given = upgrade_prior_keys(given, str(config))  # written with ``prior`` like the base
    return settings_from_dict(merge(settings_to_dict(base), given), source=str(config))
