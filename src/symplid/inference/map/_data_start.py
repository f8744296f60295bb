"""Starting values and scales of the MAP search from the data (a smoothed path and collocation).

The MAP search needs a start near the answer and steps on each parameter's own scale. Neither
can come from the prior alone: a default prior such as Laplace(0, 10) knows nothing of the
units, and a gravitational parameter is 3e-4 in AU³/day² but 39.5 in AU³/yr². This module
reads both from the data, in three cheap steps that use no filter:

1. **Smoothed path.** Each measured component's noise variance is estimated without a model
   (:func:`~symplid.inference.map._noise.noise_variance`: the smaller of difference estimators
   and a cross-validated smoothing spline, which also follows a few clumped points along a
   curved path). Each measured position component of each trajectory is then
   fitted by a cubic smoothing spline (:func:`scipy.interpolate.make_smoothing_spline`) whose
   roughness penalty is set so that its mean squared residual equals that variance (the
   discrepancy principle, solved for log λ by Brent's method; cross-validation interpolates a
   coarsely sampled orbit). The spline gives the path q(t) and the velocity q̇(t) at the
   observation times.
2. **Collocation fit.** With the smoothed q_i and q̇_i at the observation times t_i held
   fixed, the dynamic parameters φ (the potential's or Hamiltonian's coefficients and a
   damping rate) and the unobserved momenta p_i are fitted together by nonlinear least
   squares (trust-region reflective, exact Jacobian by JAX) to Hamilton's equations::

       q̇_i − ∂H/∂p(q_i, p_i; φ)                                  (velocity residual)
       p_{i+1} − p_i − ½ h_i [g(q_i, p_i) + g(q_{i+1}, p_{i+1})]   (trapezoidal momentum step)

   with g = −∂H/∂q − γ ∂H/∂p (γ: the damping rate of a damped model), h_i = t_{i+1} − t_i,
   each residual divided by the typical size of its term; measured momenta add
   p_i − y_i residuals. A long record is thinned evenly to at most :data:`~._paths.MAX_NODES` nodes.
   The fit starts at the prior medians and p_i = q̇_i. The positions being held fixed, a
   separable H whose potential is linear in its parameters (Kepler's GM, a polynomial)
   makes every residual linear in (φ, p): one linear least-squares problem; a general H
   gives a small nonlinear one. The residuals, their Jacobian and the force g are one
   compiled program whose arguments are the data (:func:`_collocation_program`).
3. **Scales.** The least-squares covariance s²(JᵀJ)⁻¹ gives each parameter's standard error.
   Starts after the first are spread by max(3 × that error, 10 % of the value) for the dynamic
   parameters, by the noise's standard deviation (positions) and the momenta's standard
   error (momenta) for a learned initial state, and by a factor exp(N(0, 1)) for the
   variances.

Sparse samples of an oscillation (a few per period, at uneven times) defeat the spline,
which flattens what it cannot follow. The **spectral** data start (``smoother="spectral"``)
reads the path as a sum of sinusoids with frequencies from the data's periodogram
(:mod:`._spectral`) and, the path being exact between the observations, collocates on nodes
between them too.

The noise variances start from the data: each observation variance at its difference
estimate, the process variance at the mean squared defect of the collocation's momentum step
(what the fitted dynamics leave unexplained over one gap). A learned initial state starts on
the smoothed path at t0 with the fitted momentum (one trapezoidal step back when t0 < t_1).

The method needs a linear observation operator that measures every position directly (rows
of the form y_j = c·q_i), at least five observations per trajectory, and a separable or
non-separable H that the model can evaluate; otherwise :func:`data_start` returns None and
:func:`~symplid.inference.map._starts.default_start` is used.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from symplid.inference.map._paths import SMOOTHERS, Smoothed, position_rows, smoothed_paths
from symplid.inference.map._starts import default_start
from symplid.model._params import USER_GROUP

Array = jax.Array
COEFFICIENT_GROUPS = ("coefficients", USER_GROUP)
"""Groups of the dynamics' coefficients: a built-in family's, a user model's declared ones."""
DYNAMIC_GROUPS = (*COEFFICIENT_GROUPS, "damping")


