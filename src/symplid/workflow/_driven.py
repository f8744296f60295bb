"""Driven models in a run: the force of ``model.force`` and the inputs of ``[inputs]``.

A run whose settings give ``model.force`` (:mod:`symplid.dynamics._forcing`) is driven: its
data carry the inputs u(t) (:mod:`symplid.model._inputs`), read here from what ``[inputs]``
says — the data file's input columns (``u1, u2, …`` or ``inputs.columns``, possibly on a
denser grid than the observations), a file of their own (``inputs.file``) or expressions in t
(``inputs.expressions``). The declared parameters that the force's expressions name are the
force's (θ's ``force`` block); the others are H's. A run folder keeps sampled inputs beside
its data (``inputs.csv``), so that its report, predictions and a resumed fit read them back.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from symplid.dynamics._forcing import INPUT_NAME, Force, force_parameters, user_force
from symplid.dynamics._user_models import UserModelError
from symplid.io import read_trajectories
from symplid.io._inputfiles import INPUT_COLUMN, read_driven_csv, read_input_file
from symplid.model._data import DataError, Observations
from symplid.model._inputs import AnalyticInputs, InputSignal, SampledInputs

__all__ = [
    "INPUTS_FILE",
    "attach_inputs",
    "build_force",
    "force_names",
    "force_texts",
    "hamiltonian_parameters",
    "is_driven",
    "power_balance_lines",
    "predicted_inputs",
    "read_data_for",
    "read_driven",
    "read_run_inputs",
    "refuse_forecast",
    "simulate_driven",
    "write_run_inputs",
]

#: The file of a run folder that keeps a driven run's sampled inputs.
INPUTS_FILE = "inputs.csv"


def is_driven(model: Any) -> bool:
    """Whether the model settings give a force."""
    return bool(str(getattr(model, "force", "")).strip())


def force_texts(model: Any) -> str | tuple[str, ...]:
    """``model.force`` as the force's expressions (one per momentum), or a ``file:`` spec."""
    text = str(model.force).strip()
    if text.startswith("file:"):
        return text
    return tuple(part.strip() for part in text.split(";") if part.strip())


def force_names(model: Any) -> tuple[str, ...]:
    """The declared parameters that belong to the force, in the order declared (every one
    for a ``file:`` force that H does not name)."""
    if not is_driven(model):
        return ()
    declared = tuple(p.name for p in model.parameters)
    texts = force_texts(model)
    if isinstance(texts, str):  # a file: what H's expression does not name
        h_text = model.hamiltonian if model.hamiltonian != "separable" else model.potential
        return tuple(n for n in declared if n not in force_parameters(h_text, declared))
    return force_parameters(texts, declared)


def hamiltonian_parameters(model: Any) -> tuple[str, ...]:
    """The declared parameters of H (or U): those the force does not take."""
    own = set(force_names(model))
    return tuple(p.name for p in model.parameters if p.name not in own)


def _num_inputs(texts: str | tuple[str, ...], data: Any) -> int:
    signal = getattr(data, "inputs", None)
    have = signal.num_inputs if signal is not None else 0
    if isinstance(texts, str):
        return have
    used = [int(m) for text in texts for m in re.findall(r"\bu([1-9][0-9]*)\b", text)]
    return max([have, *used])


def build_force(model: Any, dim: int, data: Any = None) -> Force | None:
    """The force of the model settings for ``dim`` coordinates (None for free motion).

    Raises
    ------
    UserModelError
        One line, as for a user's model: an expression that cannot be read, an unknown name.
    """
    if not is_driven(model):
        return None
    texts = force_texts(model)
    first = data[0] if isinstance(data, list | tuple) and data else data
    names = force_names(model)
    clash = {"t", *(n for n in names if INPUT_COLUMN.match(n))}
    bad = [p.name for p in model.parameters if p.name in clash]
    if bad:
        raise UserModelError(f"model.parameters: {bad[0]!r} names the time or an input of the "
                             "force; choose another name")
    return user_force(texts, dim, names, _num_inputs(texts, first),
                      max_size=model.max_expression_size)


# ---------------------------------------------------------------------------- inputs
def _analytic(inputs: Any) -> AnalyticInputs:
    expressions = {INPUT_NAME.format(k + 1): text for k, text in enumerate(inputs.expressions)}
    return AnalyticInputs(expressions)


def attach_inputs(obs: Any, inputs: Any, signal: Any = None) -> Any:
    """``obs`` (one or a list) with the inputs that ``inputs`` settings give: ``signal``
    when given (a run folder's), the expressions, or ``inputs.file``."""
    if signal is None:
        if inputs.expressions:
            signal = _analytic(inputs)
        elif inputs.file:
            signal = read_input_file(Path(inputs.file).expanduser(), inputs.interpolation)
        else:
            return obs
    if isinstance(obs, list):
        return [replace(o, inputs=signal) for o in obs]
    return replace(obs, inputs=signal)


