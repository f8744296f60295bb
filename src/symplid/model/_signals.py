"""Excitation signals for driven experiments: multisine, chirp, steps (seeded).

What a lab feeds a shaker or a motor to identify a system, as functions of time that return
the input at any times (NumPy), so that a simulation can integrate against the signal itself
and a data file can sample it on any grid:

* :func:`multisine`: a sum of sines at ``num_tones`` frequencies evenly spread over
  [f_min, f_max] with random phases (Schroeder's idea of a flat spectrum without one large
  peak, the phases drawn from the seed), scaled to the RMS ``amplitude``;
* :func:`chirp`: a sine whose frequency sweeps linearly from f_min to f_max over ``duration``;
* :func:`steps`: a piecewise-constant level, a new level drawn uniformly in
  [−amplitude, amplitude] every ``hold`` time units.

Frequencies are in cycles per time unit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from symplid._registry import Registry

__all__ = ["SIGNALS", "chirp", "multisine", "steps"]

Signal = Callable[[np.ndarray], np.ndarray]


def multisine(amplitude: float = 1.0, f_min: float = 0.05, f_max: float = 0.5,
              num_tones: int = 8, seed: int = 0, duration: float = 100.0) -> Signal:
    """u(t) = Σ_k a cos(2π f_k t + φ_k), φ_k uniform from ``seed``, RMS ``amplitude``."""
    rng = np.random.default_rng(seed)
    freqs = np.linspace(f_min, f_max, int(num_tones))
    phases = rng.uniform(0.0, 2 * np.pi, freqs.size)
    scale = amplitude / np.sqrt(freqs.size / 2.0)  # the RMS of a sum of unit sines

    def u(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return scale * np.cos(2 * np.pi * freqs * t[..., None] + phases).sum(axis=-1)

    return u


def chirp(amplitude: float = 1.0, f_min: float = 0.05, f_max: float = 0.5,
          num_tones: int = 0, seed: int = 0, duration: float = 100.0) -> Signal:
    """u(t) = a sin(2π (f_min t + (f_max − f_min) t² / (2 duration))) (no randomness)."""
    rate = (f_max - f_min) / float(duration)

    def u(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return amplitude * np.sin(2 * np.pi * (f_min * t + 0.5 * rate * t * t))

    return u


def steps(amplitude: float = 1.0, f_min: float = 0.05, f_max: float = 0.5,
          num_tones: int = 0, seed: int = 0, duration: float = 100.0) -> Signal:
    """A new level uniform in [−a, a] every 1/f_max time units (levels from ``seed``)."""
    hold = 1.0 / f_max
    rng = np.random.default_rng(seed)
    levels = rng.uniform(-amplitude, amplitude, int(np.ceil(duration / hold)) + 2)

    def u(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        index = np.clip(np.floor(t / hold).astype(int), 0, levels.size - 1)
        return levels[index]

    return u


#: Named excitation signals (``symplid simulate --input NAME``); each builder takes
#: ``amplitude, f_min, f_max, num_tones, seed, duration`` and returns u(t).
SIGNALS: Registry[Callable[..., Signal]] = Registry("input signal")
SIGNALS.register("multisine", multisine)
SIGNALS.register("chirp", chirp)
SIGNALS.register("steps", steps)
