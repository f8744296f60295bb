"""Paths and posterior bands of a driven model: the force and its inputs integrated along.

A driven model's predictions need u(t) over the whole predicted window: the inputs of the
data for paths over the data's span, the future inputs for a forecast. The paths are
integrated with the forced form of the prediction integrator
(:func:`~symplid.dynamics._forced.with_force`) on the grid of
:func:`~symplid.inference._predictive.time_grid`, the inputs tabulated at the integrator's
nodes (:func:`~symplid.model._inputs.node_table`, which refuses inputs that do not cover the
window in one line), and summarised as a
:class:`~symplid.inference._predictive.PosteriorPredictive` like a free model's.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import cumulative_trapezoid

from symplid.dynamics._forced import bind_forced, forced_solve_gaps, with_force
from symplid.dynamics._potentials import inverse_mass
from symplid.inference._predictive import (
    DEFAULT_STORED_POINTS,
    PosteriorPredictive,
    time_grid,
)
from symplid.model._inputs import node_table

__all__ = ["forced_band", "forced_paths", "power_balance"]


def forced_paths(model: Any, signal: Any, params: Any, x0: Any, t0: float, t_end: float,
                 dt: float, integrator: str = "leapfrog", every: int | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Paths of the driven ``model`` from ``x0`` ``(B, 2d)`` under θ_Ψ ``params`` ``(B, nd)``.

    Returns the stored times ``(T,)`` and the states ``(B, T, 2d)`` (``x0`` first).

    Raises
    ------
    DataError
        When ``signal`` does not cover [t0, t_end].
    """
    integ = with_force(integrator)
    _, n, _ = time_grid(float(t0), float(t_end), float(dt))
    every = max(1, math.ceil(n / DEFAULT_STORED_POINTS)) if every is None else int(every)
    times, n, h = time_grid(float(t0), float(t_end), float(dt), every)
    steps = np.diff(np.round((times - times[0]) / h).astype(int))
    sizes = np.full(steps.shape, h)
    node_times, inputs = node_table(signal, float(t0), sizes, steps, integ.nodes,
                                    model.force.num_inputs)
    inv_mass = inverse_mass(model.mass, model.hamiltonian.dim)
    max_steps = int(steps.max())

    def one(theta: Any, x: Any) -> Any:
        dynamics = bind_forced(model.hamiltonian, model.force, theta, inv_mass)
        return forced_solve_gaps(integ, dynamics, x, sizes, steps, node_times, inputs,
                                 max_steps)

    run = jax.jit(jax.vmap(one))
    params = jnp.atleast_2d(jnp.asarray(params, dtype=float))
    x0 = jnp.atleast_2d(jnp.asarray(x0, dtype=float))
    out = np.asarray(run(params, x0))
    return times, np.concatenate([np.asarray(x0)[:, None, :], out], axis=1)


def forced_band(model: Any, signal: Any, draws: Any, x0: Any, t0: float, t_end: float,
                dt: float, integrator: str = "leapfrog", num_paths: int = 100,
                seed: int = 0, quantiles: tuple[float, ...] = (0.025, 0.975),
                most: int = 400) -> PosteriorPredictive:
    """The pointwise band of the paths of (at most ``most``) posterior draws θ_Ψ ``(N, nd)``,
    each from its own initial state ``x0`` ``(N, 2d)`` (or one for all)."""
    draws = np.atleast_2d(np.asarray(draws, dtype=float))
    rng = np.random.default_rng(seed)
    rows = rng.permutation(draws.shape[0])[:most]
    x0 = np.asarray(x0, dtype=float)
    x0 = np.broadcast_to(x0, (draws.shape[0], x0.shape[-1])) if x0.ndim == 1 else x0
    times, paths = forced_paths(model, signal, draws[rows], x0[rows], t0, t_end, dt,
                                integrator)
    finite = np.all(np.isfinite(paths), axis=-1)
    kept = paths[np.all(finite, axis=1)]
    source = kept if kept.shape[0] else paths
    levels = tuple(float(q) for q in quantiles)
    qs = np.quantile(source, np.asarray((*levels, 0.5)), axis=0)
    k = min(int(num_paths), paths.shape[0])
    return PosteriorPredictive(
        times=times, quantile_levels=levels, quantiles=qs[:-1], median=qs[-1],
        paths=paths[:k].copy(), path_indices=rows[:k].copy(),
        finite_fraction=finite.mean(axis=0), num_draws=int(rows.size), dt=float(dt),
        every=1, integrator=with_force(integrator).name, seed=seed,
    )


# ---------------------------------------------------------------------------- power balance
def power_balance(model: Any, signal: Any, theta_psi: Any, x0: Any, t0: float,
                  times: Any, dt: float, integrator: str = "leapfrog") -> dict[str, np.ndarray]:
    """The energy budget of the MAP path over each gap between ``times``.

    Along the path of θ_Ψ from ``x0`` at ``t0`` (forced ``integrator`` at step ``dt``), the
    change of H over gap k, ΔH_k, against the work of the force there, split into the input's
    part W_in = ∫ ∂H/∂p · (F − F|_{u=0}) dt (the input power) and the rest W_F0 = ∫ ∂H/∂p ·
    F|_{u=0} dt (minus the dissipation, for a friction), by the trapezoid rule on the path's
    steps. The power balance dH/dt = ∂H/∂p · F makes ``residual`` = ΔH − W_in − W_F0 a check
    of the model's path: it shrinks with dt², while a model whose force is wrong for the data
    shows in the fit, not here. Returns arrays of one entry per gap: ``dH``, ``work_input``,
    ``work_other``, ``residual``.
    """
    times = np.asarray(times, dtype=float)
    span = float(times[-1])
    grid, paths = forced_paths(model, signal, np.asarray(theta_psi)[None], np.asarray(x0)[None],
                               t0, span, dt, integrator, every=1)
    path = paths[0]
    d = model.hamiltonian.dim
    k = np.asarray(theta_psi).shape[-1] - model.force.num_params
    coeffs = jnp.asarray(theta_psi[:k])
    theta_f = jnp.asarray(theta_psi[k:])
    q, p = jnp.asarray(path[:, :d].T), jnp.asarray(path[:, d:].T)
    u = jnp.asarray(signal.evaluate(grid)[..., : model.force.num_inputs])

    def point(qi, pi, ui, ti):
        h, vel = jax.value_and_grad(lambda pp: model.energy(coeffs, jnp.concatenate([qi, pp])))(pi)
        f = model.force(qi, pi, ui, ti, theta_f)
        f0 = model.force(qi, pi, jnp.zeros_like(ui), ti, theta_f)
        return h, vel @ (f - f0), vel @ f0

    energy, p_in, p_other = jax.vmap(point, in_axes=(1, 1, 0, 0))(q, p, u, jnp.asarray(grid))
    energy, p_in, p_other = (np.asarray(a) for a in (energy, p_in, p_other))
    cum_in, cum_other = (cumulative_trapezoid(a, grid, initial=0.0) for a in (p_in, p_other))
    at = np.searchsorted(grid, np.concatenate([[t0], times]) - 1e-9 * max(1.0, span))
    at = np.clip(at, 0, grid.size - 1)
    dh, w_in, w_other = (np.diff(a[at]) for a in (energy, cum_in, cum_other))
    return {"dH": dh, "work_input": w_in, "work_other": w_other,
            "residual": dh - w_in - w_other}
