"""Conditional modes for the shift study: the maximum of a log posterior over part of θ.

The decomposition of :mod:`._shift` needs many point fits of one posterior structure on many
data sets: the deterministic likelihood's MAP on hundreds of noise draws, the filter's MAP with
the process variance Σ held at a given value, the noise-free least-squares fit. This module
gives one tool for all of them, :class:`ConditionalMode`:

* the parameters named in ``fixed`` keep the values of the start (Σ at 1.4e-5, say); the mode is
  taken over the others: argmax over θ_free of log π(θ_free, θ_fixed | Y). Holding Σ fixed is
  the simplest honest way to ask "what would the coefficients be at this Σ" — the prior of Σ
  is then a constant and drops out, and nothing else of the posterior changes;
* ``prior=False`` maximises the log-likelihood alone (the least-squares fit on noise-free data,
  where the coefficients' Laplace prior would pin a zero coefficient at its kink);
* the search is Newton's method with the exact Hessian (JAX) and a backtracking line search, in
  the MAP search's coordinates (variances as log v), compiled once per posterior structure
  with the data as an argument, so that other data sets of the same shape reuse the program;
  :meth:`ConditionalMode.fit_many` maps it over a batch of data sets (``jax.vmap``). A
  Hessian that is not positive definite is replaced by its eigenvalues' absolute values (the
  step stays a descent direction). A fit has converged when the Newton decrement gᵀH⁻¹g is
  below ``tol`` (default 1e-9: the log density is within about 1e-9 of its maximum, and θ
  within about 3e-5 of its standard deviation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.inference.map import LowOptimisationJit

__all__ = ["ConditionalMode", "ModeFit", "stack_data"]

#: Groups searched on a log scale (bounded below by 0).
_LOG_GROUPS = ("process_var", "obs_var", "obs_rel_var", "damping")


@dataclass(frozen=True)
class ModeFit:
    """One conditional mode: θ (the fixed entries as given), the log density there, the last
    Newton decrement and whether it is below the tolerance."""

    theta: np.ndarray
    log_density: float
    decrement: float
    converged: bool


def stack_data(posteriors: Sequence[Any]) -> Any:
    """The data of posteriors of one structure stacked along a new first axis (for
    :meth:`ConditionalMode.fit_many`)."""
    return jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[p.data for p in posteriors])


class ConditionalMode:
    """The mode of ``posterior``'s log density over θ without the entries held fixed.

    Which entries are fixed and whether the prior counts are arguments of each fit, not of
    the compiled program: one program per posterior structure serves the noise-free
    least-squares fit, the MAPs and the fixed-Σ fits alike.

    Parameters
    ----------
    posterior
        A :class:`~symplid.model._posterior.Posterior` (anything with ``log_density_with``,
        ``data``, ``param_names``, ``param_groups`` and ``space.log_prior``).
    max_iter, tol
        Newton iterations at most, and the decrement below which a fit has converged.
    """

    def __init__(self, posterior: Any, max_iter: int = 60, tol: float = 1e-9) -> None:
        self.posterior = posterior
        self.names = list(posterior.param_names)
        self.log = np.array([g in _LOG_GROUPS for g in posterior.param_groups])
        self.max_iter, self.tol = int(max_iter), float(tol)
        self._one = LowOptimisationJit(self._solve)
        self._many = LowOptimisationJit(jax.vmap(self._solve))

    # ------------------------------------------------------------------ objective
    def _theta(self, u: jax.Array, base: jax.Array, free: jax.Array) -> jax.Array:
        return jnp.where(free, jnp.where(self.log, jnp.exp(u), u), base)

    def _objective(self, u: jax.Array, args: tuple) -> jax.Array:
        base, free, prior, data = args
        theta = self._theta(u, base, free)
        value = self.posterior.log_density_with(data, theta)
        value = value - (1.0 - prior) * self.posterior.space.log_prior(theta)
        return jnp.where(jnp.isfinite(value), -value, jnp.inf)

    # ------------------------------------------------------------------ Newton
    def _solve(self, u0: jax.Array, base: jax.Array, free: jax.Array, prior: jax.Array,
               data: Any) -> tuple[jax.Array, ...]:
        f, args = self._objective, (base, free, prior, data)
        grad, hess = jax.grad(f), jax.hessian(f)

        def direction(u):
            # the fixed entries: zero gradient, unit curvature, so a zero step
            g = jnp.where(free, grad(u, args), 0.0)
            h = jnp.where(free[:, None] & free[None, :], hess(u, args), jnp.diag(1.0 - free))
            w, v = jnp.linalg.eigh(0.5 * (h + h.T))
            w = jnp.maximum(jnp.abs(w), 1e-12 * jnp.max(jnp.abs(w)) + 1e-300)
            d = -v @ ((v.T @ g) / w)
            return d, jnp.where(jnp.all(jnp.isfinite(d)), -g @ d, jnp.inf)

        def line_search(u, value, d, decrement):
            def cond(state):
                step, trial = state
                return (trial > value - 1e-4 * step * decrement) & (step > 1e-10)

            def body(state):
                step = 0.5 * state[0]
                return step, f(u + step * d, args)

            step, trial = jax.lax.while_loop(cond, body, (1.0, f(u + d, args)))
            ok = trial <= value
            return jnp.where(ok, u + step * d, u), jnp.where(ok, trial, value), ok

        def cond(state):
            it, _, _, decrement, moved = state
            return (it < self.max_iter) & (decrement > self.tol) & moved

        def body(state):
            it, u, value, _, _ = state
            d, decrement = direction(u)
            u_new, value_new, ok = line_search(u, value, d, decrement)
            return it + 1, u_new, value_new, decrement, ok

        value0 = f(u0, args)
        state = (0, u0, value0, jnp.inf, jnp.isfinite(value0))
        _, u, value, _, _ = jax.lax.while_loop(cond, body, state)
        _, decrement = direction(u)  # at the point returned
        return self._theta(u, base, free), -value, decrement

    # ------------------------------------------------------------------ public
    def _arguments(self, start: Any, fixed: Sequence[str], prior: bool) -> tuple:
        base = np.asarray(start, dtype=float)
        if base.shape != (len(self.names),):
            raise ValueError(f"the start has shape {base.shape}, θ has {len(self.names)} "
                             "entries")
        unknown = [n for n in fixed if n not in self.names]
        if unknown:
            raise ValueError(f"no parameter named {', '.join(unknown)} in θ "
                             f"({', '.join(self.names)})")
        if np.any(base[self.log] <= 0):
            raise ValueError("a variance of the start is not positive")
        free = np.array([n not in fixed for n in self.names])
        u0 = np.where(self.log, np.log(np.where(self.log, base, 1.0)), base)
        return u0, base, free, np.asarray(1.0 if prior else 0.0)

    def fit(self, start: Any, data: Any = None, fixed: Sequence[str] = (),
            prior: bool = True) -> ModeFit:
        """The mode from ``start`` on ``data`` (default: the posterior's own), the entries
        named in ``fixed`` held at their values in ``start``; ``prior=False``: the
        log-likelihood's maximum."""
        args = self._arguments(start, fixed, prior)
        theta, value, decrement = self._one(*args, self.posterior.data if data is None
                                            else data)
        return _mode_fit(theta, value, decrement, self.tol)

    def fit_many(self, starts: Sequence[Any], data: Any, fixed: Sequence[Sequence[str]],
                 prior: Sequence[bool]) -> list[ModeFit]:
        """:meth:`fit` on a batch in one compiled call: ``data`` stacked
        (:func:`stack_data`), one start, fixed set and prior flag per data set. The program
        is compiled once per batch size."""
        if not len(starts) == len(fixed) == len(prior):
            raise ValueError("one start, one fixed set and one prior flag per data set")
        columns = zip(*(self._arguments(s, f, p) for s, f, p in
                        zip(starts, fixed, prior, strict=True)), strict=True)
        thetas, values, decrements = self._many(*(np.stack(c) for c in columns), data)
        return [_mode_fit(t, v, d, self.tol) for t, v, d in zip(
            np.asarray(thetas), np.asarray(values), np.asarray(decrements), strict=True)]


def _mode_fit(theta: Any, value: Any, decrement: Any, tol: float) -> ModeFit:
    value, decrement = float(value), float(decrement)
    return ModeFit(np.asarray(theta, dtype=float), value, decrement,
                   bool(np.isfinite(value) and decrement <= tol))
