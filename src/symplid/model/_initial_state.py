"""Each trajectory's initial state for :class:`~symplid.model._posterior.Posterior`.

Reads the per-trajectory inputs (data, ``x0``, ``P0``, ``t0``), builds the prior of a learned
initial state (its rule is in the docstring of :mod:`symplid.model._posterior`), and conditions
N(x0, P0) on the first observation when the state sits at the first observation time
(``t0=None``), by the filter's own Gaussian update (eqs 11–12).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid.filters import ObservationMoments, gaussian_update
from symplid.model._data import DataError, Observations
from symplid.model._priors import Laplace, Normal, Prior, as_prior

Array = jax.Array

KNOWN_P0 = 1e-16
"""Diagonal of P0 for a known (or learned) initial state, as in the model."""

UNOBSERVED_SCALE_FACTOR = 3.0
"""How much wider the default initial-state prior is for components y_1 does not measure."""


class FirstObservation(NamedTuple):
    """y_1 of a trajectory whose initial state sits at the first observation time.

    ``process_noise``: add the model's process-noise covariance Σ to P0 before y_1's update
    (a learned initial state with the default P0; see :func:`first_observation_update`).
    """

    y: np.ndarray  # observed components of y_1
    index: np.ndarray  # their positions in y
    process_noise: bool = False


def state_names(dim: int) -> tuple[str, ...]:
    """``q1..qd, p1..pd`` for a system of ``dim`` degrees of freedom."""
    return tuple(f"q{i + 1}" for i in range(dim)) + tuple(f"p{i + 1}" for i in range(dim))


# ---------------------------------------------------------------------------- inputs
def as_datasets(data: Any) -> tuple[Observations, ...]:
    """One :class:`Observations` or a non-empty list of them, as a tuple."""
    if isinstance(data, Observations):
        return (data,)
    if isinstance(data, Sequence) and not isinstance(data, str):
        out = tuple(data)
        if not out:
            raise DataError("data is an empty list: give at least one Observations")
        for k, obs in enumerate(out):
            if not isinstance(obs, Observations):
                raise TypeError(
                    f"data[{k}] must be a symplid.Observations, got {type(obs).__name__}"
                )
        return out
    raise TypeError(f"data must be an Observations or a list of them, got {type(data).__name__}")


def per_trajectory(value: Any, K: int, name: str) -> list[Any]:
    """A shared value, or a list/tuple with one entry per trajectory (when K > 1)."""
    if K > 1 and isinstance(value, list | tuple):
        if len(value) != K:
            raise ValueError(f"{name}: {len(value)} entries given for {K} trajectories")
        return list(value)
    if K == 1 and isinstance(value, list | tuple) and name == "t0" and len(value) == 1:
        return list(value)
    return [value] * K


def as_P0(value: Any, n: int, k: int) -> np.ndarray:
    """P0 of trajectory k as an ``(n, n)`` symmetric positive semi-definite matrix."""
    if value is None:
        return KNOWN_P0 * np.eye(n)
    P0 = np.asarray(value, dtype=float)
    if P0.ndim == 0:
        P0 = float(P0) * np.eye(n)
    elif P0.ndim == 1:
        if P0.shape != (n,):
            raise ValueError(
                f"P0 of trajectory {k}: a diagonal must have {n} entries, got {P0.shape}"
            )
        P0 = np.diag(P0)
    if P0.shape != (n, n):
        raise ValueError(f"P0 of trajectory {k} must be ({n}, {n}), got {P0.shape}")
    if not np.all(np.isfinite(P0)) or not np.allclose(P0, P0.T):
        raise ValueError(f"P0 of trajectory {k} must be finite and symmetric")
    if np.min(np.linalg.eigvalsh(P0)) < 0:
        raise ValueError(f"P0 of trajectory {k} must be positive semi-definite")
    return P0


def is_point_mass(P0: np.ndarray) -> bool:
    """Whether P0 describes a point rather than a distribution (every entry ≤ 1e-12, the
    filter's jitter; the default :data:`KNOWN_P0` is one)."""
    return bool(np.max(np.abs(P0)) <= 1e-12)


def as_x0(value: Any, n: int, K: int, required: bool) -> list[np.ndarray] | None:
    """The known initial states, one ``(n,)`` array per trajectory (None when not given)."""
    if value is None:
        if required:
            raise ValueError(
                "x0 is required when the initial state is known: pass x0=... "
                "(or learn_initial_state=True to learn it)"
            )
        return None
    if K > 1 and isinstance(value, list | tuple) and len(value) == K:
        arrays = [np.asarray(v, dtype=float) for v in value]
    else:
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 1 and K == 1:
            arrays = [arr]
        elif arr.ndim == 2 and arr.shape[0] == K:
            arrays = list(arr)
        else:
            raise ValueError(
                f"x0 must have shape ({n},) for one trajectory or ({K}, {n}) for {K}, "
                f"got {arr.shape}"
            )
    for k, a in enumerate(arrays):
        if a.shape != (n,):
            raise ValueError(f"x0 of trajectory {k} must have shape ({n},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"x0 of trajectory {k} must be finite, got {a}")
    return arrays


def split_first(obs: Observations, t0: float | None, k: int):
    """(the data the filter runs over, its start time, y_1 when the state sits at t_1)."""
    if t0 is None:
        if obs.num_times < 2:
            raise DataError(
                f"trajectory {k} has one observation: with t0=None the initial state "
                "sits at it and at least one more observation is needed"
            )
        mask = obs.mask[0]
        first = FirstObservation(obs.values[0][mask], np.flatnonzero(mask))
        return obs.subset(slice(1, None)), float(obs.times[0]), first
    start = float(t0)
    if not start < obs.times[0]:
        raise DataError(
            f"trajectory {k}: t0 = {start:g} must be before its first observation "
            f"time {obs.times[0]:g} (or pass t0=None to put the initial state there)"
        )
    return obs, start, None


# ---------------------------------------------------------------------------- the prior
def initial_state_prior(
    model: Any, obs: Observations, x0: np.ndarray | None, spec: Any, names: Sequence[str]
) -> tuple[np.ndarray, list[Prior]]:
    """Centre and absolute per-component priors of one trajectory's learned initial state.

    ``x0`` (when given) is the centre, every component counted as measured; otherwise the
    centre comes from y_1 (:func:`centre_from_first`). ``spec`` is the offset's prior: None
    (Normal(0, s) with s from :func:`data_scale`), a scale, a prior, or one prior per component.
    """
    n = len(names)
    if x0 is not None:
        centre, measured = np.asarray(x0, dtype=float), np.ones(n, dtype=bool)
    else:
        centre, measured = centre_from_first(model, obs, n)
    offsets: list[Prior]
    if spec is None or isinstance(spec, int | float | np.number):
        s = data_scale(obs) if spec is None else float(spec)
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"initial_state_prior: a scale must be > 0, got {spec!r}")
        offsets = [Normal(0.0, s if m else UNOBSERVED_SCALE_FACTOR * s) for m in measured]
    elif isinstance(spec, Sequence) and not isinstance(spec, str | Mapping):
        if len(spec) != n:
            raise ValueError(
                f"initial_state_prior: {len(spec)} priors given for a {n}-component state "
                f"({', '.join(names)})"
            )
        offsets = [_offset_prior(as_prior(p, "initial_state_prior")) for p in spec]
    else:
        base = _offset_prior(as_prior(spec, "initial_state_prior"))
        wide = dataclasses.replace(base, scale=UNOBSERVED_SCALE_FACTOR * base.scale)
        offsets = [base if m else wide for m in measured]
    return centre, [_shift(p, c) for p, c in zip(offsets, centre, strict=True)]


def centre_from_first(model: Any, obs: Observations, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Prior centre of x0 from y_1, and which components y_1 measures directly."""
    matrix = model.observation_matrix
    measured = np.zeros(n, dtype=bool)
    centre = np.zeros(n)
    if matrix is None:
        return centre, measured
    H = np.asarray(matrix, dtype=float)
    mask = obs.mask[0]
    H, y = H[mask], obs.values[0][mask]
    if H.shape[0] == 0:
        return centre, measured
    centre = np.linalg.pinv(H) @ y
    for j in range(H.shape[0]):
        nz = np.flatnonzero(H[j])
        if nz.size == 1:
            i = nz[0]
            centre[i] = y[j] / H[j, i]
            measured[i] = True
    return centre, measured


def data_scale(obs: Observations) -> float:
    """The largest standard deviation over time of an observed component (1 if undefined)."""
    with np.errstate(all="ignore"):
        counts = np.sum(obs.mask, axis=0)
        values = np.where(obs.mask, obs.values, np.nan)
        stds = [np.nanstd(values[:, j]) for j in range(obs.dim) if counts[j] >= 2]
    s = max(stds) if stds else float("nan")
    return float(s) if np.isfinite(s) and s > 0 else 1.0


def _offset_prior(prior: Prior) -> Normal | Laplace:
    if not isinstance(prior, Normal | Laplace):
        raise ValueError(
            "initial_state_prior: the prior of the offset from the first observation must be "
            f"normal or laplace (any real value), got {prior}"
        )
    return prior


def _shift(prior: Prior, centre: float) -> Prior:
    return dataclasses.replace(prior, loc=prior.loc + float(centre))  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------- y_1
def first_observation_update(
    model: Any, model_theta: Array, first: FirstObservation, x0: Array, P0: Array
) -> tuple[Array, Array, Array]:
    """Condition N(x0, P0) on y_1: (mean, covariance, log p(y_1)), eqs 11–12.

    With ``first.process_noise`` the prior of the update is N(x0, P0 + Σ): y_1 meets the
    state after one process-noise increment, like every later observation. This is what a
    *learned* initial state at the first observation time needs: with P0 ≈ 0, p(y_1 | x0)
    = N(y_1; h(x0), Γ) grows without bound as x0 → y_1 and Γ → 0 while Σ absorbs the noise
    of the other observations, a degenerate optimum with Γ on its floor and x0 on the
    datum; with Σ in the update the variance of y_1 is Σ + Γ and that ridge disappears.

    The observation operator is used through its matrix when linear (exact), else linearised
    at x0 (ŷ = h(x0), H = ∂h/∂x at x0); the update is the filter's
    :func:`~symplid.filters.gaussian_update` over the observed components of y_1.
    """
    idx = first.index
    if idx.size == 0:
        return x0, P0, jnp.zeros(())
    matrix = model.observation_matrix
    if matrix is not None:
        H = jnp.asarray(np.asarray(matrix)[idx])
        y_hat = H @ x0
    else:
        observe = model.observation

        def h(x: Array) -> Array:
            return jnp.ravel(observe(x))[idx]

        y_hat = h(x0)
        H = jax.jacfwd(h)(x0)
    _, proc_cov, obs_cov = model.split(model_theta)
    if first.process_noise:
        P0 = P0 + proc_cov
    R = obs_cov[np.ix_(idx, idx)]
    cross = P0 @ H.T
    moments = ObservationMoments(y_hat, H @ cross, cross)
    noise = model.noise_model  # declared by the StateSpaceModel protocol
    if noise.multiplicative:  # R = Γ + diag(r ∘ E[h∘h]) (filters.noise)
        R = noise.covariance_fn(R, model.relative_variances(model_theta)[idx])(moments)
    observed = jnp.ones(idx.size, dtype=bool)
    mean, chol, log_lik = gaussian_update(x0, P0, jnp.asarray(first.y), observed, moments, R)
    return mean, chol @ chol.T, log_lik


__all__ = [
    "KNOWN_P0",
    "UNOBSERVED_SCALE_FACTOR",
    "FirstObservation",
    "as_P0",
    "as_datasets",
    "as_x0",
    "data_scale",
    "first_observation_update",
    "initial_state_prior",
    "is_point_mass",
    "per_trajectory",
    "split_first",
    "state_names",
]
