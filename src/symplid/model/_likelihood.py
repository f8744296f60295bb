"""The UKF log marginal likelihood of the state-space model, as free functions (Theorem 1).

For the model of eq. (7),

    X_k = Ψ(X_{k−1}; θ_Ψ) + ξ_k,   Y_k = h(X_k) + η_k,

(or Y_k = h(X_k)∘(1 + ε_k) (+ η_k), the multiplicative models of
:mod:`symplid.filters._noise`, whose update replaces Γ by R_k = Γ + diag(r ∘ E[h∘h])),
the likelihood of the observations is computed by the unscented Kalman filter of eqs (10)–(12)
with Ψ the integrator over each gap (eq. 14). Everything here is a pure function of the
parameters θ and the prepared data: ``jit``-, ``vmap``- and ``grad``-able, no state::

    ll = log_likelihood(model, theta, prepared, x0, P0)
    result = filter_result(model, theta, prepared, x0, P0)   # the moments too

:class:`~symplid.model._statespace.HamiltonianModel` only delegates to these (it caches the
compiled program and picks a backend). The pieces come from the filters layer: the prediction
(:func:`~symplid.filters._unscented.unscented_predict`), the observation moments, the update and
the recursion (:func:`~symplid.filters._update.run_filter`).

This module also defines the JAX reference as a likelihood backend, :data:`JAX_BACKEND`,
which :mod:`symplid.model._backends` registers as ``"jax"``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._forced import at_gap
from symplid.dynamics._potentials import inverse_mass
from symplid.dynamics._trajectory import propagate
from symplid.filters import (
    FilterResult,
    ObservationMoments,
    UnscentedWeights,
    cholesky,
    observation_moments_linear,
    observation_moments_unscented,
    run_filter,
    unscented_predict,
    unscented_weights,
)
from symplid.filters._backends import LikelihoodBackend
from symplid.filters._noise import ObservationNoise
from symplid.model._deterministic import bind_model_dynamics, build_trajectory_likelihood

Array = jax.Array
FilterFn = Callable[..., FilterResult]

__all__ = [
    "JAX_BACKEND",
    "ForcedGapInputs",
    "GapInputs",
    "PreparedData",
    "StateSpaceModel",
    "bind_model_dynamics",
    "build_filter",
    "filter_result",
    "log_likelihood",
]


class GapInputs(NamedTuple):
    """What the propagator needs for each gap: substep size and number of substeps."""

    step_size: Array  # (n,)
    num_steps: Array  # (n,) int


class ForcedGapInputs(NamedTuple):
    """A forced model's gaps: their substeps and the inputs at the integrator's nodes
    (:func:`~symplid.model._inputs.node_table`)."""

    step_size: Array  # (n,)
    num_steps: Array  # (n,) int
    times: Array  # (n, S, K): the nodes' times, substep by substep
    inputs: Array  # (n, S, K, m): u there


class PreparedData(NamedTuple):
    """Observations turned into arrays for the compiled filter (built once per data set)."""

    inputs: GapInputs | ForcedGapInputs
    ys: Array
    masks: Array
    max_steps: int
    uniform_steps: bool  # every gap has max_steps substeps (no masking needed)


class StateSpaceModel(Protocol):
    """What the likelihood reads from a model (:class:`symplid.HamiltonianModel` has it all)."""

    hamiltonian: Any
    integrator: Any
    mass: Any
    observation: Any
    process_noise_per: Literal["gap", "step", "none"]
    alpha: float
    beta: float
    kappa: float
    jitter: float
    unroll: int

    @property
    def state_dim(self) -> int: ...

    @property
    def num_coefficients(self) -> int: ...

    @property
    def num_dynamics_params(self) -> int: ...

    @property
    def observation_matrix(self) -> np.ndarray | None: ...

    @property
    def noise_model(self) -> ObservationNoise:
        """The observation-noise model (:mod:`symplid.filters._noise`): additive Γ, or with a
        multiplicative term R_k = Γ + diag(r ∘ E[h∘h])."""
        ...

    def split(self, theta: Array) -> tuple[Array, Array, Array]: ...

    def noise_covariance(self, theta: Array) -> Array | Callable[..., Array]:
        """The update's observation covariance at θ: Γ, or for a multiplicative
        :attr:`noise_model` a function of the predicted observation moments giving R_k."""
        ...



def filter_result(
    model: StateSpaceModel, theta: Array, prepared: PreparedData, x0: Array, P0: Array
) -> FilterResult:
    """Run the UKF for ``model`` at θ on prepared data: log-likelihood and moments.

    Parameters
    ----------
    model
        The state-space model (static: it fixes the program).
    theta
        Parameters ``[coefficients of U, (γ,) process variance(s), observation variance(s),
        relative observation variance(s)]`` (γ for a damped model only, the last for
        multiplicative noise only);
        may be traced.
    prepared
        Data from :meth:`HamiltonianModel.prepare` (concrete: it fixes the substep counts).
    x0, P0
        Mean ``(n,)`` and covariance ``(n, n)`` of the initial state at t0; may be traced.

    Returns
    -------
    FilterResult
        ``log_likelihood`` is log p(y_1..n | θ) (Theorem 1), −∞ when a variance is not
        positive or the filter fails; the filtered and predicted moments per observation.
    """
    fn = build_filter(model, prepared.max_steps, prepared.uniform_steps)
    return fn(theta, prepared.inputs, prepared.ys, prepared.masks, x0, P0)


def log_likelihood(
    model: StateSpaceModel, theta: Array, prepared: PreparedData, x0: Array, P0: Array
) -> Array:
    """log p(y_1..n | θ) by the UKF (Theorem 1, eqs 10–12); −∞ for invalid θ or a failure.

    The JAX reference; see :func:`filter_result` for the arguments.
    """
    return filter_result(model, theta, prepared, x0, P0).log_likelihood


def build_filter(model: StateSpaceModel, max_steps: int, uniform_steps: bool) -> FilterFn:
    """The filter as ``fn(theta, inputs, ys, masks, x0, P0) -> FilterResult`` (not jitted).

    ``max_steps`` and ``uniform_steps`` come from the prepared data: the most substeps in
    one gap, and whether every gap has that many (then no substep is masked).
    A model without process noise (``process_noise_per="none"``) gets the exact
    deterministic-trajectory likelihood instead (:mod:`symplid.model._deterministic`): no
    filter, the same signature and result type.
    """
    if model.process_noise_per == "none":
        return build_trajectory_likelihood(model, max_steps, uniform_steps)
    weights = unscented_weights(model.state_dim, model.alpha, model.beta, model.kappa)
    moments = _observation_moments(model, weights)
    nc = model.num_dynamics_params  # θ_Ψ: the coefficients, and γ for a damped model

    def filter_fn(theta, inputs, ys, masks, x0, p0) -> FilterResult:
        # Invalid variances give −∞; meanwhile the filter runs on their absolute values (a
        # nearby valid point) so that no NaN reaches the gradient through the discarded branch.
        variances = theta[nc:]
        variances_ok = jnp.all(variances > 0)
        theta = theta.at[nc:].set(jnp.where(variances > 0, variances, jnp.abs(variances) + 1e-12))
        _, proc, obs = model.split(theta)
        inv_mass = inverse_mass(model.mass, model.hamiltonian.dim)
        dynamics = bind_model_dynamics(model, theta, inv_mass)
        predict = _prediction(model, dynamics, proc, weights, max_steps, uniform_steps)
        if _multiplicative(model):  # Γ replaced by R_k(ŷ, S_h) (symplid.filters._noise)
            obs = model.noise_covariance(theta)
        result = run_filter(predict, moments, x0, p0, inputs, ys, masks, obs)
        ll = jnp.where(variances_ok, result.log_likelihood, -jnp.inf)
        return result._replace(log_likelihood=ll)

    return filter_fn


def _multiplicative(model: StateSpaceModel) -> bool:
    """Whether the model's observation noise has a multiplicative term."""
    return bool(model.noise_model.multiplicative)


