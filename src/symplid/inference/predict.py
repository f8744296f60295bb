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

Integration uses :mod:`~symplid.dynamics.trajectory` (``propagate`` over chunks of ``every`` steps
inside one ``lax.scan``), so only the stored states are kept in memory.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics.integrators import Integrator, get_integrator, make_dynamics
from symplid.dynamics.potentials import Potential, hamiltonian, inverse_mass
from symplid.dynamics.trajectory import propagate
from symplid.model.data import Observations
from symplid.model.statespace import HamiltonianModel

Array = jax.Array

__all__ = [
    "PosteriorPredictive",
    "forecast_from_filter",
    "hamiltonian_along",
    "posterior_predictive",
    "predict_trajectory",
    "prediction_horizon",
    "time_grid",
]

#: Default number of stored time points of a posterior predictive (``every`` is chosen to fit).
DEFAULT_STORED_POINTS = 2000


@dataclass(frozen=True)
class PosteriorPredictive:
    """Pointwise summaries of paths integrated from posterior draws.

    Attributes
    ----------
    times
        Stored times, shape ``(T,)`` (every ``every``-th step, and the last one).
    quantile_levels
        The requested levels, e.g. ``(0.025, 0.975)``.
    quantiles
        Pointwise quantiles over the finite paths, shape ``(len(quantile_levels), T, 2d)``.
    median
        Pointwise median over the finite paths, shape ``(T, 2d)``.
    paths
        ``num_paths`` sample paths, shape ``(num_paths, T, 2d)``.
    path_indices
        Row of each sample path in the (flattened) array of draws that was passed in.
    finite_fraction
        Fraction of the paths still finite at each time, shape ``(T,)``. A path integrated
        from a draw whose dynamics blow up becomes inf/NaN and is left out of the quantiles;
        a value below 1 means the band describes the surviving paths only.
    num_draws
        Number of draws integrated (the band is over these).
    dt, every, integrator, seed
        Settings that produced the result.
    """

    times: np.ndarray
    quantile_levels: tuple[float, ...]
    quantiles: np.ndarray
    median: np.ndarray
    paths: np.ndarray
    path_indices: np.ndarray
    finite_fraction: np.ndarray
    num_draws: int
    dt: float
    every: int
    integrator: str
    seed: int | None

    @property
    def lower(self) -> np.ndarray:
        """The lowest requested quantile, shape ``(T, 2d)``."""
        return self.quantiles[0]

    @property
    def upper(self) -> np.ndarray:
        """The highest requested quantile, shape ``(T, 2d)``."""
        return self.quantiles[-1]