@dataclass(frozen=True)
class DataStart:
    """A start of the MAP search read from the data.

    Attributes
    ----------
    theta
        The start (every parameter of the posterior).
    scale
        Spread of the further starts per parameter, in θ's units (NaN for the variances,
        which are perturbed by a factor).
    noise_var
        Model-free observation-noise variance per observed component (mean over the
        trajectories), by :func:`~symplid.inference.map._noise.noise_variance`.
    data_var
        Variance of the data over time, averaged over the components.
    rate
        The fastest rate of the fitted motion (:func:`fastest_rate`): the largest modulus of
        an eigenvalue of the flow's Jacobian ∂ẋ/∂x at the collocation's nodes, in 1/time
        (ω for an oscillation of angular frequency ω); NaN when it cannot be computed.
        Computed when first read (a compiled Jacobian: the MAP's starts do not need it).
    """

    theta: np.ndarray
    scale: np.ndarray
    noise_var: np.ndarray
    data_var: float
    _rate_of: Callable[[], float] = field(default=lambda: math.nan, repr=False, compare=False)

    @functools.cached_property
    def rate(self) -> float:
        return self._rate_of()


# ----------------------------------------------------------------------------- collocation
def _vector_field(model: Any):
    """(∂H/∂p, g = −∂H/∂q − γ ∂H/∂p) at a batch of states, for model parameters θ_m."""

    def field(theta_m: Array, x: Array) -> tuple[Array, Array]:
        grad = jax.vmap(jax.grad(lambda s: model.energy(theta_m, s)))(x)
        d = x.shape[-1] // 2
        velocity = grad[:, d:]
        gamma = model.damping_rate(theta_m) if getattr(model, "damping", False) else 0.0
        return velocity, -grad[:, :d] - gamma * velocity

    return field


def _collocation_program(model: Any, dyn: np.ndarray, d: int) -> Callable:
    """One compiled program (z, base, scales, data) ↦ (the stacked, scaled collocation
    residuals, their Jacobian in z, g at the nodes of each path), z = (φ, p of every path).

    The data (smoothed path, gaps, measured momenta and where they are) and the scales are
    arguments, not constants of the program: another data set of the same shape runs the
    same program (from the persistent compilation cache in a new process). The residuals
    are the Jacobian's primal output, and g at the fit's end gives the momentum-step defects,
    so no second program is compiled."""
    field = _vector_field(model)
    num_dyn = dyn.size

    def residuals(z: Array, base_m: Array, scales: Array, data: tuple) -> tuple[Array, Any]:
        v_scale, a_scale = scales[0], scales[1]
        theta_m = base_m.at[dyn].set(z[:num_dyn])
        out, gs, offset = [], [], num_dyn
        for q, qdot, h, p_obs, measured in data:
            p = z[offset: offset + q.size].reshape(-1, d)
            offset += q.size
            velocity, g = field(theta_m, jnp.concatenate([q, p], axis=1))
            out.append(((qdot - velocity) / v_scale).ravel())
            step = p[1:] - p[:-1] - 0.5 * h * (g[1:] + g[:-1])
            out.append((step / (h * a_scale)).ravel())
            out.append(((p - p_obs) / v_scale).ravel()[measured])
            gs.append(g)
        r = jnp.concatenate(out)
        return r, (r, gs)

    def program(z: Array, base_m: Array, scales: Array, data: tuple):
        jac, (r, gs) = jax.jacfwd(residuals, has_aux=True)(z, base_m, scales, data)
        return r, jac, gs

    return jax.jit(program)