def read_driven(paths: Sequence[Path], settings: Any) -> Observations | list[Observations]:
    """The data of a driven run with their inputs (module docstring).

    Raises
    ------
    DataError
        One line: no inputs where the force reads some, a missing input value, several data
        files with input columns.
    """
    inputs = settings.inputs
    if inputs.expressions or inputs.file:
        if inputs.expressions and inputs.file:
            raise DataError("give the inputs once: inputs.expressions or inputs.file")
        return attach_inputs(read_trajectories(list(paths)), inputs)
    if len(paths) != 1:
        raise DataError("a driven model reads its inputs from the columns of one data file "
                        "(or give inputs.file or inputs.expressions)")
    return read_driven_csv(paths[0], inputs.columns, inputs.interpolation)


def read_data_for(path: Path, settings: Any) -> Any:
    """One data file for ``settings``: with its inputs when they are driven, else as it is."""
    if is_driven(settings.model):
        return read_driven([Path(path)], settings)
    from symplid.io import read_observations

    return read_observations(path)


def write_run_inputs(folder: Path, obs: Any) -> Path | None:
    """Write a driven run's sampled inputs to ``folder``/inputs.csv (nothing for none or
    for expressions, which the settings keep)."""
    first = obs[0] if isinstance(obs, list) else obs
    signal = getattr(first, "inputs", None)
    if not isinstance(signal, SampledInputs):
        return None
    path = Path(folder) / INPUTS_FILE
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(("t", *signal.names))
        for t, row in zip(signal.times, signal.values, strict=True):
            writer.writerow((repr(float(t)), *(repr(float(v)) for v in row)))
    return path


def read_run_inputs(folder: Path, obs: Any, settings: Any) -> Any:
    """A run's data with its inputs: inputs.csv when the run has one, else the settings'."""
    if not is_driven(settings.model):
        return obs
    path = Path(folder) / INPUTS_FILE
    if path.exists():
        signal = read_input_file(path, settings.inputs.interpolation)
        return attach_inputs(obs, settings.inputs, signal)
    return attach_inputs(obs, settings.inputs)



# ---------------------------------------------------------------------------- predictions
def _merged(signal: Any, future: SampledInputs) -> SampledInputs:
    """The run's samples before the future file's first time, then the future file's."""
    if not isinstance(signal, SampledInputs):
        return future
    if future.num_inputs != signal.num_inputs:
        raise DataError(f"the future inputs have {future.num_inputs} column(s), the run's "
                        f"{signal.num_inputs}")
    before = signal.times < future.times[0]
    return SampledInputs(np.concatenate([signal.times[before], future.times]),
                         np.concatenate([signal.values[before], future.values]),
                         signal.names, signal.interpolation)


def predicted_inputs(obs: Any, settings: Any, t_end: float, future: Path | None = None) -> Any:
    """A driven run's data with the inputs a prediction to ``t_end`` needs: the future
    inputs of ``future`` (a CSV ``t,u1,…``) appended to the run's, which must then cover
    [t0, t_end].

    Raises
    ------
    DataError
        One line: the inputs do not reach ``t_end`` and no ``--inputs`` file was given.
    """
    if not is_driven(settings.model):
        if future is not None:
            raise DataError("--inputs gives the future inputs of a driven run (model.force); "
                            "this run has no force")
        return obs
    trajectories = obs if isinstance(obs, list) else [obs]
    out = []
    for one in trajectories:
        signal = one.inputs
        if future is not None:
            signal = _merged(signal, read_input_file(future, settings.inputs.interpolation))
        if signal is None or signal.span[1] < t_end - 1e-9 * max(1.0, abs(t_end)):
            reach = "no inputs" if signal is None else f"inputs to t = {signal.span[1]:g}"
            raise DataError(f"the run is driven and has {reach}: predicting to t = "
                            f"{t_end:g} needs the future inputs (--inputs FUTURE.csv with "
                            "columns t,u1,…)")
        out.append(replace(one, inputs=signal))
    return out if isinstance(obs, list) else out[0]


def refuse_forecast(settings: Any, what: str) -> None:
    """One line for what has no driven form yet (forecasts from the filter's last state)."""
    if is_driven(settings.model):
        raise DataError(f"{what} of a driven run (model.force) is not available yet: predict "
                        "paths from the initial state instead (symplid predict RUN --inputs "
                        "FUTURE.csv)")


