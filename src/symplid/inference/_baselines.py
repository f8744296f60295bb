"""The least-squares objectives the paper argues against, fitted to the same data and potentials.

The paper (Section I) contrasts its marginal-likelihood posterior with two families of point
estimates, both of which treat the observed states as exact:

* **HNN's finite-difference loss, eq. (1)**: the time derivatives are replaced by forward
  differences of consecutive observations and compared with Hamilton's equations (3) at the
  earlier one::

      J(θ) = Σ_k ‖(q_k − q_{k−1})/Δt_k − ∂H/∂p(x_{k−1})‖² + ‖(p_k − p_{k−1})/Δt_k + ∂H/∂q(x_{k−1})‖²

  (``objective="hnn"``). As the paper notes, this is least squares through one forward-Euler
  step, divided by the gap; for equal gaps ``"hnn"`` and ``"euler"`` have the same minimiser.
* **Least squares through an integrator step** between consecutive observations, the paper's
  refs 13 (RK4) and 14 (leapfrog), and forward Euler::

      J(θ) = Σ_k ‖(x_k − Ψ_θ(x_{k−1}))/Δt_k‖²

  (``objective="euler"``, ``"rk4"``, ``"leapfrog"``). Ψ is the integrator of
  :data:`~symplid.dynamics._integrators.INTEGRATORS` run by the library's one propagator
  (:func:`~symplid.dynamics._trajectory.propagate`).

**Steps per gap.** By default Ψ is *exactly one step* of the integrator over each gap, as those
papers use it (``dt=None``). With ``dt`` a number, each gap is split into ⌈gap/dt⌉ equal
substeps (:func:`~symplid.dynamics._trajectory.substeps`, eq. 14), the same Ψ as the UKF
posterior's, so that the objective and not the step size is compared. HNN's loss has no
propagator and ignores ``dt``.

**Why the residuals are divided by the gap.** Dividing by Δt_k puts every residual in the
units of a time derivative, as in eq. (1): for equal gaps the minimiser is unchanged, the loss
does not shrink with the sampling step, and the gradient with respect to the coefficients is
O(1), so the solver's tolerances mean the same thing at every data density.

**Data.** Every objective needs the *full state* (q and p) at consecutive times:
positions-only data raise :class:`~symplid.model._data.DataError` (use the UKF posterior, which
handles them). A pair of consecutive observations with any missing component (NaN) is dropped;
at least one complete pair must remain. Times may be irregular.

**Solver.** Exact-gradient L-BFGS (:func:`scipy.optimize.minimize` with
``jax.value_and_grad``), the loss compiled once per (potential, objective, data shape). When
the residuals are affine in the coefficients — HNN's loss, or one Euler step per gap, with a
:class:`~symplid.dynamics._potentials.Polynomial` — the loss is linear least squares and
``method="auto"`` solves it in closed form (``method="lbfgs"`` forces the iterative solver).

A new objective is one registration in :data:`OBJECTIVES`::

    OBJECTIVES.register("yoshida4", step_objective("yoshida4"))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from symplid._compiled import jit_for
from symplid._registry import Registry
from symplid.dynamics._integrators import Dynamics, get_integrator, make_dynamics
from symplid.dynamics._potentials import Polynomial, Potential, inverse_mass
from symplid.dynamics._trajectory import propagate, substeps
from symplid.model._data import DataError, Observations

Array = jax.Array

ResidualFn = Callable[[Dynamics, Array, Array, Array, Array, int, bool], Array]
"""``(dynamics, x_prev, x_next, step_size, num_steps, max_steps, uniform) -> residuals``.

