"""Model comparison by the Laplace evidence: which polynomial order, which propagator, and
whether the dynamics need damping.

The paper fixes the model form (a cubic potential, eqs 17–18) and the propagator (leapfrog,
eq. 14). With data of an unknown system both are choices, and the marginal likelihood of the
data under each choice, p(Y | model) = ∫ L(θ; Y) π(θ) dθ (Section II-B.2, eqs 8–9), ranks
them: it rewards fit and penalises parameters the data do not need (the Occam factor).

:func:`compare_models` fits every (order, integrator, damping) candidate of a grid by MAP and
Hessian (:func:`symplid.inference.map.find_map`; no sampling) and ranks them by its log
evidence: Gaussian in the coefficients, the noise variances and a damped candidate's γ
integrated by quadrature on their log scale (:mod:`symplid.inference.map._evidence`). Laplace's

    log p(Y | model) ≈ log π(θ*) + log L(θ*) + (d/2) log 2π − ½ log det H

is kept beside it (``log_evidence_laplace``): it is 1–2 nats too low whenever a variance's
posterior is skewed against zero, which with leapfrog happens to the process variance in
nearly every fit, so it cannot rank candidates that differ in that respect.
Everything else in the settings (priors, dt, noise model, initial state, MAP starts and seed)
is the same for every candidate (``model.dt = "auto"`` is chosen once, for the grid's most
demanding model — highest order, lowest-order integrator, with damping and process noise if
any candidate has them — by :func:`symplid.workflow._step_size.choose_step`, and shared, so
that the evidences compare the models at one step) (with ``model.standardise`` on, every
candidate is fitted in the same standardised coordinates and reported in the data's units, so
the evidences stay comparable: :mod:`symplid.workflow._scaling`), so the priors must be
proper: the evidence of a candidate depends on the width of its coefficients' prior, and it is
this width that makes an unneeded coefficient cost about log(prior width / posterior width)
nats.

The table's columns are listed in :mod:`symplid.workflow._compare_table`, which also
writes it (``out/compare.csv`` and ``out/compare.txt``).

Example::

    from symplid.workflow._compare import compare_models, parse_orders
    table = compare_models(obs, settings, orders=parse_orders("2..5"),
                           integrators=["leapfrog", "rk2-midpoint"], out="runs/compare")
    # is damping needed? every candidate with and without γ
    table = compare_models(obs, settings, dampings=[False, True])
"""

from __future__ import annotations

import dataclasses
import os
import re
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from symplid.dynamics._integrators import INTEGRATORS, get_integrator
from symplid.inference.map import filter_start, find_map, without_process_var
from symplid.io import observation_layout
from symplid.model._data import DataError, Observations
from symplid.model._statespace import PROCESS_NOISE_CHOICES
from symplid.workflow._compare_table import (
    COLUMNS,
    CandidateFit,
    comparison_table,
    format_table,
    num_measured,
    write_comparison,
)
from symplid.workflow._fit import build_model, build_posterior, find_map_for
from symplid.workflow._model_builder import model_family
from symplid.workflow._scaling import resolve_standardise, scaling_for
from symplid.workflow._settings import Settings, resolve_for_data
from symplid.workflow._settings_schema import map_start
from symplid.workflow._step_size import choose_step

__all__ = [
    "COLUMNS",
    "CandidateFit",
    "compare_models",
    "comparison_table",
    "fit_candidates",
    "format_table",
    "parse_integrators",
    "parse_orders",
    "resolve_all",
    "write_comparison",
]

_RANGE = re.compile(r"^(\d+)\s*(?:\.\.|-|:)\s*(\d+)$")


