"""The log evidence with the noise variances integrated on their log scale (eqs 8–9).

Why not Laplace alone
---------------------
The Laplace evidence (:mod:`symplid.inference.map._laplace`) treats the posterior as Gaussian in θ.
The coefficients are close to Gaussian, but a noise variance often is not: with little or
no detectable process noise its posterior is skewed against zero (MAP 4e-6, median 1.6e-4),
and a Gaussian (or the 1-D scan from a bound) centred on the MAP misses 1.8–2 nats of mass.
On the log scale s = log(v − a) the same posterior is a smooth bump, so the variances are
integrated there by quadrature and only the coefficients are treated as Gaussian:

    p(Y) = ∫ ds ∫ dc π(c, v(s)) L(c, v(s); Y) · Π_j e^{s_j},        v_j(s) = a_j + e^{s_j}

where c stands for every other entry of θ (coefficients, learned initial states, any other
group) and Π e^{s_j} is the Jacobian of v ↦ s.

The rule
--------
1. **Variance parameters** are the entries of θ whose group is a variance group
   (:data:`~symplid.model._params.POSITIVE_GROUPS`) and that are bounded below only (so
   searched on a log scale by the MAP); a variance with an upper bound too stays in c.
   The damping rate γ of a damped model is in that tuple too and is integrated the same way
   (positive, and on data with little friction piled against 0 like a process variance).
2. **Profile** (:mod:`symplid.inference.map._profile`). For fixed s, c is maximised in the
   MAP search's coordinates u (θ itself, u = log(θ − a) or u = log θ in a box) by Newton's
   method with ∇²_u(−log π) = D H_θ D + diag(∂(−log π)/∂u on the logarithmic coordinates),
   D = ∂θ/∂u, from the compiled MAP θ-Hessian of the neighbouring node, carried between
   θ-Hessians by BFGS updates (the MAP search's compiled objective with the variances held;
   warm-started from a neighbouring node). Newton's answer is kept when it is an interior
   maximum: no step leaves L-BFGS-B's bounds on u (the log floor, a box), the end is on none
   of them and its Newton decrement in θ is small too. Otherwise, and whenever the
   neighbour's maximum sat on a bound, L-BFGS-B runs (before, Newton ran only when every
   entry of c was searched as itself without bounds, so never for a user's half-normal
   coefficients: on the Kepler example 7.7 value-and-gradient calls a node instead of 38). Then
   ``g(s) = log ∫ exp(log π(c, v(s))) dc + Σ s_j`` is the Gaussian integral over c from the
   θ-Hessian block there (the compiled MAP Hessian), with the Laplace module's 1-D scan for
   any entry of c on a bound. No new program is compiled.
3. **Centre and axes.** The joint mode of log π + Σ s over (c, s) is the centre s̄: L-BFGS-B
   from the MAP and from the MAP with the variances of the default start (a process variance
   as large as the data's; ``find_map`` passes it as ``other_starts``), the higher end kept.
   The variances can have two modes, and the MAP may sit in the lighter one: on the paper's
   Hénon–Heiles data with the cubic library started away from the data's initial state, a
   subset's MAP sat at a process variance of 5e-6 with the observation variance five times
   the truth, 18 nats of log π below the mode at a process variance of 4e-3; from the MAP
   alone the joint mode stayed there for some subsets and not for others, so their
   evidences were 26–40 nats apart for no reason in the data. The marginal covariance Σ_s
   of s from the Hessian in (c, s) at the centre gives the axes: s = s̄ + h·A·k with
   A Aᵀ = Σ_s, k an integer vector, h the step (one marginal standard deviation by default).
4. **Quadrature** (at most ``max_grid_dims`` = 2 variances, the isotropic model): the
   trapezoid rule on that lattice, log p(Y) = logsumexp g + m log h + log|det A|, over the
   nodes reached from the centre by unit steps along the axes, a node being expanded while g
   there is within ``drop`` (10) nats of the largest g seen (a flood fill: it follows a
   curved or skewed bump and skips the empty corners a product box would hold; what lies
   beyond is below e⁻¹⁰ of the peak). For a smooth integrand that vanishes at the ends
   the trapezoid rule converges geometrically in 1/h (Trefethen & Weideman, SIAM Review 56,
   2014): for a Gaussian the error is ≈ 2 exp(−2π²σ²/h²), so err(h) ≈ 2 (err(2h)/2)⁴, with
   err(2h) read off the same sum over the even nodes. When that estimate exceeds
   ``tolerance`` (1e-3 nats) the step is halved once (the old nodes are kept).
   ``details["error_estimate"]`` is the estimate. Measured on the 1-D oscillator of
   ``tests/test_map_evidence.py``: 1e-3 nats from brute-force quadrature over all parameters,
   with about 160 profile fits (1.3 s); the Laplace evidence was 0.7 and 1.3 nats low.
5. **More variances** (``noise = "diagonal"``): a product grid would need 13ᵐ profile fits, so
   the integral is taken along each of the m axes of A only, and combined as
   ``g(s̄) + log|det A| + Σ_j log(h Σ_k exp(g(s̄ + h A_j k) − g(s̄)))``: exact when g is a sum
   of functions of the whitened coordinates (in particular for a Gaussian g, where it is
   the Laplace approximation in log-variance coordinates), and it still corrects each
   axis's skewness. About 10 fits per axis. ``method`` says which rule was used. On the
   oscillator of ``tests/test_map_evidence.py`` (forced to this rule with two variances) it was
   0.15 nats from the product grid, where the Laplace evidence was 0.7–1.3 nats off.

6. **Log-Laplace** (``rule="log-laplace"``, ``find_map(evidence="log-laplace")``): the centre
   node alone, ``g(s̄) + (m/2) log 2π + log|det A|``: the Laplace approximation in (c, s),
   what steps 4–5 give for a Gaussian g. It costs the joint mode, one Hessian and one
   profile fit instead of 100–200 (step 4). It is the screening evidence of the term search
   (:mod:`symplid.inference._term_search`), which asks of each of ~40 subsets only whether it
   is far behind the best. Measured against the brute-force evidence of the oscillator of
   ``tests/test_map_evidence.py``: 0.16 nats (interior) and 0.27 nats (process variance on
   its floor) low, where the Laplace evidence in θ is 0.71 and 1.34 nats off. On
   Hénon–Heiles subsets: 0.13–0.34 nats below the quadrature where the data's mode has
   process noise, 0.85–1.7 nats below it where the process variance is on its floor (the
   Laplace evidence in θ there: 2.6–4.6 nats below).

A new variance group (e.g. further noise parameters) is integrated as soon as its name is in
:data:`~symplid.model._params.POSITIVE_GROUPS`: the variances are found by group, not position.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.optimize
from scipy.special import logsumexp

from symplid._stopping import check as check_stop
from symplid.inference.map._laplace import repaired_eigenvalues
from symplid.inference.map._profile import Profile, Warm, u_hessian
from symplid.inference.map._space import SearchSpace
from symplid.model._params import POSITIVE_GROUPS

EVIDENCE_RULES = ("quadrature", "log-laplace")
"""Choices of :func:`quadrature_evidence`'s ``rule`` (module docstring, steps 4–6)."""

