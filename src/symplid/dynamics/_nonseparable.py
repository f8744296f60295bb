"""Structure-preserving one-step methods that need no separability of H(q, p).

Registered in :data:`~symplid.dynamics._integrators.INTEGRATORS` by that registry's module,
which lists every built-in method:

* ``"tao"``, ``"tao4"``: Tao's explicit symplectic methods (Tao 2016, Phys. Rev. E 94,
  043303). The phase space is doubled to ``(q, p, x, y)`` with the augmented Hamiltonian

      H̄ = H(q, y) + H(x, p) + ½ω (|q − x|² + |p − y|²),

  whose three parts have exact flows: φ_A of H(q, y) moves p and x, φ_B of H(x, p) moves q
  and y, φ_C of the binding term rotates (q − x, p − y) by the angle 2ωδ. The order-2 step is
  the symmetric Strang splitting φ_A^{δ/2} φ_B^{δ/2} φ_C^{δ} φ_B^{δ/2} φ_A^{δ/2}; ``"tao4"``
  is its triple-jump composition (weights γ, 1 − 2γ, γ with γ = 1/(2 − 2^{1/3})). Each map is
  symplectic on the doubled space. The copies start equal, ``(x, y) = (q, p)``; the state the
  integrator reports is their mean ((q + x)/2, (p + y)/2), and their half-difference is carried
  from step to step (the integrator's ``start``/``force_step`` carry) and re-started at zero
  at the beginning of every propagated observation gap. The change of variables to (mean,
  half-difference) is linear, so the carried map stays symplectic. The mean is the better
  estimate: the binding flow φ_C leaves it unchanged and only the difference oscillates at
  frequency 2ω (on the double pendulum at δ = 0.05 the largest one-gap error is 6.6e-3 for
  the mean against 2e-2 to 7e-2 for the first copy, ω from 0.5 to 40).

  **The binding constant ω** (``model.binding``) ties the copies together. Tao's analysis
  bounds the error by a term growing like δ^ℓ·ω (ℓ the order), valid over a time that grows
  with ω: too small an ω lets the copies drift apart over long runs, too large an ω costs
  accuracy (and 2ωδ should stay below π, away from the rotation's resonance). The method runs
  with ω fixed (its order in δ is then ℓ). A model's default is ω = 1/dt
  (:data:`DEFAULT_BINDING_STEPS` over the learning step: ω·dt = 1, of order one); a bare
  registry entry uses :data:`DEFAULT_BINDING`. Measured on the double pendulum (δ = 0.025,
  T = 200): the energy error stays at 2e-3 for ω = 10 and 40 (rk4: 2e-3) but reaches 2 to 8
  for ω = 0.5 and 2, where the copies unbind; over one observation gap (copies re-started)
  the error of ``"tao"`` is the same for ω from 1 to 40, and that of ``"tao4"`` grows about
  in proportion to ω (8e-5 at ω = 0.5, 9e-4 at ω = 10, δ = 0.025).

* ``"implicit-midpoint"``: z⁺ = z + δ f((z + z⁺)/2) with f = (∂H/∂p, −∂H/∂q), symplectic for
  every H and of order 2 — the reference. ``"gauss4"``, the two-stage Gauss–Legendre method
  (of which the midpoint rule is the one-stage case), is of order 4, symplectic for every H
  and needs no binding constant. The implicit equation is solved per point by a fixed
  number of Newton iterations (Jacobian by ``jax.jacfwd``) from an explicit-Euler guess, so
  the step runs inside ``jit`` and differentiates like any other function.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from symplid.dynamics._onestep import (
    Dynamics,
    GeneralDynamics,
    Integrator,
    as_general,
)
from symplid.dynamics._potentials import over_points

Array = jax.Array

__all__ = [
    "DEFAULT_BINDING",
    "DEFAULT_BINDING_STEPS",
    "GAUSS4_TABLEAU",
    "TaoIntegrator",
    "gauss_legendre_integrator",
    "implicit_midpoint_integrator",
    "tao_integrator",
    "with_binding",
]

#: ω of a registry entry used on its own (time units of the problem; ω·δ = 1 at δ = 0.1).
DEFAULT_BINDING = 10.0
#: A model's default ω is this number over its learning step ``dt``.
DEFAULT_BINDING_STEPS = 1.0

Extended = tuple[Array, Array, Array, Array]


def _flow_a(f: GeneralDynamics, z: Extended, h: Array) -> Extended:
    """Exact flow of H(q, y) for time h: p and x move."""
    q, p, x, y = z
    return q, p - h * f.grad_q(q, y), x + h * f.grad_p(q, y), y


def _flow_b(f: GeneralDynamics, z: Extended, h: Array) -> Extended:
    """Exact flow of H(x, p) for time h: q and y move."""
    q, p, x, y = z
    return q + h * f.grad_p(x, p), p, x, y - h * f.grad_q(x, p)


def _flow_c(z: Extended, h: Array, binding: float) -> Extended:
    """Exact flow of ½ω(|q − x|² + |p − y|²): a rotation of (q − x, p − y) by 2ωh."""
    q, p, x, y = z
    c, s = jnp.cos(2.0 * binding * h), jnp.sin(2.0 * binding * h)
    u, v = q - x, p - y
    u, v = c * u + s * v, -s * u + c * v
    mq, mp = q + x, p + y
    return 0.5 * (mq + u), 0.5 * (mp + v), 0.5 * (mq - u), 0.5 * (mp - v)


def tao_extended_step(
    dynamics: Dynamics | GeneralDynamics,
    z: Extended,
    dt: Array,
    binding: float,
    weights: tuple[float, ...] = (1.0,),
) -> Extended:
    """One step of Tao's method on the doubled state ``z = (q, p, x, y)``.

    The order-2 Strang splitting φ_A^{h/2} φ_B^{h/2} φ_C^{h} φ_B^{h/2} φ_A^{h/2}, composed
    over sub-steps ``w·dt`` for ``w`` in ``weights`` (``(1,)``: order 2; the triple jump:
    order 4). Symplectic on the doubled phase space.
    """
    f = as_general(dynamics)
    for w in weights:
        h = w * dt
        z = _flow_a(f, z, 0.5 * h)
        z = _flow_b(f, z, 0.5 * h)
        z = _flow_c(z, h, binding)
        z = _flow_b(f, z, 0.5 * h)
        z = _flow_a(f, z, 0.5 * h)
    return z


@dataclass(frozen=True)
class TaoIntegrator(Integrator):
    """Tao's method with its binding constant ω (``binding``) and composition ``weights``."""

    binding: float = DEFAULT_BINDING
    weights: tuple[float, ...] = (1.0,)

    def with_binding(self, binding: float) -> TaoIntegrator:
        """The same method with binding constant ω = ``binding`` (> 0)."""
        return tao_integrator(self.name, self.order, self.weights, binding)


