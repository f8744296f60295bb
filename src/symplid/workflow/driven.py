"""Driven models in a run: the force of ``model.force`` and the inputs of ``[inputs]``.

A run whose settings give ``model.force`` (:mod:`symplid.dynamics.forcing`) is driven: its
data carry the inputs u(t) (:mod:`symplid.model.inputs`), read here from what ``[inputs]``
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

from symplid.dynamics.forcing import INPUT_NAME, Force, force_parameters, user_force
from symplid.dynamics.user_models import UserModelError
from symplid.io import read_trajectories
from symplid.io.inputfiles import INPUT_COLUMN, read_driven_csv, read_input_file
from symplid.model.data import DataError, Observations
from symplid.model.inputs import AnalyticInputs, SampledInputs

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
    "read_driven",
    "read_run_inputs",
    "refuse_forecast",
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
    path over the data (:func:`~symplid.inference.driven.power_balance`), the input's work,
    the rest of the force's work (minus the dissipation), the change of H and the largest
    gap's imbalance."""
    from symplid.inference.driven import power_balance

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
