"""Settings against a data set: what the data decide (the observation kind) and what they must
offer the model (two times, no empty column, gaps the integrator can cross).

The checks of :func:`symplid.workflow._plan.resolve_for_data` (what every fit runs before it
builds a model; re-exported by :mod:`symplid.workflow._settings`): :func:`check_layout` before
the model's U or H is built, :func:`check_data` with it.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import Any

import numpy as np

from symplid.inference.samplers import SAMPLERS
from symplid.io import observation_layout
from symplid.model._data import DataError
from symplid.model._statespace import HamiltonianModel
from symplid.workflow._auto import resolve_noise
from symplid.workflow._model_builder import model_family
from symplid.workflow._scaling import resolve_standardise
from symplid.workflow._settings_schema import Settings
from symplid.workflow._validate import SettingsError

__all__ = ["MAX_DATA_MAGNITUDE", "MAX_SUBSTEPS_PER_GAP", "available_memory", "check_data",
           "check_layout", "run_memory"]

#: The most integrator steps one gap between observations may take (⌈gap/dt⌉, eq. 14). The
#: filter unrolls every gap into the same number of steps, so one huge gap (a time of 1e9 in a
#: file) would otherwise ask for billions of steps and terabytes of memory.
MAX_SUBSTEPS_PER_GAP = 1_000_000

#: The largest magnitude a data value may have: the filter works with squares and products of
#: the data (covariances, eq. (11)–(13)), which must stay far from float64's overflow (1.8e308).
MAX_DATA_MAGNITUDE = 1e100


def check_layout(settings: Settings, trajectories: list[Any], source: str) -> str:
    """The settings' observation kind and initial state against the data's columns; returns
    the observation kind (``model.observation = "auto"`` resolved). The first checks of
    :func:`~symplid.workflow._plan.resolve_for_data`."""
    layout = observation_layout(trajectories[0])
    d, K = layout.dim, len(trajectories)
    model = settings.model
    observation = layout.kind if model.observation == "auto" else model.observation
    if observation != layout.kind:
        have = "only positions (q1..qd)" if layout.kind == "positions" else "positions and momenta"
        raise SettingsError(
            source,
            "model.observation",
            f'is {model.observation!r} but the data have {have}; use "auto"',
        )
    init = settings.initial_state
    if init.mode == "known" and not init.x0:
        raise SettingsError(
            source,
            "initial_state.x0",
            f"is empty but initial_state.mode is 'known': give x0 ({2 * d} numbers, "
            'q1..qd then p1..pd) or set mode = "learned"',
        )
    if init.x0 and len(init.x0) not in (2 * d, 2 * d * K):
        each = f" (or {2 * d * K}: one state per trajectory)" if K > 1 else ""
        raise SettingsError(
            source,
            "initial_state.x0",
            f"has {len(init.x0)} numbers but the data's system has a {2 * d}-dimensional "
            f"state (q1..q{d}, p1..p{d}){each}",
        )
    if model.mass and len(model.mass) != d:
        raise SettingsError(source, "model.mass", f"has {len(model.mass)} numbers, expected {d}")
    return observation


def check_data(settings: Settings, trajectories: list[Any], source: str, family: Any,
               observation: str) -> Settings:
    """The data against the model of ``settings`` (its U or H ``family``, built once), and
    the settings the data decide; the last checks of
    :func:`~symplid.workflow._plan.resolve_for_data` (see there)."""
    settings = _at_first_when_equal(settings, trajectories)
    K, model = len(trajectories), settings.model
    for k, one in enumerate(trajectories):
        _check_data(one, settings, source if K == 1 else f"{source} (trajectory {k})")
    _warn_few_values(trajectories, settings, source, family)
    try:
        standardise = resolve_standardise(model, trajectories)
    except ValueError as err:
        raise SettingsError(source, "model.standardise", str(err)) from None
    resolved = dataclasses.replace(
        model,
        observation=observation,
        noise=resolve_noise(model.noise, observation),
        standardise=standardise,
    )
    return dataclasses.replace(settings, model=resolved)


def _at_first_when_equal(settings: Settings, trajectories: list[Any]) -> Settings:
    """``initial_state.t0 = "first"`` when the numeric t0 is every trajectory's first
    observation time: a state at the time of the first datum is the state the first update
    conditions (the default t0 = 0 with data that start at t = 0)."""
    init = settings.initial_state
    if init.at_first_observation:
        return settings
    firsts = {float(np.asarray(one.times, dtype=float)[0]) for one in trajectories
              if np.asarray(one.times).size}
    if firsts != {float(init.t0)}:
        return settings
    return dataclasses.replace(settings, initial_state=dataclasses.replace(init, t0="first"))


def _check_data(obs: Any, settings: Settings, source: str) -> None:
    """What a data set must offer the model of ``settings`` (see :func:`resolve_for_data`)."""
    init, model = settings.initial_state, settings.model
    times = np.asarray(obs.times, dtype=float)
    if times.size < 2:
        raise DataError(
            f"the data have {times.size} observation time; at least 2 are needed to learn "
            "the dynamics"
        )
    names = obs.names or tuple(f"column {j + 1}" for j in range(obs.dim))
    empty = [names[j] for j in range(obs.dim) if not np.any(obs.mask[:, j])]
    if empty:
        raise DataError(
            f"{', '.join(empty)} {'has' if len(empty) == 1 else 'have'} no values (every "
            "entry is missing); remove the column or give its values"
        )
    _check_magnitude(obs, times, names)
    first = float(times[0])
    if init.at_first_observation:
        starts = times[:-1]
    else:
        if not init.t0 < first:
            raise SettingsError(
                source,
                "initial_state.t0",
                f"({init.t0:g}) must be before the first observation time ({first:g}); "
                't0 = "first" puts the initial state at the first observation',
            )
        starts = np.concatenate([[float(init.t0)], times[:-1]])
    gaps = times[-starts.size :] - starts
    # "auto": the first step the fit tries is the smallest gap (symplid.workflow._step_size)
    dt = float(np.min(gaps[gaps > 0], initial=np.inf)) if model.dt == "auto" else model.dt
    steps = np.ceil(gaps / dt)
    if np.max(steps) > MAX_SUBSTEPS_PER_GAP:
        k = int(np.argmax(steps))
        raise DataError(
            f"the gap from t = {starts[k]:g} to the next observation needs {steps[k]:.3g} "
            f"integrator steps of model.dt = {dt:g}; at most {MAX_SUBSTEPS_PER_GAP:,} "
            "are allowed per gap (check the time column, or raise model.dt)"
        )
    if init.mode == "learned" and not init.x0 and not init.at_first_observation:
        lead = first - float(init.t0)
        if times.size > 1 and lead > float(np.max(np.diff(times))):
            warnings.warn(
                f"{source}: the learned initial state sits at t0 = {init.t0:g} but its prior "
                f"is centred on the first observation at t = {first:g}; set "
                'initial_state.t0 = "first" (--t0 first) to put the state there',
                UserWarning,
                stacklevel=3,
            )


def _check_magnitude(obs: Any, times: np.ndarray, names: tuple[str, ...]) -> None:
    """Refuse (one line) a value whose square (in the filter's covariances) would overflow."""
    values = np.where(obs.mask, np.asarray(obs.values, dtype=float), 0.0)
    big = np.abs(values) > MAX_DATA_MAGNITUDE
    if np.any(big):
        k, j = (int(i[0]) for i in np.nonzero(big))
        raise DataError(
            f"the value {values[k, j]:g} of {names[j]} at t = {times[k]:g} is too large: the "
            f"filter squares the data, so values must stay within ±{MAX_DATA_MAGNITUDE:g} "
            "(check the file, or change the units)")


def _warn_few_values(trajectories: list[Any], settings: Settings, source: str,
                     family: Any) -> None:
    """One line when θ has more entries than the data have values (all trajectories); a
    model the integrator cannot take (a non-separable H with leapfrog) is refused here."""
    model, init = settings.model, settings.initial_state
    values = sum(int(np.sum(obs.mask)) for obs in trajectories)
    layout = observation_layout(trajectories[0])
    d = layout.dim
    try:  # the model itself: its size, and whether the integrator can take its H
        built = HamiltonianModel(family, model.integrator,
                                 observation=layout.kind,
                                 noise=resolve_noise(model.noise, layout.kind),
                                 observation_noise=model.observation_noise,
                                 damping=model.damping)
    except ValueError as err:
        raise SettingsError(source, "model.integrator", f"({model.integrator!r}): {err}") from None
    num_params = built.num_params + (2 * d * len(trajectories) if init.mode == "learned" else 0)
    num_times = sum(int(np.asarray(obs.times).size) for obs in trajectories)
    _check_memory(settings, num_params, num_times, built.state_dim, source)
    _check_cap(settings, num_params, source)
    if num_params > values:
        name = model_family(model).name
        what = f"order {model.order}" if name == "polynomial" else f"{name!r}"
        warnings.warn(f"{source}: the model has {num_params} parameters ({what}) for {values} "
                      "data values; the priors decide most of the posterior (a smaller model, "
                      "or more data)", UserWarning, stacklevel=3)


def _dim(obs: Any) -> int:
    """The configuration dimension d of the system the data observe."""
    return observation_layout(obs).dim


#: Floats the samplers record per draw besides θ (log posterior, acceptance, step sizes, ...).
_STATS_PER_DRAW = 8


def run_memory(settings: Settings, num_params: int, num_times: int, state_dim: int) -> int:
    """Bytes a fit's sampler needs, as an estimate from above (float64 throughout).

    Per chain: its kept draws of θ and their statistics, held three times (the chains'
    arrays, ArviZ's dataset, the netCDF file made in memory); the sampler's own state (a few
    P × P matrices: proposal and adaptation); the filter's working arrays along the data (eq.
    (9)–(13): per time, the 2n + 1 sigma points and n × n covariances, kept for a gradient).
    """
    s = settings.sampler
    draws = 3 * s.max_draws * (num_params + _STATS_PER_DRAW)
    sampler = 4 * num_params**2
    n = state_dim
    filter_ = 4 * num_times * n * (3 * n + 1)
    return 8 * s.num_chains * (draws + sampler + filter_)


def available_memory() -> int | None:
    """Bytes of memory this machine can give now (``MemAvailable``; the physical memory where
    that is unknown; None where neither is)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None


def _check_cap(settings: Settings, num_params: int, source: str) -> None:
    """Refuse (one line) a cap on the iterations of ``num_iterations = "auto"`` that leaves no
    draw after the sampler's first burn-in for this many parameters."""
    s = settings.sampler
    if s.fixed or s.resolved_burn_in is not None:
        return  # a fixed budget, or a burn-in given: checked by the settings alone
    first = SAMPLERS[s.method].first_burn_in(num_params)
    if first >= s.max_iterations:
        raise SettingsError(
            source, "sampler.max_iterations",
            f"({s.max_iterations:,}) must be greater than the first burn-in of {s.method} for "
            f"{num_params} parameters ({first:,} iterations); raise it or set sampler.burn_in")


def _check_memory(settings: Settings, num_params: int, num_times: int, state_dim: int,
                  source: str) -> None:
    """Refuse (one line) before anything is allocated a sampler whose chains × draws ×
    parameters cannot fit in this machine's memory (as gaps needing too many substeps are)."""
    need, have = run_memory(settings, num_params, num_times, state_dim), available_memory()
    if have is None or need <= have:
        return
    s = settings.sampler
    raise SettingsError(
        source, "sampler.num_chains",
        f"({s.num_chains:,}) × {s.max_draws:,} draws kept per chain × {num_params} parameters "
        f"need about {need / 2**30:,.1f} GiB of memory, more than the {have / 2**30:,.1f} GiB "
        "available; use fewer chains or iterations, or thin (sampler.thin)")