def _observation_moments(
    model: StateSpaceModel, weights: UnscentedWeights
) -> Callable[[Array, Array], ObservationMoments]:
    """``(m⁻, P⁻) -> (ŷ, S, C)``: exact for a linear h, unscented for a function."""
    matrix = model.observation_matrix
    if matrix is not None:
        h = np.asarray(matrix)  # a constant: built outside any trace

        def linear(m, p) -> ObservationMoments:
            return observation_moments_linear(m, p, h)

        return linear
    observe = model.observation

    def unscented(m, p) -> ObservationMoments:
        return observation_moments_unscented(m, p, lambda x: jnp.ravel(observe(x)), weights)

    return unscented


def _prediction(
    model: StateSpaceModel,
    dynamics,
    proc: Array,
    weights: UnscentedWeights,
    max_steps: int,
    uniform_steps: bool,
) -> Callable[[Array, Array, object], tuple[Array, Array]]:
    """Eq. (10) over one gap: ``predict(m, L, inputs_k) -> (m⁻, P⁻)``.

    Sigma points travel as one ``(2d, 2n+1)`` array of columns, so every substep is
    elementwise over the points. With ``process_noise_per="gap"`` (the default) the points
    are pushed through all the gap's substeps and Σ is added once; with ``"step"`` the
    unscented prediction (and Σ) is repeated after every substep.
    """
    d = model.hamiltonian.dim
    integrator = model.integrator
    jitter = model.jitter

    if model.process_noise_per == "step":

        def step_points(points, step_size):
            q, p = integrator.step(dynamics, points[:d], points[d:], step_size)
            return jnp.concatenate([q, p])

        def predict_per_step(m, chol, inp):
            def body(i, carry):
                mi, li, pi = carry
                mn, pn, _ = unscented_predict(
                    mi, li, lambda pts: step_points(pts, inp.step_size), proc, weights, jitter
                )
                active = i < inp.num_steps
                return (
                    jnp.where(active, mn, mi),
                    jnp.where(active, cholesky(pn), li),
                    jnp.where(active, pn, pi),
                )

            m, _, p = jax.lax.fori_loop(0, max_steps, body, (m, chol, chol @ chol.T))
            return m, p

        return predict_per_step

    def propagate_points(dynamics, points, step_size, num_steps):
        q, p = propagate(
            integrator,
            dynamics,
            points[:d],
            points[d:],
            step_size,
            num_steps,
            max_steps,
            model.unroll,
            masked=not uniform_steps,
        )
        return jnp.concatenate([q, p])

    def predict_per_gap(m, chol, inp):
        if isinstance(inp, ForcedGapInputs):  # this gap's inputs at the integrator's nodes
            gap_dynamics = at_gap(dynamics, inp.times, inp.inputs)
        else:
            gap_dynamics = dynamics
        mn, pn, _ = unscented_predict(
            m,
            chol,
            lambda pts: propagate_points(gap_dynamics, pts, inp.step_size, inp.num_steps),
            proc,
            weights,
            jitter,
        )
        return mn, pn

    return predict_per_gap


def _jax_supports(model: StateSpaceModel, prepared: PreparedData | None) -> str | None:
    return None  # the reference handles every model


def _jax_build(model: StateSpaceModel, prepared: PreparedData) -> FilterFn:
    return build_filter(model, prepared.max_steps, prepared.uniform_steps)


#: The JAX reference: every model, the filtered moments as well as the log-likelihood.
JAX_BACKEND = LikelihoodBackend(
    name="jax",
    supports=_jax_supports,
    build=_jax_build,
    filtered_moments=True,
    priority=0,
    description="the JAX reference UKF (every model; jit, vmap and grad)",
)
