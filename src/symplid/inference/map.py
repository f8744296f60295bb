"""The MAP point, the Hessian there, and the Laplace approximation (Sections II-B.2 and IV).

:func:`find_map` maximises the log posterior with SciPy's bounded quasi-Newton method
(L-BFGS-B) from several seeded starts, using the exact gradient by JAX (``value_and_grad``,
compiled once per posterior). The paper used MATLAB's fmincon for the MAP and the inverse
Hessian of the negative log posterior there as the first DRAM proposal; so does this module.

Search space
------------
Parameters bounded below only (the variances, bound 0) are searched as u = log(θ − a), with
the bound u ≥ log(``positive_floor``) (default 1e-14, below the filter's 1e-12 jitter, where
the likelihood no longer changes); every other parameter is searched as itself, with its
bounds given to L-BFGS-B. The log scale lets one method handle coefficients of order one
and variances of order 1e-7. The MAP is a property of the density over θ, so no Jacobian is
added: the point found is the mode of π(θ | Y). Because the gradient in u vanishes as θ
approaches its bound, a log-searched parameter is finally moved onto the floor when the log
posterior there is no lower, and is then reported as sitting on its bound (with the paper's
data and leapfrog this happens to the process variance: no process noise is detectable).

Starting points
---------------
Start 0 is ``init`` when given, else the default start:

* coefficients (and any other unbounded parameter) at their prior median (0 for the paper's
  Laplace prior), moved inside the bounds;
* the process-noise variance at the variance of the data (over time and components), and the
  observation-noise variance at a tenth of it;
* a learned initial state at its prior's centre (the first observation).

With all coefficients at zero the model alone is a free particle, but the large process
noise makes the filter follow the data, so the likelihood is smooth and informative; as the
optimiser lowers the process variance it moves to the deterministic fit (a homotopy that the
marginal likelihood gives for free). Starting instead from prior draws fails: coefficients
drawn from Laplace(0, 10) make most trajectories escape to infinity.

Starts 1, 2, ... perturb the default start: each unbounded parameter by a normal draw of
standard deviation ``start_spread`` × its prior's standard deviation (0.02 × 14.1 = 0.28 for
the coefficients under Laplace(0, 10)), each variance by a factor exp(N(0, 1)); a start
with a non-finite log posterior is drawn again with half the perturbation (up to 8 times).
Draws use ``jax.random.fold_in(jax.random.key(seed), k)`` for start k.

A non-finite objective (a failed filter, an overflow) is returned to L-BFGS-B as a large
value, so its line search backs off. A start counts as converged only when L-BFGS-B says so
and the Newton decrement ½ gᵀH⁻¹g there is below 1e-3 (see :class:`StartResult`); the best
start (highest log posterior) gives the MAP whether or not the others converged.

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
which is warned about.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

Array = jax.Array

_LOG_2PI = math.log(2.0 * math.pi)
_EIGEN_FLOOR = 1e-12
_NONFINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


class BoundWarning(UserWarning):
    """The MAP sits on a bound of θ."""


class MapConvergenceWarning(UserWarning):
    """No start of the MAP search reported convergence."""


@dataclass(frozen=True)
class StartResult:
    """One start of :func:`find_map`.

    ``success`` means that L-BFGS-B reported convergence *and* the point is a maximum to
    within 1e-3 in log posterior: the Newton decrement ½ gᵀH⁻¹g over the parameters off the
    bounds (``newton_decrement``) is below 1e-3 when the Hessian is computed; otherwise the
    largest projected-gradient component in the search space (``projected_gradient``) must
    be below 1e-3·max(1, |log π|). A run that stalls against a region where the filter fails
    is thus not counted as converged, whatever L-BFGS-B's message says.
    """

    start: np.ndarray
    theta: np.ndarray
    log_posterior: float
    success: bool
    message: str
    num_iterations: int
    num_evaluations: int
    seconds: float
    projected_gradient: float = math.nan
    newton_decrement: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "start": _json_list(self.start),
            "theta": _json_list(self.theta),
            "log_posterior": _json_float(self.log_posterior),
            "success": bool(self.success),
            "message": str(self.message),
            "num_iterations": int(self.num_iterations),
            "num_evaluations": int(self.num_evaluations),
            "seconds": float(self.seconds),
            "projected_gradient": _json_float(self.projected_gradient),
            "newton_decrement": _json_float(self.newton_decrement),
        }


@dataclass(frozen=True)
class MapResult:
    """The MAP point, the Hessian there and the Laplace approximation.

    Attributes
    ----------
    theta
        The MAP point, in the posterior's parameter order (``param_names``).
    log_posterior
        log π(θ*) + log L(θ*), the unnormalised log posterior at the MAP.
    success, message
        Convergence of the best start, as reported by L-BFGS-B.
    num_starts, starts
        How many starts were run, and each one's result (best first is *not* implied: in
        the order they were run).
    hessian
        ∇²(−log posterior) at the MAP, ``(d, d)``, by JAX autodiff (None when not computed).
    covariance
        The inverse Hessian, repaired to positive definite when needed (module docstring).
    covariance_repaired
        Whether the Hessian was not positive definite and had eigenvalues replaced.
    log_evidence
        Laplace approximation of log p(Y) (NaN when the Hessian was not computed).
    param_names
        Names of θ's entries.
    at_bounds
        Names of the parameters whose MAP value sits on a bound.
    seed, seconds
        The seed of the starts, and the wall time of the whole search.
    """

    theta: np.ndarray
    log_posterior: float
    success: bool
    message: str
    num_starts: int
    starts: tuple[StartResult, ...]
    hessian: np.ndarray | None
    covariance: np.ndarray | None
    covariance_repaired: bool
    log_evidence: float
    param_names: tuple[str, ...]
    at_bounds: tuple[str, ...] = ()
    seed: int = 0
    seconds: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray | None:
        """Laplace standard deviations, √diag(covariance)."""
        if self.covariance is None:
            return None
        return np.sqrt(np.diag(self.covariance))

    @property
    def params(self) -> dict[str, float]:
        """``{name: MAP value}``."""
        return {n: float(v) for n, v in zip(self.param_names, self.theta, strict=True)}

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict; non-finite floats as ``"nan"``, ``"inf"``, ``"-inf"``."""
        return {
            "param_names": list(self.param_names),
            "theta": _json_list(self.theta),
            "params": {k: _json_float(v) for k, v in self.params.items()},
            "log_posterior": _json_float(self.log_posterior),
            "success": bool(self.success),
            "message": str(self.message),
            "num_starts": int(self.num_starts),
            "starts": [s.to_dict() for s in self.starts],
            "hessian": None if self.hessian is None else _json_list(self.hessian),
            "covariance": None if self.covariance is None else _json_list(self.covariance),
            "covariance_repaired": bool(self.covariance_repaired),
            "std": None if self.std is None else _json_list(self.std),
            "log_evidence": _json_float(self.log_evidence),
            "at_bounds": list(self.at_bounds),
            "seed": int(self.seed),
            "seconds": float(self.seconds),
            "settings": dict(self.settings),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> MapResult:
        """Inverse of :meth:`to_dict` (e.g. after reading ``map.json``)."""

        def arr(x: Any) -> np.ndarray | None:
            return None if x is None else np.asarray(_decode(x), dtype=float)

        starts = tuple(
            StartResult(
                arr(s["start"]),
                arr(s["theta"]),
                float(_decode(s["log_posterior"])),
                bool(s["success"]),
                str(s["message"]),
                int(s["num_iterations"]),
                int(s["num_evaluations"]),
                float(s["seconds"]),
                float(_decode(s.get("projected_gradient", "nan"))),
                float(_decode(s.get("newton_decrement", "nan"))),
            )
            for s in d.get("starts", [])
        )
        return cls(
            theta=arr(d["theta"]),
            log_posterior=float(_decode(d["log_posterior"])),
            success=bool(d["success"]),
            message=str(d["message"]),
            num_starts=int(d["num_starts"]),
            starts=starts,
            hessian=arr(d.get("hessian")),
            covariance=arr(d.get("covariance")),
            covariance_repaired=bool(d.get("covariance_repaired", False)),
            log_evidence=float(_decode(d.get("log_evidence", "nan"))),
            param_names=tuple(d["param_names"]),
            at_bounds=tuple(d.get("at_bounds", ())),
            seed=int(d.get("seed", 0)),
            seconds=float(d.get("seconds", 0.0)),
            settings=dict(d.get("settings", {})),
        )

    def __repr__(self) -> str:
        lines = [
            f"MapResult(log_posterior={self.log_posterior:.6g}, success={self.success}, "
            f"starts={self.num_starts}, log_evidence={self.log_evidence:.6g})"
        ]
        std = self.std
        for i, name in enumerate(self.param_names):
            sd = "" if std is None else f" ± {std[i]:.3g}"
            flag = "  (on a bound)" if name in self.at_bounds else ""
            lines.append(f"  {name:>14s} = {self.theta[i]: .6g}{sd}{flag}")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- search space
@dataclass(frozen=True)
class _Space:
    """θ ↔ u: log(θ − a) for parameters bounded below only, the identity for the others."""

    lower: np.ndarray
    upper: np.ndarray
    log: np.ndarray  # bool mask
    floor: float

    @classmethod
    def of(cls, posterior: Any, floor: float) -> _Space:
        lower = np.asarray(posterior.lower, dtype=float)
        upper = np.asarray(posterior.upper, dtype=float)
        return cls(lower, upper, np.isfinite(lower) & ~np.isfinite(upper), float(floor))

    def to_theta(self, u: Array) -> Array:
        lo = np.where(self.log, self.lower, 0.0)
        return jnp.where(self.log, lo + jnp.exp(jnp.where(self.log, u, 0.0)), u)

    def to_u(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            logged = np.log(np.maximum(theta - np.where(self.log, self.lower, 0.0), 0.0))
        return np.where(self.log, np.maximum(logged, math.log(self.floor)), theta)

    def bounds(self) -> list[tuple[float | None, float | None]]:
        out = []
        for lo, hi, lg in zip(self.lower, self.upper, self.log, strict=True):
            if lg:
                out.append((math.log(self.floor), None))
            else:
                out.append(
                    (float(lo) if np.isfinite(lo) else None, float(hi) if np.isfinite(hi) else None)
                )
        return out

    def at_bounds(self, u: np.ndarray, tol: float = 1e-8) -> np.ndarray:
        hits = np.zeros(u.shape[0], dtype=bool)
        for i, (lo, hi) in enumerate(self.bounds()):
            for b in (lo, hi):
                if b is not None and abs(u[i] - b) <= tol * max(1.0, abs(b)):
                    hits[i] = True
        return hits


# Compiled functions, cached per posterior object (compilation dominates short searches).
_COMPILED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _compiled(posterior: Any, space: _Space) -> dict[str, Callable]:
    try:
        entry = _COMPILED.setdefault(posterior, {})
    except TypeError:  # not weak-referenceable: no cache
        entry = {}
    key = ("u", space.log.tobytes(), space.lower.tobytes())
    # A posterior that takes its data as an argument keeps the data out of the compiled
    # programs, so another data set of the same shape reuses them (persistent cache).
    with_data = getattr(posterior, "log_density_with", None)
    data = getattr(posterior, "data", None)
    if with_data is None or data is None:
        log_density = posterior.log_density

        def with_data(_, theta):
            return log_density(theta)

    if key not in entry:

        def negative_u(u: Array, data: Any) -> Array:
            return -with_data(data, space.to_theta(u))

        vg = jax.jit(jax.value_and_grad(negative_u))
        entry[key] = lambda u: vg(u, data)
    if "hessian" not in entry:
        hessian = _LowOptimisationJit(jax.hessian(lambda t, data: -with_data(data, t)))
        entry["hessian"] = lambda t: hessian(t, data)
    return {"value_and_grad": entry[key], "hessian": entry["hessian"]}


class _LowOptimisationJit:
    """``jax.jit`` with XLA's backend optimisations off, for functions evaluated once.

    The Hessian is evaluated once per search, so its compile time is all that matters: with
    optimisation level 0 it compiles in about half the time (same numbers to ~1e-12). Falls
    back to a plain ``jax.jit`` if the backend rejects the options.
    """

    OPTIONS: dict[str, Any] = {  # noqa: RUF012
        "xla_backend_optimization_level": 0,
        "xla_llvm_disable_expensive_passes": True,
    }

    def __init__(self, fn: Callable) -> None:
        self._fn = fn
        self._jitted: Callable | None = None

    def __call__(self, *args: Any) -> Any:
        if self._jitted is None:
            try:
                jitted = jax.jit(self._fn, compiler_options=self.OPTIONS)
                out = jitted(*args)
            except Exception:  # an unknown option on another backend: compile normally
                jitted = jax.jit(self._fn)
                out = jitted(*args)
            self._jitted = jitted
            return out
        return self._jitted(*args)


# ----------------------------------------------------------------------------- starts
def default_start(posterior: Any) -> np.ndarray:
    """The default first start of :func:`find_map` (see the module docstring)."""
    d = int(posterior.num_params)
    lower = np.asarray(posterior.lower, dtype=float)
    upper = np.asarray(posterior.upper, dtype=float)
    groups = tuple(getattr(posterior, "param_groups", ("",) * d))
    priors = getattr(posterior, "priors", None)
    data_var = _data_variance(posterior)
    start = np.empty(d)
    for i in range(d):
        if groups[i] == "process_var" and data_var is not None:
            v = data_var
        elif groups[i] == "obs_var" and data_var is not None:
            v = 0.1 * data_var
        elif priors is not None:
            v = float(priors[i].median)
        else:
            v = 0.0 if not np.isfinite(lower[i]) or not np.isfinite(upper[i]) else np.nan
        start[i] = _inside(v, lower[i], upper[i])
    return start


def _inside(v: float, lo: float, hi: float) -> float:
    """v moved strictly inside [lo, hi] (a quarter of the width in, or a unit step)."""
    if np.isfinite(lo) and np.isfinite(hi):
        if not (lo < v < hi):
            v = 0.5 * (lo + hi)
    elif np.isfinite(lo) and not v > lo:
        v = lo + 1.0
    elif np.isfinite(hi) and not v < hi:
        v = hi - 1.0
    elif not np.isfinite(v):
        v = 0.0
    return float(v)


def _data_variance(posterior: Any) -> float | None:
    datasets = getattr(posterior, "datasets", None)
    if not datasets:
        return None
    with np.errstate(all="ignore"):
        values = [np.where(obs.mask, obs.values, np.nan) for obs in datasets]
        v = float(np.nanmean([np.nanvar(x, axis=0) for x in values]))
    return v if np.isfinite(v) and v > 0 else None


def _prior_std(posterior: Any, i: int, theta_i: float) -> float:
    priors = getattr(posterior, "priors", None)
    if priors is not None:
        s = float(priors[i].std)
        if np.isfinite(s) and s > 0:
            return s
    return max(1.0, abs(theta_i))


def _as_theta(init: Any, posterior: Any, default: np.ndarray) -> np.ndarray:
    """``init`` as θ: an array, a ``{name: value}`` mapping (others default) or a MapResult."""
    names = tuple(posterior.param_names)
    if hasattr(init, "theta"):
        init = init.theta
    if isinstance(init, Mapping):
        unknown = [k for k in init if k not in names]
        if unknown:
            raise ValueError(
                f"init names unknown parameter(s) {', '.join(map(repr, unknown))}; "
                f"the parameters are {', '.join(names)}"
            )
        theta = default.copy()
        for k, v in init.items():
            theta[names.index(k)] = float(v)
    else:
        theta = np.asarray(init, dtype=float)
        if theta.shape != (len(names),):
            raise ValueError(
                f"init must have shape ({len(names)},) ({', '.join(names)}), got {theta.shape}"
            )
    lower, upper = np.asarray(posterior.lower), np.asarray(posterior.upper)
    outside = np.flatnonzero((theta < lower) | (theta > upper) | ~np.isfinite(theta))
    if outside.size:
        i = int(outside[0])
        raise ValueError(
            f"init: {names[i]} = {theta[i]:g} is outside its bounds [{lower[i]:g}, {upper[i]:g}]"
        )
    return theta


def _perturbed_start(
    key: Array,
    posterior: Any,
    space: _Space,
    base: np.ndarray,
    spread: float,
    is_finite: Callable[[np.ndarray], bool],
    max_halvings: int = 8,
) -> np.ndarray:
    d = base.shape[0]
    noise = np.asarray(jax.random.normal(key, (d,), dtype=jnp.float64))
    scale = np.array([_prior_std(posterior, i, base[i]) for i in range(d)])
    u_base = space.to_u(base)
    step = np.where(space.log, 1.0, spread * scale) * noise
    bounds = space.bounds()
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds])
    for _ in range(max_halvings + 1):
        u = np.clip(u_base + step, lo, hi)
        theta = np.asarray(space.to_theta(jnp.asarray(u)))
        if is_finite(theta):
            return theta
        step = 0.5 * step
    return base.copy()


