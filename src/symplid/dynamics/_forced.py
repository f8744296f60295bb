"""Propagators of the driven system q̇ = ∂H/∂p, ṗ = −∂H/∂q + F(q, p, u(t), t) that keep
their order.

The force depends on the time, so a step needs u at given times inside it. Every forced
method declares its **nodes**: the fractions c of a substep [t, t + h] at which it evaluates
F; the data preparation tabulates the inputs there (:mod:`symplid.model._inputs`), and a
propagated gap carries the table, one row per substep (:class:`ForcedDynamics`), so the
compiled programs never depend on the input values.

* **Compositions** (leapfrog, yoshida4): each leapfrog sub-step of size h becomes the
  generalised Störmer–Verlet step of the partitioned system (q, t | p), with ṫ = 1
  (Hairer, Lubich & Wanner, *Geometric Numerical Integration*, II.2, eq. 2.2)::

      p½ = p + ½h (−∂U(q) + F(q, p½, u(t), t))          (implicit in p½ when F reads p)
      q⁺ = q + h ∂T(p½),  t⁺ = t + h
      p⁺ = p½ + ½h (−∂U(q⁺) + F(q⁺, p½, u(t⁺), t⁺))

  It is symmetric and of order 2, so Yoshida's triple jump of it is of order 4 (the nodes of
  yoshida4 are the sub-steps' ends, 0, w₁, w₁ + w₀, 1: two of them outside [0, 1]). With
  F = 0 it is the kick–drift–kick leapfrog of eqs (5)–(6). The implicit half-kick is solved
  per point by Newton's method from the explicit guess, with as many iterations as the force
  needs (:attr:`~symplid.dynamics._forcing.Force.newton_steps`: none when F does not read p,
  one, exact, when it is linear in p).
* **Runge–Kutta** tableaus (euler, rk2, rk4; separable or not): the tableau on the whole
  forced vector field, stage i at t + c_i h, so the method keeps its order.

A model without a force never comes here: its propagators are today's, unchanged.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid._compiled import cached
from symplid.dynamics._forcing import Force
from symplid.dynamics._integrators import (
    Dynamics,
    GeneralDynamics,
    Integrator,
    get_integrator,
    make_dynamics,
)
from symplid.dynamics._schemes import ButcherTableau, Composition
from symplid.dynamics._trajectory import propagate

Array = jax.Array

__all__ = [
    "ForcedDynamics",
    "ForcedIntegrator",
    "at_gap",
    "bind_forced",
    "forced_solve_gaps",
    "is_forced",
    "with_force",
]


class ForcedDynamics(NamedTuple):
    """The unforced right-hand side, the force bound to θ_F, and one gap's inputs.

    ``force(q, p, u, t)`` takes points ``(d,)`` or ``(d, N)``. ``times`` ``(S, K)`` and
    ``inputs`` ``(S, K, m)``: for each of a gap's substeps (at most S), the times of the
    integrator's K nodes and u there. :func:`at_gap` puts a gap's table in.
    """

    base: Dynamics | GeneralDynamics
    force: Callable[[Array, Array, Array, Array], Array]
    newton_steps: int
    times: Array
    inputs: Array

    @property
    def grad_potential(self) -> Callable[[Array], Array]:
        """∂U/∂q of a separable base (what the loop's start asks of a separable H)."""
        return self.base.grad_potential  # type: ignore[union-attr]


def bind_forced(potential: Any, force: Force, params: Array,
                inv_mass: Any = None) -> ForcedDynamics:
    """θ_Ψ = [H's parameters ..., θ_F ...] bound; the gap's table left empty (:func:`at_gap`)."""
    params = jnp.asarray(params)
    k = params.shape[-1] - force.num_params
    base = make_dynamics(potential, params[:k], inv_mass)
    theta_f = params[k:]

    def bound(q: Array, p: Array, u: Array, t: Array) -> Array:
        return force(q, p, u, t, theta_f)

    empty = jnp.zeros((0, 0))
    return ForcedDynamics(base, bound, force.newton_steps, empty,
                          jnp.zeros((0, 0, force.num_inputs)))


def at_gap(dynamics: Any, times: Array, inputs: Array) -> Any:
    """``dynamics`` with one gap's node times and inputs (a forced one; others as they are)."""
    if not isinstance(dynamics, ForcedDynamics):
        return dynamics
    return dynamics._replace(times=times, inputs=inputs)


# ---------------------------------------------------------------------------- steps
def _implicit_kick(dyn: ForcedDynamics, q: Array, p: Array, accel: Array, tau: Array,
                   u: Array, t: Array) -> Array:
    """x = p + τ (accel + F(q, x, u, t)), by Newton from the explicit guess (per point)."""
    x = p + tau * (accel + dyn.force(q, p, u, t))
    if dyn.newton_steps == 0:
        return x
    d = q.shape[0]

    def one(qi: Array, pi: Array, ai: Array, xi: Array) -> Array:
        def residual(z: Array) -> Array:
            return z - pi - tau * (ai + dyn.force(qi, z, u, t))

        for _ in range(dyn.newton_steps):
            jac = jax.jacfwd(residual)(xi)
            xi = xi - jnp.linalg.solve(jac, residual(xi))
        return xi

    if q.ndim == 1:
        return one(q, p, accel, x)
    flat = [a.reshape(d, -1) for a in (q, p, accel, x)]
    out = jax.vmap(one, in_axes=(1, 1, 1, 1), out_axes=1)(*flat)
    return out.reshape(q.shape)


def _stormer_verlet(dyn: ForcedDynamics, q: Array, p: Array, h: Array, t0: Array,
                    t1: Array, u0: Array, u1: Array) -> tuple[Array, Array]:
    """The generalised Störmer–Verlet step of the forced separable system (module docstring)."""
    base = dyn.base
    half = _implicit_kick(dyn, q, p, -base.grad_potential(q), 0.5 * h, u0, t0)
    q = q + h * base.velocity(half)
    p = half + 0.5 * h * (-base.grad_potential(q) + dyn.force(q, half, u1, t1))
    return q, p


def _composition_step(weights: tuple[float, ...]) -> Callable[..., tuple[Array, Array]]:
    def step(dyn: ForcedDynamics, q: Array, p: Array, h: Array, times: Array,
             inputs: Array) -> tuple[Array, Array]:
        if isinstance(dyn.base, GeneralDynamics):
            raise ValueError("a forced leapfrog composition needs a separable H = T(p) + U(q); "
                             "for a non-separable H choose a Runge–Kutta method (rk4, rk2)")
        for i, w in enumerate(weights):
            q, p = _stormer_verlet(dyn, q, p, w * h, times[i], times[i + 1], inputs[i],
                                   inputs[i + 1])
        return q, p

    return step


def _runge_kutta_step(a: np.ndarray, b: np.ndarray, node_of_stage: tuple[int, ...]
                      ) -> Callable[..., tuple[Array, Array]]:
    stages = len(b)

    def rhs(dyn: ForcedDynamics, q: Array, p: Array, t: Array, u: Array
            ) -> tuple[Array, Array]:
        base = dyn.base
        if isinstance(base, GeneralDynamics):
            return base.grad_p(q, p), -base.grad_q(q, p) + dyn.force(q, p, u, t)
        return base.velocity(p), -base.grad_potential(q) + dyn.force(q, p, u, t)

    def step(dyn: ForcedDynamics, q: Array, p: Array, h: Array, times: Array,
             inputs: Array) -> tuple[Array, Array]:
        kq: list[Array] = []
        kp: list[Array] = []
        for i in range(stages):
            qi, pi = q, p
            for j in range(i):
                if a[i, j] != 0.0:
                    qi, pi = qi + h * a[i, j] * kq[j], pi + h * a[i, j] * kp[j]
            n = node_of_stage[i]
            dq, dp = rhs(dyn, qi, pi, times[n], inputs[n])
            kq.append(dq)
            kp.append(dp)
        for i in range(stages):
            if b[i] != 0.0:
                q, p = q + h * b[i] * kq[i], p + h * b[i] * kp[i]
        return q, p

    return step


# ---------------------------------------------------------------------------- integrators
@dataclass(frozen=True)
class ForcedIntegrator(Integrator):
    """A registered integrator made to propagate the forced system; steps
    :class:`ForcedDynamics`.

    ``nodes`` are the fractions of a substep where the force is evaluated (module
    docstring); ``forced_step(dynamics, q, p, h, times, inputs)`` is one substep, ``times``
    ``(K,)`` and ``inputs`` ``(K, m)`` at the nodes. Through the common loop
    (:func:`symplid.dynamics._trajectory.propagate`) it runs as a first-same-as-last step whose
    carry is the substep's index, which picks the row of the gap's table.
    """

    base: Integrator | None = None
    nodes: tuple[float, ...] = (0.0, 1.0)
    forced_step: Callable[..., tuple[Array, Array]] | None = None


def _counter_start(dynamics: Any, q: Array, p: Array) -> Array:
    return jnp.zeros((), dtype=jnp.int32)


def _counted(forced_step: Callable[..., tuple[Array, Array]]) -> Callable[..., Any]:
    def force_step(dyn: ForcedDynamics, q: Array, p: Array, j: Array, h: Array):
        q, p = forced_step(dyn, q, p, h, dyn.times[j], dyn.inputs[j])
        return q, p, j + 1

    return force_step


def _unsupported_step(dynamics: Any, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
    raise ValueError("a forced integrator steps through its gap's table of inputs: "
                     "propagate it over a gap (symplid.dynamics._trajectory.propagate)")


def with_force(integrator: str | Integrator) -> ForcedIntegrator:
    """The forced form of a registered integrator (built once per integrator, then reused).

    Raises
    ------
    ValueError
        For an integrator without composition weights or a Butcher tableau (Tao's methods,
        the Gauss–Legendre methods, a bare step function): no forced form yet.
    """
    integrator = get_integrator(integrator)
    if isinstance(integrator, ForcedIntegrator):
        return integrator
    return cached(integrator, ("with_force",), lambda: _build(integrator))


def _build(base: Integrator) -> ForcedIntegrator:
    scheme = base.scheme
    if isinstance(scheme, Composition):
        nodes = tuple(float(x) for x in np.concatenate([[0.0], np.cumsum(scheme.weights)]))
        nodes = (*nodes[:-1], 1.0)  # the last node is the substep's end exactly
        step = _composition_step(scheme.weights)
        text = f"forced {base.name}: generalised Störmer–Verlet sub-steps (force at their ends)"
        nonseparable = False
    elif isinstance(scheme, ButcherTableau):
        c = [float(x) for x in scheme.c]
        nodes = tuple(sorted(set(c)))
        step = _runge_kutta_step(np.asarray(scheme.a, dtype=float),
                                 np.asarray(scheme.b, dtype=float),
                                 tuple(nodes.index(x) for x in c))
        text = f"{base.name} on the forced vector field (stage i at t + c_i h)"
        nonseparable = True
    else:
        raise ValueError(f"the integrator {base.name!r} has no forced form: a driven model "
                         "needs a leapfrog composition (leapfrog, yoshida4) or a Runge–Kutta "
                         "method (rk4, rk2-midpoint, rk2-heun, euler)")
    return ForcedIntegrator(
        f"forced-{base.name}", base.order, False, _unsupported_step, text,
        force_step=_counted(step), nonseparable=nonseparable, start=_counter_start,
        base=base, nodes=nodes, forced_step=step,
    )


def is_forced(integrator: Any) -> bool:
    """Whether ``integrator`` steps the forced system."""
    return isinstance(integrator, ForcedIntegrator)


# ---------------------------------------------------------------------------- paths
def forced_solve_gaps(integrator: ForcedIntegrator, dynamics: ForcedDynamics, x0: Array,
                      step_sizes: Array, num_steps: Array, times: Array, inputs: Array,
                      max_steps: int) -> Array:
    """The states at the end of consecutive gaps of the forced system (no noise).

    ``times`` ``(G, S, K)`` and ``inputs`` ``(G, S, K, m)`` are each gap's table (S =
    ``max_steps``); ``x0`` ``(2d,)``. Returns ``(G, 2d)``.
    """
    x0 = jnp.asarray(x0, dtype=float)
    d = x0.shape[-1] // 2

    def gap(x: Array, inp: tuple[Array, ...]) -> tuple[Array, Array]:
        h, n, ts, us = inp
        q, p = propagate(integrator, at_gap(dynamics, ts, us), x[:d], x[d:], h, n, max_steps)
        x = jnp.concatenate([q, p])
        return x, x

    xs = (jnp.asarray(step_sizes, dtype=float), jnp.asarray(num_steps), jnp.asarray(times),
          jnp.asarray(inputs))
    _, out = jax.lax.scan(gap, x0, xs)
    return out
