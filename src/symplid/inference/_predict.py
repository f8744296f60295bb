"""Predictions from a learned Hamiltonian: MAP trajectories, posterior predictive bands, energy.

After learning, the paper predicts by integrating the learned Hamiltonian deterministically
from a known initial state, X_k = Ψ^k(X_0; θ_Ψ) (Section II-B.2), with any integrator and any
step (Section IV uses leapfrog at the "fine" Δt = 0.01 for 200 s, whatever propagator was used
for learning). The posterior predictive π(X_k | Y_n) = ∫ π(X_k | θ) π(θ | Y_n) dθ is
approximated by integrating one path per posterior draw of θ_Ψ and taking pointwise quantiles
(Fig. 3's 2.5–97.5 % band).

Public functions:

* :func:`predict_trajectory`: one deterministic path (e.g. the MAP's), every step or every k-th.
* :func:`posterior_predictive`: paths for many coefficient draws (``vmap``, in batches so that
  memory stays bounded), pointwise quantiles, the median and a few sample paths.
* :func:`forecast_from_filter`: the same from the end of the data, starting each path from a
  draw of the filter's last state (for data whose initial state is unknown).
* :func:`hamiltonian_along`: H(q, p) along paths, eq. (2).
* :func:`prediction_horizon`: the first time a prediction leaves the truth by a threshold.

Integration uses the one trajectory solver, :func:`symplid.dynamics._trajectory.solve`, so only
the stored states are kept in memory. The shared core lives in
:mod:`~symplid.inference._predictive`, the forecast in :mod:`~symplid.inference._forecast`, the
energy and horizon in :mod:`~symplid.inference._measures`; every public name is importable
from here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from symplid.dynamics._integrators import Integrator
from symplid.dynamics._potentials import Potential
from symplid.inference._forecast import forecast_from_filter
from symplid.inference._measures import hamiltonian_along, prediction_horizon
from symplid.inference._predictive import (
    DEFAULT_STORED_POINTS,
    PosteriorPredictive,
    check_state,
    flatten_draws,
    integrate_paths,
    key_and_seed,
    positive_int,
    predictive_band,
    resolve_propagator,
    time_grid,
)
from symplid.model._statespace import HamiltonianModel

Array = jax.Array

__all__ = [
    "DEFAULT_STORED_POINTS",
    "PosteriorPredictive",
    "forecast_from_filter",
    "hamiltonian_along",
    "posterior_predictive",
    "predict_trajectory",
    "prediction_horizon",
    "time_grid",
]


def predict_trajectory(
    model_or_potential: HamiltonianModel | Potential,
    theta_or_coefficients: Any,
    x0: Any,
    t_end: float,
    dt: float = 0.01,
    integrator: str | Integrator = "leapfrog",
    t0: float = 0.0,
    every: int = 1,
    mass: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the learned Hamiltonian deterministically: X_k = Ψ^k(X_0; θ_Ψ) (Section II-B.2).

    Parameters
    ----------
    model_or_potential
        A :class:`~symplid.HamiltonianModel` (its potential and mass are used; its learning
        integrator and dt are not) or a potential.
    theta_or_coefficients
        θ of the model (the variances are ignored) or the potential's coefficients; for a
        damped model θ or θ_Ψ = [coefficients, γ] (the path is then damped too).
    x0
        Initial state ``(q, p)`` at ``t0``, shape ``(2d,)``.
    t_end
        Final time.
    dt
        Step size (the paper's fine step is 0.01); see :func:`time_grid` when it does not
        divide ``t_end − t0``.
    integrator
        Any name of :data:`symplid.INTEGRATORS`; it need not be the learning one (footnote 1
        of the paper). Default leapfrog, as in Section IV.
    t0
        Initial time.
    every
        Store every ``every``-th state (and the last).
    mass
        Mass matrix M (overrides the model's); identity when None.

    Returns
    -------
    times : ndarray, shape (T,)
    states : ndarray, shape (T, 2d)
    """
    potential, coefficients, inv_mass, integ = resolve_propagator(
        model_or_potential, theta_or_coefficients, integrator, mass
    )
    if coefficients.ndim != 1:
        raise ValueError(
            f"one coefficient vector expected, got shape {coefficients.shape}; "
            "use posterior_predictive for many draws"
        )
    x0 = check_state(x0, potential.dim)
    if x0.ndim != 1:
        raise ValueError(f"x0 must have shape ({2 * potential.dim},), got {x0.shape}")
    times, n, h = time_grid(float(t0), float(t_end), float(dt), every)
    paths = integrate_paths(potential, integ, n, every, coefficients[None], x0[None], h, inv_mass)
    return times, paths[0]


def posterior_predictive(
    model_or_potential: HamiltonianModel | Potential,
    coefficient_draws: Any,
    x0: Any,
    t_end: float,
    dt: float = 0.01,
    integrator: str | Integrator = "leapfrog",
    quantiles: Sequence[float] = (0.025, 0.975),
    num_paths: int = 100,
    seed: int | Array = 0,
    *,
    t0: float = 0.0,
    every: int | None = None,
    max_draws: int | None = 1000,
    batch_size: int = 256,
    mass: Any = None,
) -> PosteriorPredictive:
    """Posterior predictive band: one deterministic path per posterior draw, pointwise quantiles.

    Approximates π(X(t) | Y_n) = ∫ π(X(t) | θ) π(θ | Y_n) dθ (Section II-B.2) as in Fig. 3:
    every draw's coefficients are integrated from ``x0`` with ``integrator`` at step ``dt``.

    Parameters
    ----------
    model_or_potential
        A :class:`~symplid.HamiltonianModel` or a potential (see :func:`predict_trajectory`).
    coefficient_draws
        Draws of θ or of the coefficients, shape ``(S, P)`` or ``(chains, draws, P)`` (leading
        axes are flattened, chain-major).
    x0
        Initial state, shape ``(2d,)``, or one per draw, shape ``(S, 2d)``.
    t_end, dt, integrator, t0, mass
        As in :func:`predict_trajectory`.
    quantiles
        Levels of the band, each in (0, 1).
    num_paths
        Number of sample paths returned (drawn at random among the integrated draws).
    seed
        An int or a ``jax.random`` key; chooses the draws used and the sample paths.
    every
        Store every ``every``-th step. Default: the smallest value that keeps at most
        :data:`DEFAULT_STORED_POINTS` + 1 stored times (10 for 200 s at dt = 0.01).
    max_draws
        At most this many draws (a random subset, without replacement) are integrated; None
        integrates all of them. The stored paths take ``S·T·2d·8`` bytes.
    batch_size
        Draws integrated at once by one ``vmap``-ed call (bounds the working memory).

    Returns
    -------
    PosteriorPredictive
    """
    potential, draws, inv_mass, integ = resolve_propagator(
        model_or_potential, coefficient_draws, integrator, mass
    )
    draws = flatten_draws(draws)
    x0 = check_state(x0, potential.dim)
    if x0.ndim == 1:
        x0 = np.broadcast_to(x0, (draws.shape[0], x0.shape[0]))
    elif x0.shape[:-1] != (draws.shape[0],):
        raise ValueError(f"x0 must have shape (2d,) or ({draws.shape[0]}, 2d), got {x0.shape}")
    key, seed_int = key_and_seed(seed)
    order = np.asarray(jax.random.permutation(key, draws.shape[0]))
    used = order if max_draws is None else order[: positive_int(max_draws, "max_draws")]
    return predictive_band(
        potential, inv_mass, draws[used], x0[used], used, t0, t_end, dt, integ,
        quantiles, num_paths, seed_int, every, batch_size,
    )
