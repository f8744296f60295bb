"""The Hessian at the MAP, the Laplace covariance and evidence (Sections II-B.2 and IV).

Hessian, covariance, evidence
-----------------------------
``hessian`` is ∇²(−log π) at the MAP by JAX autodiff (``jax.hessian``), over all of θ. It is
compiled with XLA's backend optimisations off: it runs once, and that halves its compile time.

``covariance`` is built from it by this documented rule:

1. **Parameters on a bound are decoupled.** At a bound the local quadratic says nothing
   useful: in the paper's problem the process variance sits at 0, where the Hessian's entries
   involving it reach 1e17 while the posterior mass spreads over 1e-7 to 1e-5. For a parameter j
   the log posterior is scanned along θ_j alone (the others at the MAP), from the bound inwards
   on a geometric grid, until it has dropped by 30; the 1-D density w(δ) = exp(log π − log π*)
   gives the mass M_j = ∫ w and the variance of δ under w / M_j, which becomes θ_j's variance
   (zero covariance with the others).
2. **The other parameters** get the inverse of their block of the Hessian (conditional on the
   bound parameters at their MAP values), through the eigendecomposition H = V diag(λ) Vᵀ.
   When that block is not positive definite (a flat direction, a saddle) it is **repaired**
   by replacing every eigenvalue with max(|λ|, 1e-12·max|λ|): negative curvature is flipped
   (keeping the local scale of that direction, which is what a proposal needs) and null
   directions are lifted. ``covariance_repaired`` says whether step 1 or 2 changed anything.

The result is symmetric positive definite. ``log_evidence`` is the Laplace approximation

    log p(Y) ≈ log π(θ*) + log L(θ*) + (d/2) log 2π − ½ log det H

over the free parameters (d of them, H their repaired block), plus log M_j for each parameter
on a bound (its 1-D integral in place of a Gaussian one). With no parameter on a bound this is
the textbook formula. It assumes normalised priors (a prior cut by a bound, such as a normal
prior on a variance, is not renormalised) and is rougher when a parameter is on a bound,
which is warned about. It is 1–2 nats too low when a noise variance's posterior is skewed
against zero, on its bound or not; ``MapResult.log_evidence`` therefore integrates the
variances by quadrature over their logarithms (:mod:`symplid.inference.map._evidence`, which
uses this module's Gaussian integral for the other parameters) and keeps this value as
``log_evidence_laplace``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from typing import Any, NamedTuple

import jax
import numpy as np

from symplid._saved_programs import saved_jit
from symplid.inference.map._space import SearchSpace

_LOG_2PI = math.log(2.0 * math.pi)
EIGEN_FLOOR = 1e-12
"""Eigenvalues of the Hessian are floored at this fraction of the largest one (step 2)."""


def repaired_eigenvalues(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(λ, V, max(|λ|, floor), floor) of the symmetrised ``matrix``, floor = 1e-12·max|λ|."""
    lam, vecs = np.linalg.eigh(0.5 * (matrix + matrix.T))
    top = float(np.max(np.abs(lam)))
    floor = EIGEN_FLOOR * top if top > 0 else 1.0
    return lam, vecs, np.maximum(np.abs(lam), floor), floor


def newton_step(grad: np.ndarray, hessian: np.ndarray) -> np.ndarray:
    """H⁻¹g with H repaired as in step 2: the Newton step up log π (g its gradient, H the
    Hessian of −log π)."""
    _, vecs, fixed, _ = repaired_eigenvalues(hessian)
    return vecs @ ((vecs.T @ grad) / fixed)


def newton_decrement(grad: np.ndarray, hessian: np.ndarray) -> float:
    """½ gᵀH⁻¹g with H repaired as in step 2: the gain in log π a Newton step promises."""
    if grad.size == 0:
        return 0.0
    _, vecs, fixed, _ = repaired_eigenvalues(hessian)
    return 0.5 * float(np.sum((vecs.T @ grad) ** 2 / fixed))


class BoundScan(NamedTuple):
    """The 1-D density along a parameter that sits on a bound (module docstring, step 1)."""

    log_mass: float  # log ∫ exp(log π − log π*) dθ_j
    variance: float


