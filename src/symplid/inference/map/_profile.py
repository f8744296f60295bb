"""The inner fit of the quadrature evidence: max over c of log π with the variances held.

Step 2 of :mod:`symplid.inference.map._evidence`. For fixed log-variances s, the other entries
c of θ are maximised in the MAP search's coordinates u (:class:`~._space.SearchSpace`: θ itself,
or u = log(θ − a) bounded below by the log floor, or u = log θ within a box) with the MAP
search's compiled objective and Hessian, warm-started from a neighbouring node.

Newton's method in u
--------------------
The Hessian of −log π in u is

    ∇²_u(−log π) = D H_θ D + diag(∂(−log π)/∂u on the logarithmic coordinates),   D = ∂θ/∂u,

(:func:`u_hessian`; on u = log(θ − a) and u = log θ, ∂²θ/∂u² = ∂θ/∂u, whence the diagonal
term). Newton's steps start from it with the θ-Hessian of the neighbouring node (the Gaussian
integral of step 2 needs one θ-Hessian per node anyway, so the steps should need no other),
and the u-Hessian is carried from step to step by the BFGS update (Nocedal & Wright,
*Numerical Optimization*, eq. 6.19), which keeps the convergence superlinear where the
neighbour's curvature is off (on the Kepler example, far out in the process variance, the
plain chord crawled at a factor 2 a step and ran out of its 30 steps). A new θ-Hessian is
computed when a step is cut, when a step promises no less than the last one (its Newton
decrement), and at the end, where the answer is checked with it and it is the Hessian
returned.
Its answer is kept only when it is an interior maximum: every step stays
strictly inside L-BFGS-B's bounds on u (the log floor, a box), the end is on none of them, and
the Newton decrement in θ (gradient ∂(−log π)/∂θ = D⁻¹ ∂(−log π)/∂u) is small as well; the last
test rejects a coefficient sliding down to θ = a on its log scale, where the gradient in u
vanishes with eᵘ while the one in θ does not. Otherwise (a step leaving the bounds, a
non-finite value, no convergence in ``max_newton`` steps, or a neighbour whose maximum sat on a
bound) L-BFGS-B runs from the same start, and the entries on a bound get the 1-D scan of
step 2.

On the examples' user models (``examples/user_models/``, half-normal coefficients, so searched
on the log scale) and a Duffing oscillator, an inner fit took 2.6–8.0 value-and-gradient calls
where L-BFGS-B's took 12–38, with the same g at every node to 4e-6 and the same evidence to
5e-8 nats (``benchmarks/evidence_newton.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.optimize

from symplid._stopping import check as check_stop
from symplid.inference.map._laplace import laplace_covariance, repaired_eigenvalues, scan_from_bound
from symplid.inference.map._space import SearchSpace

Warm = tuple[np.ndarray, np.ndarray | None]
"""A warm start: u at a neighbouring node's inner maximum and the θ-Hessian there (or None)."""

#: Tests and benchmarks only: True makes every inner fit L-BFGS-B's (the reference path).
_LBFGSB_ONLY = False

#: The largest Newton decrement in θ (nats) at which Newton's end counts as θ's maximum.
THETA_DECREMENT = 1e-8


def u_hessian(space: SearchSpace, h_theta: np.ndarray, u: np.ndarray,
              grad_u: np.ndarray) -> np.ndarray:
    """∇²_u(−log π) = D H_θ D + diag(∂(−log π)/∂u on the logarithmic coordinates), D = ∂θ/∂u,
    from the θ-Hessian ``h_theta`` and the u-gradient ``grad_u`` at ``u``."""
    scale = space.jacobian_diagonal(u)
    diagonal = np.where(space.logarithmic, grad_u, 0.0)
    return scale[:, None] * h_theta * scale[None, :] + np.diag(diagonal)


