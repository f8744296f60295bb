"""The observation noise the data show without a model: what the MAP's start and checks use.

Two estimators, each unbiased for white noise on a constant signal and biased *upward* by a
smooth signal, so that the smaller one is the less contaminated (:func:`noise_variance`):

* :func:`difference_variance`: mean((Δᵏy)²) / C(2k, k), the smallest over k = 2, 3, 4. Cheap
  and accurate for a record sampled densely and evenly; on a few points along a curved path
  (25 positions of an orbit, clumped, with gaps of a fifth of a period) the differences are
  the motion, not the noise (0.17 AU² for a noise of 1e-6 AU²).
* :func:`cross_validated_variance`: each interior point predicted by a smoothing spline of
  its neighbours (:data:`NEIGHBOURS` on each side; its roughness chosen by generalised
  cross-validation,
  :func:`scipy.interpolate.make_smoothing_spline`); the median of the squared prediction errors
  divided by 0.4549 (the median of χ²₁), so that a few predictions across a long gap do not
  count. The error of a prediction is the noise at the point plus the spline's error there
  (≥ 0 on average): an upper estimate that follows a sparse, irregular, curved path.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
from scipy.interpolate import make_smoothing_spline

MEDIAN_CHI2_1 = 0.454936423119572
"""The median of a χ² variable with one degree of freedom."""
MAX_LEFT_OUT = 60
"""Most points left out, one at a time, by :func:`cross_validated_variance` (evenly spread)."""
NEIGHBOURS = 10
"""Points on each side of a left-out point that its spline is fitted to (the prediction is
local: the cost does not grow with the record's length)."""
MIN_CV_POINTS = 6
"""Fewest finite values :func:`cross_validated_variance` needs."""


def difference_variance(y: np.ndarray) -> float:
    """A model-free noise variance of a sampled smooth signal: the smallest of the
    difference estimators mean((Δᵏy)²) / C(2k, k), k = 2, 3, 4 (each is unbiased for white
    noise and biased upward by the signal, so the smallest is the least contaminated)."""
    y = y[np.isfinite(y)]
    values = [float(np.mean(np.diff(y, k) ** 2)) / math.comb(2 * k, k)
              for k in (2, 3, 4) if y.size > k + 1]
    return min(values) if values else math.nan


def cross_validated_variance(t: np.ndarray, y: np.ndarray) -> float:
    """The noise variance of y(t) by leave-one-out prediction with a smoothing spline (module
    docstring); NaN with fewer than :data:`MIN_CV_POINTS` finite values or repeated times."""
    ok = np.isfinite(y) & np.isfinite(t)
    t, y = np.asarray(t, dtype=float)[ok], np.asarray(y, dtype=float)[ok]
    if t.size < MIN_CV_POINTS or np.any(np.diff(t) <= 0):
        return math.nan
    left_out = np.unique(np.round(np.linspace(1, t.size - 2, min(MAX_LEFT_OUT, t.size - 2)))
                         .astype(int))
    errors = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i in left_out:
            near = np.arange(max(0, i - NEIGHBOURS), min(t.size, i + NEIGHBOURS + 1))
            keep = near[near != i]
            try:
                spline = make_smoothing_spline(t[keep], y[keep])
            except (ValueError, np.linalg.LinAlgError):
                continue
            errors.append(float(y[i] - spline(t[i])))
    if len(errors) < MIN_CV_POINTS - 2:
        return math.nan
    value = float(np.median(np.square(errors))) / MEDIAN_CHI2_1
    return value if math.isfinite(value) else math.nan


def noise_variance(t: np.ndarray, y: np.ndarray) -> float:
    """The smaller of :func:`difference_variance` and :func:`cross_validated_variance` of
    y(t) (NaN values are missing observations); NaN when neither can be computed. The MAP's
    start and its checks ask for the same series: the last few answers are remembered."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    return _noise_variance(t.tobytes(), y.tobytes())


@functools.lru_cache(maxsize=64)
def _noise_variance(t_bytes: bytes, y_bytes: bytes) -> float:
    t, y = np.frombuffer(t_bytes), np.frombuffer(y_bytes)
    values = [v for v in (difference_variance(y), cross_validated_variance(t, y))
              if math.isfinite(v)]
    return min(values) if values else math.nan


__all__ = ["cross_validated_variance", "difference_variance", "noise_variance"]