# ----------------------------------------------------------------------------- parsing
def parse_orders(text: str | int | Sequence[int]) -> list[int]:
    """Polynomial orders from text such as ``"2..5"``, ``"2,3,5"``, ``"2..4,6"`` or ``"3"``.

    A range ``a..b`` includes both ends (``a-b`` and ``a:b`` are read the same way). An
    integer or a sequence of integers is accepted as is. The result is sorted, without
    repeats.

    Raises
    ------
    ValueError
        For text that is not a list of orders or ranges, an empty range (``"5..2"``), or an
        order below 1; the message quotes the offending part.
    """
    if isinstance(text, bool):
        raise ValueError(f"orders: expected e.g. '2..5' or '2,3,4', got {text!r}")
    if isinstance(text, int | np.integer):
        values = [int(text)]
    elif isinstance(text, str):
        parts = [p.strip() for p in text.split(",")]
        if not text.strip() or any(not p for p in parts):
            raise ValueError(f"orders: expected e.g. '2..5' or '2,3,4', got {text!r}")
        values = []
        for part in parts:
            match = _RANGE.match(part)
            if match:
                lo, hi = int(match.group(1)), int(match.group(2))
                if hi < lo:
                    raise ValueError(f"orders: {part!r} is an empty range (write '{hi}..{lo}')")
                values.extend(range(lo, hi + 1))
            elif part.isdigit():
                values.append(int(part))
            else:
                raise ValueError(
                    f"orders: {part!r} is not an order or a range (expected e.g. '2..5' or "
                    "'2,3,4')"
                )
    elif isinstance(text, Sequence):
        values = []
        for v in text:
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise ValueError(f"orders: {v!r} is not an integer")
            values.append(int(v))
        if not values:
            raise ValueError("orders: give at least one order")
    else:
        raise ValueError(f"orders: expected e.g. '2..5' or '2,3,4', got {text!r}")
    for v in values:
        if v < 1:
            raise ValueError(f"orders: {v} is not a polynomial order (orders are ≥ 1)")
    return sorted(set(values))


def parse_integrators(text: str | Sequence[str]) -> list[str]:
    """Integrator names from ``"leapfrog,rk2"`` or a list; canonical names, in the given order.

    Aliases are resolved (``"rk2"`` → ``"rk2-midpoint"``); repeats are dropped.

    Raises
    ------
    ValueError
        Naming the unknown integrator and listing the known ones.
    """
    if isinstance(text, str):
        names = [p.strip() for p in text.split(",")]
    else:
        names = [str(p).strip() for p in text]
    if not names or any(not n for n in names):
        raise ValueError(f"integrators: expected e.g. 'leapfrog,rk2-midpoint', got {text!r}")
    out: list[str] = []
    for name in names:
        try:
            canonical = get_integrator(name).name
        except ValueError:
            raise ValueError(
                f"integrators: {name!r} is not a known integrator (choose from "
                f"{', '.join(INTEGRATORS)})"
            ) from None
        if canonical not in out:
            out.append(canonical)
    return out


# ----------------------------------------------------------------------------- fitting
def _as_list(obs: Observations | Sequence[Observations]) -> list[Observations]:
    if isinstance(obs, Observations):
        return [obs]
    if isinstance(obs, Sequence) and not isinstance(obs, str):
        items = list(obs)
        if not items:
            raise DataError("no observations given: pass an Observations or a list of them")
        for k, item in enumerate(items):
            if not isinstance(item, Observations):
                raise TypeError(
                    f"obs[{k}] must be a symplid.Observations, got {type(item).__name__}"
                )
        return items
    raise TypeError(f"obs must be an Observations or a list of them, got {type(obs).__name__}")


def resolve_all(settings: Settings, datasets: list[Observations], source: str) -> Settings:
    """Settings resolved against every trajectory (they must share one layout; a known x0
    holds one state, so several trajectories need a learned one)."""

    resolved = resolve_for_data(settings, datasets[0], source)
    if len(datasets) > 1 and settings.initial_state.mode == "known":
        raise ValueError(
            f"{source}: initial_state.mode is 'known' but {len(datasets)} trajectories were "
            "given and initial_state.x0 holds one state; set initial_state.mode = \"learned\" "
            "(each trajectory's initial state is then learned)"
        )
    layout = observation_layout(datasets[0])
    for k, obs in enumerate(datasets[1:], start=1):
        other = observation_layout(obs)
        if other != layout:
            raise DataError(
                f"trajectory {k} has columns for {other.kind} observations of {other.dim} "
                f"degree(s) of freedom, trajectory 0 for {layout.kind} of {layout.dim}; "
                "trajectories compared together must share their columns"
            )
        resolve_for_data(settings, obs, source)  # checks t0 against its first time
    if settings.model.standardise == "auto" and len(datasets) > 1:  # the scale of them all
        model = dataclasses.replace(settings.model, order=resolved.model.order)
        standardise = resolve_standardise(model, datasets)
        resolved = dataclasses.replace(
            resolved, model=dataclasses.replace(resolved.model, standardise=standardise)
        )
    return resolved