def _solve(matrix: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """H⁻¹g with H's eigenvalues repaired (their moduli, floored)."""
    _, vecs, fixed, _ = repaired_eigenvalues(matrix)
    return vecs @ ((vecs.T @ grad) / fixed)


def _bfgs(b: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The BFGS update of the Hessian ``b`` by the step ``s`` and the change ``y`` of the
    gradient (skipped when yᵀs is not positive)."""
    ys = float(y @ s)
    bs = b @ s
    sbs = float(s @ bs)
    if ys <= 1e-300 or sbs <= 1e-300:
        return b
    return b - np.outer(bs, bs) / sbs + np.outer(y, y) / ys


class Profile:
    """The inner fits of step 2 with the compiled search objective and θ-Hessian."""

    def __init__(self, value_and_grad: Callable, hessian: Callable, space: SearchSpace,
                 var: np.ndarray, options: dict, max_newton: int) -> None:
        self.hessian, self.space, self.var = hessian, space, var
        self.evaluations = 0  # value-and-gradient calls, and those of the inner fits
        self.fit_evaluations = 0

        def vg(u: Any) -> Any:
            self.evaluations += 1
            return value_and_grad(u)

        self.vg = vg
        self.free = np.setdiff1d(np.arange(space.lower.size), var)
        self.bounds = [space.bounds()[i] for i in self.free]
        self.low = np.array([-math.inf if b[0] is None else b[0] for b in self.bounds])
        self.high = np.array([math.inf if b[1] is None else b[1] for b in self.bounds])
        self.options, self.max_newton = options, max_newton
        self.num_fits = 0
        self.calls = {"newton": 0, "lbfgsb": 0}  # inner fits ended by each method

    def u_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """θ ↦ u of the search space without its floor (s may lie below it)."""
        return self.space.to_u(theta, floor=False)

    def log_density(self, theta: np.ndarray) -> float:
        value = float(self.vg(jnp.asarray(self.u_of_theta(theta)))[0])
        return -value if np.isfinite(value) else -math.inf

    def theta_hessian(self, u: np.ndarray) -> np.ndarray:
        return np.asarray(self.hessian(self.space.to_theta(jnp.asarray(u))), dtype=float)

    def fit(self, s: np.ndarray, warm: Warm) -> tuple[float, np.ndarray, np.ndarray | None]:
        """(max over c of log π, u at the maximum, ∇²_θ(−log π) there or None) with the
        variances at v(s): Newton's method in u, else L-BFGS-B."""
        before = self.evaluations
        try:
            return self._fit(s, warm)
        finally:
            self.fit_evaluations += self.evaluations - before

    def _fit(self, s: np.ndarray, warm: Warm) -> tuple[float, np.ndarray, np.ndarray | None]:
        u = np.array(warm[0], dtype=float)
        u[self.var] = s
        self.num_fits += 1
        if self.free.size == 0:
            return self.log_density(np.asarray(self.space.to_theta(jnp.asarray(u)))), u, None
        # the joint mode's Hessian, passed for the centre node, is this point's own
        fresh = warm[1] is not None and np.array_equal(u, warm[0])
        found = None
        if not _LBFGSB_ONLY and not np.any(self.space.at_bounds(warm[0])[self.free]):
            found = self._newton(u, warm[1], fresh)
        if found is not None:
            self.calls["newton"] += 1
            return found
        self.calls["lbfgsb"] += 1
        return (*self._lbfgs(u), None)

    def _inside(self, u: np.ndarray) -> bool:
        """Whether the free entries of u lie strictly inside L-BFGS-B's bounds and on none."""
        x = u[self.free]
        return bool(np.all((x > self.low) & (x < self.high))
                    and not np.any(self.space.at_bounds(u)[self.free]))

    def _theta_converged(self, u: np.ndarray, grad: np.ndarray, full: np.ndarray) -> bool:
        """Whether the Newton decrement in θ, ½ g_θᵀ H_θ⁻¹ g_θ, is below ``THETA_DECREMENT``."""
        scale = self.space.jacobian_diagonal(u)[self.free]
        if not np.all(scale > 0):
            return False
        g_theta = grad[self.free] / scale
        block = full[np.ix_(self.free, self.free)]
        return 0.5 * float(g_theta @ _solve(block, g_theta)) < THETA_DECREMENT

    def _newton(self, u: np.ndarray, start_hessian: np.ndarray | None, fresh: bool = False
                ) -> tuple[float, np.ndarray, np.ndarray] | None:
        """Newton's method in u with the (repaired) u-Hessian, carried by BFGS updates between
        new θ-Hessians, and a backtracking line search (module docstring). None when it fails
        or ends outside the interior (then L-BFGS-B runs)."""
        free, u = self.free, u.copy()
        value, grad = (np.asarray(x, dtype=float) for x in self.vg(jnp.asarray(u)))
        full, chord, last = start_hessian, None, math.inf
        for _ in range(self.max_newton):
            if full is None:
                full, fresh, chord = self.theta_hessian(u), True, None
            g = grad[free]
            if not (np.isfinite(value) and np.all(np.isfinite(g)) and np.all(np.isfinite(full))):
                return None
            if chord is None:
                chord = u_hessian(self.space, full, u, grad)[np.ix_(free, free)]
            step = -_solve(chord, g)
            slope = float(g @ step)
            if -0.5 * slope < 1e-11:
                if not fresh:
                    full = None  # converged with the neighbour's Hessian: check with this one's
                    continue
                if self._inside(u) and self._theta_converged(u, grad, full):
                    return -float(value), u, full
                return None
            found = self._line_search(u, value, step, slope)
            if found is None:
                return None
            moved, (u, value, grad, t) = found[0][free] - u[free], found
            if t < 1.0 or (not fresh and -0.5 * slope >= last):
                full = None  # a cut step, or BFGS's curvature no help: a new θ-Hessian
            else:
                chord = _bfgs(chord, moved, grad[free] - g)
            fresh, last = False, -0.5 * slope
        return None

    def _line_search(self, u: np.ndarray, value: float, step: np.ndarray, slope: float
                     ) -> tuple[np.ndarray, float, np.ndarray, float] | None:
        """(u, value, gradient, t) after the backtracking (Armijo) line search along
        ``step``; None when a trial point leaves the bounds or no decrease is found."""
        t = 1.0
        while t > 1e-6:
            trial = u.copy()
            trial[self.free] += t * step
            x = trial[self.free]
            if not np.all((x > self.low) & (x < self.high)):
                return None
            v, gr = (np.asarray(y, dtype=float) for y in self.vg(jnp.asarray(trial)))
            if np.isfinite(v) and v <= value + 1e-4 * t * slope:
                return trial, float(v), gr, t
            t *= 0.5
        return None

    def _lbfgs(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        penalty = 1e10 + 1e3 * abs(float(self.vg(jnp.asarray(u))[0]))

        def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
            check_stop()  # a safe point (symplid._stopping)
            u[self.free] = x
            value, grad = self.vg(jnp.asarray(u))
            value, grad = float(value), np.asarray(grad, dtype=float)[self.free]
            if not (np.isfinite(value) and np.all(np.isfinite(grad))):
                return penalty, np.zeros_like(x)
            return value, grad

        res = scipy.optimize.minimize(fun, u[self.free], jac=True, method="L-BFGS-B",
                                      bounds=self.bounds, options=self.options)
        u[self.free] = res.x
        value = float(self.vg(jnp.asarray(u))[0])
        return (-value if np.isfinite(value) else -math.inf), u

    def value(self, s: np.ndarray, warm: Warm) -> tuple[float, Warm]:
        """(g(s), (u, θ-Hessian) at the inner maximum, the warm start of the next node):
        the Gaussian integral over c from the θ-Hessian block, with the 1-D scan for any
        entry of c on a bound (step 2)."""
        log_post, u, full = self.fit(s, warm)
        if not np.isfinite(log_post):
            return -math.inf, (u, None)
        theta = np.asarray(self.space.to_theta(jnp.asarray(u)), dtype=float)
        if self.free.size == 0:
            return log_post + float(np.sum(s)), (u, None)
        if full is None:
            full = self.theta_hessian(u)
        block = full[np.ix_(self.free, self.free)]
        on_bound = np.flatnonzero(self.space.at_bounds(u)[self.free])
        scans = [scan_from_bound(self.log_density, theta, int(self.free[j]), self.space, u,
                                 log_post) for j in on_bound]
        _, _, log_mass = laplace_covariance(block, log_post, list(on_bound), scans)
        return (log_mass + float(np.sum(s)) if np.isfinite(log_mass) else -math.inf), (u, full)


__all__ = ["Profile", "Warm", "u_hessian"]
