"""Observations: the data container, its validation, and CSV/NPZ files.

An :class:`Observations` holds times ``t_1 < … < t_n`` and values ``y_k`` of shape
``(n, d_y)``; a NaN in ``y_k`` means that component was not measured at ``t_k`` (the filter
drops it from that update). Every check raises :class:`DataError` with a message a user can act
on; nothing is silently repaired.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["DataError", "Observations"]


class DataError(ValueError):
    """Bad input data: the message says what is wrong and where."""


@dataclass(frozen=True)
class Observations:
    """Noisy measurements of one trajectory.

    Parameters
    ----------
    times
        Strictly increasing, finite observation times, shape ``(n,)``.
    values
        Measurements, shape ``(n, d_y)`` (a 1-D array is one component). NaN = missing;
        ±inf is an error.
    names
        Optional component names (``q1, q2, p1, p2``, ...), used by files and figures.
    inputs
        The measured inputs u(t) of a driven system (:mod:`symplid.model._inputs`), known
        over the data's window and beyond it where forecasts need them; None without.
    """

    times: np.ndarray
    values: np.ndarray
    names: tuple[str, ...] | None = field(default=None)
    inputs: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        try:
            times = np.asarray(self.times, dtype=float)
        except (TypeError, ValueError) as err:
            raise DataError(f"times must be numbers: {err}") from None
        try:
            values = np.asarray(self.values, dtype=float)
        except (TypeError, ValueError) as err:
            raise DataError(f"values must be numbers (NaN for missing): {err}") from None
        if times.ndim != 1:
            raise DataError(f"times must be one-dimensional, got shape {times.shape}")
        if values.ndim == 1:
            values = values[:, None]
        if values.ndim != 2:
            raise DataError(f"values must have shape (n, d_y), got {values.shape}")
        if times.shape[0] == 0:
            raise DataError("there are no observations")
        if values.shape[0] != times.shape[0]:
            raise DataError(f"{times.shape[0]} times but {values.shape[0]} rows of values")
        if not np.all(np.isfinite(times)):
            raise DataError("times must be finite (no NaN or inf)")
        if times.shape[0] > 1 and np.any(np.diff(times) <= 0):
            k = int(np.argmax(np.diff(times) <= 0))
            raise DataError(
                f"times must be strictly increasing: t[{k}] = {times[k]:g} "
                f"is followed by t[{k + 1}] = {times[k + 1]:g}"
            )
        if np.any(np.isinf(values)):
            raise DataError("values contain inf; use NaN for a missing value")
        if np.all(np.isnan(values)):
            raise DataError("every value is missing (NaN)")
        names = self.names
        if names is not None:
            names = tuple(str(n) for n in names)
            if len(names) != values.shape[1]:
                raise DataError(f"{len(names)} names for {values.shape[1]} observed components")
        times.setflags(write=False)
        values.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "names", names)

    @property
    def num_times(self) -> int:
        return int(self.times.shape[0])

    @property
    def dim(self) -> int:
        """Number of observed components ``d_y``."""
        return int(self.values.shape[1])

    @property
    def mask(self) -> np.ndarray:
        """True where a value was measured."""
        return ~np.isnan(self.values)

    def __len__(self) -> int:
        return self.num_times

    def subset(self, index: Sequence[int] | slice | np.ndarray) -> Observations:
        """The observations at the given indices (keeps names and inputs)."""
        return Observations(self.times[index], self.values[index], self.names, self.inputs)
