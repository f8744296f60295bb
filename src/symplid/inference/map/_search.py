"""One L-BFGS-B run of :func:`~symplid.inference.map.find_map` and its convergence test.

The search space, the floor snap and the convergence rule are described in the docstring
of :mod:`symplid.inference.map`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.optimize

from symplid._stopping import check as check_stop
from symplid.inference.map._laplace import newton_decrement, newton_step
from symplid.inference.map._result import StartResult
from symplid.inference.map._space import SearchSpace


class Objective:
    """−log π in the search space (compiled) and log π of θ through it.

    The last ``REMEMBERED`` values of log π are kept by θ: the starts are checked for a
    finite log π and then searched from, which asks for the same value again."""

    REMEMBERED = 8

    def __init__(self, space: SearchSpace, value_and_grad: Callable) -> None:
        self.space = space
        self.value_and_grad = value_and_grad
        self._known: dict[bytes, float] = {}

    def log_density(self, theta: np.ndarray) -> float:
        key = np.asarray(theta, dtype=float).tobytes()
        if key not in self._known:
            if len(self._known) >= self.REMEMBERED:
                del self._known[next(iter(self._known))]
            # through the compiled search function: no second compilation for plain values
            self._known[key] = -float(self.value_and_grad(jnp.asarray(self.space.to_u(theta)))[0])
        return self._known[key]

    def is_finite(self, theta: np.ndarray) -> bool:
        return bool(np.isfinite(self.log_density(theta)))


def _snap_to_floor(
    theta: np.ndarray,
    log_post: float,
    space: SearchSpace,
    log_density: Callable[[np.ndarray], float],
) -> tuple[np.ndarray, float]:
    """Move a log-searched parameter whose optimum is its bound onto the floor.

    In u = log(θ − a) the gradient vanishes as θ → a, so the search stops short of a bound
    that is the optimum. A parameter is moved to the floor when the log posterior there is
    not lower (within 1e-10 relative); it is then reported on its bound.
    """
    theta = np.array(theta, dtype=float)
    floor_value = space.lower + space.floor
    for i in np.flatnonzero(space.log):
        if theta[i] <= floor_value[i]:
            continue
        trial = theta.copy()
        trial[i] = floor_value[i]
        value = log_density(trial)
        if np.isfinite(value) and value >= log_post - 1e-10 * max(1.0, abs(log_post)):
            theta, log_post = trial, max(value, log_post)
    return theta, log_post


def run_start(theta0: np.ndarray, objective: Objective, options: dict[str, Any]) -> StartResult:
    """L-BFGS-B from θ0; then the floor snap, and a second run from there if it moved."""
    t0 = time.perf_counter()
    space, value_and_grad = objective.space, objective.value_and_grad
    u0 = space.to_u(theta0)
    f0 = -objective.log_density(theta0)  # the same value, checked at the start already
    penalty = 1e10 + 1e3 * abs(f0)
    bounds = space.bounds()

    def fun(u: np.ndarray) -> tuple[float, np.ndarray]:
        check_stop()  # a safe point: a requested stop (symplid._stopping) ends the search here
        value, grad = value_and_grad(jnp.asarray(u))
        value = float(value)
        grad = np.asarray(grad, dtype=float)
        if not (np.isfinite(value) and np.all(np.isfinite(grad))):
            return penalty, np.zeros_like(u)
        return value, grad

    def search(u: np.ndarray) -> Any:
        return scipy.optimize.minimize(
            fun,
            u,
            jac=True,
            method="L-BFGS-B",
            bounds=bounds,
            options={**options, "maxfun": 4 * options["maxiter"]},
        )

    res = search(u0)
    iterations, evaluations = int(res.nit), int(res.nfev)
    theta = np.asarray(space.to_theta(jnp.asarray(res.x)), dtype=float)
    snapped, _ = _snap_to_floor(theta, -float(res.fun), space, objective.log_density)
    if not np.array_equal(snapped, theta):
        again = search(space.to_u(snapped))
        iterations, evaluations = iterations + int(again.nit), evaluations + int(again.nfev)
        if again.fun <= res.fun:
            res = again
    value, grad = value_and_grad(jnp.asarray(res.x))
    value = float(value)
    log_post = -value if np.isfinite(value) else -math.inf
    projected = _projected_gradient(np.asarray(res.x), np.asarray(grad, dtype=float), bounds)
    converged = (
        bool(res.success) and np.isfinite(log_post) and projected <= 1e-3 * max(1.0, abs(log_post))
    )
    message = res.message if isinstance(res.message, str) else str(res.message)
    return StartResult(
        start=np.asarray(theta0, dtype=float),
        theta=np.asarray(space.to_theta(jnp.asarray(res.x)), dtype=float),
        log_posterior=log_post,
        success=converged,
        message=message,
        num_iterations=iterations,
        num_evaluations=evaluations,
        seconds=time.perf_counter() - t0,
        projected_gradient=projected,
    )


def judge_with_hessian(
    result: StartResult, hessian: np.ndarray, objective: Objective
) -> StartResult:
    """Convergence by the Newton decrement ½ gᵀH⁻¹g over the parameters not held by a bound.

    A parameter on a bound is left out only where the bound holds it (:func:`active_bounds`,
    the KKT sign condition); one on a bound whose gradient points inside stays in the
    decrement, so a search that stopped on a bound it should leave has not converged.

    The decrement is the log-posterior gain a Newton step would promise: scale-free, unlike
    the gradient, and robust to the small-scale roughness a filter with almost no process
    noise can show. A start converged when the decrement is < 1e-3 and L-BFGS-B stopped by
    its own test or because its line search could gain nothing more ("ABNORMAL" termination:
    at the optimum the objective's rounding-level roughness is all a line search sees);
    a start stopped by the iteration limit has not converged.
    """
    g, free = _free_gradient(result.theta, objective)
    decrement = math.inf
    if g is not None and np.all(np.isfinite(hessian)):
        decrement = newton_decrement(g, hessian[np.ix_(free, free)])
    message = result.message.upper()
    stopped_itself = "CONVERGENCE" in message or "ABNORMAL" in message
    lbfgs_ok = stopped_itself and np.isfinite(result.log_posterior)
    return dataclasses.replace(
        result, success=bool(lbfgs_ok and decrement < 1e-3), newton_decrement=decrement
    )


def _free_gradient(theta: np.ndarray, objective: Objective) -> tuple[np.ndarray | None,
                                                                     np.ndarray]:
    """(∇ log π in θ over the parameters no bound holds, their mask) at θ; the gradient is
    None where the search's gradient is not finite."""
    space = objective.space
    u = space.to_u(theta)
    grad_u = np.asarray(objective.value_and_grad(jnp.asarray(u))[1], dtype=float)
    free = ~active_bounds(u, grad_u, space)
    if not np.all(np.isfinite(grad_u)):
        return None, free
    scale = space.jacobian_diagonal(space.to_u(theta, floor=False))
    return -(grad_u / scale)[free], free


def newton_point(result: StartResult, hessian: np.ndarray,
                 objective: Objective) -> np.ndarray | None:
    """A point of higher log π than a start that stopped short of a maximum, or None.

    The Newton step Δθ = H⁻¹g (H repaired as for the decrement) over the parameters no bound
    holds, halved until log π rises, each trial projected into the box; a log-searched
    parameter is kept a hair above its floor. This is how a search leaves a spot where its
    own coordinates go flat but θ's do not: in u = log(θ − a) the gradient of a parameter
    near its bound is (θ − a)·∂/∂θ, so L-BFGS-B stops at a dynamics parameter driven to its
    floor (e.g. a quartic coefficient of 1e-14) even though log π still rises along it.
    """
    space = objective.space
    theta = np.asarray(result.theta, dtype=float)
    g, free = _free_gradient(theta, objective)
    if g is None or not (free.any() and np.all(np.isfinite(hessian))):
        return None
    step = np.zeros_like(theta)
    step[free] = newton_step(g, hessian[np.ix_(free, free)])
    lo = np.where(space.log, space.lower + 10.0 * space.floor, space.lower)
    hi = space.upper
    for alpha in 0.5 ** np.arange(12):
        trial = np.clip(theta + alpha * step, lo, hi)
        value = objective.log_density(trial)
        if np.isfinite(value) and value > result.log_posterior + 1e-6:
            return trial
    return None


def escaped(
    result: StartResult,
    hessian: np.ndarray,
    objective: Objective,
    options: dict[str, Any],
    hessian_at: Callable[[np.ndarray], np.ndarray],
    rounds: int = 3,
) -> tuple[StartResult, np.ndarray]:
    """``result`` (judged by :func:`judge_with_hessian`) continued from a Newton point
    (:func:`newton_point`) while its decrement says it is no maximum: up to ``rounds`` new
    L-BFGS-B runs, each kept only where it ends higher; iterations and time accumulate."""
    for _ in range(rounds):
        if result.success or not np.isfinite(result.log_posterior):
            break
        trial = newton_point(result, hessian, objective)
        if trial is None:
            break
        again = run_start(trial, objective, options)
        if not again.log_posterior > result.log_posterior:
            break
        hessian = hessian_at(again.theta)
        again = judge_with_hessian(again, hessian, objective)
        result = dataclasses.replace(
            again, start=result.start,
            num_iterations=result.num_iterations + again.num_iterations,
            num_evaluations=result.num_evaluations + again.num_evaluations,
            seconds=result.seconds + again.seconds)
    return result, hessian


def active_bounds(u: np.ndarray, grad: np.ndarray, space: SearchSpace) -> np.ndarray:
    """Which entries of u a bound holds: on a bound (:meth:`SearchSpace.at_bounds`) with the
    gradient of −log π pointing out of the box or zero there (the KKT condition of a
    constrained minimum: the multiplier of an active bound has the sign of the gradient)."""
    hits = space.at_bounds(u)
    bounds = space.bounds()
    out = np.zeros_like(hits)
    for i in np.flatnonzero(hits):
        lower_side = space.on_lower_side(u, i)
        upper = bounds[i][1]
        on_upper = upper is not None and abs(u[i] - upper) <= 1e-8 * max(1.0, abs(upper))
        # lower bound: holds when −log π grows inward (g ≥ 0); upper: when g ≤ 0
        out[i] = bool((lower_side and grad[i] >= 0) or (on_upper and grad[i] <= 0)
                      or not np.isfinite(grad[i]))
    return out


def _projected_gradient(
    u: np.ndarray, grad: np.ndarray, bounds: Sequence[tuple[float | None, float | None]]
) -> float:
    """Largest component of the gradient of −log π that a move inside the bounds can use."""
    if not np.all(np.isfinite(grad)):
        return math.inf
    g = grad.copy()
    for i, (lo, hi) in enumerate(bounds):
        if lo is not None and u[i] <= lo and g[i] > 0:
            g[i] = 0.0
        if hi is not None and u[i] >= hi and g[i] < 0:
            g[i] = 0.0
    return float(np.max(np.abs(g))) if g.size else 0.0


__all__ = [
    "Objective", "active_bounds", "escaped", "judge_with_hessian", "newton_point", "run_start",
]
