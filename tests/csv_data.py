"""Small data files for the command-line tests: a CSV writer and a noisy harmonic oscillator."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_csv(path: Path, times, columns: dict[str, np.ndarray]) -> Path:
    """``t`` and the given columns, every number to 17 significant digits."""
    header = ",".join(["t", *columns])
    rows = [",".join([f"{t:.17g}", *(f"{columns[c][k]:.17g}" for c in columns)])
            for k, t in enumerate(times)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def harmonic(times, noise=0.02, seed=0):
    """q1 = cos t, p1 = −sin t with Gaussian noise of sd ``noise``."""
    rng = np.random.default_rng(seed)
    t = np.asarray(times, dtype=float)
    return {"q1": np.cos(t) + noise * rng.normal(size=t.size),
            "p1": -np.sin(t) + noise * rng.normal(size=t.size)}