# ----------------------------------------------------------------------------- the search
def find_map(
    posterior: Any,
    seed: int = 0,
    num_starts: int = 4,
    init: Any = None,
    *,
    start_spread: float = 0.02,
    positive_floor: float = 1e-14,
    maxiter: int = 10_000,
    ftol: float = 1e-14,
    gtol: float = 1e-8,
    maxcor: int = 30,
    compute_hessian: bool = True,
    warn: bool = True,
) -> MapResult:
    """The maximum a posteriori point of ``posterior`` by L-BFGS-B from several starts.

    Parameters
    ----------
    posterior
        A :class:`~symplid.model.posterior.Posterior`, or any object with ``num_params``,
        ``param_names``, ``lower``, ``upper`` and a JAX ``log_density(theta)``.
    seed
        Seed of the perturbed starts (start k uses ``fold_in(key(seed), k)``).
    num_starts
        Number of L-BFGS-B runs; the first starts at ``init`` or the default start.
    init
        First start: an array, a ``{name: value}`` mapping (the others at the default start)
        or a previous :class:`MapResult`. The further starts perturb it.
    start_spread
        Perturbation of the further starts, as a fraction of each prior's standard deviation.
    positive_floor
        Smallest value searched for a parameter bounded below only (above its bound).
    maxiter, ftol, gtol, maxcor
        L-BFGS-B settings (iterations, relative reduction of the objective, projected
        gradient, number of stored corrections).
    compute_hessian
        Compute the Hessian, covariance and evidence (one extra compilation).
    warn
        Warn (:class:`BoundWarning`) when the MAP is on a bound, and
        (:class:`MapConvergenceWarning`) when no start converged.

    Returns
    -------
    MapResult
    """
    t_begin = time.perf_counter()
    if int(num_starts) != num_starts or num_starts < 1:
        raise ValueError(f"num_starts must be an integer ≥ 1, got {num_starts!r}")
    if not (positive_floor > 0 and math.isfinite(positive_floor)):
        raise ValueError(f"positive_floor must be a finite number > 0, got {positive_floor!r}")
    if not (start_spread >= 0 and math.isfinite(start_spread)):
        raise ValueError(f"start_spread must be a finite number ≥ 0, got {start_spread!r}")
    names = tuple(str(n) for n in posterior.param_names)
    space = _Space.of(posterior, positive_floor)
    fns = _compiled(posterior, space)
    value_and_grad = fns["value_and_grad"]

    def log_density(theta: np.ndarray) -> float:
        # through the compiled search function: no second compilation for plain values
        return -float(value_and_grad(jnp.asarray(space.to_u(theta)))[0])

    def is_finite(theta: np.ndarray) -> bool:
        return bool(np.isfinite(log_density(theta)))

    default = default_start(posterior)
    first = default if init is None else _as_theta(init, posterior, default)
    if not is_finite(first):
        where = "init" if init is not None else "the default start"
        raise ValueError(
            f"the log posterior is not finite at {where} "
            f"({', '.join(f'{n}={v:.4g}' for n, v in zip(names, first, strict=True))}); "
            "pass init=... at a point where the model can be evaluated"
        )
    root = jax.random.key(int(seed))
    starts = [first]
    for k in range(1, int(num_starts)):
        starts.append(
            _perturbed_start(
                jax.random.fold_in(root, k), posterior, space, first, start_spread, is_finite
            )
        )

    results = [
        _run_start(theta0, space, value_and_grad, log_density, maxiter, ftol, gtol, maxcor)
        for theta0 in starts
    ]
    hessians: list[np.ndarray | None] = [None] * len(results)
    if compute_hessian:
        for k, r in enumerate(results):
            if np.isfinite(r.log_posterior):
                hessians[k] = np.asarray(fns["hessian"](jnp.asarray(r.theta)), dtype=float)
                results[k] = _judge_with_hessian(r, hessians[k], space, value_and_grad)
    k_best = max(
        range(len(results)),
        key=lambda k: (
            results[k].log_posterior if np.isfinite(results[k].log_posterior) else -np.inf
        ),
    )
    best = results[k_best]
    theta, log_post = best.theta, best.log_posterior
    u_best = space.to_u(theta)
    at_bounds = tuple(n for n, hit in zip(names, space.at_bounds(u_best), strict=True) if hit)

    hessian = covariance = None
    repaired = False
    log_evidence = math.nan
    if compute_hessian:
        hessian = hessians[k_best]
        if hessian is None:
            hessian = np.asarray(fns["hessian"](jnp.asarray(theta)), dtype=float)
        bound_idx = [names.index(n) for n in at_bounds]
        scans = [
            _scan_from_bound(log_density, theta, i, space, u_best, log_post) for i in bound_idx
        ]
        covariance, repaired, log_evidence = _laplace(hessian, log_post, bound_idx, scans)
        if covariance is None:
            if warn:
                warnings.warn(
                    "the Hessian at the MAP has non-finite entries; the covariance falls back "
                    "to a diagonal of (1% of |θ|)² and the evidence is NaN",
                    MapConvergenceWarning,
                    stacklevel=2,
                )
            covariance = np.diag((0.01 * np.maximum(np.abs(theta), 1e-8)) ** 2)
            repaired = True

    if warn and at_bounds:
        desc = []
        for n in at_bounds:
            i = names.index(n)
            lo = space.bounds()[i][0]
            lower_side = lo is not None and abs(u_best[i] - lo) <= 1e-8 * max(1.0, abs(lo))
            bound = space.lower[i] if lower_side else space.upper[i]
            side = "lower" if lower_side else "upper"
            desc.append(f"{n} = {theta[i]:.3g} (its {side} bound is {bound:g})")
        warnings.warn(
            "the MAP sits on a bound: " + "; ".join(desc) + ". The data do not pull these "
            "parameters away from the bound (e.g. no detectable process noise); their Laplace "
            "variance and the Laplace evidence are unreliable.",
            BoundWarning,
            stacklevel=2,
        )
    if warn and not any(r.success for r in results):
        warnings.warn(
            f"no start of the MAP search converged (best: {best.message}); try more starts, "
            "a better init or a larger maxiter",
            MapConvergenceWarning,
            stacklevel=2,
        )
    settings = {
        "num_starts": int(num_starts),
        "start_spread": float(start_spread),
        "positive_floor": float(positive_floor),
        "maxiter": int(maxiter),
        "ftol": float(ftol),
        "gtol": float(gtol),
        "maxcor": int(maxcor),
        "init": init is not None,
    }
    return MapResult(
        theta=theta,
        log_posterior=float(log_post),
        success=bool(best.success),
        message=best.message,
        num_starts=int(num_starts),
        starts=tuple(results),
        hessian=hessian,
        covariance=covariance,
        covariance_repaired=repaired,
        log_evidence=log_evidence,
        param_names=names,
        at_bounds=at_bounds,
        seed=int(seed),
        seconds=time.perf_counter() - t_begin,
        settings=settings,
    )