``x_prev`` and ``x_next`` are ``(2d, N)`` (one column per pair of consecutive observations),
``step_size`` and ``num_steps`` are ``(N,)``; the residuals have the shape of ``x_next``, in
units of a time derivative."""


@dataclass(frozen=True)
class Objective:
    """A least-squares objective: residuals between consecutive observed states.

    Attributes
    ----------
    name
        Registered name.
    residuals
        See :data:`ResidualFn`.
    affine_one_step
        Whether the residuals are affine in the coefficients of a potential linear in them
        when every gap is one step (then the loss is linear least squares).
    uses_substeps
        Whether ``dt`` (⌈gap/dt⌉ substeps) applies; False for derivative matching (HNN).
    description
        One line for help texts.
    """

    name: str
    residuals: ResidualFn
    affine_one_step: bool
    uses_substeps: bool = True
    description: str = ""


def _hnn_residuals(dynamics, x_prev, x_next, step_size, num_steps, max_steps, uniform):
    """Eq. (1): forward differences minus Hamilton's equations (3) at the earlier state."""
    d = x_prev.shape[0] // 2
    q, p = x_prev[:d], x_prev[d:]
    derivative = jnp.concatenate([dynamics.velocity(p), -dynamics.grad_potential(q)])
    return (x_next - x_prev) / step_size - derivative


def step_objective(integrator: str, description: str = "") -> Objective:
    """Least squares through Ψ = the integrator over each gap, divided by the gap.

    Parameters
    ----------
    integrator
        A name in :data:`~symplid.dynamics._integrators.INTEGRATORS`.
    description
        One line for help texts.
    """
    integ = get_integrator(integrator)

    def residuals(dynamics, x_prev, x_next, step_size, num_steps, max_steps, uniform):
        d = x_prev.shape[0] // 2
        q, p = propagate(
            integ, dynamics, x_prev[:d], x_prev[d:], step_size, num_steps, max_steps,
            masked=not uniform,
        )
        gap = step_size * num_steps
        return (x_next - jnp.concatenate([q, p])) / gap

    return Objective(
        integ.name,
        residuals,
        affine_one_step=integ.name == "euler",
        description=description or f"least squares through {integ.name} steps",
    )


OBJECTIVES: Registry[Objective] = Registry("objective")
"""The baseline objectives by name; ``OBJECTIVES.register(name, Objective(...))`` adds one."""

OBJECTIVES.register(
    "hnn",
    Objective("hnn", _hnn_residuals, affine_one_step=True, uses_substeps=False,
              description="HNN's finite-difference loss, eq. (1)"),
)
OBJECTIVES.register("euler", step_objective("euler", "least squares through forward Euler"))
OBJECTIVES.register("rk4", step_objective("rk4", "least squares through RK4 (ref. 13)"))
OBJECTIVES.register(
    "leapfrog", step_objective("leapfrog", "least squares through leapfrog (ref. 14)")
)


class Pairs:
    """Consecutive complete full-state observations as arrays (built once per data set).

    Attributes
    ----------
    x_prev, x_next
        ``(2d, N)``: the earlier and later state of each kept pair.
    step_size, num_steps
        ``(N,)``: substep size and number of substeps over each gap.
    max_steps, uniform
        The largest number of substeps, and whether every gap has it.
    """

    def __init__(self, potential: Potential, data: Observations, dt: float | None) -> None:
        if not isinstance(data, Observations):
            raise TypeError(f"data must be a symplid.Observations, got {type(data).__name__}")
        d = int(potential.dim)
        if data.dim == d:
            raise DataError(
                f"the data have {d} components per time, the positions only: the baseline "
                f"objectives need the full state (q and p, {2 * d} components); fit "
                "positions-only data with the UKF posterior (symplid.Posterior)"
            )
        if data.dim != 2 * d:
            raise DataError(
                f"the data have {data.dim} components per time; a potential in {d} "
                f"coordinates needs the full state, {2 * d} components (q then p)"
            )
        if data.num_times < 2:
            raise DataError("the baseline objectives need at least 2 observations (one pair)")
        complete = np.all(data.mask, axis=1)
        keep = complete[:-1] & complete[1:]
        if not np.any(keep):
            raise DataError(
                "no two consecutive observations are both complete: every pair has a missing "
                "(NaN) component, and the baseline objectives drop such pairs"
            )
        gaps = np.diff(data.times)[keep]
        if dt is None:
            num_steps, step_size = np.ones(gaps.shape, dtype=np.int64), gaps
        else:
            num_steps, step_size = substeps(gaps, float(dt))
        self.x_prev = jnp.asarray(data.values[:-1][keep].T)
        self.x_next = jnp.asarray(data.values[1:][keep].T)
        self.step_size = jnp.asarray(step_size)
        self.num_steps = jnp.asarray(num_steps)
        self.max_steps = int(num_steps.max())
        self.uniform = bool(np.all(num_steps == self.max_steps))
        self.num_pairs = int(gaps.shape[0])
        self.num_dropped = int(np.sum(~keep))




