"""Where the MAP search of a model without process noise starts: from the filter's MAP.

The deterministic-trajectory likelihood (``process_noise_per="none"``,
:mod:`symplid.model._deterministic`) compares the data with one integrated path. On a long
record of a nearly chaotic system that path depends so sharply on the coefficients that the
likelihood is rugged far from the answer: started from zero coefficients, a quasi-Newton
search stops in a local optimum (on the paper's Hénon–Heiles data, 20 observations over 100 s:
log posterior −27.5 instead of +99.7).

The filter's likelihood does not have this problem while its process variance Σ is large: the
filter re-anchors the state at every observation, and the MAP search starts there and lowers
Σ as the coefficients improve (:mod:`symplid.inference.map`, "Starting points"). Its MAP,
with the process variance dropped, is therefore the first start of the deterministic search:
a homotopy from a large Σ to Σ = 0 in two stages. :func:`filter_start` computes it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from symplid.inference.map._checks import removes_dynamics
from symplid.inference.map._find import find_map
from symplid.model._priors import HalfNormal, LogUniform

__all__ = ["filter_start", "half_normal_start", "with_process_noise", "without_process_var"]


def with_process_noise(posterior: Any) -> Any:
    """The posterior of the same data and priors under the model with process noise added
    once per gap (``process_noise_per="gap"``)."""
    model = dataclasses.replace(posterior.model, process_noise_per="gap")
    return posterior.with_model(model)


def without_process_var(groups: Any, theta: Any) -> np.ndarray:
    """θ of a posterior with process noise, its process variance(s) left out: a θ of the same
    posterior without process noise (``groups``: the posterior's ``param_groups``)."""
    keep = [i for i, group in enumerate(groups) if group != "process_var"]
    return np.asarray(theta, dtype=float)[keep]


def filter_start(posterior: Any, seed: int = 0, num_starts: int = 4,
                 init: Any = None) -> np.ndarray | None:
    """The first MAP start of a posterior without process noise: the MAP of the same
    posterior with process noise, its process variance(s) left out (module docstring).

    Returns None when the posterior's model has process noise (nothing to do), when the
    filter's MAP is not finite, or when it switched the dynamics off (a coefficient on its
    zero bound, :func:`~symplid.inference.map._checks.dynamics_removed`: a start that
    would only lead the deterministic search astray).

    Parameters
    ----------
    posterior
        A :class:`~symplid.model._posterior.Posterior` (its model a
        :class:`~symplid.model._statespace.HamiltonianModel`).
    seed, num_starts
        The filter's MAP search (:func:`~symplid.inference.map.find_map`).
    init
        Its first start (a declared ``{name: value}`` start is the same for both posteriors).
    """
    if not getattr(posterior.model, "deterministic", False):
        return None
    twin = with_process_noise(posterior)
    result = find_map(twin, seed=seed, num_starts=num_starts, init=init, compute_hessian=False,
                      warn=False)
    if removes_dynamics(result.failure):
        return None
    start = without_process_var(twin.param_groups, result.theta)
    return start if np.all(np.isfinite(start)) else None


def half_normal_start(posterior: Any, seed: int = 0, num_starts: int = 4,
                      init: Any = None) -> np.ndarray | None:
    """The first MAP start of a posterior whose process variance has a log-uniform prior:
    the MAP under the paper's HalfNormal(1) on Σ, Σ moved into the log-uniform's support.

    The log-uniform prior (:mod:`symplid.model._variance_prior`) pulls Σ towards its lower
    end, where the filter is nearly deterministic and the likelihood of a long chaotic record
    as rugged as without process noise: a search from the default start (Σ at the data's
    variance) lets Σ collapse before the coefficients are right and stops in a local optimum
    (on the paper's Hénon–Heiles data, seed 1000: log posterior 101.5 instead of 128.6). The
    half-normal search keeps Σ large while the coefficients improve; its MAP is a start in
    the right basin (the same homotopy as :func:`filter_start`).

    Returns None when no process variance has a log-uniform prior, or when that MAP is not
    finite. ``init``: its first start, as in :func:`filter_start`.
    """
    groups = list(getattr(posterior, "param_groups", ()))
    index = [i for i, g in enumerate(groups) if g == "process_var"]
    if not index or not all(isinstance(posterior.priors[i], LogUniform) for i in index):
        return None
    names = {posterior.param_names[i] for i in index}
    overrides = {k: v for k, v in posterior.prior.overrides.items() if k not in names}
    prior = dataclasses.replace(posterior.prior, process_var=HalfNormal(1.0), overrides=overrides)
    twin = posterior.with_prior(prior)
    result = find_map(twin, seed=seed, num_starts=num_starts, init=init, compute_hessian=False,
                      warn=False)
    start = np.asarray(result.theta, dtype=float).copy()
    for i in index:
        low, high = posterior.priors[i].support
        span = np.log(high / low)
        start[i] = float(np.clip(start[i], low * np.exp(1e-3 * span), high * np.exp(-1e-3 * span)))
    return start if np.all(np.isfinite(start)) else None
