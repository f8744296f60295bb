"""What the command line does besides parsing: read its values, build the settings, say its
mistakes (click-free; the commands, click's options and the exits are :mod:`symplid.cli`).

A user's mistake found here is a :class:`UserError`, a ``ValueError``: the command line shows
it as one line on stderr and exit code 2, and a caller from Python gets an ordinary exception.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = [
    "UserError",
    "compare_candidates",
    "converged",
    "floats",
    "model_text",
    "settings_from_options",
    "time_or_word",
]


class UserError(ValueError):
    """A mistake in what the user gave the command line (an option's value, a combination of
    options): one line and exit code 2 on the command line."""


def floats(text: str | None, name: str) -> list[float] | None:
    if text is None:
        return None
    try:
        return [float(v) for v in text.replace(",", " ").split()]
    except ValueError:
        raise UserError(f"{name} must be numbers separated by commas, got {text!r}") from None


def converged(summary: dict[str, Any]) -> bool:
    from symplid.inference._diagnostics import ESS_THRESHOLD, RHAT_THRESHOLD

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
    from symplid.workflow._settings import Settings, load_settings, merge_overrides, parse_override

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


def compare_candidates(obs: Any, files: str, config: Path | None, orders: str | None,
                       overrides: dict[str, Any], sets: tuple[str, ...], integrators: Any,
                       out: Path | None, progress: bool, dampings: Any) -> Any:
    """``symplid compare --candidates a.toml,b.toml``: each file is one whole model, labelled
    by its name; the options and ``--set`` apply to every one."""
    from symplid.workflow._compare_candidates import compare_settings

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


def model_text(text: str | None) -> str | None:
    """``--potential``/``--hamiltonian``: ``FILE.py:NAME`` becomes ``file:FILE.py:NAME``; a family
    name or an expression is passed on as written."""
    if text is None:
        return None
    path, sep, name = text.strip().rpartition(":")
    if sep and path.endswith(".py") and not text.strip().startswith("file:"):
        return f"file:{path}:{name}"
    return text


def _merged_file(base: Any, config: Path) -> Any:
    """``base`` with the keys of the settings file ``config`` replaced (the others kept)."""
    import tomllib

    from symplid.workflow._settings import (
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
