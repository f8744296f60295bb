"""One-step integrators for separable Hamiltonians, and the propagator over a gap (eq. 14).

Every integrator has one call signature::

    q_next, p_next = integrator.step(dynamics, q, p, dt)

where ``dynamics`` bundles ∂U/∂q and the velocity map p ↦ M⁻¹p. Integrators are declared as
data, each with its order and whether it is symplectic:

* symplectic compositions: a tuple of leapfrog weights (leapfrog = ``(1,)``; Yoshida's
  fourth-order method = ``(w1, w0, w1)``), each leapfrog sub-step written in the integer-step
  form of eqs (5)–(6);
* explicit Runge–Kutta methods: a Butcher tableau (forward Euler, RK2 midpoint and Heun, RK4).

A non-separable H(q, p; θ) (:mod:`symplid.dynamics._hamiltonians`) arrives as
:class:`GeneralDynamics` (∂H/∂q and ∂H/∂p of the whole state). The Runge–Kutta methods accept it
(the natural non-structure-preserving baseline); the leapfrog compositions need the split of
eq. (4) and refuse it with a clear error; Tao's extended-phase-space methods and the
Gauss–Legendre methods (:mod:`symplid.dynamics._nonseparable`, ``"tao"``, ``"tao4"``,
``"implicit-midpoint"``, ``"gauss4"``) are the structure-preserving choices for it.

To add an integrator, register it in :data:`INTEGRATORS` (``INTEGRATORS.register(name,
Integrator(...))``), from this module or any other: settings, the command line and sweeps
read the registry.
"""

from __future__ import annotations

import jax
import numpy as np

from symplid._registry import Registry
from symplid.dynamics._nonseparable import (
    gauss_legendre_integrator,
    implicit_midpoint_integrator,
    tao_integrator,
)
from symplid.dynamics._onestep import (
    Dynamics,
    ForceStepFn,
    GeneralDynamics,
    Integrator,
    StepFn,
    as_general,
    make_dynamics,
)
from symplid.dynamics._schemes import ButcherTableau, Composition

__all__ = [
    "INTEGRATORS",
    "Dynamics",
    "ForceStepFn",
    "GeneralDynamics",
    "Integrator",
    "StepFn",
    "as_general",
    "get_integrator",
    "leapfrog_force_step",
    "leapfrog_step",
    "make_dynamics",
    "require_separable",
    "runge_kutta",
    "runge_kutta_integrator",
    "separable_only_error",
    "symplectic_composition",
    "symplectic_integrator",
]

Array = jax.Array


def leapfrog_step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
    """Leapfrog (Störmer–Verlet) at integer steps, eqs (5)–(6), with a mass matrix M.

    q⁺ = q + Δt M⁻¹p − ½Δt² M⁻¹∂U(q);  p⁺ = p − ½Δt (∂U(q) + ∂U(q⁺)).
    """
    q_next, p_next, _ = leapfrog_force_step(dynamics, q, p, dynamics.grad_potential(q), dt)
    return q_next, p_next


def leapfrog_force_step(
    dynamics: Dynamics, q: Array, p: Array, force: Array, dt: Array
) -> tuple[Array, Array, Array]:
    """Eqs (5)–(6) with ``force = ∂U(q)`` given; returns the new state and ∂U(q⁺).

    For a kinetic energy other than ½pᵀM⁻¹p (``dynamics.linear`` false) the drift uses the
    half-kicked momentum, q⁺ = q + Δt ∂T(p − ½Δt ∂U(q)): the same step when ∂T is linear.
    """
    if getattr(dynamics, "linear", True):
        q_next = q + dt * dynamics.velocity(p) - 0.5 * dt * dt * dynamics.velocity(force)
    else:
        q_next = q + dt * dynamics.velocity(p - 0.5 * dt * force)
    force_next = dynamics.grad_potential(q_next)
    p_next = p - 0.5 * dt * (force + force_next)
    return q_next, p_next, force_next


def symplectic_composition(weights: tuple[float, ...]) -> tuple[StepFn, ForceStepFn]:
    """A step made of leapfrog sub-steps of sizes ``w_i·Δt`` (symmetric composition).

    Returns the plain step and its first-same-as-last form.
    """
    weights = tuple(float(w) for w in weights)

    def force_step(
        dynamics: Dynamics, q: Array, p: Array, force: Array, dt: Array
    ) -> tuple[Array, Array, Array]:
        require_separable(dynamics, "a leapfrog composition")
        for w in weights:
            q, p, force = leapfrog_force_step(dynamics, q, p, force, w * dt)
        return q, p, force

    def step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        require_separable(dynamics, "a leapfrog composition")
        q, p, _ = force_step(dynamics, q, p, dynamics.grad_potential(q), dt)
        return q, p

    return step, force_step


def symplectic_integrator(
    name: str, order: int, weights: tuple[float, ...], description: str
) -> Integrator:
    """A symplectic composition of leapfrog sub-steps of sizes ``w_i·Δt`` (eqs 5–6).

    Parameters
    ----------
    name
        The name it is registered under in :data:`INTEGRATORS`.
    order
        Its order of accuracy (2 for leapfrog, 4 for Yoshida's triple jump).
    weights
        The sub-step fractions ``w_i`` (symmetric, summing to 1); ``(1.0,)`` is leapfrog.
    description
        One line for help texts.

    Returns
    -------
    Integrator
        A separable-only integrator that carries its weights as data (``scheme``), so the
        compiled likelihood kernel runs it too.
    """
    scheme = Composition(weights)  # checks symmetry, Σ w = 1 and the order conditions
    step, force_step = symplectic_composition(scheme.weights)
    return Integrator(name, order, True, step, description, force_step, scheme)