def _mean_square(coefficients, pairs_arrays, inv_mass, *, potential, objective, max_steps, uniform):
    """Mean over pairs of the squared residual norm (eq. 1 up to the factor N)."""
    return jnp.sum(
        jnp.mean(
            _residuals(coefficients, pairs_arrays, inv_mass, potential, objective, max_steps,
                       uniform) ** 2,
            axis=-1,
        )
    )


def _residuals(coefficients, pairs_arrays, inv_mass, potential, objective, max_steps, uniform):
    x_prev, x_next, step_size, num_steps = pairs_arrays
    dynamics = make_dynamics(potential, coefficients, inv_mass)
    return objective.residuals(
        dynamics, x_prev, x_next, step_size, num_steps, max_steps, uniform
    )


def _loss(potential, objective, max_steps, uniform, coefficients, pairs_arrays, inv_mass):
    return _mean_square(coefficients, pairs_arrays, inv_mass, potential=potential,
                        objective=objective, max_steps=max_steps, uniform=uniform)


def _loss_and_grad(potential, objective, max_steps, uniform, coefficients, pairs_arrays,
                   inv_mass):
    return jax.value_and_grad(_loss, argnums=4)(
        potential, objective, max_steps, uniform, coefficients, pairs_arrays, inv_mass
    )


def _compiled(fn, static: dict[str, Any]):
    """``fn`` compiled once per (potential, objective, loop length), kept on the potential."""
    return jit_for(static["potential"], fn, static["objective"], static["max_steps"],
                   static["uniform"])


def loss_function(
    potential: Potential,
    data: Observations,
    objective: str = "hnn",
    *,
    dt: float | None = None,
    mass: Any = None,
) -> Callable[[Array], Array]:
    """The objective as a jitted function of the coefficients (mean squared residual norm).

    The arguments are those of :func:`fit`.
    """
    entry = OBJECTIVES.get_entry(objective)
    pairs = Pairs(potential, data, dt if entry.uses_substeps else None)
    static, arrays, inv_mass = _bind(potential, entry, pairs, mass)
    loss = _compiled(_loss, static)
    return lambda c: loss(jnp.asarray(c, dtype=float), arrays, inv_mass)


def _bind(potential, entry, pairs, mass):
    static = {
        "potential": potential,
        "objective": entry,
        "max_steps": pairs.max_steps,
        "uniform": pairs.uniform,
    }
    arrays = (pairs.x_prev, pairs.x_next, pairs.step_size, pairs.num_steps)
    return static, arrays, inverse_mass(mass, potential.dim)


