"""The data-scaled prior of the process variance Σ: log-uniform over eight decades.

Why not the paper's HalfNormal(1) for Σ. When the data carry no process noise, the
likelihood is flat in Σ below the level the data can resolve (about 1e-5 on the paper's
Hénon–Heiles data); a HalfNormal(1) prior is flat there too, so the posterior keeps Σ at
1e-6…1e-4 instead of letting it go to zero. On a nearly chaotic flow that small Σ is enough
to inflate the filter's predicted covariance to the size of the observation noise, and the
−½ log det S term of the marginal likelihood then favours less expansive dynamics: the cubic
coefficients shift by about one posterior standard deviation and their 95 % intervals miss.

A log-uniform prior puts the same mass on every decade of [low, high]. Its high end is the
data's variance scale ``b`` (:func:`data_variance_scale`): a process noise with the variance
of the whole signal would make the dynamics meaningless, so nothing above it is needed. Its
low end, ``b·1e-8``, is far below what any record resolves, so most of the prior's mass lies
where the data cannot tell Σ from zero: the posterior can follow Σ down to where the filter
is effectively deterministic. The same mass makes the prior's density 1/Σ highest at the
low end: when the data do not resolve Σ, its MAP is the bound b·1e-8 itself (reported in
``MapResult.at_bounds``), a property of this range and not a measurement; the MAP search
runs on log Σ within the range (:class:`symplid.inference.map._space.SearchSpace`). It is opt-in
(``priors.process_var = "log-uniform"``): what was measured with it on the paper's setting,
and why it is not the default, is in ``docs/howto/process-noise.md`` (section "The prior of
Σ").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from symplid.model._data import Observations
from symplid.model._priors import LogUniform

__all__ = ["DECADES", "data_variance_scale", "process_variance_prior"]

DECADES = 8.0
"""How many decades below the data's variance scale the default prior reaches."""


def data_variance_scale(data: Observations | Sequence[Observations]) -> float:
    """The data's variance scale: the mean over observed components of their sample variance.

    Missing values are skipped; several trajectories are pooled per component. A record
    whose every component is constant (or has a single value) has no scale: 1.0 is returned.

    Parameters
    ----------
    data
        One trajectory's observations or a list of them (same components).

    Returns
    -------
    float
        A positive, finite variance.
    """
    datasets = [data] if isinstance(data, Observations) else list(data)
    values = np.concatenate([np.asarray(d.values, dtype=float) for d in datasets], axis=0)
    per_component = []
    for column in values.T:
        seen = column[np.isfinite(column)]
        if seen.size > 1:
            per_component.append(float(np.var(seen, ddof=1)))
    scale = float(np.mean(per_component)) if per_component else math.nan
    return scale if math.isfinite(scale) and scale > 0 else 1.0


def process_variance_prior(data: Observations | Sequence[Observations],
                           decades: float = DECADES) -> LogUniform:
    """LogUniform(b·10^−decades, b) with b = :func:`data_variance_scale` of ``data``.

    >>> obs = Observations(times=[1.0, 2.0, 3.0], values=[[0.0], [1.0], [2.0]])
    >>> process_variance_prior(obs)
    LogUniform(low=1e-08, high=1.0)
    """
    if not (math.isfinite(decades) and decades > 0):
        raise ValueError(f"decades must be a finite number > 0, got {decades!r}")
    high = data_variance_scale(data)
    return LogUniform(high * 10.0 ** (-decades), high)