# ---------------------------------------------------------------------------- report
def power_balance_lines(settings: Any, model: Any, posterior: Any, theta_map: Any) -> list[str]:
    """The report's "Power balance" section of a driven run: per trajectory, along the MAP
    path over the data (:func:`~symplid.inference._driven.power_balance`), the input's work,
    the rest of the force's work (minus the dissipation), the change of H and the largest
    gap's imbalance."""
    from symplid.inference._driven import power_balance

    if getattr(model, "force", None) is None:
        return []
    nc = model.num_dynamics_params
    lines = ["## Power balance", "",
             "Along the MAP path over the data: dH/dt = ∂H/∂p · F, the input's power "
             "(F − F at u = 0) and the rest of the force's (friction: minus the dissipation).",
             "", "| trajectory | input work | other work | ΔH | largest gap imbalance |",
             "|---|---|---|---|---|"]
    for k, obs in enumerate(posterior.datasets):
        t0 = settings.initial_state.start_time(obs.times[0])
        x0 = np.asarray(posterior.initial_state(theta_map, k))
        times = obs.times[obs.times > t0]
        dt = min(settings.prediction.dt, float(np.min(np.diff(times))) / 4)
        b = power_balance(model, obs.inputs, np.asarray(theta_map[:nc]), x0, t0, times, dt,
                          settings.prediction.integrator)
        lines.append(f"| {k} | {b['work_input'].sum():.4g} | {b['work_other'].sum():.4g} | "
                     f"{b['dH'].sum():.4g} | {np.abs(b['residual']).max():.2g} |")
    return [*lines, ""]


# ---------------------------------------------------------------------------- simulate
class _FunctionInputs(InputSignal):
    """A signal from a function of t (a named excitation of
    :data:`~symplid.systems.SIGNALS`), defined at every time."""

    def __init__(self, fn: Any) -> None:
        self.names = ("u1",)
        self._fn = fn

    @property
    def span(self) -> tuple[float, float]:
        return -np.inf, np.inf

    def evaluate(self, times: Any) -> np.ndarray:
        t = np.asarray(times, dtype=float)
        return np.asarray(self._fn(t), dtype=float)[..., None]


def simulate_driven(system: str, out: Path, force_text: str, signal: str, signal_seed: int,
                    amplitude: float, t_end: float | None, num_obs: int | None,
                    noise_std: float | None, seed: int, observation: str | None,
                    dense: int = 5) -> str:
    """``symplid simulate SYSTEM --force F --input NAME``: a driven record of a named system.

    The force (numbers, q, p, u1, t: no parameters) acts on the system's H; u1 is a named
    signal of :data:`~symplid.systems.SIGNALS` (seeded) or a CSV ``t,u1``. The truth is
    the forced yoshida4 (rk4 for a non-separable H) at step 1e-3 against the signal itself;
    the file holds t, the observed columns with noise at the observation times, and u1 on a
    grid ``dense`` times finer (rows with empty observed cells). Returns its one line.
    """
    from symplid.dynamics._forced import bind_forced, forced_solve_gaps, with_force
    from symplid.dynamics._hamiltonians import is_hamiltonian
    from symplid.dynamics._systems import get_system
    from symplid.dynamics._trajectory import substeps
    from symplid.model._inputs import node_table
    from symplid.model._signals import SIGNALS

    sys_ = get_system(system)
    if sys_.damping:
        raise DataError(f"{sys_.name} is damped: write its friction into --force "
                        "(e.g. '- 0.1*p1') and simulate its undamped form")
    n = int(num_obs or sys_.num_obs)
    end = float(t_end if t_end is not None else sys_.obs_interval * n)
    if end <= 0:
        raise DataError(f"--t-end must be positive, got {end:g}")
    times = end / n * np.arange(1, n + 1)
    dim = sys_.potential.dim
    force = user_force(force_text, dim, (), 1, key="--force")
    if signal.lower().endswith(".csv"):
        source: Any = read_input_file(Path(signal), "cubic")
    else:
        source = _FunctionInputs(SIGNALS.get_entry(signal)(
            amplitude=amplitude, seed=signal_seed, duration=end + 1.0))
    integrator = with_force("rk4" if is_hamiltonian(sys_.potential) else "yoshida4")
    counts, sizes = substeps(np.diff(np.concatenate([[0.0], times])), 1e-3)
    nodes, inputs = node_table(source, 0.0, sizes, counts, integrator.nodes, 1)
    dynamics = bind_forced(sys_.potential, force, np.asarray(sys_.coefficients, dtype=float))
    states = np.asarray(forced_solve_gaps(integrator, dynamics, np.asarray(
        sys_.initial_state, dtype=float), sizes, counts, nodes, inputs, int(counts.max())))
    kind = observation or sys_.observation
    observed = states if kind == "full" else states[:, :dim]
    rng = np.random.default_rng(seed)
    sd = sys_.noise_std if noise_std is None else noise_std
    observed = observed + sd * rng.standard_normal(observed.shape)
    grid = end / (n * dense) * np.arange(0, n * dense + 1)
    u = source.evaluate(grid)[:, 0]
    names = [f"q{i + 1}" for i in range(dim)] + ([f"p{i + 1}" for i in range(dim)]
                                                  if kind == "full" else [])
    with open(out, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t", *names, "u1"])
        for j, (t, value) in enumerate(zip(grid, u, strict=True)):
            row = observed[j // dense - 1] if j % dense == 0 and j > 0 else None
            cells = [repr(float(v)) for v in row] if row is not None else [""] * len(names)
            writer.writerow([f"{t:.10g}", *cells, repr(float(value))])
    return (f"{out}: {n} times × {len(names)} components of {sys_.name} driven by {signal} "
            f"(F = {force.text}), u1 every {end / (n * dense):g}")