def _snap_to_floor(
    theta: np.ndarray, log_post: float, space: _Space, log_density: Callable[[np.ndarray], float]
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


def _run_start(
    theta0: np.ndarray,
    space: _Space,
    value_and_grad: Callable,
    log_density: Callable[[np.ndarray], float],
    maxiter: int,
    ftol: float,
    gtol: float,
    maxcor: int,
) -> StartResult:
    """L-BFGS-B from θ0; then the floor snap, and a second run from there if it moved."""
    t0 = time.perf_counter()
    u0 = space.to_u(theta0)
    f0 = float(value_and_grad(jnp.asarray(u0))[0])
    penalty = 1e10 + 1e3 * abs(f0)
    bounds = space.bounds()

    def fun(u: np.ndarray) -> tuple[float, np.ndarray]:
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
            options={
                "maxiter": int(maxiter),
                "ftol": ftol,
                "gtol": gtol,
                "maxcor": int(maxcor),
                "maxfun": 4 * int(maxiter),
            },
        )

    res = search(u0)
    iterations, evaluations = int(res.nit), int(res.nfev)
    theta = np.asarray(space.to_theta(jnp.asarray(res.x)), dtype=float)
    snapped, _ = _snap_to_floor(theta, -float(res.fun), space, log_density)
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


