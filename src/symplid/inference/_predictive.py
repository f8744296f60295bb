"""The core of predictions: resolving θ, the time grid, integrating batches of paths, bands.

Shared by :mod:`~symplid.inference._predict` (paths from a known initial state) and
:mod:`~symplid.inference._forecast` (paths from the filter's last state). Every path is
integrated by the one trajectory solver, :func:`symplid.dynamics._trajectory.solve`, which
keeps only the stored states in memory.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import jit_for
from symplid.dynamics._damping import bind_dynamics, is_damped, with_damping
from symplid.dynamics._hamiltonians import is_hamiltonian
from symplid.dynamics._integrators import Integrator, get_integrator
from symplid.dynamics._potentials import Potential, inverse_mass
from symplid.dynamics._trajectory import solve
from symplid.model._statespace import HamiltonianModel

Array = jax.Array

__all__ = [
    "DEFAULT_STORED_POINTS",
    "PosteriorPredictive",
    "check_state",
    "flatten_draws",
    "integrate_paths",
    "key_and_seed",
    "positive_int",
    "predictive_band",
    "resolve_coefficients",
    "resolve_propagator",
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
def resolve_coefficients(model_or_potential: Any, coefficients: Any, mass: Any = None):
    """(potential, coefficients with trailing axis num_params, M⁻¹) from a model or a potential.

    With a :class:`HamiltonianModel`, ``coefficients`` may be full θ vectors (the variances are
    dropped), θ_Ψ (coefficients and γ of a damped model; γ is dropped) or bare coefficients,
    and the model's mass is used unless ``mass`` is given. For paths of a damped model see
    :func:`resolve_propagator`.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    if coefficients.ndim == 0:
        coefficients = coefficients[None]
    if isinstance(model_or_potential, HamiltonianModel):
        model = model_or_potential
        potential = model.hamiltonian
        n = coefficients.shape[-1]
        if n in (model.num_params, model.num_dynamics_params):
            coefficients = coefficients[..., : model.num_coefficients]
        elif n != model.num_coefficients:
            raise ValueError(
                f"expected θ with {model.num_params} entries ({', '.join(model.param_names)}) "
                f"or {model.num_coefficients} coefficients, got {n}"
            )
        if mass is None:
            mass = model.mass
    elif isinstance(model_or_potential, Potential) or is_hamiltonian(model_or_potential):
        potential = model_or_potential
        if coefficients.shape[-1] != potential.num_params:
            raise ValueError(
                f"expected {potential.num_params} coefficients "
                f"({', '.join(potential.param_names)}), got {coefficients.shape[-1]}"
            )
    else:
        raise TypeError(
            "expected a potential (symplid.Polynomial, FunctionPotential, ...), a "
            f"Hamiltonian or a HamiltonianModel, got {type(model_or_potential).__name__}"
        )
    return potential, coefficients, inverse_mass(mass, potential.dim)


def resolve_propagator(
    model_or_potential: Any, theta_or_coefficients: Any, integrator: str | Integrator, mass: Any
) -> tuple[Any, np.ndarray, Any, Integrator]:
    """(potential, θ_Ψ, M⁻¹, integrator) for integrating paths: :func:`resolve_coefficients`,
    except that a damped model keeps γ (θ_Ψ = [coefficients, γ]) and integrates with the
    damped form of ``integrator`` (:func:`~symplid.dynamics._damping.with_damping`); with a
    potential and a damped ``integrator``, θ_Ψ = [coefficients, γ] is expected."""
    model = model_or_potential
    integ = get_integrator(integrator)
    if isinstance(model, Potential) and is_damped(integ):  # [coefficients, γ] given
        params = np.asarray(theta_or_coefficients, dtype=float)
        potential, _, inv_mass = resolve_coefficients(model, params[..., :-1], mass)
        return potential, params, inv_mass, integ
    if not (isinstance(model, HamiltonianModel) and model.damping):
        potential, coefficients, inv_mass = resolve_coefficients(model, theta_or_coefficients, mass)
        return potential, coefficients, inv_mass, integ
    params = np.asarray(theta_or_coefficients, dtype=float)
    n, nd = params.shape[-1] if params.ndim else 1, model.num_dynamics_params
    if n not in (model.num_params, nd):
        raise ValueError(
            f"the model is damped: expected θ with {model.num_params} entries "
            f"({', '.join(model.param_names)}) or θ_Ψ with {nd} (the coefficients and gamma), "
            f"got {n}"
        )
    potential, _, inv_mass = resolve_coefficients(model, params, mass)
    return potential, params[..., :nd], inv_mass, with_damping(integrator)