# ---------------------------------------------------------------------------- helpers
def _resolve(model_or_potential: Any, coefficients: Any, mass: Any = None):
    """(potential, coefficients with trailing axis num_params, M⁻¹) from a model or a potential.

    With a :class:`HamiltonianModel`, ``coefficients`` may be full θ vectors (the variances are
    dropped) or bare coefficients, and the model's mass is used unless ``mass`` is given.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    if coefficients.ndim == 0:
        coefficients = coefficients[None]
    if isinstance(model_or_potential, HamiltonianModel):
        model = model_or_potential
        potential = model.potential
        n = coefficients.shape[-1]
        if n == model.num_params:
            coefficients = coefficients[..., : model.num_coefficients]
        elif n != model.num_coefficients:
            raise ValueError(
                f"expected θ with {model.num_params} entries ({', '.join(model.param_names)}) "
                f"or {model.num_coefficients} coefficients, got {n}"
            )
        if mass is None:
            mass = model.mass
    elif isinstance(model_or_potential, Potential):
        potential = model_or_potential
        if coefficients.shape[-1] != potential.num_params:
            raise ValueError(
                f"expected {potential.num_params} coefficients "
                f"({', '.join(potential.param_names)}), got {coefficients.shape[-1]}"
            )
    else:
        raise TypeError(
            "expected a potential (symplid.Polynomial, FunctionPotential, ...) or a "
            f"HamiltonianModel, got {type(model_or_potential).__name__}"
        )
    return potential, coefficients, inverse_mass(mass, potential.dim)


def _check_state(x0: Any, dim: int, name: str = "x0") -> np.ndarray:
    x0 = np.asarray(x0, dtype=float)
    if x0.shape[-1:] != (2 * dim,):
        raise ValueError(f"{name} must have shape ({2 * dim},) = (q, p), got {x0.shape}")
    if not np.all(np.isfinite(x0)):
        raise ValueError(f"{name} must be finite, got {x0}")
    return x0


def time_grid(t0: float, t_end: float, dt: float, every: int = 1) -> tuple[np.ndarray, int, float]:
    """The step grid of a fixed-step prediction and the stored times.

    ``⌈(t_end − t0)/dt⌉`` equal steps of size ``h = (t_end − t0)/n`` (``h = dt`` when dt
    divides the interval; a relative tolerance of 1e-9 absorbs rounding). States are stored at
    steps ``0, every, 2·every, …`` and at the last step.

    Returns
    -------
    times, num_steps, step_size
    """
    for name, val in (("t0", t0), ("t_end", t_end), ("dt", dt)):
        if not np.isfinite(val):
            raise ValueError(f"{name} must be a finite number, got {val}")
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    if t_end <= t0:
        raise ValueError(f"t_end = {t_end:g} must be after t0 = {t0:g}")
    if int(every) != every or every < 1:
        raise ValueError(f"every must be a positive integer, got {every}")
    every = int(every)
    n = max(math.ceil((t_end - t0) / dt * (1.0 - 1e-9)), 1)
    h = (t_end - t0) / n
    k = np.arange(0, n + 1, every)
    if k[-1] != n:
        k = np.append(k, n)
    return t0 + h * k, n, h


def _chunk_steps(num_steps: int, every: int) -> np.ndarray:
    """Steps per stored interval: ``every`` each, the last one takes the remainder."""
    full, rem = divmod(num_steps, every)
    return np.array([every] * full + ([rem] if rem else []), dtype=np.int64)


@partial(jax.jit, static_argnames=("potential", "integrator", "every"))
def _batch_paths(potential, integrator, every, coefficients, x0, step_size, chunk_steps, inv_mass):
    """States at the stored steps for a batch of (coefficients, x0): ``(B, T, 2d)``.

    An outer ``lax.scan`` over the stored intervals, each advanced by
    :func:`~.trajectory.propagate` (``every`` steps, masked for the last, shorter one).
    """
    d = x0.shape[-1] // 2

    def one(c, x):
        dynamics = make_dynamics(potential, c, inv_mass)

        def chunk(state, n):
            q, p = propagate(
                integrator, dynamics, state[:d], state[d:], step_size, n, every, unroll=1
            )
            nxt = jnp.concatenate([q, p])
            return nxt, nxt

        _, xs = jax.lax.scan(chunk, x, chunk_steps)
        return jnp.concatenate([x[None], xs])

    return jax.vmap(one)(coefficients, x0)


def _integrate_batch(
    potential, integrator: Integrator, every: int, coefficients, x0, step_size, chunk_steps,
    inv_mass,
) -> np.ndarray:
    out = _batch_paths(
        potential,
        integrator,
        every,
        jnp.asarray(coefficients, dtype=float),
        jnp.asarray(x0, dtype=float),
        jnp.asarray(step_size, dtype=float),
        jnp.asarray(chunk_steps),
        inv_mass,
    )
    return np.asarray(out)


def _key(seed: int | Array) -> tuple[Array, int | None]:
    if isinstance(seed, int | np.integer):
        return jax.random.key(int(seed)), int(seed)
    return seed, None


# ---------------------------------------------------------------------------- public API
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
        θ of the model (the variances are ignored) or the potential's coefficients.
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
    potential, coefficients, inv_mass = _resolve(model_or_potential, theta_or_coefficients, mass)
    if coefficients.ndim != 1:
        raise ValueError(
            f"one coefficient vector expected, got shape {coefficients.shape}; "
            "use posterior_predictive for many draws"
        )
    x0 = _check_state(x0, potential.dim)
    if x0.ndim != 1:
        raise ValueError(f"x0 must have shape ({2 * potential.dim},), got {x0.shape}")
    integ = get_integrator(integrator)
    times, n, h = time_grid(float(t0), float(t_end), float(dt), every)
    states = _integrate_batch(
        potential, integ, int(every), coefficients[None], x0[None], h, _chunk_steps(n, int(every)),
        inv_mass,
    )[0]
    return times, states


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
    potential, draws, inv_mass = _resolve(model_or_potential, coefficient_draws, mass)
    draws = _flatten_draws(draws)
    x0 = _check_state(x0, potential.dim)
    if x0.ndim == 1:
        x0 = np.broadcast_to(x0, (draws.shape[0], x0.shape[0]))
    elif x0.shape[:-1] != (draws.shape[0],):
        raise ValueError(f"x0 must have shape (2d,) or ({draws.shape[0]}, 2d), got {x0.shape}")
    key, seed_int = _key(seed)
    order = np.asarray(jax.random.permutation(key, draws.shape[0]))
    used = order if max_draws is None else order[: _positive_int(max_draws, "max_draws")]
    return _predictive(
        potential, inv_mass, draws[used], x0[used], used, t0, t_end, dt, integrator,
        quantiles, num_paths, seed_int, every, batch_size,
    )


def _flatten_draws(draws: np.ndarray) -> np.ndarray:
    if draws.ndim < 2:
        raise ValueError(f"draws must have shape (S, P) or (chains, draws, P), got {draws.shape}")
    draws = draws.reshape(-1, draws.shape[-1])
    if draws.shape[0] == 0:
        raise ValueError("there are no draws")
    return draws


def _positive_int(value: Any, name: str) -> int:
    if int(value) != value or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value}")
    return int(value)


def _predictive(
    potential, inv_mass, draws, x0, rows, t0, t_end, dt, integrator, quantiles, num_paths,
    seed, every, batch_size,
) -> PosteriorPredictive:
    """Integrate ``draws`` (already chosen, in random order) from ``x0`` and summarise.

    Rows of ``x0`` may be NaN (a failed filter): their paths are NaN and count as non-finite.
    ``rows`` maps each draw back to the caller's array.
    """
    levels = tuple(float(q) for q in np.atleast_1d(quantiles))
    if not levels or any(not 0.0 < q < 1.0 for q in levels):
        raise ValueError(f"quantiles must be levels in (0, 1), got {quantiles}")
    if int(num_paths) != num_paths or num_paths < 0:
        raise ValueError(f"num_paths must be a non-negative integer, got {num_paths}")
    batch = min(_positive_int(batch_size, "batch_size"), draws.shape[0])
    integ = get_integrator(integrator)
    _, n, _ = time_grid(float(t0), float(t_end), float(dt))
    if every is None:
        every = max(1, math.ceil(n / DEFAULT_STORED_POINTS))
    times, n, h = time_grid(float(t0), float(t_end), float(dt), every)
    chunks = _chunk_steps(n, int(every))

    num = draws.shape[0]
    paths = np.empty((num, times.shape[0], 2 * potential.dim))
    for start in range(0, num, batch):
        stop = min(start + batch, num)
        idx = np.arange(start, stop)
        if stop - start < batch:  # pad the last batch: one compiled shape for every call
            idx = np.concatenate([idx, np.full(batch - (stop - start), start)])
        out = _integrate_batch(
            potential, integ, int(every), draws[idx], x0[idx], h, chunks, inv_mass
        )
        paths[start:stop] = out[: stop - start]

    finite = np.all(np.isfinite(paths), axis=-1)  # (S, T)
    qs = _finite_quantiles(paths, finite, (*levels, 0.5))
    median = qs[-1]
    qs = qs[:-1]
    k = min(int(num_paths), num)
    return PosteriorPredictive(
        times=times,
        quantile_levels=levels,
        quantiles=qs,
        median=median,
        paths=paths[:k].copy(),
        path_indices=np.asarray(rows[:k]).copy(),
        finite_fraction=finite.mean(axis=0),
        num_draws=num,
        dt=float(h),
        every=int(every),
        integrator=integ.name,
        seed=seed,
    )


def _finite_quantiles(paths: np.ndarray, finite: np.ndarray, levels: Sequence[float]) -> np.ndarray:
    """Pointwise quantiles over the draws whose path is finite at that time.

    The ``linear`` rule of :func:`numpy.quantile`, vectorised over time and components
    (``numpy.nanquantile`` loops in Python over every column). NaN where no path is finite.
    """
    if finite.all():
        return np.quantile(paths, np.asarray(levels), axis=0)
    ordered = np.sort(np.where(finite[..., None], paths, np.inf), axis=0)  # finite first
    count = np.broadcast_to(finite.sum(axis=0)[:, None], paths.shape[1:])  # (T, n)
    out = np.empty((len(levels), *paths.shape[1:]))
    for i, q in enumerate(levels):
        pos = q * np.maximum(count - 1, 0)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
        a = np.take_along_axis(ordered, lo[None], axis=0)[0]
        b = np.take_along_axis(ordered, hi[None], axis=0)[0]
        with np.errstate(invalid="ignore"):
            out[i] = np.where(count > 0, a + (pos - lo) * np.where(hi > lo, b - a, 0.0), np.nan)
    return out


def forecast_from_filter(
    model: HamiltonianModel,
    theta_draws: Any,
    data: Observations,
    x0: Any,
    t_end: float,
    P0: Any = None,
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
) -> PosteriorPredictive:
    """Forecast from the end of the data with parameter and state uncertainty.

    For each posterior draw θ, the unscented Kalman filter of ``model`` (Theorem 1) is run over
    ``data``; a state is drawn from its last filtered distribution N(m_n, P_n) at the last
    observation time t_n and integrated deterministically to ``t_end``. The band mixes the
    posterior over θ_Ψ with what the data leave uncertain about the current state: the right
    starting point when the initial state is not known. No process noise is added along the
    forecast (as in Fig. 3). A draw whose filter fails gives a NaN path, reported through
    ``finite_fraction``.

    Parameters
    ----------
    model
        The model the draws come from (its filter settings and learning integrator are used
        for the filter; ``integrator`` and ``dt`` for the forecast).
    theta_draws
        Full θ draws, shape ``(S, num_params)`` or ``(chains, draws, num_params)``.
    data, x0, P0, t0
        As in :meth:`HamiltonianModel.filter`.
    t_end
        Forecast horizon, after the last observation time.
    dt, integrator, quantiles, num_paths, seed, every, max_draws, batch_size
        As in :func:`posterior_predictive`.

    Returns
    -------
    PosteriorPredictive
        Times run from the last observation time to ``t_end``; ``path_indices`` are rows of the
        flattened ``theta_draws``.
    """
    if not isinstance(model, HamiltonianModel):
        raise TypeError("forecast_from_filter needs the HamiltonianModel the draws come from")
    theta = _flatten_draws(np.asarray(theta_draws, dtype=float))
    if theta.shape[-1] != model.num_params:
        raise ValueError(
            f"theta_draws must end with {model.num_params} entries "
            f"({', '.join(model.param_names)}), got {theta.shape[-1]}"
        )
    if not isinstance(data, Observations):
        raise TypeError("data must be a symplid.Observations")
    t_last = float(data.times[-1])
    if not t_end > t_last:
        raise ValueError(f"t_end = {t_end:g} must be after the last observation t = {t_last:g}")
    x0 = _check_state(x0, model.potential.dim)
    key, seed_int = _key(seed)
    key_select, key_state = jax.random.split(key)
    order = np.asarray(jax.random.permutation(key_select, theta.shape[0]))
    used = order if max_draws is None else order[: _positive_int(max_draws, "max_draws")]
    prepared = model.prepare(data, t0)
    # One filter call per draw reuses the model's compiled filter (the one the fit used),
    # which costs less than compiling a vmapped filter for a one-off forecast.
    z = np.asarray(jax.random.normal(key_state, (used.shape[0], model.state_dim)))
    starts = np.empty((used.shape[0], model.state_dim))
    for i, row in enumerate(used):
        res = model.filter(theta[row], prepared, x0, P0)
        m = np.asarray(res.filtered_means[-1])
        cov = np.asarray(res.filtered_covs[-1])
        starts[i] = m + _cholesky_or_nan(cov) @ z[i]
    starts[~np.all(np.isfinite(starts), axis=1)] = np.nan
    inv_mass = inverse_mass(model.mass, model.potential.dim)
    coefficients = theta[used, : model.num_coefficients]
    return _predictive(
        model.potential, inv_mass, coefficients, starts, used, t_last, t_end, dt, integrator,
        quantiles, num_paths, seed_int, every, batch_size,
    )


def _cholesky_or_nan(cov: np.ndarray) -> np.ndarray:
    """Cholesky factor of a (symmetrised, slightly jittered) covariance; NaN if it fails."""
    cov = 0.5 * (cov + cov.T)
    cov = cov + 1e-14 * max(float(np.trace(cov)), 1.0) * np.eye(cov.shape[0])
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return np.full_like(cov, np.nan)


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
    potential, coefficients, inv_mass = _resolve(model_or_potential, coefficients, mass)
    states = np.asarray(states, dtype=float)
    if states.shape[-1] != 2 * potential.dim:
        raise ValueError(
            f"states must end with 2d = {2 * potential.dim} components, got {states.shape}"
        )
    c, x = jnp.asarray(coefficients), jnp.asarray(states)
    if coefficients.ndim == 1:
        return np.asarray(_energy(potential, c, x, inv_mass))
    if coefficients.ndim != 2 or states.ndim != 3 or states.shape[0] != coefficients.shape[0]:
        raise ValueError(
            "with one coefficient vector per path, coefficients must be (S, P) and states "
            f"(S, T, 2d); got {coefficients.shape} and {states.shape}"
        )
    return np.asarray(_energy_per_path(potential, c, x, inv_mass))


@partial(jax.jit, static_argnums=0)
def _energy(potential, coefficients, states, inv_mass):
    return hamiltonian(potential, coefficients, states, inv_mass)


@partial(jax.jit, static_argnums=0)
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