def _judge_with_hessian(
    result: StartResult, hessian: np.ndarray, space: _Space, value_and_grad: Callable
) -> StartResult:
    """Convergence by the Newton decrement ½ gᵀH⁻¹g over the parameters off the bounds.

    The decrement is the log-posterior gain a Newton step would promise: scale-free, unlike
    the gradient, and robust to the small-scale roughness a filter with almost no process
    noise can show. A start converged when L-BFGS-B said so and the decrement is < 1e-3.
    """
    u = space.to_u(result.theta)
    grad_u = np.asarray(value_and_grad(jnp.asarray(u))[1], dtype=float)
    scale = np.where(space.log, result.theta - np.where(space.log, space.lower, 0.0), 1.0)
    free = ~space.at_bounds(u)
    decrement = math.inf
    if np.all(np.isfinite(grad_u)) and np.all(np.isfinite(hessian)):
        g = -(grad_u / scale)[free]  # gradient of log π in θ
        block = hessian[np.ix_(free, free)]
        if g.size == 0:
            decrement = 0.0
        else:
            lam, vecs = np.linalg.eigh(0.5 * (block + block.T))
            top = float(np.max(np.abs(lam)))
            fixed = np.maximum(np.abs(lam), _EIGEN_FLOOR * top if top > 0 else 1.0)
            decrement = 0.5 * float(np.sum((vecs.T @ g) ** 2 / fixed))
    lbfgs_ok = "CONVERGENCE" in result.message.upper() and np.isfinite(result.log_posterior)
    return dataclasses.replace(
        result, success=bool(lbfgs_ok and decrement < 1e-3), newton_decrement=decrement
    )


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