def fit_candidates(
    obs: Observations | Sequence[Observations],
    settings: Settings,
    orders: Sequence[int] | str | int | None = None,
    integrators: Sequence[str] | str | None = None,
    progress: bool = True,
    source: str = "settings",
    dampings: Sequence[bool] | None = None,
    label: str | None = None,
    process_noises: Sequence[str] | None = None,
) -> list[CandidateFit]:
    """MAP and Hessian of every (order, integrator, damping, process noise) candidate, in
    grid order.

    Parameters are those of :func:`compare_models`; ``label`` names the model in the table
    (default: its family's name). Each candidate uses ``settings`` with
    ``model.order``, ``model.integrator``, ``model.damping`` and ``model.process_noise_per``
    replaced, and the MAP search of ``settings.map`` (its seed and number of starts), without
    the sampler. A candidate without process noise starts its MAP search from the MAP of the
    same candidate with process noise (:mod:`symplid.inference.map._homotopy`): the one fitted in
    this grid when there is one; otherwise a user model's declared starts come first.
    """

    datasets = _as_list(obs)
    order_list = [settings.model.order] if orders is None else parse_orders(orders)
    base = resolve_all(settings, datasets, source)
    # the settings' integrator as the data resolved it (a non-separable H: Tao's method)
    integrator_list = (
        [base.model.integrator] if integrators is None else parse_integrators(integrators)
    )
    damping_list = [settings.model.damping] if dampings is None else _dampings(dampings)
    noise_list = ([settings.model.process_noise_per] if process_noises is None
                  else _process_noises(process_noises))
    if base.model.dt == "auto":  # one step for all
        base = _shared_step(base, datasets, (order_list, integrator_list, damping_list,
                                             noise_list))
    grid = [(o, i, g, n) for n in noise_list for g in damping_list for i in integrator_list
            for o in order_list]
    fits: list[CandidateFit] = []
    with_noise: dict[tuple, np.ndarray] = {}  # the MAP with process noise, to start from
    bar = _progress(len(grid), progress)
    try:
        for order, integrator, damping, noise in grid:
            bar.set_postfix_str(f"order {order}, {integrator}" + (", damped" if damping else "")
                                + (", no process noise" if noise == "none" else ""))
            fits.append(_fit_candidate(base, datasets, (order, integrator, damping, noise),
                                       with_noise, label))
            bar.update(1)
    finally:
        bar.close()
    return fits


def _shared_step(base: Settings, datasets: list[Observations],
                 grid: tuple[list[int], list[str], list[bool], list[str]]) -> Settings:
    """``base`` with ``model.dt = "auto"`` chosen once (:func:`choose_step`) for the grid's
    most demanding candidate — its highest order, its integrator of lowest order, damped if
    any candidate is, with process noise if any candidate has it (the filter's MAP is a
    smooth search; the deterministic path's is not) — so that every candidate is compared
    at a step fine enough for each."""
    orders, integrators, dampings, noises = grid
    model = dataclasses.replace(
        base.model, order=max(orders), damping=any(dampings),
        integrator=min(integrators, key=lambda name: get_integrator(name).order),
        process_noise_per=next((n for n in noises if n != "none"), noises[0]))
    chosen = choose_step(dataclasses.replace(base, model=model),
                         datasets if len(datasets) > 1 else datasets[0], search=find_map_for)
    return dataclasses.replace(base, model=dataclasses.replace(base.model,
                                                               dt=chosen.settings.model.dt))


def _fit_candidate(base: Settings, datasets: list[Observations],
                   candidate: tuple[int, str, bool, str], with_noise: dict[tuple, np.ndarray],
                   label: str | None) -> CandidateFit:
    """The MAP of one (order, integrator, damping, process noise) candidate of
    :func:`fit_candidates`; a candidate with process noise leaves its MAP in ``with_noise``
    for the same candidate without."""
    order, integrator, damping, noise = candidate
    model_settings = dataclasses.replace(base.model, order=order, integrator=integrator,
                                         damping=damping, process_noise_per=noise)
    s = dataclasses.replace(base, model=model_settings)
    start = time.perf_counter()
    # model.standardise: fit on q/a, p/a, report in the data's units (workflow.scaling)
    scaling = scaling_for(s, datasets)
    fit_s = s if scaling is None else scaling.settings(s)
    fit_sets = datasets if scaling is None else [scaling.observations(d) for d in datasets]
    fit_data = fit_sets[0] if len(fit_sets) == 1 else fit_sets
    model = build_model(fit_s, fit_sets[0])
    posterior = build_posterior(fit_s, fit_data, model)  # type: ignore[arg-type]
    init = _start_without_noise(posterior, with_noise.get((order, integrator, damping)), s)
    result = find_map(
        posterior, seed=s.map.seed, num_starts=s.map.num_starts, warn=False,
        init=map_start(s) if init is None else init,  # declared starts, if any
    )
    if noise != "none":
        with_noise[(order, integrator, damping)] = without_process_var(
            posterior.param_groups, result.theta)
    seconds = time.perf_counter() - start
    log_prior = float(posterior.log_prior(np.asarray(result.theta)))
    log_likelihood = result.log_posterior - log_prior
    if scaling is not None:
        result = scaling.map_result(result, posterior.param_groups, datasets)
        log_likelihood += scaling.log_likelihood_shift(datasets)
    return CandidateFit(order, integrator, s, posterior, result, log_likelihood, seconds,
                        damping, label or model_family(s.model).name, noise)


