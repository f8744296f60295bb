"""Leapfrog and Yoshida on H = T(p) + U(q) with a kinetic energy that is not ½pᵀM⁻¹p.

Each property is checked against something independent of the step being tested: SciPy's
adaptive DOP853 at tight tolerance (the order), the symplectic form Ω (the Jacobian of one step
by jax.jacfwd), the quadratic-T code path (T = ½p²), and the truth of simulated data (a fit).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from symplid.dynamics._integrators import get_integrator, make_dynamics
from symplid.dynamics._potentials import FunctionPotential, hamiltonian
from symplid.dynamics._separable import SeparablePotential
from symplid.dynamics._user_models import build_user_model

# A non-quadratic T: ∂T/∂p = sinh(p)/a, a relativistic-like kinetic term, in a pendulum well.
U_FN = lambda q, c: 1.0 - jnp.cos(q[0])  # noqa: E731
T_FN = lambda p, c: (jnp.cosh(p[0]) - 1.0) / c[0]  # noqa: E731
MODEL = SeparablePotential(U_FN, T_FN, dim=1, num_params=1, names=("a",))
A = jnp.array([1.5])


def _flow(x0: np.ndarray, t: float, a: float = 1.5) -> np.ndarray:
    sol = solve_ivp(lambda _, x: [np.sinh(x[1]) / a, -np.sin(x[0])], (0.0, t), x0,
                    method="DOP853", rtol=1e-13, atol=1e-14)
    return sol.y[:, -1]


def _run(integrator: str, x0: np.ndarray, t: float, n: int, model=MODEL, c=A) -> np.ndarray:
    step = get_integrator(integrator).step
    dyn = make_dynamics(model, c)
    dt = t / n

    @jax.jit
    def run(x):
        def body(_, qp):
            return step(dyn, qp[0], qp[1], dt)
        return jax.lax.fori_loop(0, n, body, (x[:1], x[1:]))

    q, p = run(jnp.asarray(x0))
    return np.concatenate([np.asarray(q), np.asarray(p)])


@pytest.mark.parametrize(("integrator", "ratio"), [("leapfrog", 4.0), ("yoshida4", 16.0)])
def test_order_on_a_non_quadratic_kinetic_energy(integrator, ratio):
    x0 = np.array([0.8, 0.3])
    reference = _flow(x0, 2.0)
    errors = [np.linalg.norm(_run(integrator, x0, 2.0, n) - reference) for n in (20, 40)]
    assert errors[0] / errors[1] == pytest.approx(ratio, rel=0.1)


@pytest.mark.parametrize("integrator", ["leapfrog", "yoshida4"])
def test_one_step_is_symplectic(integrator):
    step = get_integrator(integrator).step
    model = build_user_model("k*(1 - cos(q1)) + 0.1*q1*q2^2 + q2^2",
                             "potential", 2, ["k"], kinetic="cosh(p1) + log(cosh(p2))")
    dyn = make_dynamics(model, jnp.array([2.0]))

    def one(x):
        q, p = step(dyn, x[:2], x[2:], 0.3)
        return jnp.concatenate([q, p])

    jac = jax.jacfwd(one)(jnp.array([0.4, -0.7, 0.9, 0.2]))
    omega = jnp.block([[jnp.zeros((2, 2)), jnp.eye(2)], [-jnp.eye(2), jnp.zeros((2, 2))]])
    np.testing.assert_allclose(jac.T @ omega @ jac, omega, atol=1e-13)
    assert not np.allclose(jac, np.eye(4))  # the step does move the state


@pytest.mark.parametrize("integrator", ["leapfrog", "yoshida4"])
def test_quadratic_kinetic_energy_matches_the_mass_matrix_path(integrator):
    separable = SeparablePotential(U_FN, lambda p, c: 0.5 * jnp.sum(p * p), 1, 1)
    plain = FunctionPotential(U_FN, 1, 1)
    x0 = np.array([1.1, -0.4])
    a = _run(integrator, x0, 5.0, 50, separable)
    b = _run(integrator, x0, 5.0, 50, plain)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-14)


def test_energy_of_a_separable_model_uses_its_own_kinetic_energy():
    state = jnp.array([[0.5, 0.7]])
    expected = (np.cosh(0.7) - 1) / 1.5 + 1 - np.cos(0.5)
    np.testing.assert_allclose(hamiltonian(MODEL, A, state), [expected], rtol=1e-14)


def test_leapfrog_keeps_the_energy_of_a_non_quadratic_t_bounded():
    x0 = np.array([0.8, 0.3])
    h0 = float(hamiltonian(MODEL, A, jnp.asarray(x0)))
    x = _run("leapfrog", x0, 200.0, 2000)
    # No drift over ~30 periods: the error stays at the O(dt²) level of a symplectic method.
    assert abs(float(hamiltonian(MODEL, A, jnp.asarray(x))) - h0) < 5e-3