def scan_from_bound(
    log_density: Callable[[np.ndarray], float],
    theta: np.ndarray,
    i: int,
    space: SearchSpace,
    u: np.ndarray,
    log_post: float,
    drop: float = 30.0,
    growth: float = 1.1,
    max_points: int = 1000,
) -> BoundScan:
    """The 1-D density along θ_i from its bound inwards (module docstring, step 1).

    The log posterior is scanned on a geometric grid (first step ``space.floor`` for a
    log-searched parameter, else 1e-12·max(1, |bound|), growing by ``growth``) until it has
    dropped by ``drop``; the mass and the variance of the offset follow by the trapezoid rule.
    """
    lower_side = space.on_lower_side(u, i)
    bound = space.lower[i] if lower_side else space.upper[i]
    other = space.upper[i] if lower_side else space.lower[i]
    direction = 1.0 if lower_side else -1.0
    reach = abs(other - bound) if np.isfinite(other) else np.inf
    first = space.floor if space.log[i] else 1e-12 * max(1.0, abs(bound))
    deltas, values = [], []
    delta = first
    point = np.array(theta, dtype=float)
    while len(deltas) < max_points:
        delta = min(delta, reach)
        point[i] = bound + direction * delta
        value = log_density(point) - log_post
        deltas.append(delta)
        values.append(value if np.isfinite(value) else -np.inf)
        if not np.isfinite(value) or value < -drop or delta >= reach:
            break
        delta *= growth
    d = np.concatenate([[0.0], deltas])
    w = np.exp(np.concatenate([[values[0]], values]))
    mass = float(np.trapezoid(w, d))
    if not (np.isfinite(mass) and mass > 0):
        return BoundScan(math.nan, math.nan)
    mean = float(np.trapezoid(w * d, d)) / mass
    var = float(np.trapezoid(w * (d - mean) ** 2, d)) / mass
    return BoundScan(math.log(mass), var)


def laplace_covariance(
    hessian: np.ndarray, log_post: float, bound_idx: Sequence[int], scans: Sequence[BoundScan]
) -> tuple[np.ndarray | None, bool, float]:
    """(covariance, repaired?, log evidence) by the rule of the module docstring."""
    d = hessian.shape[0]
    free = np.setdiff1d(np.arange(d), np.asarray(bound_idx, dtype=int))
    block = hessian[np.ix_(free, free)]
    if not np.all(np.isfinite(block)):
        return None, True, math.nan
    cov = np.zeros((d, d))
    repaired = bool(len(bound_idx))
    log_det = 0.0
    if free.size:
        lam, vecs, fixed, floor = repaired_eigenvalues(block)
        repaired = repaired or bool(np.any(lam < floor))
        inv = (vecs / fixed) @ vecs.T
        cov[np.ix_(free, free)] = 0.5 * (inv + inv.T)
        log_det = float(np.sum(np.log(fixed)))
    log_evidence = log_post + 0.5 * free.size * _LOG_2PI - 0.5 * log_det
    for i, scan in zip(bound_idx, scans, strict=True):
        variance = scan.variance
        if not (np.isfinite(variance) and variance > 0):
            h = abs(hessian[i, i])
            variance = 1.0 / h if np.isfinite(h) and h > 0 else 1.0
        cov[i, i] = variance
        log_evidence += scan.log_mass
    return cov, repaired, float(log_evidence)


class LowOptimisationJit:
    """``jax.jit`` with XLA's backend optimisations off, for functions evaluated once.

    The Hessian is evaluated once per search, so its compile time is all that matters: with
    optimisation level 0 it compiles in about half the time (same numbers to ~1e-12). Falls
    back to a plain ``jax.jit`` if the backend rejects the options. With an ``identity`` (what
    ``fn`` closes over), its program is saved for later processes
    (:func:`symplid._saved_programs.saved_jit`).
    """

    OPTIONS: dict[str, Any] = {  # noqa: RUF012
        "xla_backend_optimization_level": 0,
        "xla_llvm_disable_expensive_passes": True,
    }

    def __init__(self, fn: Callable, identity: Hashable | None = None,
                 name: str = "low-optimisation") -> None:
        self._fn = fn
        self._jitted: Callable | None = None
        self._identity, self._name = identity, name

    def __call__(self, *args: Any) -> Any:
        if self._jitted is None:
            try:
                jitted = saved_jit(self._fn, self._name, self._identity, self.OPTIONS)
                out = jitted(*args)
            except Exception:  # an unknown option on another backend: compile normally
                jitted = jax.jit(self._fn)
                out = jitted(*args)
            self._jitted = jitted
            return out
        return self._jitted(*args)


def hessian_function(log_density_with: Callable[[Any, Any], Any], data: Any,
                     identity: Hashable | None = None) -> Callable:
    """``θ ↦ ∇²(−log π)(θ)``, compiled with low optimisation (:class:`LowOptimisationJit`);
    ``identity``: what ``log_density_with`` closes over, for its saved program."""
    hessian = LowOptimisationJit(jax.hessian(lambda t, data: -log_density_with(data, t)),
                                 identity, "map-hessian")
    return lambda t: hessian(t, data)


__all__ = [
    "EIGEN_FLOOR",
    "BoundScan",
    "LowOptimisationJit",
    "hessian_function",
    "laplace_covariance",
    "newton_decrement",
    "newton_step",
    "repaired_eigenvalues",
    "scan_from_bound",
]
