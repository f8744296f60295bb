"""Integrators: symplecticity, reversibility, measured order, energy behaviour, substeps."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import symplid
from symplid.dynamics._integrators import INTEGRATORS, get_integrator, make_dynamics
from symplid.dynamics._trajectory import integrate, propagate, solve, solve_gaps, substeps
from symplid.inference._predict import predict_trajectory

OMEGA = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.eye(2), np.zeros((2, 2))]])
NON_SYMPLECTIC = [name for name, integ in INTEGRATORS.items() if not integ.symplectic]
# Tao's methods carry a second copy of the state (their `start`): they are symplectic on the
# doubled phase space, not as a one-step map of (q, p) alone; tests/test_nonseparable.py
# checks their symplecticity, symmetry and order there.
EXTENDED = [name for name, integ in INTEGRATORS.items() if integ.start is not None]
SYMPLECTIC = [
    name for name, integ in INTEGRATORS.items() if integ.symplectic and name not in EXTENDED
]
# A generic phase-space point (not the initial state, not a fixed point).
POINT = np.array([0.15, -0.3, 0.35, 0.1])


@pytest.fixture(scope="module")
def hh_dynamics(hh):
    return make_dynamics(hh.potential, jnp.asarray(hh.coefficients))


def _flat_step(integrator, dynamics, dt):
    integ = get_integrator(integrator)

    def step(x):
        q, p = integ.step(dynamics, x[:2], x[2:], dt)
        return jnp.concatenate([q, p])

    return step


@functools.cache
def _runner(name: str):
    """Jitted ``(coefficients, x0, dt, n) -> x_n`` for Hénon–Heiles, compiled once per method."""
    integ = get_integrator(name)
    pot = symplid.get_system("henon-heiles").potential

    @jax.jit
    def run(coefficients, x0, dt, n):
        dynamics = make_dynamics(pot, coefficients)
        q, p = jax.lax.fori_loop(
            0, n, lambda _, c: integ.step(dynamics, c[0], c[1], dt), (x0[:2], x0[2:])
        )
        return jnp.concatenate([q, p])

    return run


def test_registry_declares_orders_and_symplecticity():
    expected = {
        "leapfrog": (2, True),
        "yoshida4": (4, True),
        "euler": (1, False),
        "rk2-midpoint": (2, False),
        "rk2-heun": (2, False),
        "rk4": (4, False),
        "tao": (2, True),
        "tao4": (4, True),
        "implicit-midpoint": (2, True),
        "gauss4": (4, True),
    }
    assert {n: (i.order, i.symplectic) for n, i in INTEGRATORS.items()} == expected
    assert get_integrator("rk2") is INTEGRATORS["rk2-midpoint"]
    with pytest.raises(ValueError, match="unknown integrator 'rk3'"):
        get_integrator("rk3")


@pytest.mark.parametrize("name", SYMPLECTIC)
def test_symplectic_methods_preserve_omega(name, hh_dynamics):
    jac = np.asarray(jax.jacfwd(_flat_step(name, hh_dynamics, 0.25))(jnp.asarray(POINT)))
    np.testing.assert_allclose(jac.T @ OMEGA @ jac, OMEGA, atol=1e-10, rtol=0)


@pytest.mark.parametrize("name", NON_SYMPLECTIC)
def test_non_symplectic_methods_do_not_preserve_omega(name, hh_dynamics):
    jac = np.asarray(jax.jacfwd(_flat_step(name, hh_dynamics, 0.25))(jnp.asarray(POINT)))
    # RK4's defect is O(dt⁵) ≈ 1e-5 here; the others are larger.
    assert np.max(np.abs(jac.T @ OMEGA @ jac - OMEGA)) > 1e-6


def test_leapfrog_with_mass_matrix_is_symplectic(hh):
    mass = np.array([[2.0, 0.3], [0.3, 1.0]])
    dyn = make_dynamics(hh.potential, jnp.asarray(hh.coefficients), jnp.linalg.inv(mass))
    jac = np.asarray(jax.jacfwd(_flat_step("leapfrog", dyn, 0.25))(jnp.asarray(POINT)))
    np.testing.assert_allclose(jac.T @ OMEGA @ jac, OMEGA, atol=1e-10, rtol=0)


@pytest.mark.parametrize("name", SYMPLECTIC)
def test_symmetric_methods_are_reversible(name, hh_dynamics):
    step = _flat_step(name, hh_dynamics, 0.25)
    flip = jnp.array([1.0, 1.0, -1.0, -1.0])
    x = jnp.asarray(POINT)
    for _ in range(5):  # several steps forward, flip p, as many forward, flip p
        x = step(x)
    x = flip * x
    for _ in range(5):
        x = step(x)
    np.testing.assert_allclose(flip * x, POINT, atol=1e-13, rtol=0)


def _henon_heiles_rhs(_t, x):
    q1, q2, p1, p2 = x
    return [p1, p2, -(q1 + 2 * q1 * q2), -(q2 + q1**2 - q2**2)]


@pytest.fixture(scope="module")
def order_reference(hh):
    """The exact Hénon–Heiles flow at T = 2 from POINT, by DOP853 at tight tolerance."""
    sol = solve_ivp(_henon_heiles_rhs, (0.0, 2.0), POINT, method="DOP853", rtol=1e-13, atol=1e-15)
    return sol.y[:, -1]


@pytest.mark.parametrize("name", [name for name in INTEGRATORS if name not in EXTENDED])
def test_measured_order_equals_declared_order(name, hh, order_reference):
    dts = np.array([0.1, 0.05, 0.025, 0.0125])
    run = _runner(name)
    errors = [
        np.linalg.norm(
            np.asarray(run(jnp.asarray(hh.coefficients), jnp.asarray(POINT), dt, round(2.0 / dt)))
            - order_reference
        )
        for dt in dts
    ]
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    assert slope == pytest.approx(get_integrator(name).order, abs=0.15), (slope, errors)


@pytest.fixture(scope="module")
def long_run_energies(hh, hh_dynamics):
    """H along 10,000 steps at dt = 0.25 from the paper's initial state, per method."""

    def energies(name):
        xs = integrate(name, hh_dynamics, hh.initial_state, 0.25, 10_000)
        return np.asarray(symplid.hamiltonian(hh.potential, hh.coefficients, xs))

    return {name: energies(name) for name in ("leapfrog", "rk2-midpoint")}


