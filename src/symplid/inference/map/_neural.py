"""MAP and a scalable Laplace approximation for potentials with many weights (neural potentials).

:func:`~symplid.inference.map.find_map` runs L-BFGS-B from several starts and takes the exact
autodiff Hessian: right for a polynomial's nine coefficients, too costly for an MLP's thousand
weights. Here, for the same :class:`~symplid.model._posterior.Posterior` (eq. 8: the prior times
the UKF marginal likelihood of Theorem 1):

**MAP** by Optax: Adam for ``adam_steps`` steps, then optionally ``optax.lbfgs`` (with its
zoom line search) to polish. The search runs in the posterior's unconstrained space z
(:meth:`~symplid.model._posterior.Posterior.to_unconstrained`: the variances by their logarithm,
the weights unchanged), so no step leaves the support. The weights' prior is the posterior's
coefficient prior; :func:`neural_posterior` builds the usual Gaussian one, Normal(0, s).

**Laplace covariance** by the generalised Gauss–Newton (Fisher) approximation, in θ space::

    Σ⁻¹ = Σ_k [J_kᵀ S_k⁻¹ J_k + ½ (tr(S_k⁻¹ ∂_i S_k S_k⁻¹ ∂_j S_k))_ij] − ∇² log π(θ)

with ŷ_k = H m_k⁻ and S_k = H P_k⁻ Hᵀ + Γ the UKF's predicted observation mean and covariance
(the log likelihood is Σ_k log N(y_k; ŷ_k(θ), S_k(θ)), Theorem 1) and J_k = ∂ŷ_k/∂θ. It is the
Fisher information of that Gaussian likelihood, i.e. the Hessian with the second derivatives of
ŷ_k and S_k dropped. Why this and not the exact Hessian or its diagonal:

* **cost**: it needs only first derivatives of the filter's moments, one forward-mode pass per
  parameter (or one reverse pass per output, whichever is fewer); the exact Hessian needs
  forward-over-reverse passes through the whole UKF scan, several times dearer each and
  holding the reverse pass's residuals in memory — prohibitive for ~1,000 weights;
* **positive semi-definite by construction**, so the covariance needs no repair; the exact
  Hessian of a network at an approximate optimum (Adam stops before the gradient is zero) is
  often indefinite;
* **correlations kept**: a diagonal approximation would ignore the strong correlations between
  the weights of one unit (a unit's output weight against its input weights), which dominate a
  network's posterior, and the exact diagonal costs as much as the full Hessian in autodiff.

The prior's term is exact (independent priors: a diagonal Hessian). ``laplace="hessian"`` takes
the exact autodiff Hessian instead (small networks; tests compare the two).

Needs a linear observation operator and known initial states at t0 (not learned, not at the
first observation time); the exact Hessian has no such restriction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import cached
from symplid._stopping import check as check_stop
from symplid.inference.map._find import default_start
from symplid.inference.map._result import MapResult, StartResult
from symplid.model._posterior import Posterior
from symplid.model._priors import Normal

Array = jax.Array


@dataclass(frozen=True)
class NeuralMapResult:
    """The MAP point and its Laplace approximation.

    Attributes
    ----------
    theta
        The MAP point, in ``param_names`` order.
    covariance
        The Laplace covariance in θ space, ``(d, d)`` (None when not computed).
    log_posterior
        log π(θ*) + log L(θ*).
    param_names
        Names of θ's entries.
    laplace
        ``"ggn"`` or ``"hessian"`` (how the covariance was computed), or None.
    history
        −log posterior after each optimiser step (Adam, then L-BFGS).
    start
        Where the search started (θ), when known.
    """

    theta: np.ndarray
    covariance: np.ndarray | None
    log_posterior: float
    param_names: tuple[str, ...]
    laplace: str | None = None
    history: np.ndarray = field(default_factory=lambda: np.zeros(0))
    start: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray | None:
        """Laplace standard deviations, √diag(covariance); NaN where a diagonal entry is ≤ 0
        (possible with ``laplace="hessian"`` away from a strict maximum, never with GGN)."""
        if self.covariance is None:
            return None
        diag = np.diag(self.covariance)
        return np.sqrt(np.where(diag > 0, diag, np.nan))

    @property
    def log_evidence(self) -> float:
        """Laplace approximation of log p(Y): log π(θ*) + log L(θ*) + ½ log det(2πΣ) (NaN
        without a covariance, or when Σ is not positive definite)."""
        if self.covariance is None:
            return math.nan
        sign, logdet = np.linalg.slogdet(2.0 * np.pi * self.covariance)
        return self.log_posterior + 0.5 * logdet if sign > 0 else math.nan

    def to_map_result(self, seconds: float = 0.0, seed: int = 0) -> MapResult:
        """The same point as a :class:`~symplid.inference.map._result.MapResult` (one "start"),
        so run folders, samplers and summaries take it like the polynomial MAP."""
        start = StartResult(
            self.theta if self.start is None else self.start, self.theta, self.log_posterior,
            bool(np.isfinite(self.log_posterior)),
            f"Adam then L-BFGS, {self.history.size} steps", int(self.history.size),
            int(self.history.size), float(seconds),
        )
        precision = None if self.covariance is None else np.linalg.inv(self.covariance)
        return MapResult(
            theta=self.theta, log_posterior=self.log_posterior, success=start.success,
            message=start.message, num_starts=1, starts=(start,), hessian=precision,
            covariance=self.covariance, covariance_repaired=False,
            log_evidence=self.log_evidence, param_names=self.param_names, seed=int(seed),
            seconds=float(seconds), settings={"laplace": self.laplace or "none"},
        )


def neural_posterior(
    model: Any, data: Any, x0: Any, weight_scale: float = 1.0, **kwargs: Any
) -> Posterior:
    """A :class:`Posterior` with a Gaussian prior Normal(0, ``weight_scale``) on every weight.

    ``kwargs`` go to :class:`Posterior` (``P0``, ``t0``, ...); a ``prior`` mapping there is
    merged, its ``coefficients`` entry replaced.
    """
    if not (np.isfinite(weight_scale) and weight_scale > 0):
        raise ValueError(f"weight_scale must be a positive number, got {weight_scale!r}")
    prior = dict(kwargs.pop("prior", None) or {})
    prior["coefficients"] = Normal(0.0, float(weight_scale))
    return Posterior(model, data, prior=prior, x0=x0, **kwargs)


def find_map_neural(
    posterior: Posterior,
    init: Any = None,
    *,
    adam_steps: int = 2000,
    learning_rate: float = 1e-2,
    lbfgs_steps: int = 200,
    laplace: str | None = "ggn",
    polish: str = "optax",
) -> NeuralMapResult:
    """MAP by Adam then L-BFGS (Optax), and the Laplace covariance (module docstring).

    Parameters
    ----------
    posterior
        The log posterior (e.g. from :func:`neural_posterior`).
    init
        Start θ; default: the potential's ``initial_coefficients()`` (else the prior medians)
        and :func:`~symplid.inference.map.default_start`'s variances.
    adam_steps, learning_rate
        Adam's number of steps and step size (in the unconstrained space).
    lbfgs_steps
        Steps of L-BFGS after Adam (0 to skip).
    polish
        Which L-BFGS: ``"optax"`` (``optax.lbfgs`` with its zoom line search, compiled as one
        step) or ``"scipy"`` (L-BFGS-B on the posterior's own compiled value and gradient: no
        further compilation, the quicker choice for small networks).
    laplace
        ``"ggn"`` (default), ``"hessian"`` (exact autodiff), or None (no covariance).
    """
    import optax  # lazily, like the neural potentials

    if polish not in ("optax", "scipy"):
        raise ValueError(f"polish must be 'optax' or 'scipy', got {polish!r}")
    if laplace not in ("ggn", "hessian", None):
        raise ValueError(f"laplace must be 'ggn', 'hessian' or None, got {laplace!r}")
    theta0 = _start(posterior) if init is None else np.asarray(init, dtype=float)
    if theta0.shape != (posterior.num_params,):
        raise ValueError(f"init must have shape ({posterior.num_params},), got {theta0.shape}")

    def loss(z: Array) -> Array:
        return -posterior.log_density_unconstrained(z)

    z = jnp.asarray(posterior.to_unconstrained(theta0))
    if not np.isfinite(float(loss(z))):
        raise ValueError("the log posterior is not finite at the start; pass init=...")
    history: list[float] = []
    z = _run_adam(optax, posterior, z, int(adam_steps), float(learning_rate), history)
    if lbfgs_steps > 0 and polish == "optax":
        z = _run_lbfgs(optax, loss, z, int(lbfgs_steps), history)
    elif lbfgs_steps > 0:
        z = _run_scipy(posterior, z, int(lbfgs_steps), history)
    theta = np.asarray(posterior.from_unconstrained(z), dtype=float)
    covariance = None
    if laplace == "ggn":
        covariance = np.linalg.inv(ggn_precision(posterior, theta))
    elif laplace == "hessian":
        hess = jax.hessian(lambda t: -posterior.log_density(t))(jnp.asarray(theta))
        covariance = np.linalg.inv(np.asarray(hess))
    if covariance is not None:
        covariance = 0.5 * (covariance + covariance.T)
    return NeuralMapResult(
        theta, covariance, float(posterior.log_density(jnp.asarray(theta))),
        tuple(posterior.param_names), laplace, np.asarray(history), np.asarray(theta0),
    )


def _start(posterior: Posterior) -> np.ndarray:
    theta = default_start(posterior)
    initial = getattr(posterior.model.hamiltonian, "initial_coefficients", None)
    if callable(initial):
        nc = int(posterior.model.num_coefficients)
        theta[:nc] = np.asarray(initial(), dtype=float)
    return theta


def _run_adam(optax: Any, posterior: Posterior, z: Array, steps: int, learning_rate: float,
              history: list) -> Array:
    """Adam on −log density(z), with the posterior's compiled value and gradient."""
    value_and_grad = posterior.value_and_grad(unconstrained=True)
    opt = optax.adam(learning_rate)
    update = jax.jit(opt.update)
    state = opt.init(z)
    best_z, best = z, np.inf
    for _ in range(steps):
        check_stop()  # a safe point between steps (symplid._stopping)
        value, grad = value_and_grad(z)
        value = -float(value)
        if not np.isfinite(value):
            break
        if value < best:
            best_z, best = z, value
        history.append(value)
        updates, state = update(-grad, state, z)
        z = z + updates
    return best_z