def check_state(x0: Any, dim: int, name: str = "x0") -> np.ndarray:
    """``x0`` as floats, checked to end with the 2d components ``(q, p)`` and to be finite."""
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


def _split_damping_rate(integrator: Integrator, row: Array) -> tuple[Array, Array | None]:
    """θ_Ψ → (the Hamiltonian's parameters, γ): for a damped ``integrator`` a row is
    [coefficients ..., γ], the order of a model's layout (its dynamics block, then ``damping``:
    :mod:`symplid.model._layout`); otherwise the coefficients, and no γ."""
    if not is_damped(integrator):
        return row, None
    return row[..., :-1], row[..., -1]


def _batch_paths(potential, integrator, num_steps, every, coefficients, x0, step_size, inv_mass):
    """States at the stored steps for a batch of (coefficients, x0): ``(B, T, 2d)``.

    One :func:`~symplid.dynamics._trajectory.solve` per path, ``vmap``-ed over the batch.
    """

    def one(c: Array, x: Array) -> Array:
        params, gamma = _split_damping_rate(integrator, c)
        dynamics = bind_dynamics(integrator, potential, params, inv_mass, gamma)
        return solve(integrator, dynamics, x, step_size, num_steps, every)

    return jax.vmap(one)(coefficients, x0)


def integrate_paths(
    potential: Potential,
    integrator: Integrator,
    num_steps: int,
    every: int,
    coefficients: Any,
    x0: Any,
    step_size: float,
    inv_mass: Any,
) -> np.ndarray:
    """Paths for a batch of coefficient vectors ``(B, P)`` and initial states ``(B, 2d)``.

    For a damped ``integrator`` each row is θ_Ψ = [coefficients, γ].

    ``num_steps`` steps of ``step_size``, stored as in :func:`time_grid`: shape ``(B, T, 2d)``.
    """
    out = jit_for(potential, _batch_paths, integrator, int(num_steps), int(every))(
        jnp.asarray(coefficients, dtype=float),
        jnp.asarray(x0, dtype=float),
        jnp.asarray(step_size, dtype=float),
        inv_mass,
    )
    return np.asarray(out)


def key_and_seed(seed: int | Array) -> tuple[Array, int | None]:
    """A ``jax.random`` key from an int seed (returned too, to record it) or the key given."""
    if isinstance(seed, int | np.integer):
        return jax.random.key(int(seed)), int(seed)
    return seed, None


def flatten_draws(draws: np.ndarray) -> np.ndarray:
    """Draws ``(S, P)`` or ``(chains, draws, P)`` as ``(S, P)``, chain-major; at least one."""
    if draws.ndim < 2:
        raise ValueError(f"draws must have shape (S, P) or (chains, draws, P), got {draws.shape}")
    draws = draws.reshape(-1, draws.shape[-1])
    if draws.shape[0] == 0:
        raise ValueError("there are no draws")
    return draws


def positive_int(value: Any, name: str) -> int:
    """``value`` as an int ≥ 1, or a ValueError naming ``name``."""
    if int(value) != value or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value}")
    return int(value)


def predictive_band(
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
    batch = min(positive_int(batch_size, "batch_size"), draws.shape[0])
    integ = get_integrator(integrator)
    _, n, _ = time_grid(float(t0), float(t_end), float(dt))
    if every is None:
        every = max(1, math.ceil(n / DEFAULT_STORED_POINTS))
    times, n, h = time_grid(float(t0), float(t_end), float(dt), every)

    num = draws.shape[0]
    paths = np.empty((num, times.shape[0], 2 * potential.dim))
    for start in range(0, num, batch):
        stop = min(start + batch, num)
        idx = np.arange(start, stop)
        if stop - start < batch:  # pad the last batch: one compiled shape for every call
            idx = np.concatenate([idx, np.full(batch - (stop - start), start)])
        out = integrate_paths(potential, integ, n, every, draws[idx], x0[idx], h, inv_mass)
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
