"""A path through sparse, irregularly timed positions as a sum of sinusoids: the spectral
smoother of the MAP's data start (:mod:`._data_start`).

A smoothing spline follows a motion only where the data sample it densely. On a coupled
pair of oscillators seen at 30 random times over 20 s (about five positions per period of
the faster normal mode) the spline flattened the fast mode, the collocation read a
stiffness of 1.5 where the truth is 3.5, and every MAP start ended in optima 70 nats below
the true parameters' mode. Oscillations are what Hamiltonian data most often show, and a
few sinusoids describe them between sparse samples far better than a cubic spline.

The path of one trajectory, its position components j sharing the frequencies (the normal
modes, their harmonics and combinations are those of the whole motion)::

    q_j(t) = c_j + Σ_k [a_jk cos ω_k (t − t_1) + b_jk sin ω_k (t − t_1)]

The frequencies are chosen one at a time:

1. the next ω is the maximum of the Lomb–Scargle periodogram (:func:`scipy.signal.lombscargle`,
   which allows uneven times) of the residuals, summed over the components, on a grid from
   π/T to the Nyquist frequency of the median gap, π/h (above it, evenly spaced samples
   cannot tell a frequency from its alias: a pendulum seen every 0.25 s read as 48.9 rad/s
   instead of 1.37, and a close pair of times put the grid's top there), in steps of
   π/(8T) (T: the record's span; :data:`OVERSAMPLING`), away from the frequencies already
   chosen;
2. all frequencies chosen so far are refined together by least squares, the amplitudes
   solved linearly at each step (variable projection, Golub and Pereyra 1973);
3. a sinusoid is kept when it lowers the residual sum of squares by more than noise would
   at the best of the grid's independent frequencies (an F test of its amplitudes with a
   Bonferroni correction, false alarms at most :data:`FALSE_ALARM`); the search stops at
   the first one that does not, or at :data:`MAX_FREQUENCIES`. (The Bayesian information
   criterion, which ignores that the frequency was searched for, kept four spurious
   sinusoids at high frequencies on 30 noisy positions.)

The path and its derivative are then exact functions of t, so the collocation can use
nodes between the observations (:data:`SUBDIVISIONS` per gap), where a trapezoidal momentum
step over a whole gap would misread a fast motion.
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.stats
from scipy.signal import lombscargle

MAX_FREQUENCIES = 8
"""Most sinusoids in a path."""
SUBDIVISIONS = 4
"""Collocation nodes per gap between observations on a spectral path (the observation times
and three between each pair); fewer when the record is long (``most`` nodes at most)."""
MIN_POINTS = 5
"""Fewest finite values of a component that the sinusoids are fitted to."""
OVERSAMPLING = 8
"""Grid frequencies per independent one (the periodogram's resolution π/T over its step)."""
FALSE_ALARM = 0.01
"""The chance, over the whole grid, that noise alone adds a sinusoid to a path."""


@dataclass(frozen=True)
class SpectralPath:
    """A fitted sum of sinusoids: ``values(t)`` and ``derivative(t)`` are (len(t), d)."""

    origin: float
    frequencies: np.ndarray  # (K,)
    coefficients: np.ndarray  # (1 + 2K, d): c_j, then (a_jk, b_jk) per frequency
    residual_var: np.ndarray  # (d,): mean squared residual of each component

    def values(self, t: np.ndarray) -> np.ndarray:
        return _design(np.asarray(t, dtype=float) - self.origin, self.frequencies) @ (
            self.coefficients)

    def derivative(self, t: np.ndarray) -> np.ndarray:
        s = np.asarray(t, dtype=float)[:, None] - self.origin
        w = self.frequencies[None, :]
        cols = np.empty((s.shape[0], 1 + 2 * w.size))
        cols[:, 0] = 0.0
        cols[:, 1::2] = -w * np.sin(w * s)
        cols[:, 2::2] = w * np.cos(w * s)
        return cols @ self.coefficients


def _design(s: np.ndarray, frequencies: np.ndarray) -> np.ndarray:
    """Columns 1, cos ω_k s, sin ω_k s (k = 1..K) at the times s."""
    w = np.asarray(frequencies, dtype=float)[None, :]
    cols = np.empty((s.size, 1 + 2 * w.size))
    cols[:, 0] = 1.0
    cols[:, 1::2] = np.cos(w * s[:, None])
    cols[:, 2::2] = np.sin(w * s[:, None])
    return cols


def _amplitudes(s: np.ndarray, y: np.ndarray, ok: np.ndarray,
                frequencies: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each component's least-squares amplitudes over its finite values, and the residuals
    (0 where a value is missing)."""
    design = _design(s, frequencies)
    coef = np.empty((design.shape[1], y.shape[1]))
    resid = np.zeros_like(y)
    for j in range(y.shape[1]):
        rows = ok[:, j]
        coef[:, j] = np.linalg.lstsq(design[rows], y[rows, j], rcond=None)[0]
        resid[rows, j] = y[rows, j] - design[rows] @ coef[:, j]
    return coef, resid


def _grid(s: np.ndarray) -> np.ndarray:
    """The periodogram's frequencies (module docstring, step 1)."""
    span = float(s[-1] - s[0])
    gaps = np.diff(s)
    top = math.pi / float(np.median(gaps[gaps > 0]))
    return np.arange(math.pi / span, top, math.pi / (OVERSAMPLING * span))


def _next_frequency(s: np.ndarray, resid: np.ndarray, ok: np.ndarray, grid: np.ndarray,
                    chosen: list[float], span: float) -> float | None:
    """The grid's frequency of the largest summed periodogram of the residuals, at least one
    resolution π/T from those already chosen (module docstring, step 1); None when the
    residuals are flat."""
    power = np.zeros(grid.size)
    for j in range(resid.shape[1]):
        rows = ok[:, j]
        centred = resid[rows, j] - np.mean(resid[rows, j])
        if np.ptp(centred) > 0:
            power += lombscargle(s[rows], centred, grid)
    for w in chosen:
        power[np.abs(grid - w) < math.pi / span] = 0.0
    return float(grid[np.argmax(power)]) if np.any(power > 0) else None


def _significant(rss: float, new_rss: float, added: int, dof: int, trials: float) -> bool:
    """Whether a sinusoid lowered the residual sum of squares from ``rss`` to ``new_rss``
    by more than noise would at the best of ``trials`` frequencies: the F statistic of its
    ``added`` amplitudes, its tail probability times ``trials`` (Bonferroni) below
    :data:`FALSE_ALARM`."""
    if not (dof > 0 and math.isfinite(new_rss) and 0 < new_rss < rss):
        return False
    statistic = ((rss - new_rss) / added) / (new_rss / dof)
    return bool(scipy.stats.f.sf(statistic, added, dof) * trials < FALSE_ALARM)


def spectral_path(times: np.ndarray, values: np.ndarray) -> SpectralPath | None:
    """The sum of sinusoids through ``values`` (n, d; NaN where missing) observed at
    ``times`` (module docstring), or None when a component has fewer than
    :data:`MIN_POINTS` finite values or no frequency can be fitted."""
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float).reshape(t.size, -1)
    ok = np.isfinite(y)
    if t.size < MIN_POINTS or np.any(ok.sum(axis=0) < MIN_POINTS) or not t[-1] > t[0]:
        return None
    s, y = t - t[0], np.where(ok, y, 0.0)
    count = int(ok.sum())
    grid, span = _grid(s), float(s[-1])
    chosen: list[float] = []
    best: SpectralPath | None = None
    trials = max(grid.size / OVERSAMPLING, 1.0)
    resid = y - np.where(ok, np.nanmean(np.where(ok, y, np.nan), axis=0), 0.0)
    rss = float(np.sum(resid**2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(min(MAX_FREQUENCIES, (count - y.shape[1]) // (3 * y.shape[1]))):
            nxt = _next_frequency(s, resid, ok, grid, chosen, span)
            if nxt is None:
                break
            try:
                fit = scipy.optimize.least_squares(
                    lambda w: _amplitudes(s, y, ok, w)[1].ravel(), np.array([*chosen, nxt]),
                    method="lm")
            except (ValueError, np.linalg.LinAlgError):
                break
            frequencies = np.abs(fit.x)
            coef, new_resid = _amplitudes(s, y, ok, frequencies)
            new_rss = float(np.sum(new_resid**2))
            unknowns = frequencies.size * (1 + 2 * y.shape[1]) + y.shape[1]
            if not _significant(rss, new_rss, 2 * y.shape[1], count - unknowns, trials):
                break
            chosen, resid, rss = [float(w) for w in frequencies], new_resid, new_rss
            var = np.sum(resid**2, axis=0) / np.maximum(ok.sum(axis=0), 1)
            best = SpectralPath(float(t[0]), np.array(chosen), coef, var)
    return best


def subdivided(times: np.ndarray, most: int) -> np.ndarray:
    """The observation times with up to :data:`SUBDIVISIONS` − 1 evenly spaced nodes in
    each gap, as many as ``most`` nodes allow (at least the observation times)."""
    t = np.asarray(times, dtype=float)
    per_gap = max(1, min(SUBDIVISIONS, (most - 1) // max(t.size - 1, 1)))
    if per_gap == 1:
        return t
    inner = [np.linspace(a, b, per_gap, endpoint=False) for a, b in itertools.pairwise(t)]
    return np.concatenate([*inner, t[-1:]])


__all__ = ["MAX_FREQUENCIES", "SUBDIVISIONS", "SpectralPath", "spectral_path", "subdivided"]
