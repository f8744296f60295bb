"""What is measured along predicted paths: the energy H(q, p) (eq. 2) and the horizon.

The paper judges a learned model by how well it conserves the true energy (Fig. 2) and by how
long its prediction stays near the truth (Fig. 3).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import jit_for
from symplid.dynamics._potentials import Potential, hamiltonian
from symplid.inference._predictive import resolve_coefficients
from symplid.model._statespace import HamiltonianModel

__all__ = ["hamiltonian_along", "potential_slices", "prediction_horizon"]


def hamiltonian_along(
    model_or_potential: HamiltonianModel | Potential,
    coefficients: Any,
    states: Any,
    mass: Any = None,
) -> np.ndarray:
    """H(q, p) = ½pᵀM⁻¹p + U(q) (eqs 2, 4) at every state of one path or of many.

    Parameters
    ----------
    model_or_potential
        A potential or a :class:`~symplid.HamiltonianModel` (θ or bare coefficients accepted).
    coefficients
        One coefficient vector ``(P,)`` for all states, or one per path ``(S, P)`` together
        with ``states`` of shape ``(S, T, 2d)`` (``vmap``-ed over the paths).
    states
        ``(T, 2d)`` or ``(S, T, 2d)`` (any leading axes with one coefficient vector).
    mass
        Mass matrix (overrides the model's).

    Returns
    -------
    ndarray with the leading shape of ``states`` (``(T,)`` or ``(S, T)``).
    """
    potential, coefficients, inv_mass = resolve_coefficients(model_or_potential, coefficients, mass)
    states = np.asarray(states, dtype=float)
    if states.shape[-1] != 2 * potential.dim:
        raise ValueError(
            f"states must end with 2d = {2 * potential.dim} components, got {states.shape}"
        )
    c, x = jnp.asarray(coefficients), jnp.asarray(states)
    if coefficients.ndim == 1:
        return np.asarray(jit_for(potential, _energy)(c, x, inv_mass))
    if coefficients.ndim != 2 or states.ndim != 3 or states.shape[0] != coefficients.shape[0]:
        raise ValueError(
            "with one coefficient vector per path, coefficients must be (S, P) and states "
            f"(S, T, 2d); got {coefficients.shape} and {states.shape}"
        )
    return np.asarray(jit_for(potential, _energy_per_path)(c, x, inv_mass))


def _energy(potential, coefficients, states, inv_mass):
    return hamiltonian(potential, coefficients, states, inv_mass)


def _energy_per_path(potential, coefficients, states, inv_mass):
    return jax.vmap(hamiltonian, in_axes=(None, 0, 0, None))(
        potential, coefficients, states, inv_mass
    )


def prediction_horizon(
    times: Any,
    predicted: Any,
    truth: Any,
    threshold: float = 0.1,
    component: int | Sequence[int] | None = 0,
) -> float:
    """First time the prediction leaves the truth by more than ``threshold``.

    The paper's measure of how long a learned model stays valid (Fig. 3: about 150 s with
    leapfrog, 20 s with RK2, for the MAP trajectory against the truth in q1).

    Parameters
    ----------
    times
        Common time grid, shape ``(T,)``, increasing.
    predicted, truth
        States on that grid, shape ``(T, n)`` (or ``(T,)`` for one component).
    threshold
        Allowed deviation (> 0).
    component
        Index of the compared component (default 0, q1); a sequence of indices or None compares
        the Euclidean distance over those components (None: all of them).

    Returns
    -------
    float
        The first grid time at which the deviation exceeds ``threshold`` (a non-finite
        prediction counts as exceeding); ``times[-1]`` if it never does.
    """
    times = np.asarray(times, dtype=float)
    predicted = np.asarray(predicted, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if predicted.ndim == 1:
        predicted = predicted[:, None]
    if truth.ndim == 1:
        truth = truth[:, None]
    if times.ndim != 1 or times.shape[0] == 0:
        raise ValueError(f"times must be a non-empty 1-D array, got shape {times.shape}")
    if predicted.shape != truth.shape or predicted.shape[0] != times.shape[0]:
        raise ValueError(
            f"times {times.shape}, predicted {predicted.shape} and truth {truth.shape} "
            "must share the time axis and the components"
        )
    if not threshold > 0:
        raise ValueError(f"threshold must be positive, got {threshold}")
    n = predicted.shape[1]
    diff = predicted - truth
    if component is None:
        err = np.linalg.norm(diff, axis=1)
    else:
        idx = np.atleast_1d(np.asarray(component))
        if idx.dtype.kind not in "iu" or np.any(idx < -n) or np.any(idx >= n):
            raise ValueError(f"component must be indices in [0, {n}), got {component}")
        err = np.abs(diff[:, idx[0]]) if np.ndim(component) == 0 else np.linalg.norm(
            diff[:, idx], axis=1
        )
    outside = ~(err <= threshold)  # NaN counts as outside
    if not outside.any():
        return float(times[-1])
    return float(times[int(np.argmax(outside))])


def _potential_values(potential: Potential, coefficients: jax.Array, points: jax.Array):
    """U at every point ``(M, d)`` for every coefficient vector ``(S, P)``: ``(S, M)``."""
    at_points = jax.vmap(lambda c: jax.vmap(lambda q: potential.value(q, c))(points))
    return at_points(coefficients)


def potential_slices(
    potential: Potential,
    coefficients: Any,
    centre: Sequence[float],
    lower: Sequence[float],
    upper: Sequence[float],
    num: int = 161,
    levels: tuple[float, ...] = (0.025, 0.5, 0.975),
) -> list[dict[str, np.ndarray]]:
    """The learned potential U(q; c) along one line per axis, with its posterior band.

    Slice i runs q_i over ``[lower_i, upper_i]`` with the other coordinates at ``centre``
    (for d = 1, U over the range). ``coefficients`` ``(S, P)`` are posterior draws; a single
    row ``(P,)`` (the MAP, the truth) gives its own values as every quantile. Returns one dict
    per axis: ``q`` ``(num,)``, ``points`` ``(num, d)`` and ``quantiles``
    ``(len(levels), num)``.
    """
    coefficients = jnp.atleast_2d(jnp.asarray(coefficients, dtype=float))
    centre = np.asarray(centre, dtype=float)
    out = []
    for i in range(centre.size):
        q = np.linspace(float(lower[i]), float(upper[i]), int(num))
        line = np.tile(centre, (q.size, 1))
        line[:, i] = q
        values = np.asarray(_potential_values(potential, coefficients, jnp.asarray(line)))
        quantiles = np.quantile(values, levels, axis=0)
        out.append({"q": q, "points": line, "quantiles": quantiles})
    return out
