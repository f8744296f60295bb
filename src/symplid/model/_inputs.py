"""Measured inputs u(t) of a driven system: the signal, its rule between samples, and its
table at the propagator's nodes.

An input is known, not learned. It comes as samples (:class:`SampledInputs`: the input
columns of a data file, on the observation times or a denser grid) with a rule between
samples — ``"zoh"`` (zero-order hold: the last sample holds until the next), ``"linear"``
or ``"cubic"`` (SciPy's not-a-knot cubic spline) — or as expressions in t
(:class:`AnalyticInputs`, a lab's known excitation such as ``"0.5*sin(1.3*t)"``).

The forced propagators (:mod:`symplid.dynamics._forced`) evaluate the force at fixed fractions
of each substep, their nodes; :func:`node_table` tabulates u there, gap by gap and substep by
substep, on the host, once per data set. The table is an argument of the compiled
likelihood, never a constant in it. Before the first sample and after the last, within one
substep of the window (yoshida4's inner nodes reach 0.35 of a substep outside it), a sampled
input continues its end piece (the last held value, the end segment's line, the spline's end
cubic): holding a smooth input constant there would cost yoshida4 two orders; an input that
does not cover the fitted or forecast window [t0, t_n] is an error.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from symplid.dynamics._expressions import UserModelError, parse_expression
from symplid.model._data import DataError

__all__ = ["INTERPOLATIONS", "AnalyticInputs", "InputSignal", "SampledInputs", "node_table"]

#: The rules between samples of a sampled input (``inputs.interpolation``).
INTERPOLATIONS = ("zoh", "linear", "cubic")


class InputSignal:
    """What an input signal offers: its names, the span it covers and its values."""

    names: tuple[str, ...]

    @property
    def num_inputs(self) -> int:
        """m, the number of inputs."""
        return len(self.names)

    @property
    def span(self) -> tuple[float, float]:
        """The times the signal covers (±inf for an expression)."""
        raise NotImplementedError

    def evaluate(self, times: Any) -> np.ndarray:
        """u at ``times`` (any shape): shape ``times.shape + (m,)``."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class SampledInputs(InputSignal):
    """Inputs sampled at ``times`` (strictly increasing), ``values`` of shape ``(n, m)``,
    with one of :data:`INTERPOLATIONS` between samples.

    Raises
    ------
    DataError
        For a missing (NaN) or infinite sample, times that do not increase, fewer than two
        samples (four for ``"cubic"``), or an unknown rule.
    """

    times: np.ndarray
    values: np.ndarray
    names: tuple[str, ...] = ("u1",)
    interpolation: str = "linear"
    _spline: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        values = np.asarray(self.values, dtype=float)
        values = values[:, None] if values.ndim == 1 else values
        names = tuple(str(n) for n in self.names)
        if self.interpolation not in INTERPOLATIONS:
            raise DataError(f"inputs.interpolation must be one of {', '.join(INTERPOLATIONS)}, "
                            f"got {self.interpolation!r}")
        if values.shape != (times.shape[0], len(names)):
            raise DataError(f"{values.shape[0]} input rows of {values.shape[1]} columns for "
                            f"{times.shape[0]} times and the inputs {', '.join(names)}")
        least = 4 if self.interpolation == "cubic" else 2
        if times.shape[0] < least:
            raise DataError(f"the inputs {', '.join(names)} have {times.shape[0]} sample(s); "
                            f"{self.interpolation!r} needs at least {least}")
        bad = ~np.isfinite(values)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise DataError(f"input {names[col]} has no value at t = {times[row]:g} (a missing "
                            "input cannot be filled in: give every input at every input time)")
        if np.any(np.diff(times) <= 0) or not np.all(np.isfinite(times)):
            raise DataError("input times must be finite and strictly increasing")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "names", names)
        if self.interpolation != "zoh":  # both continue their end pieces outside the span
            from scipy.interpolate import CubicSpline, make_interp_spline

            spline = (CubicSpline(times, values, axis=0) if self.interpolation == "cubic"
                      else make_interp_spline(times, values, k=1, axis=0))
            object.__setattr__(self, "_spline", spline)

    @property
    def span(self) -> tuple[float, float]:
        return float(self.times[0]), float(self.times[-1])

    def evaluate(self, times: Any) -> np.ndarray:
        t = np.asarray(times, dtype=float)
        flat = t.ravel()
        if self._spline is not None:
            out = self._spline(flat)
        else:  # zero-order hold: the sample at or before t (the first before the record)
            index = np.clip(np.searchsorted(self.times, flat, side="right") - 1, 0, None)
            out = self.values[index]
        return np.asarray(out, dtype=float).reshape((*t.shape, len(self.names)))


