"""Comparison of whole models by the log evidence: each candidate its own settings.

:func:`symplid.workflow._compare.compare_models` ranks the polynomial orders, propagators and
damping of one model family. A user who has written two models of their own (two
expressions, say a pendulum's k(1 − cos q) and a harmonic ½kq²) compares them here, each
from its own settings file (``symplid compare DATA --candidates a.toml,b.toml``); the table
is the same, with the ``model`` column naming each candidate.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import pandas as pd

from symplid.model._data import Observations
from symplid.workflow._compare import (
    CandidateFit,
    comparison_table,
    fit_candidates,
    parse_orders,
    write_comparison,
)
from symplid.workflow._model_builder import model_family
from symplid.workflow._settings import Settings, settings_to_dict

__all__ = ["MODEL_SECTIONS", "candidate_orders", "check_distinct", "compare_settings"]

#: The sections of the settings that make a model (what its evidence depends on).
MODEL_SECTIONS = ("model", "priors", "initial_state")


def candidate_orders(settings: Settings, orders: str | None) -> list[int] | None:
    """The orders a comparison tries: ``orders`` (text for :func:`parse_orders`) for the
    polynomial family, 2..5 when not given; None (the model itself) for any other family,
    whose ``model.order`` is not read. Orders given for another family are an error."""
    family = model_family(settings.model).name
    if family == "polynomial":
        return parse_orders(orders if orders is not None else "2..5")
    if orders is not None:
        raise ValueError(f"--orders applies to the polynomial family; the model is "
                         f"{family!r} (one candidate): drop --orders")
    return None


def check_distinct(candidates: Sequence[tuple[str, Settings]]) -> None:
    """Refuse (one line) two candidates with one label, or two that are the same model
    (equal :data:`MODEL_SECTIONS`): the table would rank a model against itself, at even
    odds, without a word."""
    seen: dict[str, str] = {}
    for label, settings in candidates:
        as_dict = settings_to_dict(settings)
        key = repr([as_dict.get(name) for name in MODEL_SECTIONS])
        if label in seen.values():
            raise ValueError(f"two candidates are named {label!r}; give each model once, "
                             "under its own name")
        if key in seen:
            raise ValueError(f"candidates {seen[key]!r} and {label!r} are the same model "
                             f"(equal [{'], ['.join(MODEL_SECTIONS)}]); give each model once")
        seen[key] = label


def compare_settings(
    obs: Observations | Sequence[Observations],
    candidates: Sequence[tuple[str, Settings]],
    integrators: Sequence[str] | str | None = None,
    out: str | os.PathLike | None = None,
    progress: bool = True,
    dampings: Sequence[bool] | None = None,
) -> pd.DataFrame:
    """Rank whole models, each from its own settings (e.g. two users' expressions), by the
    log evidence; ``candidates`` are ``(label, settings)`` pairs, the label naming the row.

    Each candidate is fitted as by :func:`compare_models` with its own priors, model and
    ``[map]`` (a polynomial candidate at its ``model.order``); ``integrators`` and
    ``dampings`` apply to every one. The evidences are comparable when every candidate's
    priors are proper.
    """
    if len(candidates) < 1:
        raise ValueError("give at least one candidate")
    check_distinct(candidates)
    fits: list[CandidateFit] = []
    for label, settings in candidates:
        fits += fit_candidates(obs, settings, None, integrators, progress, label, dampings,
                               label=label)
    table = comparison_table(fits)
    if out is not None:
        write_comparison(table, out, f"Model comparison: {len(fits)} candidate(s) "
                         f"({', '.join(label for label, _ in candidates)})")
    return table