def _run_lbfgs(optax: Any, loss, z: Array, steps: int, history: list):
    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(loss)

    @jax.jit
    def step(z, state):
        value, grad = value_and_grad(z, state=state)
        updates, state = opt.update(grad, state, z, value=value, grad=grad, value_fn=loss)
        return optax.apply_updates(z, updates), state, value

    state = opt.init(z)
    for _ in range(steps):
        check_stop()
        new_z, state, value = step(z, state)
        if not np.isfinite(float(loss(new_z))):
            break
        history.append(float(value))
        z = new_z
    return z


def _run_scipy(posterior: Posterior, z: Array, steps: int, history: list) -> Array:
    """L-BFGS-B on −log density(z) with the posterior's compiled value and gradient."""
    import scipy.optimize

    value_and_grad = posterior.value_and_grad(unconstrained=True)

    def fun(x: np.ndarray) -> tuple[float, np.ndarray]:
        check_stop()
        value, grad = value_and_grad(jnp.asarray(x))
        value = -float(value)
        if not np.isfinite(value):
            return np.inf, np.zeros_like(x)
        history.append(value)
        return value, -np.asarray(grad, dtype=float)

    result = scipy.optimize.minimize(
        fun, np.asarray(z), jac=True, method="L-BFGS-B",
        options={"maxiter": steps, "maxcor": 30, "ftol": 1e-14, "gtol": 1e-8},
    )
    return jnp.asarray(result.x)