def _collocation_data(paths: list[Smoothed]) -> tuple[np.ndarray, tuple]:
    """(velocity and acceleration scales, each path's (q, q̇, gaps, measured p, flat indices
    of the measured p)) for :func:`_collocation_program`."""
    v_scale = max(float(np.sqrt(np.mean(np.concatenate([p.qdot for p in paths]) ** 2))), 1e-300)
    a_scale = max(v_scale / float(np.median(np.concatenate([np.diff(p.times) for p in paths]))),
                  1e-300)
    data = tuple((p.q, p.qdot, np.diff(p.times)[:, None], np.nan_to_num(p.p_obs),
                  np.flatnonzero(np.isfinite(p.p_obs))) for p in paths)
    return np.array([v_scale, a_scale]), data


def _evaluator(program: Callable, *args: Any) -> Callable[[np.ndarray], tuple]:
    """z ↦ the program's (residuals, Jacobian, g per path) as NumPy arrays, the last point's
    kept: the least-squares search asks for the residuals and then the Jacobian at a point."""
    last: dict[str, Any] = {}

    def at(z: np.ndarray) -> tuple:
        key = np.asarray(z, dtype=float).tobytes()
        if last.get("key") != key:
            r, jac, gs = program(jnp.asarray(z, dtype=float), *args)
            last.update(key=key, value=(np.asarray(r), np.asarray(jac),
                                        [np.asarray(g) for g in gs]))
        return last["value"]

    return at


def _collocate(posterior: Any, paths: list[Smoothed], base: np.ndarray):
    """(φ, momenta per path, standard errors of z, momentum-step defect variance) or None."""
    groups = tuple(posterior.param_groups)
    dyn = np.array([i for i, g in enumerate(groups) if g in DYNAMIC_GROUPS], dtype=int)
    program = _collocation_program(posterior.model, dyn, paths[0].q.shape[1])
    scales, data = _collocation_data(paths)
    at = _evaluator(program, base[: posterior.model.num_params], scales, data)
    z0 = np.concatenate([base[dyn]] + [p.qdot.ravel() for p in paths])
    lower = np.concatenate([posterior.lower[dyn], np.full(z0.size - dyn.size, -np.inf)])
    upper = np.concatenate([posterior.upper[dyn], np.full(z0.size - dyn.size, np.inf)])
    with np.errstate(all="ignore"):
        try:
            fit = scipy.optimize.least_squares(
                lambda z: at(z)[0].copy(), np.clip(z0, lower, upper), jac=lambda z: at(z)[1].copy(),
                bounds=(lower, upper), method="trf", x_scale="jac", max_nfev=200)
        except (ValueError, np.linalg.LinAlgError):
            return None
    if not (np.all(np.isfinite(fit.x)) and np.isfinite(fit.cost)):
        return None
    z = fit.x
    dof = max(fit.fun.size - z.size, 1)
    s2 = 2.0 * fit.cost / dof
    with np.errstate(all="ignore"):
        cov = s2 * np.linalg.pinv(fit.jac.T @ fit.jac)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    momenta, defects, offset = [], [], dyn.size
    for p, g in zip(paths, at(z)[2], strict=True):
        mom = z[offset: offset + p.q.size].reshape(-1, p.q.shape[1])
        offset += p.q.size
        h = np.diff(p.times)[:, None]
        defects.append((mom[1:] - mom[:-1] - 0.5 * h * (g[1:] + g[:-1])).ravel())
        momenta.append((mom, g))
    return dyn, z[: dyn.size], momenta, stderr, float(np.mean(np.concatenate(defects) ** 2))