class _BoundScan(NamedTuple):
    """The 1-D density along a parameter that sits on a bound (module docstring, step 1)."""

    log_mass: float  # log ∫ exp(log π − log π*) dθ_j
    variance: float


def _scan_from_bound(
    log_density: Callable[[np.ndarray], float],
    theta: np.ndarray,
    i: int,
    space: _Space,
    u: np.ndarray,
    log_post: float,
    drop: float = 30.0,
    growth: float = 1.1,
    max_points: int = 1000,
) -> _BoundScan:
    lo_u = space.bounds()[i][0]
    lower_side = lo_u is not None and abs(u[i] - lo_u) <= 1e-8 * max(1.0, abs(lo_u))
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
        return _BoundScan(math.nan, math.nan)
    mean = float(np.trapezoid(w * d, d)) / mass
    var = float(np.trapezoid(w * (d - mean) ** 2, d)) / mass
    return _BoundScan(math.log(mass), var)


def _laplace(
    hessian: np.ndarray, log_post: float, bound_idx: Sequence[int], scans: Sequence[_BoundScan]
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
        sym = 0.5 * (block + block.T)
        lam, vecs = np.linalg.eigh(sym)
        top = float(np.max(np.abs(lam)))
        floor = _EIGEN_FLOOR * top if top > 0 else 1.0
        fixed = np.maximum(np.abs(lam), floor)
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


# ----------------------------------------------------------------------------- JSON helpers
def _json_float(x: float) -> float | str:
    x = float(x)
    if math.isfinite(x):
        return x
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")


def _json_list(a: np.ndarray) -> list:
    a = np.asarray(a, dtype=float)
    if a.ndim == 0:
        return _json_float(a)  # type: ignore[return-value]
    return [_json_list(x) if a.ndim > 1 else _json_float(x) for x in a]


def _decode(x: Any) -> Any:
    if isinstance(x, str):
        return _NONFINITE.get(x, x)
    if isinstance(x, Sequence):
        return [_decode(v) for v in x]
    return x


__all__ = [
    "BoundWarning",
    "MapConvergenceWarning",
    "MapResult",
    "StartResult",
    "default_start",
    "find_map",
]
