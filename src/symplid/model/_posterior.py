"""The posterior π(θ | Y) ∝ π(θ) L(θ; Y) over a model's parameters (Section II-B.2, eq. 8).

:class:`Posterior` binds a :class:`~._statespace.HamiltonianModel`, one or several observed
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
linearised at x0 if it is a function; exact for a linear one). A *learned* initial state
with the default P0 (any P0 ≤ 1e-12·I: a point, not a distribution) is updated from
N(x0, P0 + Σ) instead, Σ the process-noise covariance: y_1 then meets the state after one
process-noise increment like every later observation, and enters the likelihood once, with
the variance Σ + Γ. With P0 ≈ 0 alone, x0 would sit on y_1 with Γ on its floor (a
likelihood that grows without bound there while Σ carries the other observations' noise);
a P0 larger than 1e-12 is used as given. This is the natural choice for
measured data with an unknown initial state, because the prior's centre y_1 then refers to the
same time as the state. The default ``t0=0.0`` is the paper's convention (the first datum one
gap after t = 0).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import cached, clear
from symplid.dynamics._potentials import coefficient_name
from symplid.model._data import Observations
from symplid.model._initial_state import (
    KNOWN_P0,
    UNOBSERVED_SCALE_FACTOR,
    FirstObservation,
    as_datasets,
    as_P0,
    as_x0,
    data_scale,
    first_observation_update,
    initial_state_prior,
    is_point_mass,
    per_trajectory,
    split_first,
    state_names,
)
from symplid.model._layout import Block, ParameterLayout
from symplid.model._located_priors import LocatedPriors, located_log_prior
from symplid.model._params import ParameterSpace
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import Prior

Array = jax.Array


class _Trajectory(NamedTuple):
    leaves: tuple  # array leaves of the model's prepared data
    first: FirstObservation | None
    x0: np.ndarray | None  # known initial state (None when learned)
    P0: np.ndarray  # (n, n)


def _is_array_leaf(leaf: Any) -> bool:
    return isinstance(leaf, np.ndarray | jax.Array)


class Posterior:
    """Log posterior over θ for a model and one or several observed trajectories.

    Parameters
    ----------
    model
        A :class:`~._statespace.HamiltonianModel` (or anything with its ``layout``, or
        ``param_names`` and ``param_groups``, and its ``state_dim``, ``prepare``,
        ``log_likelihood``, ``split`` and ``observation_matrix``).
    data
        One :class:`~symplid.model._data.Observations` or a list of them (trajectories sharing θ).
    prior
        A :class:`~symplid.model._prior_spec.PriorSpec`, a mapping read by
        ``PriorSpec.from_dict``, or None for the paper's Laplace(0, 10) and HalfNormal(1).
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
    layout
        θ's :class:`~symplid.model._layout.ParameterLayout`: the model's blocks, then
        ``x0[0]``, ``x0[1]``, … when the initial state is learned.
    space
        The :class:`~symplid.model._params.ParameterSpace` of θ: names, groups, priors, bounds
        and the bijectors to the unconstrained space.
    num_params, param_names, param_groups
        Size, names and groups (``coefficients``, ``process_var``, ``obs_var``,
        ``obs_rel_var``,
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
        self._arguments = {"data": data, "prior": prior, "x0": x0, "P0": P0, "t0": t0,
                           "learn_initial_state": learn_initial_state,
                           "initial_state_prior": initial_state_prior}
        self.datasets = as_datasets(data)
        self.num_trajectories = K = len(self.datasets)
        self.learn_initial_state = bool(learn_initial_state)
        self.prior = PriorSpec() if prior is None else PriorSpec.from_dict(prior)
        self.state_dim = n = int(model.state_dim)
        self.state_names = state_names(n // 2)
        self.t0 = per_trajectory(t0, K, "t0")
        self.P0 = [as_P0(p, n, k) for k, p in enumerate(per_trajectory(P0, K, "P0"))]
        _check_point_start(model, self.P0, self.datasets)
        x0s = as_x0(x0, n, K, required=not self.learn_initial_state)

        names, groups = self._layout()
        self.prior.check_names(list(names))
        self._prepare_trajectories(x0s)
        self.space = ParameterSpace.from_priors(
            names, groups, self._resolve_priors(names, groups, x0s, initial_state_prior)
        )
        self._reference = jnp.asarray(self.space.interior_point())
        # The observations enter the compiled programs as arguments (``self.data``), not as
        # constants: the same model structure then compiles to the same program for any data
        # set of the same shape, which JAX's persistent compilation cache can serve. So do
        # the numbers the data place a learned initial state's prior by (and the interior
        # point that depends on them), after the trajectories: ``data[K]``.
        self._located = LocatedPriors.of(self.space.priors, self._initial_state_entries())
        self.data: tuple[Any, ...] = tuple(t.leaves for t in self._trajectories)
        if self._located is not None:
            self.data += ((jnp.asarray(self._located.loc), jnp.asarray(self._located.scale),
                           self._reference),)
        self._groups = self._group_trajectories()

    def with_model(self, model: Any) -> Posterior:
        """The same data, priors and initial states for another model (e.g. the one with
        process noise beside one without: :mod:`symplid.inference.map._homotopy`)."""
        return Posterior(model, **self._arguments)

    def with_prior(self, prior: PriorSpec) -> Posterior:
        """The same model, data and initial states under other priors (e.g. the paper's
        HalfNormal(1) on Σ beside a log-uniform one: :mod:`symplid.inference.map._homotopy`)."""
        return Posterior(self.model, **{**self._arguments, "prior": prior})

    # ------------------------------------------------------------------ construction steps
    def _layout(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """θ's layout (:mod:`~symplid.model._layout`): the model's blocks, then one block
        ``x0[k]`` (group ``initial_state``) per trajectory when the initial state is learned."""
        model = self.model
        base = getattr(model, "layout", None)
        if not isinstance(base, ParameterLayout):  # a model that states names and groups only
            base = ParameterLayout.from_groups(tuple(model.param_names), model.param_groups)
        self.num_model_params = base.size
        initial = [
            Block(f"x0[{k}]", "initial_state", tuple(f"x0[{k}].{s}" for s in self.state_names))
            for k in range(self.num_trajectories)
        ] if self.learn_initial_state else []
        self.layout = base.extend(initial)
        return self.layout.names, self.layout.groups

    def _prepare_trajectories(self, x0s: list[np.ndarray] | None) -> None:
        """Each trajectory's prepared data (array leaves and a static key), y_1 when t0=None."""
        self._trajectories: list[_Trajectory] = []
        self._static: list[tuple] = []
        for k, obs in enumerate(self.datasets):
            rest, start, first = split_first(obs, self.t0[k], k)
            if first is not None and self.learn_initial_state and is_point_mass(self.P0[k]):
                first = first._replace(process_noise=True)
            leaves, treedef = jax.tree_util.tree_flatten(self.model.prepare(rest, start))
            arrays = tuple(jnp.asarray(v) for v in leaves if _is_array_leaf(v))
            static = tuple((i, v) for i, v in enumerate(leaves) if not _is_array_leaf(v))
            key = (treedef, static, tuple((a.shape, a.dtype) for a in arrays), first is None)
            if first is not None:  # y_1 too is an argument, not a constant (after the rest)
                arrays += (jnp.asarray(first.y, dtype=float),)
            self._static.append((key, len(leaves)))
            self._trajectories.append(
                _Trajectory(arrays, first, None if x0s is None else x0s[k], self.P0[k])
            )

    def _resolve_priors(
        self, names: Sequence[str], groups: Sequence[str], x0s: list[np.ndarray] | None,
        spec: Any,
    ) -> list[Prior]:
        """The absolute prior of every entry of θ (group priors, per-name overrides)."""
        m = self.num_model_params
        priors = [
            self.prior.overrides.get(coefficient_name(name)) or self.prior.group_prior(group)
            for name, group in zip(names[:m], groups[:m], strict=True)
        ]
        self._x0_centres: list[np.ndarray] = []
        if not self.learn_initial_state:
            return priors
        if spec is None and self.prior.initial_state is not None:
            spec = self.prior.initial_state
        for k, obs in enumerate(self.datasets):
            x0 = None if x0s is None else x0s[k]
            centre, comp = initial_state_prior(self.model, obs, x0, spec, self.state_names)
            self._x0_centres.append(centre)
            for i, p in enumerate(comp):
                priors.append(self.prior.overrides.get(f"x0[{k}].{self.state_names[i]}") or p)
        return priors

    def _initial_state_entries(self) -> list[int]:
        """The entries of θ whose prior the data place (a learned initial state's, unless a
        per-name override gives it)."""
        if not self.learn_initial_state:
            return []
        names = self.space.names
        return [i for i in range(self.num_model_params, len(names))
                if names[i] not in self.prior.overrides]

    def _group_trajectories(self) -> list[tuple[list[int], Any, int]]:
        """Trajectories with identical shapes are stacked and vmapped through one filter."""
        groups: dict[Any, list[int]] = {}
        for k, (key, _) in enumerate(self._static):
            groups.setdefault(key, []).append(k)
        return [(ks, key, self._static[ks[0]][1]) for key, ks in groups.items()]

    # ------------------------------------------------------------------ the layout of θ
    @property
    def param_names(self) -> tuple[str, ...]:
        return self.space.names

    @property
    def param_groups(self) -> tuple[str, ...]:
        return self.space.groups

    @property
    def num_params(self) -> int:
        return self.space.size

    @property
    def priors(self) -> tuple[Prior, ...]:
        return self.space.priors  # type: ignore[return-value]

    @property
    def lower(self) -> np.ndarray:
        return self.space.lower

    @lower.setter
    def lower(self, value: Any) -> None:
        self._set_bounds(value, self.upper)

    @property
    def upper(self) -> np.ndarray:
        return self.space.upper

    @upper.setter
    def upper(self, value: Any) -> None:
        self._set_bounds(self.lower, value)

    def _set_bounds(self, lower: Any, upper: Any) -> None:
        """New bounds for θ (the priors stay); what was compiled for the old ones is dropped."""
        self.space = self.space.with_bounds(lower, upper)
        clear(self)

    def model_theta(self, theta: Array) -> Array:
        """The model's parameters (coefficients, variances): the first ``num_model_params``."""
        return jnp.asarray(theta)[..., : self.num_model_params]

    def initial_state_slice(self, k: int = 0) -> slice:
        """Where trajectory k's learned initial state sits in θ (its block ``x0[k]``)."""
        if not self.learn_initial_state:
            raise ValueError("the initial state is known, not part of θ")
        if not 0 <= k < self.num_trajectories:
            raise IndexError(f"trajectory {k} of {self.num_trajectories}")
        return self.layout.slice(f"x0[{k}]")

    def initial_state(self, theta: Array, k: int = 0) -> Array:
        """Trajectory k's initial state: from θ when learned, else the known x0."""
        if self.learn_initial_state:
            return jnp.asarray(theta)[..., self.initial_state_slice(k)]
        return jnp.asarray(self._trajectories[k].x0)

    # ------------------------------------------------------------------ public densities
    def log_likelihood(self, theta: Array) -> Array:
        """Σ_k log p(y^(k) | θ) over the trajectories (Theorem 1); jit/vmap/grad-able."""
        return self._jitted("log_likelihood", self._log_likelihood)(theta, self.data)

    def log_density(self, theta: Array) -> Array:
        """log prior + log likelihood; −∞ outside the bounds or when the filter fails."""
        return self._jitted("log_density", self._log_density)(theta, self.data)

    def log_density_unconstrained(self, z: Array) -> Array:
        """The log density of z = to_unconstrained(θ), log-Jacobian included."""
        fn = self._jitted("log_density_unconstrained", self._log_density_unconstrained)
        return fn(z, self.data)

    def log_prior(self, theta: Array) -> Array:
        """Σ log π_i(θ_i) over the parameters; −∞ outside the bounds."""
        return cached(self, "log_prior", lambda: jax.jit(self._log_prior))(theta)

    def log_density_with(self, data: Any, theta: Array) -> Array:
        """:meth:`log_density` with the observations passed in (``data`` like ``self.data``).

        Jitting a function of ``(θ, data)`` rather than of θ alone keeps the data out of the
        compiled program as constants (see the constructor).
        """
        return self._log_density(theta, data)

    def _jitted(self, name: str, fn: Any) -> Any:
        return cached(self, name, lambda: jax.jit(fn))

    # ------------------------------------------------------------------ densities
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
            first = first._replace(y=arrays[-1])
            x0, P0, extra = first_observation_update(self.model, model_theta, first, x0, P0)
        return self.model.log_likelihood(model_theta, prepared, x0, P0) + extra

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
                    total = total + self._trajectory_loglik(
                        model_theta, self._leaves(k, data), x0s[j], P0s[j], key, num_leaves,
                        firsts[j],
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
        return self.space.in_bounds(theta)

    def _log_prior(self, theta: Array, data: Any = None) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        self._check_theta(theta)
        if self._located is None:
            return self.space.log_prior(theta)
        loc, scale, _ = self._placed(data)
        lp = located_log_prior(self._located, theta, loc, scale)
        lp = jnp.where(self.space.in_bounds(theta), lp, -jnp.inf)
        return jnp.where(jnp.isnan(lp), -jnp.inf, lp)

    def _placed(self, data: Any) -> tuple[Array, Array, Array]:
        """(locations, scales, interior point) of the priors the data place: from ``data``
        (arguments of a compiled program), else this posterior's own."""
        if data is not None and self._located is not None:
            return data[self.num_trajectories]
        located = self._located
        if located is None:
            return jnp.zeros(0), jnp.ones(0), self._reference
        return jnp.asarray(located.loc), jnp.asarray(located.scale), self._reference

    def _log_density(self, theta: Array, data: Any = None) -> Array:
        theta = jnp.asarray(theta, dtype=float)
        self._check_theta(theta)
        inside = self._in_bounds(theta)
        # Outside the bounds the likelihood is evaluated at a fixed interior point instead, so
        # that nothing there (an overflow, a failed factorisation) can leak NaN into a gradient.
        safe = jnp.where(inside, theta, self._placed(data)[2])
        total = self._log_prior(safe, data) + self._log_likelihood(safe, data)
        total = jnp.where(inside, total, -jnp.inf)
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    def _check_theta(self, theta: Array) -> None:
        if theta.ndim != 1 or theta.shape[0] != self.num_params:
            raise ValueError(
                f"θ must have shape ({self.num_params},) ({', '.join(self.param_names)}), "
                f"got {theta.shape}; use jax.vmap for a batch"
            )

    # ------------------------------------------------------------------ unconstrained space
    def from_unconstrained(self, z: Array) -> Array:
        """z ∈ ℝᵈ ↦ θ by each parameter's bijector (:class:`~._params.ParameterSpace`)."""
        return self.space.from_unconstrained(z)

    def to_unconstrained(self, theta: Array) -> Array:
        """θ ↦ z, the inverse of :meth:`from_unconstrained` (±∞ on a bound)."""
        return self.space.to_unconstrained(theta)

    def log_abs_det_jacobian(self, z: Array) -> Array:
        """log ``|det ∂θ/∂z|`` of :meth:`from_unconstrained` (a sum over the parameters)."""
        return self.space.log_abs_det_jacobian(z)

    def _log_density_unconstrained(self, z: Array, data: Any = None) -> Array:
        z = jnp.asarray(z, dtype=float)
        space = self.space
        total = self._log_density(space.from_unconstrained(z), data)
        total = total + space.log_abs_det_jacobian(z)
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    # ------------------------------------------------------------------ conveniences
    def value_and_grad(self, unconstrained: bool = False) -> Any:
        """A jitted ``θ ↦ (log density, gradient)`` (or of z), compiled once and cached."""
        fn = self._log_density_unconstrained if unconstrained else self._log_density
        jitted = cached(self, ("value_and_grad", bool(unconstrained)),
                        lambda: jax.jit(jax.value_and_grad(fn)))
        return lambda x: jitted(x, self.data)

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


def _check_point_start(model: Any, P0s: list[np.ndarray], datasets: list[Observations]) -> None:
    """A model without process noise follows one path from a point: refuse a spread P0.

    Its likelihood (:mod:`symplid.model._deterministic`) starts from the mean x0 and does not
    read P0, so a P0 that is not negligible would be silently ignored: an error. Negligible
    is relative to the size of the motion s (:func:`~._initial_state.data_scale`, the largest
    sd over time of an observed component), so that the check does not depend on units:
    every entry at most :data:`_POINT_P0` · s².
    """
    if not getattr(model, "deterministic", False):
        return
    scale = max(data_scale(obs) for obs in datasets)
    largest = max(float(np.max(np.abs(p))) for p in P0s)
    if largest > _POINT_P0 * scale**2:
        raise ValueError(
            f"process_noise_per='none' integrates one path from a point initial state, but P0 "
            f"has entries up to {largest:.3g}; use a known x0 with P0 ≈ 0 (p0_var ≤ "
            f"{_POINT_P0 * scale**2:.3g}, the default 1e-16 is fine) or learn the initial state"
        )


_POINT_P0 = 1e-8
"""The largest P0 entry a deterministic-likelihood posterior accepts, relative to the square
of the data's scale (a start whose spread is 1e-4 of the motion's size is a point)."""

__all__ = ["KNOWN_P0", "UNOBSERVED_SCALE_FACTOR", "Posterior"]