def tao_integrator(
    name: str,
    order: int,
    weights: tuple[float, ...],
    binding: float = DEFAULT_BINDING,
) -> TaoIntegrator:
    """Tao's explicit symplectic method for a non-separable H, with binding constant ω."""
    binding = float(binding)
    if not binding > 0 or not math.isfinite(binding):  # plain Python: no JAX at import
        raise ValueError(f"the binding constant ω must be a positive number, got {binding}")
    weights = tuple(float(w) for w in weights)

    def force_step(dynamics, q: Array, p: Array, half_gap: Array, dt: Array):
        # (q, p) carried here is the copies' mean; half_gap = [(q − x)/2; (p − y)/2], (2d, ...)
        d = q.shape[0]
        u, v = half_gap[:d], half_gap[d:]
        z = tao_extended_step(dynamics, (q + u, p + v, q - u, p - v), dt, binding, weights)
        q1, p1, x1, y1 = z
        gap = jnp.concatenate([0.5 * (q1 - x1), 0.5 * (p1 - y1)], axis=0)
        return 0.5 * (q1 + x1), 0.5 * (p1 + y1), gap

    def start(dynamics, q: Array, p: Array) -> Array:
        return jnp.zeros((2 * q.shape[0], *q.shape[1:]), dtype=q.dtype)

    def step(dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        q, p, _ = force_step(dynamics, q, p, start(dynamics, q, p), dt)
        return q, p

    description = (f"Tao's explicit symplectic method of order {order} for a non-separable H "
                   f"(extended phase space, ω = {binding:g})")
    return TaoIntegrator(
        name, order, True, step, description, force_step=force_step, nonseparable=True,
        start=start, binding=binding, weights=weights,
    )


def _hamilton_rhs(f: GeneralDynamics, d: int) -> Callable[[Array], Array]:
    """Hamilton's equations (3) on the stacked state z = (q, p): ż = (∂H/∂p, −∂H/∂q)."""

    def rhs(z: Array) -> Array:
        return jnp.concatenate([f.grad_p(z[:d], z[d:]), -f.grad_q(z[:d], z[d:])])

    return rhs


def implicit_midpoint_integrator(name: str = "implicit-midpoint", iterations: int = 4
                                 ) -> Integrator:
    """The implicit midpoint rule, solved by ``iterations`` Newton iterations per step.

    Newton converges quadratically from the explicit-Euler guess (error O(δ²)), so four
    iterations reach rounding error for the step sizes of a learning grid; the count is fixed
    so that the step is a plain ``jit``-able, differentiable function.
    """
    if int(iterations) != iterations or iterations < 1:
        raise ValueError(f"iterations must be an integer ≥ 1, got {iterations}")
    iterations = int(iterations)

    def step(dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        d = q.shape[0]
        rhs = _hamilton_rhs(as_general(dynamics), d)

        def solve_point(z0: Array) -> Array:
            z = z0 + dt * rhs(z0)
            eye = jnp.eye(z0.shape[0])
            for _ in range(iterations):
                mid = 0.5 * (z0 + z)
                residual = z - z0 - dt * rhs(mid)
                jac = eye - 0.5 * dt * jax.jacfwd(rhs)(mid)
                z = z - _small_solve(jac, residual)
            return z

        z = over_points(solve_point, jnp.concatenate([q, p], axis=0))
        return z[:d], z[d:]

    return Integrator(
        name, 2, True, step,
        f"implicit midpoint rule ({iterations} Newton iterations per step)", nonseparable=True,
    )


_SQRT3_6 = math.sqrt(3.0) / 6.0
#: The Butcher tableau of the two-stage Gauss–Legendre method (order 4): ``(a, b)``.
GAUSS4_TABLEAU = (((0.25, 0.25 - _SQRT3_6), (0.25 + _SQRT3_6, 0.25)), (0.5, 0.5))


def gauss_legendre_integrator(name: str = "gauss4", iterations: int = 4) -> Integrator:
    """The two-stage Gauss–Legendre collocation method: order 4, symplectic and symmetric for
    every H (Hairer, Lubich & Wanner, Geometric Numerical Integration, IV.2, VI.4).

    The stages k_i = f(z + δ Σ_j a_ij k_j) (f = (∂H/∂p, −∂H/∂q), a of
    :data:`GAUSS4_TABLEAU`) are solved per point by ``iterations`` Newton iterations on the
    two stages together (Jacobian by ``jax.jacfwd``) from k_i = f(z), then z⁺ = z + δ Σ b_i k_i.
    The starting error is O(δ) and Newton squares it, so four iterations leave far less than
    the method's own O(δ⁵) per step; the count is fixed, as for the implicit midpoint rule.
    Explicit Tao ``"tao4"`` is the other fourth-order method for a non-separable H; this one
    has no binding constant and no extended phase space, at the price of a 4d × 4d solve per
    Newton iteration.
    """
    if int(iterations) != iterations or iterations < 1:
        raise ValueError(f"iterations must be an integer ≥ 1, got {iterations}")
    iterations = int(iterations)
    (a11, a12), (a21, a22) = GAUSS4_TABLEAU[0]
    b1, b2 = GAUSS4_TABLEAU[1]

    def step(dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        d = q.shape[0]
        rhs = _hamilton_rhs(as_general(dynamics), d)

        def solve_point(z0: Array) -> Array:
            n = z0.shape[0]

            def residual(k: Array) -> Array:
                k1, k2 = k[:n], k[n:]
                return jnp.concatenate([k1 - rhs(z0 + dt * (a11 * k1 + a12 * k2)),
                                        k2 - rhs(z0 + dt * (a21 * k1 + a22 * k2))])

            first = rhs(z0)
            k = jnp.concatenate([first, first])
            for _ in range(iterations):
                k = k - _small_solve(jax.jacfwd(residual)(k), residual(k))
            return z0 + dt * (b1 * k[:n] + b2 * k[n:])

        z = over_points(solve_point, jnp.concatenate([q, p], axis=0))
        return z[:d], z[d:]

    return Integrator(
        name, 4, True, step,
        f"two-stage Gauss–Legendre collocation, order 4 ({iterations} Newton iterations per "
        "step)", nonseparable=True,
    )


#: Largest Newton system solved by unrolled elimination (larger ones call LAPACK).
UNROLLED_SOLVE_MAX = 8


def _small_solve(a: Array, b: Array) -> Array:
    """``a⁻¹b`` for one small system, by Gaussian elimination unrolled at trace time.

    The Newton matrix I − (δ/2)·Df is a perturbation of the identity at the step sizes where
    the rule is accurate, so no pivoting is needed; the unrolled arithmetic fuses under XLA
    (a LAPACK call per point would not). A zero pivot gives a non-finite step, which the
    likelihood turns into −∞. Systems above :data:`UNROLLED_SOLVE_MAX` use
    ``jnp.linalg.solve``.
    """
    n = b.shape[0]
    if n > UNROLLED_SOLVE_MAX:
        return jnp.linalg.solve(a, b)
    m = [[a[i, j] for j in range(n)] for i in range(n)]
    v = [b[i] for i in range(n)]
    for k in range(n):
        for i in range(k + 1, n):
            f = m[i][k] / m[k][k]
            for j in range(k + 1, n):
                m[i][j] = m[i][j] - f * m[k][j]
            v[i] = v[i] - f * v[k]
    x: list[Array] = [v[0]] * n
    for i in reversed(range(n)):
        acc = v[i]
        for j in range(i + 1, n):
            acc = acc - m[i][j] * x[j]
        x[i] = acc / m[i][i]
    return jnp.stack(x)


def with_binding(integrator: Integrator, binding: float | None) -> Integrator:
    """``integrator`` with Tao's binding constant ω; an error for a method that has none."""
    if binding is None:
        return integrator
    if not isinstance(integrator, TaoIntegrator):
        raise ValueError(f"binding (Tao's ω) applies to 'tao' and 'tao4', not to "
                         f"{integrator.name!r}")
    return integrator.with_binding(binding)