def runge_kutta_integrator(
    name: str,
    order: int,
    a: tuple[tuple[float, ...], ...],
    b: tuple[float, ...],
    description: str,
) -> Integrator:
    """An explicit Runge–Kutta integrator from its Butcher tableau (not symplectic)."""
    scheme = ButcherTableau(a, b)  # checks the shape and, with the order, Butcher's conditions
    return Integrator(
        name, order, False, runge_kutta(a, b), description, scheme=scheme, nonseparable=True
    )


def runge_kutta(a: tuple[tuple[float, ...], ...], b: tuple[float, ...]) -> StepFn:
    """An explicit Runge–Kutta step from its Butcher tableau (strictly lower-triangular ``a``)."""
    a_np = np.asarray(a, dtype=float)
    b_np = np.asarray(b, dtype=float)
    stages = len(b_np)
    if a_np.shape != (stages, stages) or np.any(np.triu(a_np) != 0):
        raise ValueError("an explicit Butcher tableau needs a strictly lower-triangular a")

    def step(dynamics: Dynamics, q: Array, p: Array, dt: Array) -> tuple[Array, Array]:
        kq: list[Array] = []
        kp: list[Array] = []
        for i in range(stages):
            qi, pi = q, p
            for j in range(i):
                if a_np[i, j] != 0.0:
                    qi = qi + dt * a_np[i, j] * kq[j]
                    pi = pi + dt * a_np[i, j] * kp[j]
            if isinstance(dynamics, GeneralDynamics):  # a non-separable H
                kq.append(dynamics.grad_p(qi, pi))
                kp.append(-dynamics.grad_q(qi, pi))
                continue
            kq.append(dynamics.velocity(pi))
            kp.append(-dynamics.grad_potential(qi))
        for i in range(stages):
            if b_np[i] != 0.0:
                q = q + dt * b_np[i] * kq[i]
                p = p + dt * b_np[i] * kp[i]
        return q, p

    return step


_CBRT2 = 2.0 ** (1.0 / 3.0)
_YOSHIDA_W1 = 1.0 / (2.0 - _CBRT2)
_YOSHIDA_W0 = -_CBRT2 / (2.0 - _CBRT2)

INTEGRATORS: Registry[Integrator] = Registry("integrator")
"""Every one-step method by name; ``INTEGRATORS.register(name, Integrator(...))`` adds one.

The built-in methods are registered just below, all of them: the separable ones of this
module, then Tao's methods, the implicit midpoint rule and the two-stage Gauss–Legendre method
of :mod:`symplid.dynamics._nonseparable`."""

INTEGRATORS.register(
    "leapfrog",
    symplectic_integrator("leapfrog", 2, (1.0,), "Störmer–Verlet, eqs (5)–(6)"),
    aliases=("verlet", "stormer-verlet"),
)
INTEGRATORS.register(
    "yoshida4",
    symplectic_integrator(
        "yoshida4",
        4,
        (_YOSHIDA_W1, _YOSHIDA_W0, _YOSHIDA_W1),
        "Yoshida's 4th-order composition of three leapfrog steps",
    ),
)
INTEGRATORS.register(
    "euler", runge_kutta_integrator("euler", 1, ((0.0,),), (1.0,), "forward Euler")
)
INTEGRATORS.register(
    "rk2-midpoint",
    runge_kutta_integrator(
        "rk2-midpoint",
        2,
        ((0.0, 0.0), (0.5, 0.0)),
        (0.0, 1.0),
        "explicit midpoint (the paper's non-symplectic RK2)",
    ),
    aliases=("rk2",),
)
INTEGRATORS.register(
    "rk2-heun",
    runge_kutta_integrator(
        "rk2-heun", 2, ((0.0, 0.0), (1.0, 0.0)), (0.5, 0.5), "Heun's method"
    ),
)
INTEGRATORS.register(
    "rk4",
    runge_kutta_integrator(
        "rk4",
        4,
        (
            (0.0, 0.0, 0.0, 0.0),
            (0.5, 0.0, 0.0, 0.0),
            (0.0, 0.5, 0.0, 0.0),
            (0.0, 0.0, 1.0, 0.0),
        ),
        (1 / 6, 1 / 3, 1 / 3, 1 / 6),
        "classical Runge–Kutta",
    ),
)
INTEGRATORS.register("tao", tao_integrator("tao", 2, (1.0,)))
INTEGRATORS.register(
    "tao4", tao_integrator("tao4", 4, (_YOSHIDA_W1, _YOSHIDA_W0, _YOSHIDA_W1))
)
INTEGRATORS.register(
    "implicit-midpoint", implicit_midpoint_integrator(), aliases=("midpoint-implicit",)
)
INTEGRATORS.register("gauss4", gauss_legendre_integrator(), aliases=("gauss-legendre4",))


def separable_only_error(method: str) -> ValueError:
    """The error for a separable-only ``method`` given a non-separable H, naming the choices."""
    general = [n for n, entry in INTEGRATORS.items() if entry.nonseparable]
    return ValueError(
        f"{method} needs a separable H = ½pᵀM⁻¹p + U(q); for a non-separable Hamiltonian "
        f"choose one of {', '.join(general)}"
    )


def require_separable(dynamics: Dynamics | GeneralDynamics, method: str) -> None:
    """Raise :func:`separable_only_error` when ``dynamics`` is of a non-separable H."""
    if isinstance(dynamics, GeneralDynamics):
        raise separable_only_error(method)


def get_integrator(name: str | Integrator) -> Integrator:
    """An integrator by name (``'leapfrog'``, ``'rk2-midpoint'``, ...), or the one passed."""
    if isinstance(name, Integrator):
        return name
    return INTEGRATORS.get_entry(name)