# ----------------------------------------------------------------------------- the start
def data_start(posterior: Any, default: np.ndarray,
               is_finite: Callable[[np.ndarray], bool] | None = None,
               smoother: str = "spline") -> DataStart | None:
    """A MAP start and per-parameter scales read from the data (module docstring), or None
    when the model or the data do not allow it. ``default`` supplies what the data cannot
    (e.g. relative variances) and the centre of the collocation's first step; ``is_finite``
    (θ ↦ whether log π is finite there) lets a parameter lifted off its bound be brought
    back towards it until the start can be evaluated (:func:`_lift_off_bound`).
    ``smoother`` (:data:`~._paths.SMOOTHERS`) reads the path: ``"spline"``, smoothing splines to the
    noise estimate; ``"rough"``, splines that follow the data to :data:`~._paths.ROUGHER` of it (and
    the observation variances start there), the start of a fast motion that the estimate's
    spline smooths away; ``"spectral"``, a sum of sinusoids through sparse samples of an
    oscillation (:mod:`._spectral`), collocated between the observations too."""
    model = getattr(posterior, "model", None)
    if model is None or not getattr(posterior, "datasets", None) or not hasattr(
            model, "hamiltonian"):
        return None
    found = position_rows(model)
    if found is None:
        return None
    if smoother not in SMOOTHERS:
        raise ValueError(f"smoother must be one of {', '.join(map(repr, SMOOTHERS))}, "
                         f"got {smoother!r}")
    smoothed = smoothed_paths(posterior, *found, smoother)
    if smoothed is None:
        return None
    paths, noise_var = smoothed
    try:  # a start is a heuristic: a model it cannot read falls back to the default start
        colloc = _collocate(posterior, paths, np.asarray(default, dtype=float))
    except (TypeError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    if colloc is None:
        return None
    dyn, phi, momenta, stderr, defect = colloc
    data_var = _data_var(posterior)
    theta = np.array(default, dtype=float)
    scale = np.full(theta.size, np.nan)
    theta[dyn] = phi
    scale[dyn] = np.maximum(3.0 * stderr[: dyn.size], 0.1 * np.abs(phi))
    lift = _lift_off_bound(posterior, dyn, phi, scale[dyn], np.asarray(default)[dyn])
    _set_variances(posterior, theta, noise_var, defect, data_var)
    if getattr(posterior, "learn_initial_state", False):
        _set_initial_states(posterior, theta, scale, paths, momenta, noise_var)
    lower, upper = np.asarray(posterior.lower), np.asarray(posterior.upper)
    theta = np.clip(theta, lower, upper)
    if not np.all(np.isfinite(theta)):
        return None
    return DataStart(_lifted(theta, dyn, lift, is_finite), scale, noise_var, data_var,
                     functools.partial(_rate, model, theta[: model.num_params].copy(), paths,
                                       momenta))


def _rate(model: Any, theta_m: np.ndarray, paths: list[Smoothed], momenta: list) -> float:
    """The largest |eigenvalue| of the flow's Jacobian at the collocation's nodes (the states
    (q, p) of the smoothed paths with the fitted momenta), at model parameters θ_m."""
    field = _vector_field(model)

    def jacobians(th: Array, x: Array) -> Array:
        def flow(state: Array) -> Array:
            velocity, g = field(th, state[None, :])
            return jnp.concatenate([velocity[0], g[0]])

        return jax.vmap(jax.jacfwd(flow))(x)

    states = np.concatenate([np.concatenate([p.q, mom], axis=1)
                             for p, (mom, _) in zip(paths, momenta, strict=True)])
    try:
        jac = np.asarray(jax.jit(jacobians)(jnp.asarray(theta_m), jnp.asarray(states)))
        with np.errstate(all="ignore"):
            rate = float(np.max(np.abs(np.linalg.eigvals(jac))))
    except (TypeError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return math.nan
    return rate if math.isfinite(rate) else math.nan


def fastest_rate(posterior: Any) -> float:
    """The fastest rate of the motion the data show (:attr:`DataStart.rate`), the larger of
    the data start's and the rougher data start's (:data:`~._paths.ROUGHER`: a fast motion sampled a
    few times a period shows only in the rougher spline); NaN when neither can be read.
    The learning step's search (``model.dt = "auto"``) starts at a step that resolves it."""
    default = default_start(posterior)
    rates = [found.rate for smoother in ("spline", "rough")
             if (found := data_start(posterior, default, smoother=smoother)) is not None]
    finite = [r for r in rates if math.isfinite(r)]
    return max(finite) if finite else math.nan


def _lift_off_bound(posterior: Any, dyn: np.ndarray, phi: np.ndarray, scale: np.ndarray,
                    default: np.ndarray) -> np.ndarray:
    """How far above its bound to start each dynamic parameter that is bounded below only
    and that the collocation left on the bound (0 for the others): its scale, else the
    default start's distance from the bound. The MAP searches such a parameter as
    log(θ − a) (:class:`~symplid.inference.map._space.SearchSpace`), where a start on the
    bound has no gradient to leave it by."""
    lower = np.asarray(posterior.lower, dtype=float)[dyn]
    upper = np.asarray(posterior.upper, dtype=float)[dyn]
    finite = np.where(np.isfinite(lower), lower, 0.0)
    on_bound = (np.isfinite(lower) & ~np.isfinite(upper)
                & (phi <= finite + 1e-9 * np.maximum(1.0, np.abs(finite))))
    lift = np.where(np.isfinite(scale) & (scale > 0), scale, default - lower)
    lift = np.where(np.isfinite(lift) & (lift > 0), lift, 1.0)
    return np.where(on_bound, lift, 0.0)


def _lifted(theta: np.ndarray, dyn: np.ndarray, lift: np.ndarray,
            is_finite: Callable[[np.ndarray], bool] | None, halvings: int = 30) -> np.ndarray:
    """θ with ``lift`` added to its dynamic parameters, halved while log π is not finite
    there (a stiff term can make the propagator unstable); θ itself when no lift is."""
    for _ in range(halvings if np.any(lift > 0) else 0):
        trial = theta.copy()
        trial[dyn] = theta[dyn] + lift
        if is_finite is None or is_finite(trial):
            return trial
        lift = 0.5 * lift
    return theta


def _data_var(posterior: Any) -> float:
    with np.errstate(all="ignore"):
        values = [np.where(o.mask, o.values, np.nan) for o in posterior.datasets]
        v = float(np.nanmean([np.nanvar(x, axis=0) for x in values]))
    return v if math.isfinite(v) and v > 0 else 1.0


def _set_variances(posterior: Any, theta: np.ndarray, noise_var: np.ndarray, defect: float,
                   data_var: float) -> None:
    """Observation variances at the spline's residual variance (per component, or their mean
    for a shared variance), the process variance at the collocation's defect variance."""
    groups = np.asarray(posterior.param_groups)
    floor = 1e-10 * data_var
    obs = np.flatnonzero(groups == "obs_var")
    noise = np.where(np.isfinite(noise_var), noise_var, np.nanmean(noise_var))
    if obs.size == noise.size:
        theta[obs] = np.maximum(noise, floor)
    elif obs.size:
        theta[obs] = max(float(np.mean(noise)), floor)
    proc = np.flatnonzero(groups == "process_var")
    if proc.size and math.isfinite(defect):
        theta[proc] = max(defect, floor)


def _set_initial_states(posterior: Any, theta: np.ndarray, scale: np.ndarray,
                        paths: list[Smoothed], momenta: list, noise_var: np.ndarray) -> None:
    """Each learned x0 on the smoothed path at t0 with the fitted momentum there."""
    for k, (path, (mom, g)) in enumerate(zip(paths, momenta, strict=True)):
        sl = posterior.initial_state_slice(k)
        back = path.times[0] - path.t0
        q0 = path.q[0] - back * path.qdot[0]
        p0 = mom[0] - back * g[0]
        theta[sl] = np.concatenate([q0, p0])
        sd_q = float(np.sqrt(np.nanmean(noise_var)))
        sd_p = float(np.std(mom)) / max(path.times.size ** 0.5, 1.0)
        scale[sl] = np.concatenate([np.full(q0.size, sd_q), np.full(p0.size, sd_p)])


__all__ = ["COEFFICIENT_GROUPS", "DYNAMIC_GROUPS", "DataStart", "data_start", "fastest_rate"]
