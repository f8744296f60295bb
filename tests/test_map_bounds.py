"""The MAP search on a bounded positive range (a log-uniform variance) and its KKT test.

Every expected value here is analytic: a regression whose noise variance is v0 + K·s with a
log-uniform prior on s (maximum on the lower bound of s, the coefficients then a ridge
solution in closed form), and a variance with an interior maximum S/(n + 2).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from symplid.inference.map import find_map
from symplid.inference.map._result import StartResult
from symplid.inference.map._search import Objective, active_bounds, judge_with_hessian
from symplid.inference.map._space import SearchSpace
from symplid.model._params import ParameterSpace


class InflatedRegression:
    """y_i = a + b·t_i + e_i with var(e) = v0 + K·s; a, b ~ N(0, 10²); s ~ LogUniform(lo, hi).

    The data carry noise of variance v0/2, less than v0, so the likelihood falls with s and
    the log-uniform prior (density 1/s) does too: the maximum is s = lo, on its bound, with
    the gradient pointing out of the box. Below s ≈ v0/K the likelihood is flat in s, as the
    filter's is below the process noise the data resolve. (a, b) is then the ridge solution
    at the variance v0 + K·lo.
    """

    num_params = 3
    param_names = ("a", "b", "s")

    def __init__(self, lo: float = 1e-10, hi: float = 1e-2, v0: float = 1e-2, k: float = 1e3):
        rng = np.random.default_rng(3)
        self.t = np.linspace(-1.0, 1.0, 40)
        self.y = 0.7 - 1.3 * self.t + math.sqrt(0.5 * v0) * rng.normal(size=self.t.size)
        self.lo, self.hi, self.v0, self.k = lo, hi, v0, k
        self.lower = np.array([-np.inf, -np.inf, lo])
        self.upper = np.array([np.inf, np.inf, hi])
        t, y, width = jnp.asarray(self.t), jnp.asarray(self.y), math.log(hi / lo)

        def log_density(theta):
            a, b, s = theta
            var = v0 + k * s
            r = y - a - b * t
            value = (-0.5 * jnp.sum(r * r) / var - 0.5 * t.size * jnp.log(var)
                     - 0.5 * (a * a + b * b) / 100.0 - jnp.log(s) - math.log(width))
            return jnp.where((s >= lo) & (s <= hi), value, -jnp.inf)

        self.log_density = jax.jit(log_density)

    @property
    def mode(self) -> np.ndarray:
        var = self.v0 + self.k * self.lo
        X = np.column_stack([np.ones_like(self.t), self.t])
        ab = np.linalg.solve(X.T @ X / var + np.eye(2) / 100.0, X.T @ self.y / var)
        return np.array([*ab, self.lo])


class InteriorVariance:
    """n draws x_i ~ N(0, s), s ~ LogUniform(lo, hi): log π = −(n/2 + 1) log s − S/(2s), whose
    maximum is s* = S/(n + 2) inside the range."""

    num_params = 1
    param_names = ("s",)

    def __init__(self, lo: float = 1e-8, hi: float = 1.0):
        x = np.random.default_rng(5).normal(scale=0.01, size=25)
        self.sum_sq, self.n = float(np.sum(x * x)), x.size
        self.lower, self.upper = np.array([lo]), np.array([hi])
        n, sum_sq = self.n, self.sum_sq

        def log_density(theta):
            s = theta[0]
            value = -(0.5 * n + 1.0) * jnp.log(s) - 0.5 * sum_sq / s
            return jnp.where((s >= lo) & (s <= hi), value, -jnp.inf)

        self.log_density = jax.jit(log_density)

    @property
    def mode(self) -> float:
        return self.sum_sq / (self.n + 2)


class NonlinearInflated:
    """Nine coefficients of a nonlinear regression, y = tanh(Xc/3) + e, whose noise variance
    v0 + K·s·(1 + |c|²) grows with the process-like variance s ~ LogUniform(6.6e-10, 6.6e-2)
    (the paper-claims range for data of variance 0.066): the data have noise v0, so the
    maximum is s on its lower bound, and c there is the maximum of a smooth unconstrained
    problem, solved independently by a trust-region Newton method. Searched as itself, s made
    L-BFGS-B stop on "relative reduction" with c still moving for most seeds."""

    lo, hi, d = 6.6e-10, 6.6e-2, 9

    def __init__(self, seed: int, k: float = 1e4, v0: float = 2.5e-3, n: int = 40):
        rng = np.random.default_rng(seed)
        t = np.linspace(0.0, 4.0, n)
        X = np.stack([np.sin((j + 1) * t) * (1 + 0.3 * j) for j in range(self.d)], axis=1)
        y = np.tanh(X @ rng.normal(size=self.d) / 3) + math.sqrt(v0) * rng.normal(size=n)
        self.num_params = self.d + 1
        self.param_names = (*(f"c{j}" for j in range(self.d)), "s")
        self.lower = np.array([-np.inf] * self.d + [self.lo])
        self.upper = np.array([np.inf] * self.d + [self.hi])
        Xj, yj, lo, hi, d = jnp.asarray(X), jnp.asarray(y), self.lo, self.hi, self.d

        def log_density(theta):
            c, s = theta[:d], theta[d]
            var = v0 + k * s * (1 + jnp.sum(c * c))
            r = yj - jnp.tanh(Xj @ c / 3)
            value = (-0.5 * jnp.sum(r * r / var) - 0.5 * n * jnp.log(var)
                     - 0.5 * jnp.sum(c * c) - jnp.log(s) - math.log(hi / lo))
            return jnp.where((s >= lo) & (s <= hi), value, -jnp.inf)

        self.log_density = jax.jit(log_density)

    def conditional_mode(self) -> np.ndarray:
        """argmax over c of log π(c, s = lo), by trust-region Newton from c = 0."""
        def f(c):
            return -self.log_density(jnp.concatenate([c, jnp.array([self.lo])]))

        res = scipy.optimize.minimize(jax.jit(f), np.zeros(self.d), jac=jax.jit(jax.grad(f)),
                                      hess=jax.jit(jax.hessian(f)), method="trust-exact",
                                      options={"gtol": 1e-9})
        return np.asarray(res.x)


def _objective(posterior) -> tuple[Objective, ParameterSpace]:
    space = SearchSpace.of(ParameterSpace.of(posterior), 1e-14)
    vg = jax.jit(jax.value_and_grad(lambda u: -posterior.log_density(space.to_theta(u))))
    return Objective(space, vg), space


def _start_result(posterior, theta) -> StartResult:
    theta = np.asarray(theta, dtype=float)
    return StartResult(start=theta, theta=theta,
                       log_posterior=float(posterior.log_density(jnp.asarray(theta))),
                       success=True, message="CONVERGENCE: REL_REDUCTION_OF_F", num_iterations=1,
                       num_evaluations=1, seconds=0.0)


def _hessian(posterior, theta) -> np.ndarray:
    return np.asarray(jax.hessian(lambda x: -posterior.log_density(x))(jnp.asarray(theta)))


def test_positive_range_is_searched_on_log_theta():
    space = SearchSpace.of(ParameterSpace.of(InflatedRegression()), 1e-14)
    np.testing.assert_array_equal(space.log_box, [False, False, True])
    lo, hi = space.bounds()[2]
    assert math.exp(lo) >= 1e-10 and math.exp(hi) <= 1e-2
    assert lo == pytest.approx(math.log(1e-10), abs=1e-11)
    # the bound tolerance is relative on log θ: 5e-9 is fifty times its bound, not on it
    assert not space.at_bounds(space.to_u(np.array([0.0, 0.0, 5e-9])))[2]
    assert space.at_bounds(space.to_u(np.array([0.0, 0.0, 1e-10])))[2]
    theta = np.array([0.3, -2.0, 3e-6])
    np.testing.assert_allclose(np.asarray(space.to_theta(jnp.asarray(space.to_u(theta)))),
                               theta, rtol=1e-14)


def test_maximum_on_the_bottom_of_a_log_uniform_range_is_found_and_converged():
    post = InflatedRegression()
    r = find_map(post, num_starts=3, init=[0.0, 0.0, 1e-3], evidence="laplace", warn=False)
    assert r.success, r.failure
    assert r.at_bounds == ("s",)
    np.testing.assert_allclose(r.theta[:2], post.mode[:2], rtol=1e-6)
    assert r.theta[2] == pytest.approx(post.lo, rel=1e-9)
    assert all(s.success for s in r.starts)


@pytest.mark.parametrize("seed", [2, 4])
def test_nonlinear_fit_with_a_log_uniform_variance_on_its_bound(seed):
    post = NonlinearInflated(seed)
    r = find_map(post, seed=seed, num_starts=2, init=np.r_[np.zeros(post.d), 1e-3],
                 evidence="laplace", warn=False)
    assert r.success, r.failure
    assert r.at_bounds == ("s",)
    assert r.theta[-1] == pytest.approx(post.lo, rel=1e-9)
    np.testing.assert_allclose(r.theta[:-1], post.conditional_mode(), atol=1e-6)
    # KKT at the bound: −log π grows into the box along s
    grad = jax.grad(lambda x: -post.log_density(x))(jnp.asarray(r.theta))
    assert float(grad[-1]) > 0


def test_interior_maximum_of_a_log_uniform_variance():
    post = InteriorVariance()
    r = find_map(post, num_starts=2, init=[0.5], evidence="laplace", warn=False)
    assert r.success, r.failure
    assert r.at_bounds == ()
    assert r.theta[0] == pytest.approx(post.mode, rel=1e-6)


def test_a_bound_whose_gradient_points_inward_is_not_converged():
    # s held at its lower bound 1e-8 while the maximum is at s* ≈ 4e-5: the gradient of −log π
    # on log s points into the box, so the bound does not hold s and the start has not converged
    post = InteriorVariance()
    objective, space = _objective(post)
    at_bound = np.array([1e-8])
    u = space.to_u(at_bound)
    grad = np.asarray(objective.value_and_grad(jnp.asarray(u))[1])
    assert space.at_bounds(u)[0] and grad[0] < 0
    assert not active_bounds(u, grad, space)[0]
    judged = judge_with_hessian(_start_result(post, at_bound), _hessian(post, at_bound), objective)
    assert not judged.success and judged.newton_decrement > 1.0
    # at the maximum it has
    best = np.array([post.mode])
    judged = judge_with_hessian(_start_result(post, best), _hessian(post, best), objective)
    assert judged.success and judged.newton_decrement < 1e-12


def test_a_bound_that_holds_its_parameter_is_converged():
    # the maximum of InflatedRegression is on s's bound with the gradient pointing outward:
    # the bound is active (KKT), s leaves the decrement, and the start has converged
    post = InflatedRegression()
    objective, space = _objective(post)
    mode = post.mode
    u = space.to_u(mode)
    grad = np.asarray(objective.value_and_grad(jnp.asarray(u))[1])
    assert grad[2] > 0
    np.testing.assert_array_equal(active_bounds(u, grad, space), [False, False, True])
    judged = judge_with_hessian(_start_result(post, mode), _hessian(post, mode), objective)
    assert judged.success and judged.newton_decrement < 1e-10
    # moved off the optimum in a, it has not
    off = mode + np.array([0.05, 0.0, 0.0])
    judged = judge_with_hessian(_start_result(post, off), _hessian(post, off), objective)
    assert not judged.success


def test_the_objective_remembers_its_last_values_and_run_start_reads_them():
    """log π at a θ asked again is the value computed before (against the posterior's own
    log density), with one evaluation; the oldest of more than ``REMEMBERED`` is forgotten;
    a search started at a checked θ evaluates it once (for its gradient), not twice."""
    from symplid.inference.map._search import run_start

    posterior = InflatedRegression()
    space = SearchSpace.of(ParameterSpace.of(posterior), 1e-14)
    calls = []
    inner = jax.jit(jax.value_and_grad(lambda u: -posterior.log_density(space.to_theta(u))))
    objective = Objective(space, lambda u: calls.append(np.asarray(u)) or inner(u))
    thetas = [np.array([0.1 * k, -0.2, 1e-4]) for k in range(Objective.REMEMBERED + 1)]
    for theta in thetas[:2]:
        value = objective.log_density(theta)
        assert value == pytest.approx(float(posterior.log_density(jnp.asarray(theta))),
                                      rel=1e-12)
        assert objective.log_density(theta.copy()) == value
    assert len(calls) == 2
    for theta in thetas:
        objective.log_density(theta)
    assert len(calls) == Objective.REMEMBERED + 1  # all but the two already known
    objective.log_density(thetas[0])  # the oldest, forgotten
    assert len(calls) == Objective.REMEMBERED + 2
    before = len(calls)
    result = run_start(thetas[-1], objective, {"maxiter": 50})  # known: not the evicted
    assert np.isfinite(result.log_posterior)
    at_start = [u for u in calls[before:] if np.array_equal(u, space.to_u(thetas[-1]))]
    assert len(at_start) == 1  # L-BFGS-B's own first evaluation, not a second one before it