def _process_noises(values: Sequence[str]) -> list[str]:
    """The process-noise choices of a comparison (``model.process_noise_per`` values),
    without repeats, those with process noise first (a candidate without starts from one
    with)."""
    out: list[str] = []
    for v in values:
        if v not in PROCESS_NOISE_CHOICES:
            raise ValueError(f"process noise: expected {', '.join(PROCESS_NOISE_CHOICES)}, "
                             f"got {v!r}")
        if v not in out:
            out.append(str(v))
    if not out:
        raise ValueError("process noise: give at least one of gap, none")
    return sorted(out, key=lambda v: v == "none")


def _start_without_noise(posterior: Any, fitted: np.ndarray | None, s: Settings) -> Any:
    """The first MAP start of a candidate: None (the default) with process noise; without,
    the MAP of its twin with process noise (``fitted`` when the grid has it)."""
    if not getattr(posterior.model, "deterministic", False):
        return None
    if fitted is not None and np.all(np.isfinite(fitted)):
        return fitted
    return filter_start(posterior, seed=s.map.seed, num_starts=s.map.num_starts,
                        init=map_start(s))


def _dampings(values: Sequence[bool]) -> list[bool]:
    """The damping choices of a comparison, without repeats (each must be a bool)."""
    out: list[bool] = []
    for v in values:
        if not isinstance(v, bool | np.bool_):
            raise ValueError(f"dampings: expected true/false values, got {v!r}")
        if bool(v) not in out:
            out.append(bool(v))
    if not out:
        raise ValueError("dampings: give at least one of false, true")
    return out


def _progress(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="compare", unit="model", disable=not enabled, leave=False)


# ----------------------------------------------------------------------------- entry point
def compare_models(
    obs: Observations | Sequence[Observations],
    settings: Settings,
    orders: Sequence[int] | str | int | None = None,
    integrators: Sequence[str] | str | None = None,
    out: str | os.PathLike | None = None,
    progress: bool = True,
    source: str = "settings",
    dampings: Sequence[bool] | None = None,
    process_noises: Sequence[str] | None = None,
) -> pd.DataFrame:
    """Rank polynomial orders, propagators and damping by the log evidence (MAP only).

    Parameters
    ----------
    obs
        The data: one :class:`~symplid.model._data.Observations`, or a list of trajectories sharing
        the potential (each with its own initial state; known initial states need one x0 per
        trajectory, so from a settings file use ``initial_state.mode = "learned"``).
    settings
        Run settings; everything but ``model.order`` and ``model.integrator`` is shared by the
        candidates (priors, dt, noise, initial state, ``[map]`` starts and seed). The sampler
        settings are not used.
    orders
        Polynomial orders: a list, or text for :func:`parse_orders` (``"2..5"``); None: the
        settings' order only.
    integrators
        Propagator names, or text for :func:`parse_integrators` (``"leapfrog,rk2"``); None:
        the settings' integrator only.
    out
        A folder to write ``compare.csv`` and ``compare.txt`` into (None: write nothing).
    progress
        Show a progress bar over the candidates.
    source
        Where the settings came from (a file name), for error messages.
    dampings
        Damping choices, e.g. ``[False, True]``: every candidate without and with a learned
        damping rate γ, so the evidence says whether the data need dissipation; None: the
        settings' ``model.damping`` only.
    process_noises
        Process-noise choices (``model.process_noise_per`` values), e.g. ``["gap", "none"]``:
        every candidate with and without process noise, so the evidence says whether the data
        need it (a candidate without is fitted from the MAP of the one with); None: the
        settings' choice only.

    Returns
    -------
    pandas.DataFrame
        One row per candidate, best first, with the columns of :data:`COLUMNS` and then
        one per coefficient name (NaN where a candidate lacks that coefficient).
    """
    fits = fit_candidates(obs, settings, orders, integrators, progress, source, dampings,
                          process_noises=process_noises)
    table = comparison_table(fits)
    if out is not None:
        n = num_measured(fits[0])
        k = len(fits[0].posterior.datasets)
        title = (
            f"Model comparison: {len(fits)} candidate(s), {n} measured values in {k} "
            f"trajectory(ies), learning dt = {fits[0].settings.model.dt:g}"
        )
        write_comparison(table, out, title)
    return table
