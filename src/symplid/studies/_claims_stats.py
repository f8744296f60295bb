"""Statistics of a many-seed study: binomial intervals, bootstrap medians, truth ranks.

Pure functions of arrays (no files; the bootstrap draws from a seeded generator), used by the
paper-claims study (:mod:`._paper_study`) and tested on cases with known answers:

* :func:`wilson_interval` — the Wilson score interval of a binomial fraction k / n.
* :func:`bootstrap_median` — the median of paired values with a percentile-bootstrap interval.
* :func:`truth_rank` and :func:`rank_uniformity` — simulation-based calibration: if the truth
  were a draw from the posterior, its rank among L posterior draws would be uniform on
  {0, …, L}; a χ² test on binned ranks says how far from uniform the ranks over seeds are.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "LEVEL",
    "RANK_DRAWS",
    "bootstrap_median",
    "rank_uniformity",
    "thin_evenly",
    "truth_rank",
    "wilson_interval",
]

LEVEL = 0.95
#: Bootstrap resamples per interval.
NUM_BOOTSTRAP = 4000
#: Posterior draws kept per cell for the rank of the truth (ranks take 0 … RANK_DRAWS).
RANK_DRAWS = 99


def _z(level: float) -> float:
    from scipy.stats import norm

    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    return float(norm.ppf(0.5 + level / 2.0))


def wilson_interval(k: int, n: int, level: float = LEVEL) -> tuple[float, float] | None:
    """The Wilson score interval of a binomial proportion k / n (``None`` when n = 0).

    ``(p̂ + z²/2n ± z·√(p̂(1 − p̂)/n + z²/4n²)) / (1 + z²/n)`` with z the two-sided normal
    quantile of ``level``; unlike the Wald interval it stays inside [0, 1] and is not empty at
    k = 0 or k = n.
    """
    if n < 0 or not 0 <= k <= max(n, 0):
        raise ValueError(f"need 0 ≤ k ≤ n, got k={k!r}, n={n!r}")
    if n == 0:
        return None
    z = _z(level)
    p = k / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # At k = 0 (k = n) the lower (upper) bound is exactly 0 (1); the formula's rounding would
    # leave it a hair inside, and the interval would then miss p̂ itself.
    lo = 0.0 if k == 0 else max(0.0, min(p, centre - half))
    hi = 1.0 if k == n else min(1.0, max(p, centre + half))
    return lo, hi


def bootstrap_median(
    values: Any,
    level: float = LEVEL,
    num: int = NUM_BOOTSTRAP,
    seed: int = 0,
) -> dict[str, Any]:
    """The median of ``values`` with a percentile-bootstrap interval (seeded, reproducible).

    Non-finite values are dropped. Returns ``{"median", "lo", "hi", "n", "level",
    "resamples"}``; the bounds are ``None`` for fewer than two values.
    """
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    out: dict[str, Any] = {
        "median": float(np.median(x)) if x.size else None,
        "lo": None,
        "hi": None,
        "n": int(x.size),
        "level": level,
        "resamples": int(num),
    }
    if x.size < 2:
        return out
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(int(num), x.size))
    medians = np.median(x[idx], axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(medians, [alpha, 1.0 - alpha])
    out["lo"], out["hi"] = float(lo), float(hi)
    return out


def thin_evenly(draws: Any, num: int = RANK_DRAWS) -> np.ndarray:
    """``num`` draws spread evenly over ``draws`` (chain by chain when 2-D: chain, draw), so
    that neighbours are far apart in their chain and every chain contributes its share."""
    flat = np.asarray(draws, dtype=float).reshape(-1)
    if flat.size <= num:
        return flat.copy()
    return flat[np.linspace(0, flat.size - 1, num).round().astype(int)]


def truth_rank(draws: Any, truth: float, num: int = RANK_DRAWS) -> int:
    """The rank of ``truth`` among ``num`` evenly thinned draws: how many are below it.

    Under a calibrated posterior (truth drawn from it, draws independent) the rank is uniform on
    {0, …, num}.
    """
    return int(np.sum(thin_evenly(draws, num) < truth))


def _bins(n: int, num_ranks: int) -> int:
    for b in (10, 5, 4, 2):
        if num_ranks % b == 0 and n >= 5 * b:
            return b
    return 2


def rank_uniformity(ranks: Any, num_draws: int = RANK_DRAWS) -> dict[str, Any]:
    """A χ² test that ranks on {0, …, num_draws} are uniform, in equal-width bins.

    The bins are as many as keep at least five expected ranks each (10, 5, 4 or 2, dividing the
    num_draws + 1 possible ranks). Returns ``{"n", "bins", "counts", "chi2", "p_value"}``;
    ``p_value`` is ``None`` for fewer than two ranks.
    """
    from scipy.stats import chisquare

    r = np.asarray(ranks, dtype=float).ravel()
    r = r[np.isfinite(r)].astype(int)
    if r.size and (r.min() < 0 or r.max() > num_draws):
        raise ValueError(f"ranks must lie in 0..{num_draws}")
    num_ranks = num_draws + 1
    bins = _bins(r.size, num_ranks)
    counts = np.bincount(r * bins // num_ranks, minlength=bins)
    out: dict[str, Any] = {
        "n": int(r.size),
        "bins": bins,
        "counts": counts.tolist(),
        "chi2": None,
        "p_value": None,
    }
    if r.size >= 2:
        stat, p = chisquare(counts)
        out["chi2"], out["p_value"] = float(stat), float(p)
    return out
