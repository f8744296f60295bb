"""The smoothed paths a MAP data start reads the dynamics from (:mod:`._data_start`).

For each trajectory, the measured positions become a path with its velocity at the
collocation's nodes, by one of :data:`SMOOTHERS`:

* ``"spline"``: a cubic smoothing spline per position component
  (:func:`scipy.interpolate.make_smoothing_spline`) whose mean squared residual equals the
  model-free noise estimate (:func:`~._noise.noise_variance`; the discrepancy principle,
  solved for log λ by Brent's method); the nodes are the observation times;
* ``"rough"``: the same splines following the data to :data:`ROUGHER` of that estimate;
* ``"spectral"``: a sum of sinusoids through all the components (:mod:`._spectral`), exact
  between the observations, so its nodes include points between them.

Measured momenta are carried to the nodes that are observation times; each component's
noise variance comes with the path (the spline's target, the sinusoids' residual).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
from scipy.interpolate import make_smoothing_spline

from symplid.inference.map._noise import noise_variance
from symplid.inference.map._spectral import spectral_path, subdivided

MIN_POINTS = 5
"""Fewest observations of a trajectory the smoothing spline is fitted to."""
MAX_NODES = 300
"""Most collocation nodes over all trajectories (a longer record is thinned evenly)."""


@dataclass(frozen=True)
class Smoothed:
    """One trajectory's path at the collocation nodes: q and q̇ there, the measured momenta
    (NaN where a node has none) and the time of its initial state."""

    times: np.ndarray  # (n,)
    q: np.ndarray  # (n, d)
    qdot: np.ndarray  # (n, d)
    p_obs: np.ndarray  # (n, d), NaN where a momentum is not measured
    t0: float  # time of the initial state


def position_rows(model: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """For each state component, the observation row that measures it alone and its factor
    c (−1 where none does); None when a position is not measured or h is a function."""
    matrix = getattr(model, "observation_matrix", None)
    if matrix is None:
        return None
    H = np.asarray(matrix, dtype=float)
    n = H.shape[1]
    rows, factors = -np.ones(n, dtype=int), np.ones(n)
    for j in range(H.shape[0]):
        nz = np.flatnonzero(H[j])
        if nz.size == 1 and rows[nz[0]] < 0:
            rows[nz[0]], factors[nz[0]] = j, H[j, nz[0]]
    return (rows, factors) if np.all(rows[: n // 2] >= 0) else None


SMOOTHERS = ("spline", "rough", "spectral")
"""The paths a data start can read the positions by (:func:`data_start`)."""
LOG_LAMBDA_TOL = 1e-10
"""Absolute tolerance of the root search for log λ of the discrepancy principle."""
ROUGHER = 1.0 / 30.0
"""The noise target of the rougher data start (``smoother="rough"``), as a share of
the model-free estimate. That estimate is an upper bound that the signal inflates: on a
Morse oscillator sampled 3.5 times a period (25 positions, noise sd 0.04) it was 37 times the
noise variance, the spline it sets was nearly flat, and every start fitted the slow motion
that the smoothed path showed (log π 5.4 against 43.7 at the true parameters' mode)."""


def spline_fit(t: np.ndarray, y: np.ndarray, share: float = 1.0) -> tuple[Any, float] | None:
    """A smoothing spline of y(t) over the finite values whose mean squared residual matches
    ``share`` times the model-free estimate of the noise (the discrepancy principle), and
    that variance.

    The residual grows with the roughness penalty λ: the root of mean squared residual −
    target in log λ is bracketed by λ ∈ [1e-12, 1e6] × span³ and found by Brent's method
    (:func:`scipy.optimize.brentq`) to :data:`LOG_LAMBDA_TOL`; a target outside the
    bracket's residuals gives the spline at the nearer end (as a bisection would)."""
    ok = np.isfinite(y)
    if ok.sum() < MIN_POINTS:
        return None
    t, y = t[ok], y[ok]
    target = share * noise_variance(t, y)
    if not (math.isfinite(target) and target > 0):
        return None
    span = float(t[-1] - t[0])
    lo, hi = math.log(1e-12 * span**3), math.log(1e6 * span**3)

    def excess(log_lam: float) -> float:
        """Mean squared residual − target at λ = exp(log_lam): an infinite one above the
        target, a NaN below it (as a bisection on ``residual > target`` reads them)."""
        spline = make_smoothing_spline(t, y, lam=math.exp(log_lam))
        value = float(np.mean((y - spline(t)) ** 2)) - target
        if value > 0:
            return min(value, 1e300)
        return value if math.isfinite(value) else -target

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            at_lo, at_hi = excess(lo), excess(hi)
            if at_lo > 0:  # no sign change: the bracket's end nearer the target
                log_lam = lo
            elif at_hi <= 0:  # where 40 halvings towards it end: a near-linear fit, whose
                log_lam = lo  # values depend on λ's last digits, kept as it was
                for _ in range(40):
                    log_lam = 0.5 * (log_lam + hi)
            else:
                log_lam = scipy.optimize.brentq(excess, lo, hi, xtol=LOG_LAMBDA_TOL)
            spline = make_smoothing_spline(t, y, lam=math.exp(log_lam))
        except (ValueError, np.linalg.LinAlgError, RuntimeError):
            return None
    return spline, target


def _spline_positions(t: np.ndarray, positions: np.ndarray, share: float, most: int):
    """(nodes, q, q̇, noise variances) of cubic smoothing splines through each position
    component (:func:`spline_fit`), at most ``most`` of the observation times; None when a
    spline cannot be fitted."""
    keep = _nodes(t.size, most)
    shape = (keep.size, positions.shape[1])
    q, qdot = np.empty(shape), np.empty(shape)
    var = np.empty(positions.shape[1])
    for i in range(positions.shape[1]):
        fitted = spline_fit(t, positions[:, i], share)
        if fitted is None:
            return None
        q[:, i], qdot[:, i] = fitted[0](t[keep]), fitted[0].derivative()(t[keep])
        var[i] = fitted[1]
    return t[keep], q, qdot, var


def _spectral_positions(t: np.ndarray, positions: np.ndarray, most: int):
    """(nodes, q, q̇, noise variances) of a sum of sinusoids through all the position
    components (:func:`~._spectral.spectral_path`), on the observation times and nodes
    between them (:func:`~._spectral.subdivided`); None when it cannot be fitted."""
    path = spectral_path(t, positions)
    if path is None:
        return None
    nodes = subdivided(t, most) if t.size <= most else t[_nodes(t.size, most)]
    return nodes, path.values(nodes), path.derivative(nodes), path.residual_var


def _at_nodes(nodes: np.ndarray, times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (one row per observation time) on the nodes: a node that is an
    observation time takes its row, the others NaN."""
    out = np.full((nodes.size, values.shape[1]), np.nan)
    index = np.minimum(np.searchsorted(times, nodes), times.size - 1)
    match = times[index] == nodes
    out[match] = values[index[match]]
    return out


def smoothed_paths(posterior: Any, rows: np.ndarray, factors: np.ndarray,
                   smoother: str = "spline"):
    """Each trajectory's smoothed path, and the noise variance per observed component: the
    positions by ``smoother`` (:data:`SMOOTHERS`), the measured momenta at their
    model-free noise."""
    d = rows.size // 2
    most = max(MIN_POINTS, MAX_NODES // len(posterior.datasets))
    paths, noise = [], []
    for k, obs in enumerate(posterior.datasets):
        t = np.asarray(obs.times, dtype=float)
        values = np.where(obs.mask, obs.values, np.nan)
        positions = values[:, rows[:d]] / factors[:d]
        fitted = (_spectral_positions(t, positions, most) if smoother == "spectral" else
                  _spline_positions(t, positions, ROUGHER if smoother == "rough" else 1.0,
                                    most))
        if fitted is None:
            return None
        nodes, q, qdot, q_var = fitted
        var = np.full(obs.dim, np.nan)
        var[rows[:d]] = q_var * factors[:d] ** 2
        p_obs = np.full((t.size, d), np.nan)
        for i in range(d):
            if rows[d + i] >= 0:
                p_obs[:, i] = values[:, rows[d + i]] / factors[d + i]
                var[rows[d + i]] = noise_variance(t, p_obs[:, i]) * factors[d + i] ** 2
        t0 = getattr(posterior, "t0", [None] * len(posterior.datasets))[k]
        paths.append(Smoothed(nodes, q, qdot, _at_nodes(nodes, t, p_obs),
                              float(t[0] if t0 is None else t0)))
        noise.append(var)
    return paths, np.nanmean(np.vstack(noise), axis=0)


def _nodes(n: int, most: int) -> np.ndarray:
    """At most ``most`` evenly spread indices of n times, the first one always included."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, most)).astype(int))


__all__ = ["LOG_LAMBDA_TOL", "MAX_NODES", "MIN_POINTS", "ROUGHER", "SMOOTHERS", "Smoothed",
           "position_rows", "smoothed_paths", "spline_fit"]