@dataclass(frozen=True)
class EvidenceSettings:
    """Settings of :func:`quadrature_evidence` (module docstring, steps 3–5)."""

    step: float = 1.0
    drop: float = 10.0
    tolerance: float = 1e-3
    max_nodes_per_axis: int = 41
    max_grid_dims: int = 2
    inner_ftol: float = 1e-13
    inner_gtol: float = 1e-9
    max_newton: int = 30


@dataclass(frozen=True)
class EvidenceResult:
    """The log evidence and how it was computed."""

    log_evidence: float
    method: str  # "quadrature", "axis-quadrature" or "laplace" (no variance to integrate)
    variance_names: tuple[str, ...] = ()
    details: dict[str, Any] = field(default_factory=dict)


def variance_indices(groups: tuple[str, ...], space: SearchSpace) -> np.ndarray:
    """Positions of the variance parameters integrated on their log scale (step 1)."""
    return np.array(
        [i for i, g in enumerate(groups) if g in POSITIVE_GROUPS and space.log[i]], dtype=int
    )


def _joint_mode(profile: Profile, starts: list[np.ndarray]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u at the mode of log π + Σ s over (c, s), axes A with A Aᵀ the covariance of s
    there, ∇²_θ(−log π) there): step 3. L-BFGS-B runs from each of ``starts`` (u) and the
    highest end is kept."""
    space, var, vg = profile.space, profile.var, profile.vg
    bounds = list(space.bounds())
    for i in var:
        bounds[i] = (None, None)
    penalty = 1e10 + 1e3 * abs(float(vg(jnp.asarray(starts[0]))[0]))

    def fun(u: np.ndarray) -> tuple[float, np.ndarray]:
        check_stop()
        value, grad = vg(jnp.asarray(u))
        value, grad = float(value), np.array(grad, dtype=float)
        if not (np.isfinite(value) and np.all(np.isfinite(grad))):
            return penalty, np.zeros_like(u)
        grad[var] -= 1.0
        return value - float(np.sum(u[var])), grad

    ends = [scipy.optimize.minimize(fun, u0, jac=True, method="L-BFGS-B", bounds=bounds,
                                    options=profile.options) for u0 in starts]
    u = np.asarray(min(ends, key=lambda r: float(r.fun)).x, dtype=float)
    theta = np.asarray(space.to_theta(jnp.asarray(u)), dtype=float)
    h_theta = np.asarray(profile.hessian(jnp.asarray(theta)), dtype=float)
    h_u = u_hessian(space, h_theta, u, np.asarray(vg(jnp.asarray(u))[1], dtype=float))
    cov_s = np.eye(var.size)
    if np.all(np.isfinite(h_u)):
        _, vecs, fixed, _ = repaired_eigenvalues(h_u)
        cov_s = ((vecs / fixed) @ vecs.T)[np.ix_(var, var)]
    lam, vecs = np.linalg.eigh(0.5 * (cov_s + cov_s.T))
    if not np.all(np.isfinite(lam)):
        lam, vecs = np.ones(var.size), np.eye(var.size)
    lam = np.clip(lam, 1e-6, 25.0)  # a log-variance sd between 1e-3 and 5
    return u, vecs * np.sqrt(lam), h_theta


class _Grid:
    """g on the nodes s̄ + h·A·k (k an integer vector), each fit warm-started from the node
    that reached it."""

    def __init__(self, profile: Profile, u_centre: np.ndarray, axes: np.ndarray,
                 step: float, hessian: np.ndarray | None = None) -> None:
        self.profile, self.axes, self.step = profile, axes, step
        self.centre = u_centre[profile.var].copy()
        self.values: dict[tuple[int, ...], tuple[float, Warm]] = {}
        self.root: Warm = (u_centre, hessian)

    def g(self, key: tuple[int, ...], warm: Warm | None = None) -> float:
        if key not in self.values:
            s = self.centre + self.step * self.axes @ np.asarray(key, dtype=float)
            self.values[key] = self.profile.value(s, self.root if warm is None else warm)
        return self.values[key][0]

    def halve(self) -> None:
        """Halve the step; the nodes found so far become the even nodes."""
        self.step *= 0.5
        self.values = {tuple(2 * k for k in key): v for key, v in self.values.items()}

    def log_sum(self, keys: list[tuple[int, ...]], dims: int, every: int = 1) -> float:
        """log of the trapezoid sum over ``keys`` (every ``every``-th node) in ``dims`` axes."""
        picked = [self.g(k) for k in keys if all(c % every == 0 for c in k)]
        return float(logsumexp(picked)) + dims * math.log(every * self.step)


def _flood(grid: _Grid, dims: tuple[int, ...], settings: EvidenceSettings,
           seeds: list[tuple[int, ...]], half_width: int) -> list[tuple[int, ...]]:
    """The nodes reached from ``seeds`` by unit steps along the axes ``dims``, a node being
    expanded while g there is within ``drop`` of the largest g seen (step 4)."""
    reached = set(seeds)
    queue = deque(seeds)
    top = max(grid.g(k) for k in seeds)
    while queue:
        key = queue.popleft()
        if not grid.g(key) > top - settings.drop:
            continue
        for j in dims:
            for side in (-1, 1):
                nb = tuple(c + side if i == j else c for i, c in enumerate(key))
                if nb in reached or abs(nb[j]) > half_width:
                    continue
                reached.add(nb)
                top = max(top, grid.g(nb, grid.values[key][1]))
                queue.append(nb)
    return sorted(reached)


def _integrate(grid: _Grid, dims: tuple[int, ...], settings: EvidenceSettings) -> tuple[float,
                                                                                       float]:
    """(log ∫ exp g over the axes ``dims`` by the trapezoid rule, error estimate): step 4."""
    on_dims = [k for k in grid.values if all(c == 0 for i, c in enumerate(k) if i not in dims)]
    half_width = settings.max_nodes_per_axis // 2
    region = _flood(grid, dims, settings, on_dims, half_width)
    value = grid.log_sum(region, len(dims))
    coarse_error = abs(value - grid.log_sum(region, len(dims), every=2))
    if 2.0 * (0.5 * coarse_error) ** 4 > settings.tolerance:
        grid.halve()
        region = _flood(grid, dims, settings, [tuple(2 * c for c in k) for k in region],
                        2 * half_width)
        fine = grid.log_sum(region, len(dims))
        coarse_error, value = abs(fine - value), fine
    # geometric convergence: err(h) ≈ 2·(err(2h)/2)⁴ (exact for a Gaussian, see docstring)
    return value, 2.0 * (0.5 * coarse_error) ** 4


def quadrature_evidence(
    value_and_grad: Callable,
    hessian: Callable,
    space: SearchSpace,
    groups: tuple[str, ...],
    names: tuple[str, ...],
    theta_map: np.ndarray,
    settings: EvidenceSettings | None = None,
    *,
    other_starts: Sequence[np.ndarray] = (),
    rule: str = "quadrature",
) -> EvidenceResult | None:
    """log p(Y) with the variances integrated on their log scale (module docstring).

    Parameters
    ----------
    value_and_grad
        The MAP search's compiled ``u ↦ (−log π, gradient)`` in ``space``'s coordinates.
    hessian
        The compiled ``θ ↦ ∇²(−log π)``.
    space, groups, names
        The search space of θ and the group and name of each entry.
    theta_map
        The MAP (the starting point of the joint mode and of the first fit).
    other_starts
        Further starting points (θ) of the joint mode (step 3), e.g. the MAP with the
        variances raised: the highest mode found is integrated.
    rule
        ``"quadrature"`` (steps 4–5) or ``"log-laplace"`` (step 6: the centre node only).

    Returns
    -------
    EvidenceResult or None
        None when θ has no variance parameter (the Laplace evidence is then the answer).
    """
    if rule not in EVIDENCE_RULES:
        raise ValueError(f"rule must be one of {', '.join(EVIDENCE_RULES)}, got {rule!r}")
    settings = EvidenceSettings() if settings is None else settings
    t0 = time.perf_counter()
    var = variance_indices(tuple(groups), space)
    if var.size == 0:
        return None
    options = {"ftol": settings.inner_ftol, "gtol": settings.inner_gtol, "maxiter": 2000,
               "maxcor": 30}
    profile = Profile(value_and_grad, hessian, space, var, options, settings.max_newton)
    starts = [space.to_u(theta_map)] + [space.to_u(np.asarray(t, dtype=float))
                                        for t in other_starts]
    u_centre, axes, h_centre = _joint_mode(profile, starts)
    finite = h_centre if np.all(np.isfinite(h_centre)) else None
    grid = _Grid(profile, u_centre, axes, float(settings.step), finite)
    m = var.size
    centre = grid.g((0,) * m)
    log_det = float(np.linalg.slogdet(axes)[1])
    error = math.nan
    if rule == "log-laplace":
        method = "log-laplace"
        value = centre + log_det + 0.5 * m * math.log(2.0 * math.pi)
    elif m <= settings.max_grid_dims:
        method = "quadrature"
        value, error = _integrate(grid, tuple(range(m)), settings)
        value += log_det
    else:
        method = "axis-quadrature"
        value, error = centre + log_det, 0.0
        for j in range(m):
            line, line_error = _integrate(grid, (j,), settings)
            value += line - centre
            error += line_error
    details = {
        "method": method,
        "variances": [names[i] for i in var],
        "log_variance_centre": u_centre[var].tolist(),
        "log_variance_sd": np.sqrt(np.sum(axes**2, axis=1)).tolist(),
        "theta_centre": np.asarray(space.to_theta(jnp.asarray(u_centre)), dtype=float).tolist(),
        "step": grid.step,
        "nodes": len(grid.values),
        "inner_fits": profile.num_fits,
        "error_estimate": float(error),
        "seconds": time.perf_counter() - t0,
    }
    return EvidenceResult(float(value), method, tuple(names[i] for i in var), details)


__all__ = ["EVIDENCE_RULES", "EvidenceResult", "EvidenceSettings", "quadrature_evidence",
           "variance_indices"]