def ggn_precision(posterior: Posterior, theta: Any) -> np.ndarray:
    """The generalised Gauss–Newton (Fisher) precision at θ, prior included (module docstring).

    Returns
    -------
    numpy.ndarray
        ``(d, d)``, symmetric positive semi-definite (definite with a proper prior).
    """
    if posterior.learn_initial_state or any(t is None for t in posterior.t0):
        raise NotImplementedError(
            "the Gauss–Newton precision needs known initial states at t0; "
            "use laplace='hessian'"
        )
    matrix = posterior.model.observation_matrix
    if matrix is None:
        raise NotImplementedError(
            "the Gauss–Newton precision needs a linear observation operator; "
            "use laplace='hessian'"
        )
    theta = jnp.asarray(theta, dtype=float)
    m = posterior.num_model_params
    H = jnp.asarray(matrix)
    precision = np.zeros((posterior.num_params, posterior.num_params))
    for k, obs in enumerate(posterior.datasets):
        prepared = posterior.model.prepare(obs, posterior.t0[k])
        x0 = posterior.initial_state(theta, k)
        P0 = jnp.asarray(posterior.P0[k])

        def moments(model_theta, prepared=prepared, x0=x0, P0=P0):
            result = posterior.model.filter(model_theta, prepared, x0, P0)
            y_hat = result.predicted_means @ H.T
            _, _, obs_cov = posterior.model.split(model_theta)
            S_h = jnp.einsum("ij,njk,lk->nil", H, result.predicted_covs, H)
            S = S_h + obs_cov
            if posterior.model.noise_model.multiplicative:  # + diag(r ∘ E[h∘h]), filters.noise
                r = posterior.model.relative_variances(model_theta)
                second = y_hat**2 + jnp.diagonal(S_h, axis1=1, axis2=2)
                S = S + jnp.eye(S.shape[-1]) * (r * second)[:, None, :]
            return y_hat, S

        block = _fisher(moments, theta[:m], np.asarray(obs.mask))
        precision[:m, :m] += block
    precision += np.diag(_prior_curvature(posterior, theta))
    return 0.5 * (precision + precision.T)