def fit(
    potential: Potential,
    data: Observations,
    objective: str = "hnn",
    *,
    dt: float | None = None,
    mass: Any = None,
    init: Any = None,
    method: str = "auto",
    maxiter: int = 10_000,
    gtol: float = 1e-12,
    ftol: float = 1e-15,
) -> np.ndarray:
    """The point estimate of a potential's parameters under a baseline objective.

    Parameters
    ----------
    potential
        Any potential (``dim``, ``num_params``, ``param_names``, ``value``, ``gradient``):
        a :class:`~symplid.dynamics._potentials.Polynomial`, a ``FunctionPotential``, an
        ``MLPPotential``.
    data
        Full-state observations ``(q, p)`` of one trajectory, irregular times allowed; pairs
        with a missing component are dropped (module docstring).
    objective
        A name in :data:`OBJECTIVES`: ``"hnn"`` (eq. 1), ``"euler"``, ``"rk4"``, ``"leapfrog"``.
    dt
        None (default): one integrator step per gap, as refs 13–14 do. A number: ⌈gap/dt⌉
        equal substeps per gap (eq. 14). Ignored by ``"hnn"``.
    mass
        Constant mass matrix M (identity when None), as for the model.
    init
        Start of the iterative solver (default: the potential's ``initial_coefficients()``
        when it has one, else zeros).
    method
        ``"auto"`` (closed-form linear least squares when the loss is quadratic in the
        coefficients, else L-BFGS), ``"lbfgs"`` or ``"lstsq"``.
    maxiter, gtol, ftol
        L-BFGS-B settings.

    Returns
    -------
    numpy.ndarray
        The coefficients, shape ``(num_params,)``, in ``potential.param_names`` order.

    Raises
    ------
    ValueError
        An unknown objective (with the closest name) or method, or ``"lstsq"`` where the loss
        is not linear least squares.
    DataError
        Positions-only data, fewer than two observations, or no complete consecutive pair.
    """
    entry = OBJECTIVES.get_entry(objective)
    if method not in ("auto", "lbfgs", "lstsq"):
        raise ValueError(f"method must be 'auto', 'lbfgs' or 'lstsq', got {method!r}")
    pairs = Pairs(potential, data, dt if entry.uses_substeps else None)
    static, arrays, inv_mass = _bind(potential, entry, pairs, mass)
    linear = (
        entry.affine_one_step
        and (pairs.max_steps == 1 or not entry.uses_substeps)
        and isinstance(potential, Polynomial)
    )
    if method == "lstsq" and not linear:
        raise ValueError(
            f"method='lstsq' needs residuals affine in the coefficients (objective 'hnn', or "
            f"'euler' with one step per gap, and a Polynomial); {entry.name!r} with "
            f"{type(potential).__name__} is not"
        )
    if linear and method != "lbfgs":
        return _solve_linear(arrays, inv_mass, static, potential.num_params)
    return _solve_lbfgs(potential, arrays, inv_mass, static, init, maxiter, gtol, ftol)


def _solve_linear(arrays, inv_mass, static, num_params: int) -> np.ndarray:
    """Residuals r(c) = A c + b exactly: A by forward-mode autodiff, then least squares."""

    def flat(c):
        return jnp.ravel(
            _residuals(c, arrays, inv_mass, static["potential"], static["objective"],
                       static["max_steps"], static["uniform"])
        )

    zero = jnp.zeros(num_params)
    b = np.asarray(flat(zero))
    A = np.asarray(jax.jacfwd(flat)(zero))
    coef, *_ = np.linalg.lstsq(A, -b, rcond=None)
    return coef


def _solve_lbfgs(potential, arrays, inv_mass, static, init, maxiter, gtol, ftol) -> np.ndarray:
    if init is None:
        start = getattr(potential, "initial_coefficients", None)
        x0 = np.asarray(start(), dtype=float) if callable(start) else np.zeros(potential.num_params)
    else:
        x0 = np.asarray(init, dtype=float)
    if x0.shape != (potential.num_params,):
        raise ValueError(f"init must have shape ({potential.num_params},), got {x0.shape}")

    def fun(c: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = _compiled(_loss_and_grad, static)(jnp.asarray(c), arrays, inv_mass)
        return float(value), np.asarray(grad, dtype=float)

    result = scipy.optimize.minimize(
        fun, x0, jac=True, method="L-BFGS-B",
        options={"maxiter": int(maxiter), "gtol": gtol, "ftol": ftol, "maxcor": 30},
    )
    if not np.all(np.isfinite(result.x)):
        raise FloatingPointError(f"the {static['objective'].name} fit diverged: {result.message}")
    return np.asarray(result.x, dtype=float)


__all__ = ["OBJECTIVES", "Objective", "Pairs", "fit", "loss_function", "step_objective"]
