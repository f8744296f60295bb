"""The posterior band from the start carries the posterior of the initial state.

Reference: the true path, over 50 replications of two systems (a harmonic oscillator and a
pendulum, positions only, initial state learned). Each replication's posterior is the
Laplace approximation at its exact MAP, computed here by JAX from the posterior's own log
density (one compiled program for all replications: the data enter as an argument), so the
test exercises the band (:func:`symplid.workflow._run_figures.trajectory_paths`) and not the
MAP search. The 95 % band must cover the true path at least 90 % of the time over the data
window (measured: 92–93 %); a band whose paths all start at one point, the draws' mean
initial state (zero width at t0), covers 69–70 % and fails.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

import symplid
from symplid.dynamics._potentials import FunctionPotential
from symplid.inference._predict import predict_trajectory
from symplid.model._data import Observations
from symplid.model._simulate import true_trajectory
from symplid.workflow._run_figures import trajectory_paths

REPLICATIONS = 50
DRAWS = 200
NOISE = 0.05
DT = 0.1

pytestmark = pytest.mark.slow


def _harmonic() -> tuple[FunctionPotential, np.ndarray, np.ndarray]:
    pot = FunctionPotential(lambda q, c: 0.5 * c[0] * q[0] ** 2, dim=1, num_params=1,
                            names=("k",))
    return pot, np.array([1.3]), np.array([0.8, 0.2])


def _pendulum() -> tuple[FunctionPotential, np.ndarray, np.ndarray]:
    pot = FunctionPotential(lambda q, c: -c[0] * jnp.cos(q[0]), dim=1, num_params=1,
                            names=("k",))
    return pot, np.array([2.0]), np.array([1.0, 0.0])


def _posterior(pot, truth_x0, y, times):
    """Positions only, no process noise, x0 learned with a wide prior around a fixed centre
    (not the data: every replication has the same prior)."""
    model = symplid.HamiltonianModel(pot, dt=DT, observation="positions",
                                     process_noise_per="none")
    return symplid.Posterior(model, Observations(times, y), x0=np.zeros(2),
                             learn_initial_state=True, initial_state_prior=3.0)


class _Laplace:
    """The exact MAP and Laplace covariance of any replication's data, compiled once."""

    def __init__(self, posterior) -> None:
        self.posterior = posterior
        self.obs = [i for i, g in enumerate(posterior.param_groups) if g == "obs_var"]

        def negative(u, data):  # the observation variance searched on its log scale
            theta = u.at[jnp.asarray(self.obs)].set(jnp.exp(u[jnp.asarray(self.obs)]))
            return -posterior.log_density_with(data, theta)

        self.value_and_grad = jax.jit(jax.value_and_grad(negative))
        self.hessian = jax.jit(jax.hessian(lambda t, d: -posterior.log_density_with(d, t)))

    def draws(self, data, start: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        u0 = start.copy()
        u0[self.obs] = np.log(u0[self.obs])

        def fun(u):
            value, grad = self.value_and_grad(jnp.asarray(u), data)
            return float(value), np.asarray(grad, dtype=float)

        found = scipy.optimize.minimize(fun, u0, jac=True, method="BFGS",
                                        options={"gtol": 1e-9, "maxiter": 500})
        theta = found.x.copy()
        theta[self.obs] = np.exp(theta[self.obs])
        cov = np.linalg.inv(np.asarray(self.hessian(jnp.asarray(theta), data)))
        return theta, rng.multivariate_normal(theta, 0.5 * (cov + cov.T), size=DRAWS)


def _coverage(system) -> float:
    pot, coefficients, x0 = system()
    times = np.linspace(0.25, 10.0, 40)
    true_states = true_trajectory(pot, coefficients, x0, times, dt=DT)
    base = _posterior(pot, x0, true_states[:, :1], times)
    laplace = _Laplace(base)
    settings = SimpleNamespace(prediction=SimpleNamespace(integrator="leapfrog"), seed=0)
    model = base.model
    truth_times, truth = predict_trajectory(model, coefficients, x0, times[-1], dt=DT)
    start = np.concatenate([coefficients, [NOISE**2], x0])
    rng = np.random.default_rng(7)
    inside = []
    for _ in range(REPLICATIONS):
        y = true_states[:, :1] + NOISE * rng.standard_normal((times.size, 1))
        data = _posterior(pot, x0, y, times).data
        theta_map, flat = laplace.draws(data, start, rng)
        _, _, band = trajectory_paths(settings, model, base, theta_map, flat, 0, 0.0,
                                      float(times[-1]), DT, num_paths=10)
        assert np.allclose(band.times, truth_times)
        q = truth[:, 0]
        inside.append((band.lower[:, 0] <= q) & (q <= band.upper[:, 0]))
    return float(np.mean(inside))


def test_band_coverage_fails_with_one_start():
    """The test can fail: the same replications with every path started at the draws'
    mean initial state (the band pinched at t0) do not reach 90 %."""
    global trajectory_paths
    real = trajectory_paths

    def pinched(settings, model, posterior, theta_map, flat, *args, **kwargs):
        flat, x0 = np.array(flat), posterior.initial_state_slice(0)
        flat[:, x0] = flat[:, x0].mean(axis=0)
        return real(settings, model, posterior, theta_map, flat, *args, **kwargs)

    trajectory_paths = pinched
    try:
        assert _coverage(_harmonic) < 0.9
    finally:
        trajectory_paths = real


@pytest.mark.parametrize("system", [_harmonic, _pendulum], ids=["harmonic", "pendulum"])
def test_band_from_the_start_covers_the_true_path(system):
    coverage = _coverage(system)
    assert math.isfinite(coverage)
    assert coverage >= 0.90, f"the 95 % band covered the true path {coverage:.1%} of the time"