def _fisher(moments, model_theta: Array, mask: np.ndarray) -> np.ndarray:
    """Σ_k J_kᵀ S_k⁻¹ J_k + ½ tr(S_k⁻¹ ∂_i S_k S_k⁻¹ ∂_j S_k) over the observed components."""
    num_outputs = mask.size * (1 + mask.shape[1])
    jac = jax.jacrev if num_outputs < model_theta.shape[0] else jax.jacfwd
    _, S = moments(model_theta)
    J_y, J_S = jac(moments)(model_theta)  # (n, d_y, p), (n, d_y, d_y, p)
    w = jnp.asarray(mask, dtype=float)
    both = w[:, :, None] * w[:, None, :]
    # Missing components drop out: their rows of J vanish and S is the identity there.
    S = S * both + jnp.eye(S.shape[-1]) * (1.0 - w)[:, :, None]
    J_y = J_y * w[:, :, None]
    J_S = J_S * both[..., None]
    S_inv = jnp.linalg.inv(S)
    mean_part = jnp.einsum("nap,nab,nbq->pq", J_y, S_inv, J_y)
    A = jnp.einsum("nab,nbcp->nacp", S_inv, J_S)  # S⁻¹ ∂_p S
    cov_part = 0.5 * jnp.einsum("nabp,nbaq->pq", A, A)
    return np.asarray(mean_part + cov_part)


def _prior_curvature(posterior: Posterior, theta: Array) -> np.ndarray:
    """diag(−∇² log π(θ)): the priors are independent, so the Hessian is diagonal.

    One compiled program per posterior: traced eagerly, the product of a thousand weights'
    priors dispatched (and compiled) hundreds of primitives one by one, the dearest part of
    a small network's Laplace step.
    """
    return -np.asarray(cached(posterior, "prior-curvature",
                              lambda: jax.jit(_diagonal_hessian(posterior.log_prior)))(theta))


def _diagonal_hessian(fn):
    """θ ↦ diag ∇²fn(θ) for a sum of independent one-parameter terms (a Hessian-vector
    product with the ones vector)."""
    def diagonal(theta: Array) -> Array:
        _, hvp = jax.jvp(jax.grad(fn), (theta,), (jnp.ones_like(theta),))
        return hvp
    return diagonal


__all__ = ["NeuralMapResult", "find_map_neural", "ggn_precision", "neural_posterior"]