@dataclass(frozen=True, eq=False)
class AnalyticInputs(InputSignal):
    """Inputs given as expressions in t (``{"u1": "0.5*sin(1.3*t)"}``), read by the
    safe expression reader of user models and evaluated with NumPy."""

    expressions: Mapping[str, str]
    names: tuple[str, ...] = ()
    _fns: tuple[Any, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        import sympy

        names = tuple(sorted(self.expressions, key=_input_order))
        fns = []
        for name in names:
            text = str(self.expressions[name])
            try:
                parsed = parse_expression(text, ("t",), f"inputs.{name}", require_all=False)
            except UserModelError as err:
                raise DataError(str(err)) from None
            if parsed.positions or parsed.momenta:
                raise DataError(f"inputs.{name}: an input is a function of t alone, not of "
                                "the state q, p")
            fns.append(sympy.lambdify([sympy.Symbol("t", real=True)], parsed.expr, "numpy"))
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "_fns", tuple(fns))

    @property
    def span(self) -> tuple[float, float]:
        return -np.inf, np.inf

    def evaluate(self, times: Any) -> np.ndarray:
        t = np.asarray(times, dtype=float)
        return np.stack([np.broadcast_to(np.asarray(f(t), dtype=float), t.shape)
                         for f in self._fns], axis=-1)


def _input_order(name: str) -> tuple[int, str]:
    digits = name[1:]
    return (int(digits) if digits.isdigit() else 10**9, name)


def node_table(signal: Any, start: float, step_sizes: np.ndarray, num_steps: np.ndarray,
               nodes: Sequence[float], num_inputs: int) -> tuple[np.ndarray, np.ndarray]:
    """The node times ``(G, S, K)`` and inputs ``(G, S, K, m)`` of consecutive gaps.

    Gap g starts where gap g − 1 ends (the first at ``start``) and has ``num_steps[g]``
    substeps of ``step_sizes[g]``; S is the most substeps of a gap (rows past a gap's own
    substeps repeat its end and are never used). K is the integrator's node count.

    Raises
    ------
    DataError
        When the model needs more inputs than the signal has, or the signal does not cover
        the window from ``start`` to the end of the last gap.
    """
    if signal is None:
        raise DataError(f"the model's force reads {num_inputs} input(s) (u1..) but the data "
                        "have none: name the input columns (data.inputs) or give [inputs]")
    if signal.num_inputs < num_inputs:
        raise DataError(f"the model's force reads u1..u{num_inputs} but the data have "
                        f"{signal.num_inputs} input(s) ({', '.join(signal.names)})")
    h, n = np.asarray(step_sizes, dtype=float), np.asarray(num_steps, dtype=int)
    starts = start + np.concatenate([[0.0], np.cumsum(h * n)[:-1]])
    end = float(starts[-1] + h[-1] * n[-1])
    lo, hi = signal.span
    slack = 1e-9 * max(1.0, abs(end))
    if lo > start + slack or hi < end - slack:
        raise DataError(f"the inputs cover t = {lo:g} to {hi:g} but the window to fit or "
                        f"forecast runs from {start:g} to {end:g}")
    rows = np.minimum(np.arange(int(n.max()))[None, :], n[:, None] - 1)  # (G, S)
    frac = rows[..., None] + np.asarray(nodes, dtype=float)[None, None, :]
    times = starts[:, None, None] + h[:, None, None] * frac  # (G, S, K)
    values = signal.evaluate(times)[..., :num_inputs]
    return times, values
