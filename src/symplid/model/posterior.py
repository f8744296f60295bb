"""The posterior π(θ | Y) ∝ π(θ) L(θ; Y) over a model's parameters (Section II-B.2, eq. 8).

:class:`Posterior` binds a :class:`~.statespace.HamiltonianModel`, one or several observed
trajectories and a prior into one log density over θ::

    θ = [model parameters (coefficients, process var, obs var), x0 of trajectory 0, ...]

The last block exists only when the initial state is learned. Several trajectories share the
model's parameters; each has its own initial state, P0 and t0, and their log-likelihoods
(Theorem 1, by the model's UKF) are summed.

For samplers that need the whole real line, :meth:`Posterior.to_unconstrained` maps each
parameter by its bounds: ``log(θ − a)`` for ``(a, ∞)`` (the variances, a = 0),
``log(b − θ)`` for ``(−∞, b)``, ``logit((θ − a)/(b − a))`` for ``(a, b)`` and the identity
for ``(−∞, ∞)``; :meth:`Posterior.log_density_unconstrained` adds the log-Jacobian.

Learned initial state
---------------------
With ``learn_initial_state=True`` each trajectory's initial state joins θ (names
``x0[k].q1``, …, ``x0[k].p2``) with an independent prior on each component centred on the
first observation y_1 of that trajectory:

* a component the observation operator measures directly (``y_j = c·x_i``, e.g. every
  component for ``"full"`` and the positions for ``"positions"``) is centred on ``y_1j / c``;
* any other component (the momenta of positions-only data, or everything under a nonlinear
  ``h``) is centred on the minimum-norm least-squares solution of ``H x = y_1`` (0 for an
  unmeasured momentum; 0 for a function ``h``) with a prior **three times wider**.

The default prior of the offset from that centre is Normal(0, s) with s the largest standard
deviation over time of the trajectory's observed components (the size of the motion, in the
data's own units; 1 if it cannot be computed): weakly informative, so that the likelihood
decides. Set it with ``initial_state_prior`` (a scale, a prior of the offset, or one prior per
component) or ``PriorSpec(initial_state=...)``; a per-name override in the :class:`PriorSpec`
gives an absolute prior. Given ``x0`` together with ``learn_initial_state=True`` is read as
the centre (every component counted as measured).

The initial covariance P0 then defaults to the model's "known" value (1e-16·I): the initial
state is a parameter, not a random variable of the filter.

``t0=None`` puts the initial state at the **first observation time**: the filter starts there
and y_1 enters through an exact Kalman update of N(x0, P0) (the observation operator
linearised at x0 if it is a function; exact for a linear one). This is the natural choice for
measured data with an unknown initial state, because the prior's centre y_1 then refers to the
same time as the state. The default ``t0=0.0`` is the paper's convention (the first datum one
gap after t = 0).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid.model.data import DataError, Observations
from symplid.model.priors import (
    Laplace,
    Normal,
    Prior,
    PriorSpec,
    as_prior,
    log_density_sum,
)

Array = jax.Array

KNOWN_P0 = 1e-16
"""Diagonal of P0 for a known (or learned) initial state, as in the model."""

UNOBSERVED_SCALE_FACTOR = 3.0
"""How much wider the default initial-state prior is for components y_1 does not measure."""

_LOG_2PI = math.log(2.0 * math.pi)


class _FirstObservation(NamedTuple):
    """y_1 of a trajectory whose initial state sits at the first observation time."""

    y: np.ndarray  # observed components of y_1
    index: np.ndarray  # their positions in y


class _Trajectory(NamedTuple):
    leaves: tuple  # array leaves of the model's prepared data
    first: _FirstObservation | None
    x0: np.ndarray | None  # known initial state (None when learned)
    P0: np.ndarray  # (n, n)


def _state_names(dim: int) -> tuple[str, ...]:
    return tuple(f"q{i + 1}" for i in range(dim)) + tuple(f"p{i + 1}" for i in range(dim))


def _is_array_leaf(leaf: Any) -> bool:
    return isinstance(leaf, np.ndarray | jax.Array)


class Posterior:
    """Log posterior over θ for a model and one or several observed trajectories.

    Parameters
    ----------
    model
        A :class:`~.statespace.HamiltonianModel` (or anything with its ``num_params``,
        ``param_names``, ``num_coefficients``, ``num_process_noise``, ``num_obs_noise``,
        ``state_dim``, ``prepare``, ``log_likelihood``, ``split`` and ``observation_matrix``).
    data
        One :class:`~symplid.model.data.Observations` or a list of them (trajectories sharing θ).
    prior
        A :class:`~symplid.model.priors.PriorSpec`, a mapping read by ``PriorSpec.from_dict``, or
        None for the paper's Laplace(0, 10) and HalfNormal(1).
    x0
        The known initial state, shape ``(2d,)``; for several trajectories a list of them or
        an array ``(K, 2d)``. With ``learn_initial_state=True`` it is optional and is the centre
        of the initial-state prior.
    P0
        Initial covariance (None: 1e-16·I, a known state); a scalar (times I), a diagonal or
        a matrix, shared; or a list or tuple with one entry per trajectory.
    t0
        Time of the initial state (default 0.0, the paper's); None for the first observation
        time (see the module docstring); or a list or tuple with one entry per trajectory.
    learn_initial_state
        Whether each trajectory's initial state joins θ (see the module docstring).
    initial_state_prior
        Prior of the learned initial state's offset from its centre: None (the default rule),
        a number (the scale s of Normal(0, s); unmeasured components get 3 s), a prior of
        the whole real line (unmeasured components get it with a scale three times larger),
        or a sequence of ``2d`` priors, one per component (used as given).

    Attributes
    ----------
    num_params, param_names, param_groups
        Size, names and groups (``coefficients``, ``process_var``, ``obs_var``,
        ``initial_state``) of θ.
    priors
        The resolved absolute prior of each parameter.
    lower, upper
        Bounds of θ (NumPy arrays): the priors' supports, and 0 below every variance.
    log_density, log_likelihood, log_prior, log_density_unconstrained
        Jitted pure functions of θ (or z); compose with ``jit``, ``vmap`` and ``grad``.
        ``log_density`` is −∞ outside the bounds or when the filter fails, never NaN.
    """

    def __init__(
        self,
        model: Any,
        data: Observations | Sequence[Observations],
        prior: PriorSpec | Mapping[str, Any] | None = None,
        x0: Any = None,
        P0: Any = None,
        t0: float | Sequence[float | None] | None = 0.0,
        learn_initial_state: bool = False,
        initial_state_prior: Any = None,
    ) -> None:
        self.model = model
        self.data = data
        self.datasets = _as_datasets(data)
        self.num_trajectories = len(self.datasets)
        self.learn_initial_state = bool(learn_initial_state)
        self.prior = PriorSpec() if prior is None else PriorSpec.from_dict(prior)
        n = int(model.state_dim)
        self.state_dim = n
        self.state_names = _state_names(n // 2)
        K = self.num_trajectories

        self.t0 = _per_trajectory(t0, K, "t0")
        self.P0 = [_as_P0(p, n, k) for k, p in enumerate(_per_trajectory(P0, K, "P0"))]
        x0s = _as_x0(x0, n, K, required=not self.learn_initial_state)

        # ---- layout of θ
        m = int(model.num_params)
        self.num_model_params = m
        nc, nq = int(model.num_coefficients), int(model.num_process_noise)
        groups = ["coefficients"] * nc + ["process_var"] * nq + ["obs_var"] * (m - nc - nq)
        names = list(model.param_names)
        if self.learn_initial_state:
            for k in range(K):
                names += [f"x0[{k}].{s}" for s in self.state_names]
                groups += ["initial_state"] * n
        self.param_names: tuple[str, ...] = tuple(names)
        self.param_groups: tuple[str, ...] = tuple(groups)
        self.num_params = len(names)
        self.prior.check_names(self.param_names)

        # ---- trajectories: prepared data, the first observation when t0 is None
        self._trajectories: list[_Trajectory] = []
        self._static: list[tuple] = []
        for k, obs in enumerate(self.datasets):
            first = None
            if self.t0[k] is None:
                if obs.num_times < 2:
                    raise DataError(
                        f"trajectory {k} has one observation: with t0=None the initial state "
                        "sits at it and at least one more observation is needed"
                    )
                mask = obs.mask[0]
                first = _FirstObservation(obs.values[0][mask], np.flatnonzero(mask))
                rest, start = obs.subset(slice(1, None)), float(obs.times[0])
            else:
                rest, start = obs, float(self.t0[k])
                if not start < obs.times[0]:
                    raise DataError(
                        f"trajectory {k}: t0 = {start:g} must be before its first observation "
                        f"time {obs.times[0]:g} (or pass t0=None to put the initial state there)"
                    )
            prepared = model.prepare(rest, start)
            leaves, treedef = jax.tree_util.tree_flatten(prepared)
            arrays = tuple(jnp.asarray(v) for v in leaves if _is_array_leaf(v))
            static = tuple((i, v) for i, v in enumerate(leaves) if not _is_array_leaf(v))
            key = (treedef, static, tuple((a.shape, a.dtype) for a in arrays), first is None)
            self._static.append((key, len(leaves)))
            self._trajectories.append(
                _Trajectory(arrays, first, None if x0s is None else x0s[k], self.P0[k])
            )

        # ---- priors and bounds
        self._x0_centres: list[np.ndarray] = []
        priors: list[Prior] = []
        for name, group in zip(self.param_names[:m], groups[:m], strict=True):
            priors.append(self.prior.overrides.get(name) or self.prior.group_prior(group))
        if self.learn_initial_state:
            for k in range(K):
                centre, comp = self._initial_state_priors(k, x0s, initial_state_prior)
                self._x0_centres.append(centre)
                for i, p in enumerate(comp):
                    name = f"x0[{k}].{self.state_names[i]}"
                    priors.append(self.prior.overrides.get(name) or p)
        self.priors: tuple[Prior, ...] = tuple(priors)
        lower, upper = [], []
        for name, group, p in zip(self.param_names, groups, priors, strict=True):
            lo, hi = p.support
            if group in ("process_var", "obs_var"):
                lo = max(lo, 0.0)
            if not lo < hi:
                raise ValueError(f"the prior of {name!r} ({p}) gives it no positive values")
            lower.append(lo)
            upper.append(hi)
        self.lower = np.array(lower, dtype=float)
        self.upper = np.array(upper, dtype=float)
        self._reference = jnp.asarray(self._interior_point())

        # ---- compiled functions
        # The observations enter the compiled programs as arguments (``self.data``), not as
        # constants: the same model structure then compiles to the same program for any data
        # set of the same shape, which JAX's persistent compilation cache can serve.
        self.data: tuple[tuple[Array, ...], ...] = tuple(t.leaves for t in self._trajectories)
        self._groups = self._group_trajectories()
        self.log_prior: Callable[[Array], Array] = jax.jit(self._log_prior)
        self._with_data = {
            "log_likelihood": jax.jit(lambda data, t: self._log_likelihood(t, data)),
            "log_density": jax.jit(lambda data, t: self._log_density(t, data)),
            "log_density_unconstrained": jax.jit(
                lambda data, z: self._log_density_unconstrained(z, data)
            ),
        }
        self._vg_cache: dict[str, Callable] = {}

    # ------------------------------------------------------------------ construction helpers
    def _initial_state_priors(
        self, k: int, x0s: list[np.ndarray] | None, spec: Any
    ) -> tuple[np.ndarray, list[Prior]]:
        """Centre and absolute per-component priors of trajectory k's initial state."""
        n = self.state_dim
        obs = self.datasets[k]
        if x0s is not None:
            centre, measured = np.asarray(x0s[k], dtype=float), np.ones(n, dtype=bool)
        else:
            centre, measured = _centre_from_first(self.model, obs, n)
        offsets: list[Prior]
        if spec is None and self.prior.initial_state is not None:
            spec = self.prior.initial_state
        if spec is None or isinstance(spec, int | float | np.number):
            s = _data_scale(obs) if spec is None else float(spec)
            if not (math.isfinite(s) and s > 0):
                raise ValueError(f"initial_state_prior: a scale must be > 0, got {spec!r}")
            offsets = [Normal(0.0, s if m else UNOBSERVED_SCALE_FACTOR * s) for m in measured]
        elif isinstance(spec, Sequence) and not isinstance(spec, str | Mapping):
            if len(spec) != n:
                raise ValueError(
                    f"initial_state_prior: {len(spec)} priors given for a {n}-component state "
                    f"({', '.join(self.state_names)})"
                )
            offsets = [_offset_prior(as_prior(p, "initial_state_prior")) for p in spec]
        else:
            base = _offset_prior(as_prior(spec, "initial_state_prior"))
            wide = dataclasses.replace(base, scale=UNOBSERVED_SCALE_FACTOR * base.scale)
            offsets = [base if m else wide for m in measured]
        return centre, [_shift(p, c) for p, c in zip(offsets, centre, strict=True)]

    def _interior_point(self) -> np.ndarray:
        """A point strictly inside the bounds (prior medians, pulled inside when needed)."""
        out = np.empty(self.num_params)
        for i, p in enumerate(self.priors):
            lo, hi = self.lower[i], self.upper[i]
            v = p.median
            if np.isfinite(lo) and np.isfinite(hi):
                v = min(max(v, lo + 0.25 * (hi - lo)), hi - 0.25 * (hi - lo))
            elif np.isfinite(lo):
                v = max(v, lo + max(p.std, 1e-3))
            elif np.isfinite(hi):
                v = min(v, hi - max(p.std, 1e-3))
            out[i] = v
        return out

    def _group_trajectories(self) -> list[tuple[list[int], Any, int]]:
        """Trajectories with identical shapes are stacked and vmapped through one filter."""
        groups: dict[Any, list[int]] = {}
        for k, (key, _) in enumerate(self._static):
            groups.setdefault(key, []).append(k)
        return [(ks, key, self._static[ks[0]][1]) for key, ks in groups.items()]

    # ------------------------------------------------------------------ pieces of θ
    def model_theta(self, theta: Array) -> Array:
        """The model's parameters (coefficients, variances): the first ``num_model_params``."""
        return jnp.asarray(theta)[..., : self.num_model_params]

    def initial_state_slice(self, k: int = 0) -> slice:
        """Where trajectory k's learned initial state sits in θ."""
        if not self.learn_initial_state:
            raise ValueError("the initial state is known, not part of θ")
        if not 0 <= k < self.num_trajectories:
            raise IndexError(f"trajectory {k} of {self.num_trajectories}")
        start = self.num_model_params + k * self.state_dim
        return slice(start, start + self.state_dim)

    def initial_state(self, theta: Array, k: int = 0) -> Array:
        """Trajectory k's initial state: from θ when learned, else the known x0."""
        if self.learn_initial_state:
            return jnp.asarray(theta)[..., self.initial_state_slice(k)]
        return jnp.asarray(self._trajectories[k].x0)

    # ------------------------------------------------------------------ densities
    def _first_update(
        self, model_theta: Array, first: _FirstObservation, x0: Array, P0: Array
    ) -> tuple[Array, Array, Array]:
        """Condition N(x0, P0) on y_1 (Kalman update): (mean, covariance, log p(y_1))."""
        idx = first.index
        if idx.size == 0:
            return x0, P0, jnp.zeros(())
        matrix = self.model.observation_matrix
        if matrix is not None:
            H = jnp.asarray(np.asarray(matrix)[idx])
            y_hat = H @ x0
        else:
            observe = self.model.observation

            def h(x: Array) -> Array:
                return jnp.ravel(observe(x))[idx]

            y_hat = h(x0)
            H = jax.jacfwd(h)(x0)
        _, _, obs_cov = self.model.split(model_theta)
        R = obs_cov[np.ix_(idx, idx)]
        cross = P0 @ H.T
        S = H @ cross + R
        S = 0.5 * (S + S.T)
        chol = jnp.linalg.cholesky(S)
        v = jnp.asarray(first.y) - y_hat
        w = jax.scipy.linalg.solve_triangular(chol, v, lower=True)
        log_lik = (
            -0.5 * jnp.sum(w * w) - jnp.sum(jnp.log(jnp.diagonal(chol))) - 0.5 * idx.size * _LOG_2PI
        )
        gain = jax.scipy.linalg.cho_solve((chol, True), cross.T).T
        mean = x0 + gain @ v
        A = jnp.eye(self.state_dim) - gain @ H
        cov = A @ P0 @ A.T + gain @ R @ gain.T  # Joseph form: stays positive semi-definite
        return mean, 0.5 * (cov + cov.T), log_lik

    def _trajectory_loglik(self, model_theta: Array, arrays, x0, P0, key, num_leaves, first):
        treedef, static = key[0], key[1]
        leaves: list[Any] = [None] * num_leaves
        it = iter(arrays)
        statics = dict(static)
        for i in range(num_leaves):
            leaves[i] = statics[i] if i in statics else next(it)
        prepared = jax.tree_util.tree_unflatten(treedef, leaves)
        extra = jnp.zeros(())
        if first is not None:
            x0, P0, extra = self._first_update(model_theta, first, x0, P0)
        return self.model.log_likelihood(model_theta, prepared, x0, P0) + extra

    # ------------------------------------------------------------------ public densities
    def log_likelihood(self, theta: Array) -> Array:
        """Σ_k log p(y^(k) | θ) over the trajectories (Theorem 1); jit/vmap/grad-able."""
        return self._with_data["log_likelihood"](self.data, theta)

    def log_density(self, theta: Array) -> Array:
        """log prior + log likelihood; −∞ outside the bounds or when the filter fails."""
        return self._with_data["log_density"](self.data, theta)

    def log_density_unconstrained(self, z: Array) -> Array:
        """The log density of z = to_unconstrained(θ), log-Jacobian included."""
        return self._with_data["log_density_unconstrained"](self.data, z)

    def log_density_with(self, data: Any, theta: Array) -> Array:
        """:meth:`log_density` with the observations passed in (``data`` like ``self.data``).

        Jitting a function of ``(θ, data)`` rather than of θ alone keeps the data out of the
        compiled program as constants (see the constructor).
        """
        return self._log_density(theta, data)

    def _leaves(self, k: int, data: Any) -> Any:
        return self._trajectories[k].leaves if data is None else data[k]

    def _log_likelihood(self, theta: Array, data: Any = None) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        self._check_theta(theta)
        model_theta = theta[: self.num_model_params]
        total = jnp.zeros(())
        for ks, key, num_leaves in self._groups:
            x0s = jnp.stack([self.initial_state(theta, k) for k in ks])
            P0s = jnp.stack([jnp.asarray(self._trajectories[k].P0) for k in ks])
            firsts = [self._trajectories[k].first for k in ks]
            if len(ks) == 1 or any(f is not None for f in firsts):
                for j, k in enumerate(ks):
                    traj = self._trajectories[k]
                    total = total + self._trajectory_loglik(
                        model_theta,
                        self._leaves(k, data),
                        x0s[j],
                        P0s[j],
                        key,
                        num_leaves,
                        traj.first,
                    )
                continue
            stacked = tuple(
                jnp.stack(parts) for parts in zip(*(self._leaves(k, data) for k in ks), strict=True)
            )

            def one(arrays, x0, P0, key=key, num_leaves=num_leaves):
                return self._trajectory_loglik(model_theta, arrays, x0, P0, key, num_leaves, None)

            total = total + jnp.sum(jax.vmap(one)(stacked, x0s, P0s))
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    def _in_bounds(self, theta: Array) -> Array:
        return jnp.all((theta >= self.lower) & (theta <= self.upper), axis=-1)

    def _log_prior(self, theta: Array) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        self._check_theta(theta)
        lp = log_density_sum(self.priors, theta)
        lp = jnp.where(self._in_bounds(theta), lp, -jnp.inf)
        return jnp.where(jnp.isnan(lp), -jnp.inf, lp)

    def _log_density(self, theta: Array, data: Any = None) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        self._check_theta(theta)
        inside = self._in_bounds(theta)
        # Outside the bounds the likelihood is evaluated at a fixed interior point instead, so
        # that nothing there (an overflow, a failed factorisation) can leak NaN into a gradient.
        safe = jnp.where(inside, theta, self._reference)
        total = self._log_prior(safe) + self._log_likelihood(safe, data)
        total = jnp.where(inside, total, -jnp.inf)
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    def _check_theta(self, theta: Array) -> None:
        if theta.ndim != 1 or theta.shape[0] != self.num_params:
            raise ValueError(
                f"θ must have shape ({self.num_params},) ({', '.join(self.param_names)}), "
                f"got {theta.shape}; use jax.vmap for a batch"
            )

    # ------------------------------------------------------------------ unconstrained space
    def _kinds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lo_f, hi_f = np.isfinite(self.lower), np.isfinite(self.upper)
        return lo_f & ~hi_f, ~lo_f & hi_f, lo_f & hi_f, ~lo_f & ~hi_f

    def from_unconstrained(self, z: Array) -> Array:
        """z ∈ ℝᵈ ↦ θ: a + eᶻ, b − eᶻ, a + (b − a)·σ(z) or z, by each parameter's bounds."""
        z = jnp.asarray(z, dtype=float)
        lower_only, upper_only, both, _ = self._kinds()
        lo = np.where(np.isfinite(self.lower), self.lower, 0.0)
        hi = np.where(np.isfinite(self.upper), self.upper, 0.0)
        ez = jnp.exp(jnp.where(lower_only | upper_only, z, 0.0))
        theta = jnp.where(lower_only, lo + ez, z)
        theta = jnp.where(upper_only, hi - ez, theta)
        return jnp.where(both, lo + (hi - lo) * jax.nn.sigmoid(z), theta)

    def to_unconstrained(self, theta: Array) -> Array:
        """θ ↦ z, the inverse of :meth:`from_unconstrained` (±∞ on a bound)."""
        theta = jnp.asarray(theta, dtype=float)
        lower_only, upper_only, both, _ = self._kinds()
        lo = np.where(np.isfinite(self.lower), self.lower, 0.0)
        hi = np.where(np.isfinite(self.upper), self.upper, 0.0)
        width = np.where(both, hi - lo, 1.0)
        z = jnp.where(lower_only, jnp.log(jnp.where(lower_only, theta - lo, 1.0)), theta)
        z = jnp.where(upper_only, jnp.log(jnp.where(upper_only, hi - theta, 1.0)), z)
        u = jnp.where(both, (theta - lo) / width, 0.5)
        return jnp.where(both, jnp.log(u) - jnp.log1p(-u), z)

    def log_abs_det_jacobian(self, z: Array) -> Array:
        """log |det ∂θ/∂z| of :meth:`from_unconstrained` (a sum over the parameters)."""
        z = jnp.asarray(z, dtype=float)
        lower_only, upper_only, both, _ = self._kinds()
        width = np.where(both, self.upper - self.lower, 1.0)
        terms = jnp.where(lower_only | upper_only, z, 0.0)
        logistic = np.log(width) - jax.nn.softplus(z) - jax.nn.softplus(-z)
        terms = jnp.where(both, logistic, terms)
        return jnp.sum(terms, axis=-1)

    def _log_density_unconstrained(self, z: Array, data: Any = None) -> Array:
        z = jnp.asarray(z, dtype=float)
        total = self._log_density(self.from_unconstrained(z), data) + self.log_abs_det_jacobian(z)
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    # ------------------------------------------------------------------ conveniences
    def value_and_grad(self, unconstrained: bool = False) -> Callable[[Array], tuple[Array, Array]]:
        """A jitted ``θ ↦ (log density, gradient)`` (or of z), compiled once and cached."""
        key = "z" if unconstrained else "theta"
        if key not in self._vg_cache:
            fn = self._log_density_unconstrained if unconstrained else self._log_density
            jitted = jax.jit(jax.value_and_grad(fn))
            self._vg_cache[key] = lambda x: jitted(x, self.data)
        return self._vg_cache[key]

    def sample_prior(self, key: Array, num: int) -> np.ndarray:
        """``num`` draws from the independent priors, clipped into the bounds, ``(num, d)``."""
        keys = jax.random.split(key, self.num_params)
        cols = [np.asarray(p.sample(k, (num,))) for p, k in zip(self.priors, keys, strict=True)]
        return np.clip(np.stack(cols, axis=-1), self.lower, self.upper)

    def initial_state_centres(self) -> list[np.ndarray]:
        """The centre of each learned initial state's prior (empty when the state is known)."""
        return [c.copy() for c in self._x0_centres]

    def to_dict(self) -> dict[str, Any]:
        """What defines this posterior apart from the model and the data (JSON-ready)."""
        return {
            "param_names": list(self.param_names),
            "param_groups": list(self.param_groups),
            "priors": {n: p.to_dict() for n, p in zip(self.param_names, self.priors, strict=True)},
            "lower": [float(v) if np.isfinite(v) else None for v in self.lower],
            "upper": [float(v) if np.isfinite(v) else None for v in self.upper],
            "num_trajectories": self.num_trajectories,
            "learn_initial_state": self.learn_initial_state,
            "t0": [None if t is None else float(t) for t in self.t0],
            "x0": [None if t.x0 is None else t.x0.tolist() for t in self._trajectories],
            "P0": [t.P0.tolist() for t in self._trajectories],
        }

    def __repr__(self) -> str:
        learned = ", initial state learned" if self.learn_initial_state else ""
        return (
            f"Posterior({self.num_params} parameters, {self.num_trajectories} "
            f"trajectory(ies){learned})"
        )


# ---------------------------------------------------------------------------- helpers
def _as_datasets(data: Any) -> tuple[Observations, ...]:
    if isinstance(data, Observations):
        return (data,)
    if isinstance(data, Sequence) and not isinstance(data, str):
        out = tuple(data)
        if not out:
            raise DataError("data is an empty list: give at least one Observations")
        for k, obs in enumerate(out):
            if not isinstance(obs, Observations):
                raise TypeError(
                    f"data[{k}] must be a symplid.Observations, got {type(obs).__name__}"
                )
        return out
    raise TypeError(f"data must be an Observations or a list of them, got {type(data).__name__}")


def _per_trajectory(value: Any, K: int, name: str) -> list[Any]:
    """A shared value, or a list/tuple with one entry per trajectory (when K > 1)."""
    if K > 1 and isinstance(value, list | tuple):
        if len(value) != K:
            raise ValueError(f"{name}: {len(value)} entries given for {K} trajectories")
        return list(value)
    if K == 1 and isinstance(value, list | tuple) and name == "t0" and len(value) == 1:
        return list(value)
    return [value] * K


def _as_P0(value: Any, n: int, k: int) -> np.ndarray:
    if value is None:
        return KNOWN_P0 * np.eye(n)
    P0 = np.asarray(value, dtype=float)
    if P0.ndim == 0:
        P0 = float(P0) * np.eye(n)
    elif P0.ndim == 1:
        if P0.shape != (n,):
            raise ValueError(
                f"P0 of trajectory {k}: a diagonal must have {n} entries, got {P0.shape}"
            )
        P0 = np.diag(P0)
    if P0.shape != (n, n):
        raise ValueError(f"P0 of trajectory {k} must be ({n}, {n}), got {P0.shape}")
    if not np.all(np.isfinite(P0)) or not np.allclose(P0, P0.T):
        raise ValueError(f"P0 of trajectory {k} must be finite and symmetric")
    if np.min(np.linalg.eigvalsh(P0)) < 0:
        raise ValueError(f"P0 of trajectory {k} must be positive semi-definite")
    return P0


def _as_x0(value: Any, n: int, K: int, required: bool) -> list[np.ndarray] | None:
    if value is None:
        if required:
            raise ValueError(
                "x0 is required when the initial state is known: pass x0=... "
                "(or learn_initial_state=True to learn it)"
            )
        return None
    if K > 1 and isinstance(value, list | tuple) and len(value) == K:
        arrays = [np.asarray(v, dtype=float) for v in value]
    else:
        arr = np.asarray(value, dtype=float)
        if arr.ndim == 1 and K == 1:
            arrays = [arr]
        elif arr.ndim == 2 and arr.shape[0] == K:
            arrays = list(arr)
        else:
            raise ValueError(
                f"x0 must have shape ({n},) for one trajectory or ({K}, {n}) for {K}, "
                f"got {arr.shape}"
            )
    for k, a in enumerate(arrays):
        if a.shape != (n,):
            raise ValueError(f"x0 of trajectory {k} must have shape ({n},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"x0 of trajectory {k} must be finite, got {a}")
    return arrays


def _centre_from_first(model: Any, obs: Observations, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Prior centre of x0 from y_1, and which components y_1 measures directly."""
    matrix = model.observation_matrix
    measured = np.zeros(n, dtype=bool)
    centre = np.zeros(n)
    if matrix is None:
        return centre, measured
    H = np.asarray(matrix, dtype=float)
    mask = obs.mask[0]
    H, y = H[mask], obs.values[0][mask]
    if H.shape[0] == 0:
        return centre, measured
    centre = np.linalg.pinv(H) @ y
    for j in range(H.shape[0]):
        nz = np.flatnonzero(H[j])
        if nz.size == 1:
            i = nz[0]
            centre[i] = y[j] / H[j, i]
            measured[i] = True
    return centre, measured


def _data_scale(obs: Observations) -> float:
    """The largest standard deviation over time of an observed component (1 if undefined)."""
    with np.errstate(all="ignore"):
        counts = np.sum(obs.mask, axis=0)
        values = np.where(obs.mask, obs.values, np.nan)
        stds = [np.nanstd(values[:, j]) for j in range(obs.dim) if counts[j] >= 2]
    s = max(stds) if stds else float("nan")
    return float(s) if np.isfinite(s) and s > 0 else 1.0


def _offset_prior(prior: Prior) -> Normal | Laplace:
    if not isinstance(prior, Normal | Laplace):
        raise ValueError(
            "initial_state_prior: the prior of the offset from the first observation must be "
            f"normal or laplace (any real value), got {prior}"
        )
    return prior


def _shift(prior: Prior, centre: float) -> Prior:
    return dataclasses.replace(prior, loc=prior.loc + float(centre))  # type: ignore[attr-defined]


__all__ = ["KNOWN_P0", "UNOBSERVED_SCALE_FACTOR", "Posterior"]