def test_leapfrog_energy_stays_in_a_band(long_run_energies):
    h = long_run_energies["leapfrog"]
    assert np.all(np.isfinite(h))
    # Bounded oscillation of size O(dt²) around H0 = 0.1227, no drift: the paper's Fig 2b.
    assert np.max(np.abs(h - h[0])) < 5e-3
    assert abs(np.mean(h[-1000:]) - np.mean(h[:1000])) < 1e-3


def test_rk2_energy_drifts_upward(long_run_energies):
    h = long_run_energies["rk2-midpoint"]
    h0 = h[0]
    # The paper: H ≈ 0.2 by t = 100 (400 steps); steadily rising before that.
    assert h[400] > 0.18
    assert h0 < h[100] < h[200] < h[400]
    # It eventually crosses the escape energy 1/6 and leaves the bounded region for good.
    assert np.nanmax(h) > 1.0 / 6.0
    assert not np.all(np.isfinite(h)) or h[-1] > 1.0 / 6.0


def test_substeps_ceiling_and_tolerance():
    n, h = substeps(np.array([5.0, 0.1, 1.1, 0.25, 0.5 + 1e-12]), 0.25)
    np.testing.assert_array_equal(n, [20, 1, 5, 1, 2])
    np.testing.assert_allclose(h, [0.25, 0.1, 0.22, 0.25, (0.5 + 1e-12) / 2], rtol=1e-15)
    # Observation times accumulated in floating point still give exactly 20 steps of 5 s.
    times = np.cumsum(np.full(20, 5.0)) * (1 + 3e-16)
    n, h = substeps(np.diff(np.concatenate([[0.0], times])), 0.25)
    assert np.all(n == 20)
    # A gap genuinely longer than 20 steps (beyond the 1e-9 tolerance) needs a 21st step.
    n, _ = substeps(np.array([5.0 * (1 + 1e-7)]), 0.25)
    assert n[0] == 21
    with pytest.raises(ValueError, match="dt must be a positive number"):
        substeps(np.array([1.0]), 0.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        substeps(np.array([1.0, 0.0]), 0.25)


@pytest.mark.parametrize("name", ["leapfrog", "rk4"])
def test_propagate_masks_steps_beyond_num_steps(name, hh_dynamics):
    integ = get_integrator(name)
    q0, p0 = jnp.asarray(POINT[:2]), jnp.asarray(POINT[2:])

    @jax.jit
    def run(num_steps):
        return propagate(integ, hh_dynamics, q0, p0, 0.2, num_steps, 7)

    for num in (1, 3, 7):
        q, p = q0, p0
        for _ in range(num):
            q, p = integ.step(hh_dynamics, q, p, 0.2)
        got = run(num)
        np.testing.assert_allclose(got[0], q, rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(got[1], p, rtol=1e-14, atol=1e-15)


def test_leapfrog_with_mass_conserves_its_hamiltonian(hh):
    mass = np.array([[2.0, 0.3], [0.3, 1.0]])
    inv_mass = np.linalg.inv(mass)
    dyn = make_dynamics(hh.potential, jnp.asarray(hh.coefficients), jnp.asarray(inv_mass))
    # q̇ = M⁻¹p: a tiny step moves q along M⁻¹p (checks that M is used, and how).
    q_next, _ = INTEGRATORS["leapfrog"].step(dyn, POINT[:2], POINT[2:], 1e-6)
    np.testing.assert_allclose((q_next - POINT[:2]) / 1e-6, inv_mass @ POINT[2:], rtol=1e-5)
    xs = integrate("leapfrog", dyn, POINT, 0.1, 3000)
    h = np.asarray(symplid.hamiltonian(hh.potential, hh.coefficients, xs, inv_mass))
    h_identity = np.asarray(symplid.hamiltonian(hh.potential, hh.coefficients, xs))
    assert np.max(np.abs(h - h[0])) < 1e-3
    # The identity-mass energy is not conserved along this trajectory: M matters.
    assert np.max(np.abs(h_identity - h_identity[0])) > 1e-2


# ---------------------------------------------------------------------------- the one solver
@pytest.mark.parametrize("name", ["leapfrog", "yoshida4", "rk4"])
def test_simulate_predict_and_integrate_agree(name, hh, hh_dynamics):
    """The three ways to integrate a path (simulated truth at observation times, a prediction
    stored every 50 steps, every state) share one solver: same integrator, same dt, same path."""
    times = 0.5 * np.arange(1, 11)
    simulated = symplid.simulate(
        hh, times=times, noise_std=0.0, dt=0.01, integrator=name
    ).values
    t_pred, predicted = predict_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, 5.0, dt=0.01, integrator=name, every=50
    )
    every_state = np.asarray(integrate(name, hh_dynamics, hh.initial_state, 0.01, 500))
    np.testing.assert_allclose(t_pred[1:], times, rtol=0, atol=1e-12)
    np.testing.assert_allclose(predicted[1:], simulated, rtol=0, atol=1e-12)
    np.testing.assert_allclose(every_state[50::50], simulated, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(every_state[0], hh.initial_state)


@pytest.mark.parametrize("name", ["leapfrog", "rk2-midpoint"])
@pytest.mark.parametrize("every", [3, 7, 40])
def test_solve_every_k_keeps_every_kth_state(name, every, hh_dynamics):
    full = np.asarray(solve(name, hh_dynamics, POINT, 0.05, 40))
    sub = np.asarray(solve(name, hh_dynamics, POINT, 0.05, 40, every=every))
    kept = list(range(0, 41, every)) + ([40] if 40 % every else [])
    assert sub.shape == (len(kept), 4)
    np.testing.assert_allclose(sub, full[kept], rtol=0, atol=1e-13)


def test_solve_batches_over_leading_axes(hh_dynamics):
    x0 = POINT + 0.02 * np.arange(12.0).reshape(3, 1, 4) / 12.0  # shape (3, 1, 4)
    out = np.asarray(solve("yoshida4", hh_dynamics, x0, 0.1, 25, every=4))
    assert out.shape == (3, 1, 8, 4)
    for i in range(3):
        one = np.asarray(solve("yoshida4", hh_dynamics, x0[i, 0], 0.1, 25, every=4))
        np.testing.assert_allclose(out[i, 0], one, rtol=0, atol=1e-14)


def test_solve_gaps_matches_solve_and_its_loop_bounds(hh_dynamics):
    """Gaps of 4, 4, 4 steps give the stored states of ``solve(every=4)``; a static, masked
    bound (the likelihood's form) gives the same states as the exact one."""
    ref = np.asarray(solve("leapfrog", hh_dynamics, POINT, 0.1, 12, every=4))[1:]
    sizes, steps = np.full(3, 0.1), np.array([4, 4, 4])
    for kwargs in ({}, {"max_steps": 4, "masked": False}, {"max_steps": 6}):
        got = np.asarray(solve_gaps("leapfrog", hh_dynamics, POINT, sizes, steps, **kwargs))
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14)
    # Irregular gaps: each gap's own step, as in the simulated truth.
    got = np.asarray(solve_gaps("rk4", hh_dynamics, POINT, [0.1, 0.05, 0.2], [2, 3, 1]))
    x = POINT
    for h, n in ((0.1, 2), (0.05, 3), (0.2, 1)):
        x = np.asarray(solve("rk4", hh_dynamics, x, h, n))[-1]
    np.testing.assert_allclose(got[-1], x, rtol=0, atol=1e-14)


def test_solve_rejects_bad_counts(hh_dynamics):
    with pytest.raises(ValueError, match="every must be an integer ≥ 1"):
        solve("leapfrog", hh_dynamics, POINT, 0.1, 10, every=0)
    with pytest.raises(ValueError, match="num_steps must be an integer ≥ 0"):
        solve("leapfrog", hh_dynamics, POINT, 0.1, 2.5)
    np.testing.assert_array_equal(solve("leapfrog", hh_dynamics, POINT, 0.1, 0), POINT[None])


def test_schemes_check_their_shape_and_declared_order():
    """A method given as data is checked when it is made: the registered ones pass Butcher's and
    the composition's conditions of their declared order; a weight or tableau entry off by a
    typo, or a declared order the method lacks, is a ValueError (not a silently worse method)."""
    from symplid.dynamics._integrators import runge_kutta_integrator, symplectic_integrator
    from symplid.dynamics._schemes import ButcherTableau, Composition

    rk4 = get_integrator("rk4").scheme
    assert isinstance(rk4, ButcherTableau)
    assert max(rk4.order_residuals().values()) < 1e-15
    assert isinstance(get_integrator("yoshida4").scheme, Composition)
    # Heun's method is of order 2, not 3: Σ b c² = 1/2 and Σ b a c = 0 against 1/3 and 1/6
    heun = get_integrator("rk2-heun").scheme
    assert heun.order_residuals()[3] == pytest.approx(1 / 6)
    with pytest.raises(ValueError, match="order-3 condition"):
        runge_kutta_integrator("bad", 3, heun.a, heun.b, "")
    third = (1 / 3, 1 / 3, 1 / 3)  # symmetric and consistent, but Σ w³ = 1/9, not 0
    assert Composition(third).weights == third
    with pytest.raises(ValueError, match="Σ w³ = 0"):
        symplectic_integrator("bad", 4, third, "")
    with pytest.raises(ValueError, match="sum to 1"):
        Composition((0.5, 0.6, 0.5))
    with pytest.raises(ValueError, match="palindrome"):
        Composition((0.2, 0.8))
    with pytest.raises(ValueError, match="lower-triangular"):
        ButcherTableau(((0.0, 1.0), (0.5, 0.0)), (0.5, 0.5))
