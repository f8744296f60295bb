"""Non-separable Hamiltonians: the H kinds, Tao's methods, the implicit midpoint rule, the
double pendulum, and the model, settings and predictions built on them."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._hamiltonians import (
    DoublePendulum,
    FunctionHamiltonian,
    PolynomialHamiltonian,
    PositionDependentMass,
    SeparableHamiltonian,
)
from symplid.dynamics._integrators import GeneralDynamics, get_integrator, make_dynamics
from symplid.dynamics._nonseparable import tao_extended_step
from symplid.dynamics._trajectory import propagate, solve
from symplid.model import _kernel as kernel

# A non-separable H in one degree of freedom: a mass that grows with |q| and a q·p coupling.
H1 = FunctionHamiltonian(
    lambda q, p, c: 0.5 * (1.0 + c[0] * q[0] ** 2) * p[0] ** 2 + 0.5 * q[0] ** 2
    + c[1] * q[0] * p[0] ** 3,
    dim=1,
    num_params=2,
)
C1 = jnp.array([0.5, 0.1])
X1 = jnp.array([0.8, 0.3])
PHYSICAL = {"m1": 1.3, "m2": 0.7, "l1": 1.1, "l2": 0.8, "g": 9.81}


def omega(n: int) -> np.ndarray:
    """The standard symplectic form for coordinates (q_1..q_n, p_1..p_n)."""
    return np.block([[np.zeros((n, n)), np.eye(n)], [-np.eye(n), np.zeros((n, n))]])


# ----------------------------------------------------------------------------- the H kinds
def test_polynomial_hamiltonian_gradients_match_autodiff_of_its_value():
    ham = PolynomialHamiltonian(dim=2, order=3)
    c = np.random.default_rng(0).normal(size=ham.num_params)
    q, p = jnp.array([0.3, -0.7]), jnp.array([0.4, 0.9])
    fn = FunctionHamiltonian(lambda a, b, cc: ham.value(a, b, cc), 2, ham.num_params)
    np.testing.assert_allclose(ham.grad_q(q, p, c), fn.grad_q(q, p, c), rtol=1e-13)
    np.testing.assert_allclose(ham.grad_p(q, p, c), fn.grad_p(q, p, c), rtol=1e-13)
    assert ham.param_names[:5] == ("q1", "q2", "p1", "p2", "q1^2")
    c2 = ham.coefficients_from({"q1*p2": 2.0})
    assert float(ham.value(q, p, c2)) == pytest.approx(2.0 * 0.3 * 0.9)


def test_batches_follow_the_potential_convention():
    q = jnp.linspace(-1, 1, 12).reshape(1, 3, 4)
    p = jnp.linspace(0.5, -0.5, 12).reshape(1, 3, 4)
    batched = H1.grad_q(q, p, C1)
    assert batched.shape == (1, 3, 4) and H1.value(q, p, C1).shape == (3, 4)
    one = H1.grad_q(q[:, 1, 2], p[:, 1, 2], C1)
    np.testing.assert_allclose(batched[:, 1, 2], one, rtol=1e-14)


def test_position_dependent_mass_matches_the_double_pendulum_closed_form():
    """The double pendulum written generically (Cholesky solve) against its closed form."""

    def mass(q, c):
        mu, lam = jnp.exp(c[0]), jnp.exp(c[1])
        off = lam * jnp.cos(q[0] - q[1])
        return jnp.array([[(1 + mu) * lam**2, off], [off, 1.0]])

    def potential(q, c):
        mu, lam, g = jnp.exp(c[0]), jnp.exp(c[1]), 9.81 * jnp.exp(c[2])
        return -(1 + mu) * g * lam * jnp.cos(q[0]) - g * jnp.cos(q[1])

    generic = PositionDependentMass(mass, potential, dim=2, num_params=3)
    closed = DoublePendulum()
    theta = closed.params_from(**PHYSICAL)
    q, p = jnp.array([[0.4, -1.2], [2.0, 0.3]]), jnp.array([[0.7, 0.1], [-0.5, 1.5]])
    for f in ("value", "grad_q", "grad_p"):
        np.testing.assert_allclose(
            getattr(generic, f)(q, p, theta), getattr(closed, f)(q, p, theta), rtol=1e-12
        )


def test_double_pendulum_matches_an_independent_lagrangian_derivation():
    """φ̈ from the Euler–Lagrange equations of the physical pendulum, written out by hand,
    against d/dt(∂H/∂p) along Hamilton's equations of the scaled H."""
    m1, m2, l1, l2, g = (PHYSICAL[k] for k in ("m1", "m2", "l1", "l2", "g"))
    ham = DoublePendulum()
    theta = jnp.asarray(ham.params_from(m1, m2, l1, l2, g))
    rng = np.random.default_rng(1)
    for _ in range(4):
        phi, dphi = rng.uniform(-2, 2, size=2), rng.uniform(-3, 3, size=2)
        d = phi[0] - phi[1]
        # (m1+m2) l1 φ̈1 + m2 l2 cos Δ φ̈2 = −m2 l2 φ̇2² sin Δ − (m1+m2) g sin φ1
        # l1 cos Δ φ̈1 + l2 φ̈2 = l1 φ̇1² sin Δ − g sin φ2
        a = np.array([[(m1 + m2) * l1, m2 * l2 * np.cos(d)], [l1 * np.cos(d), l2]])
        b = np.array([-m2 * l2 * dphi[1] ** 2 * np.sin(d) - (m1 + m2) * g * np.sin(phi[0]),
                      l1 * dphi[0] ** 2 * np.sin(d) - g * np.sin(phi[1])])
        expected = np.linalg.solve(a, b)
        q = jnp.asarray(phi)
        p = ham.momenta(q, jnp.asarray(dphi), theta)
        np.testing.assert_allclose(ham.grad_p(q, p, theta), dphi, rtol=1e-12)
        p_dot = -ham.grad_q(q, p, theta)
        _, accel = jax.jvp(lambda a_, b_: ham.grad_p(a_, b_, theta), (q, p), (jnp.asarray(dphi),
                                                                               p_dot))
        np.testing.assert_allclose(accel, expected, rtol=1e-10)


# ----------------------------------------------------------------------------- integrators
def test_tao_maps_are_symplectic_on_the_doubled_phase_space():
    """Tao's map of (q, p, x, y), coordinates (q, x) and momenta (p, y): JᵀΩJ = Ω."""
    dyn = make_dynamics(H1, C1)
    w0 = jnp.array([0.8, 0.75, 0.3, 0.35])  # (q, x, p, y): the copies slightly apart
    for weights in ((1.0,), get_integrator("tao4").weights):

        def step(w, weights=weights):
            q, p, x, y = tao_extended_step(dyn, (w[0:1], w[2:3], w[1:2], w[3:4]), 0.1, 10.0,
                                           weights)
            return jnp.concatenate([q, x, p, y])

        jac = np.asarray(jax.jacfwd(step)(w0))
        np.testing.assert_allclose(jac.T @ omega(2) @ jac, omega(2), atol=1e-10, rtol=0)


@pytest.mark.parametrize("name", ["tao", "tao4"])
def test_registered_tao_step_with_its_carry_is_symplectic_and_not_on_q_p_alone(name):
    """The carried map (mean, half-difference of the copies) is a linear change of variables
    of Tao's map, so it keeps the form; the (q, p) map alone with copies re-started does not."""
    integ = get_integrator(name)
    dyn = make_dynamics(H1, C1)

    def carried(w):  # w = (q̄, u, p̄, v)
        q, p, aux = integ.force_step(dyn, w[0:1], w[2:3], jnp.stack([w[1], w[3]]), 0.1)
        return jnp.concatenate([q, aux[:1], p, aux[1:]])

    jac = np.asarray(jax.jacfwd(carried)(jnp.array([0.8, 0.02, 0.3, -0.01])))
    np.testing.assert_allclose(jac.T @ omega(2) @ jac, omega(2), atol=1e-10, rtol=0)
    plain = np.asarray(
        jax.jacfwd(lambda x: jnp.concatenate(integ.step(dyn, x[:1], x[1:], 0.1)))(X1)
    )
    assert np.max(np.abs(plain.T @ omega(1) @ plain - omega(1))) > 1e-8


@pytest.mark.parametrize("name", ["implicit-midpoint", "gauss4"])
def test_gauss_legendre_methods_are_symplectic_and_symmetric_on_a_non_separable_h(name):
    ham = DoublePendulum()
    dyn = make_dynamics(ham, jnp.asarray(ham.params_from(**PHYSICAL)))
    integ = get_integrator(name)

    def step(x, h=0.05):
        return jnp.concatenate(integ.step(dyn, x[:2], x[2:], h))

    x = jnp.array([1.0, 0.5, 0.3, -0.2])
    jac = np.asarray(jax.jacfwd(step)(x))
    np.testing.assert_allclose(jac.T @ omega(2) @ jac, omega(2), atol=1e-10, rtol=0)
    np.testing.assert_allclose(step(step(x), -0.05), x, atol=1e-13, rtol=0)


@functools.cache
def _gap_runner(name: str, ham, max_steps: int):
    """Jitted ``(x0, h, n) -> x_n`` through :func:`propagate`: one compilation per method."""
    integ = get_integrator(name)

    @jax.jit
    def run(params, x0, h, n):
        d = x0.shape[0] // 2
        q, p = propagate(integ, make_dynamics(ham, params), x0[:d], x0[d:], h, n, max_steps)
        return jnp.concatenate([q, p])

    return run


@pytest.mark.parametrize("name", ["tao", "tao4", "implicit-midpoint", "gauss4"])
def test_measured_order_equals_declared_order_on_a_non_separable_h(name):
    reference = _gap_runner("rk4", H1, 640)(C1, X1, 1.0 / 640, 640)
    run = _gap_runner(name, H1, 640)
    ns = np.array([40, 80, 160])  # steps 0.025..0.00625 at ω = 10: the asymptotic range
    errors = [float(jnp.linalg.norm(run(C1, X1, 1.0 / n, n) - reference)) for n in ns]
    slope = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert slope == pytest.approx(get_integrator(name).order, abs=0.2), (slope, errors)


def _h1_rhs(t, x, a=float(C1[0]), b=float(C1[1])):
    """Hamilton's equations of H1 written out by hand (independent of JAX)."""
    q, p = x
    return [(1.0 + a * q * q) * p + 3.0 * b * q * p * p, -(a * q * p * p + q + b * p ** 3)]


@pytest.mark.parametrize("name", ["tao", "tao4", "implicit-midpoint", "gauss4"])
def test_order_against_dop853_on_a_non_separable_h(name):
    """The error at T = 1 against SciPy's DOP853 at tight tolerance falls at the declared
    order (the same methods' errors, with a reference from outside symplid)."""
    from scipy.integrate import solve_ivp

    reference = solve_ivp(_h1_rhs, (0.0, 1.0), np.asarray(X1), method="DOP853", rtol=1e-13,
                          atol=1e-15).y[:, -1]
    run = _gap_runner(name, H1, 640)
    ns = np.array([40, 80, 160])
    errors = [float(np.linalg.norm(np.asarray(run(C1, X1, 1.0 / n, n)) - reference))
              for n in ns]
    slope = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert slope == pytest.approx(get_integrator(name).order, abs=0.2), (slope, errors)


@pytest.mark.parametrize(("name", "separable"), [("tao", "leapfrog"), ("tao4", "yoshida4"),
                                                 ("implicit-midpoint", "leapfrog"),
                                                 ("gauss4", "yoshida4")])
def test_on_a_separable_h_they_agree_with_leapfrog_to_their_order(name, separable, hh):
    """Hénon–Heiles as a whole H: the difference to the separable method shrinks at the
    declared order of both."""
    as_h = SeparableHamiltonian(hh.potential)
    c = jnp.asarray(hh.coefficients)
    x0 = jnp.asarray(hh.initial_state)
    ns = np.array([80, 160])  # steps 0.025 and 0.0125: tao4's asymptotic range at ω = 10
    ours = _gap_runner(name, as_h, 160)
    theirs = _gap_runner(separable, hh.potential, 160)
    diffs = [float(jnp.linalg.norm(ours(c, x0, 2.0 / n, n) - theirs(c, x0, 2.0 / n, n)))
             for n in ns]
    order = get_integrator(name).order
    assert np.log2(diffs[0] / diffs[1]) == pytest.approx(order, abs=0.3), diffs
    assert diffs[1] < 1e-4


def test_separable_only_integrators_refuse_a_non_separable_h():
    dyn = make_dynamics(H1, C1)
    assert isinstance(dyn, GeneralDynamics)
    with pytest.raises(ValueError, match=r"needs a separable H.*tao"):
        solve("leapfrog", dyn, X1, 0.1, 3)
    with pytest.raises(ValueError, match="needs a separable H"):
        symplid.HamiltonianModel(H1, integrator="yoshida4")
    with pytest.raises(ValueError, match="binding"):
        symplid.HamiltonianModel(H1, integrator="rk4", binding=5.0)
    with pytest.raises(ValueError, match="mass"):
        symplid.HamiltonianModel(H1, integrator="tao", mass=[2.0])


def test_runge_kutta_runs_a_non_separable_h_at_its_order():
    """RK4 on H1 against a second implementation: RK4 written out on Hamilton's equations."""
    def f(x):
        q, p = x[:1], x[1:]
        return jnp.concatenate([H1.grad_p(q, p, C1), -H1.grad_q(q, p, C1)])

    x, h = X1, 0.1
    for _ in range(5):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(solve("rk4", make_dynamics(H1, C1), X1, h, 5)[-1], x, rtol=1e-13)


# ----------------------------------------------------------------------------- the model
@pytest.fixture(scope="module")
def pendulum():
    return symplid.get_system("double-pendulum")


@pytest.fixture(scope="module")
def pendulum_data(pendulum):
    return symplid.simulate(pendulum, seed=3)


def test_the_model_takes_a_hamiltonian_and_the_kernel_declines_it(pendulum):
    model = symplid.HamiltonianModel(pendulum.potential, integrator="tao", dt=0.05,
                                     observation="positions")
    assert model.param_names[:3] == ("log_mass_ratio", "log_length_ratio",
                                     "log_gravity_per_length")
    assert model.num_params == 5 and not model.separable
    assert model.integrator.binding == pytest.approx(1 / 0.05)
    assert kernel.unsupported_reason(model) is not None
    assert model.likelihood_backend == "jax"
    tao_on_polynomial = symplid.HamiltonianModel(symplid.Polynomial(2, 3), integrator="tao")
    assert kernel.unsupported_reason(tao_on_polynomial) is not None
    x = np.array([[1.0, 0.5, 0.2, -0.1]])
    h = model.energy(pendulum.coefficients, x)
    assert float(h[0]) == pytest.approx(
        float(pendulum.potential.value(x[0, :2], x[0, 2:], pendulum.coefficients)))


def test_simulate_observes_the_angles_with_the_system_truth(pendulum, pendulum_data):
    assert pendulum_data.values.shape == (40, 2)
    truth = symplid.true_trajectory(pendulum.potential, pendulum.coefficients,
                                    pendulum.initial_state, pendulum_data.times, dt=1e-3,
                                    integrator="rk4")
    residual = pendulum_data.values - truth[:, :2]
    assert 0.01 < np.std(residual) < 0.03  # the system's noise, 0.02


@pytest.fixture(scope="module")
def pendulum_map(pendulum, pendulum_data):
    """MAP and Laplace covariance with Tao's propagator at dt = 0.025 (at dt = 0.05 its
    error over a gap, up to 1e-2 in p, biases the ratios by 3–7 Laplace sd). The tests read
    θ and its Laplace sd only: the evidence's quadrature over the two variances (about 160
    profile fits with Hessians of this non-separable filter, minutes) is left out."""
    model = symplid.HamiltonianModel(pendulum.potential, integrator="tao", dt=0.025,
                                     observation="positions")
    posterior = symplid.Posterior(model, pendulum_data, x0=pendulum.initial_state, P0=1e-8)
    truth = np.concatenate([pendulum.coefficients, [1e-6, 4e-4]])
    start = truth * np.array([1.3, 0.6, 1.1, 1.0, 1.0])  # a start off the truth
    return model, symplid.find_map(posterior, init=start, num_starts=1, warn=False,
                                   evidence="laplace")


@pytest.mark.slow
def test_map_from_40_noisy_angle_pairs_recovers_the_ratios(pendulum, pendulum_map):
    """The truth of each identified combination lies in the MAP's Laplace 95 % interval."""
    _, result = pendulum_map
    theta, std = np.asarray(result.theta), np.asarray(result.std)
    for i in range(3):
        assert abs(theta[i] - pendulum.coefficients[i]) < 1.96 * std[i], (i, theta, std)
        assert std[i] < 0.2  # identified, not left to the prior (Laplace scale 10)


@pytest.mark.slow
def test_prediction_of_the_learned_pendulum_uses_a_non_separable_integrator(
    pendulum, pendulum_map
):
    model, result = pendulum_map
    times, path = symplid.predict.predict_trajectory(
        model, result.theta, pendulum.initial_state, 2.0, dt=0.01, integrator="tao4"
    )
    truth = symplid.true_trajectory(pendulum.potential, pendulum.coefficients,
                                    pendulum.initial_state, times[1:], dt=1e-3, integrator="rk4")
    assert np.max(np.abs(path[1:, :2] - truth[:, :2])) < 0.1
    with pytest.raises(ValueError, match="needs a separable H"):
        symplid.predict.predict_trajectory(model, result.theta, pendulum.initial_state, 1.0)


# ----------------------------------------------------------------------------- settings, CLI
def test_settings_name_the_hamiltonian_and_its_integrators(pendulum_data):
    from symplid.workflow._fit import build_model
    from symplid.workflow._settings import SettingsError, resolve_for_data, settings_from_dict

    base = {"initial_state": {"x0": [1.0, 0.5, 0.0, 0.0]}}
    good = settings_from_dict({
        **base, "model": {"hamiltonian": "double-pendulum", "integrator": "tao", "binding": 5.0,
                          "dt": 0.05},
        "prediction": {"integrator": "tao4"},
    })
    model = build_model(resolve_for_data(good, pendulum_data), pendulum_data)
    assert isinstance(model.hamiltonian, DoublePendulum) and model.integrator.binding == 5.0
    assert model.observation == "positions"
    leapfrog = settings_from_dict({**base, "model": {"hamiltonian": "double-pendulum"}})
    with pytest.raises(SettingsError, match=r"model\.integrator 'leapfrog' needs a separable H"):
        resolve_for_data(leapfrog, pendulum_data)
    prediction = settings_from_dict({**base, "model": {"hamiltonian": "double-pendulum",
                                                       "integrator": "rk4"}})
    with pytest.raises(SettingsError, match=r"prediction\.integrator"):
        resolve_for_data(prediction, pendulum_data)
    binding = settings_from_dict({**base, "model": {"binding": 3.0}})
    with pytest.raises(SettingsError, match=r"model\.binding is Tao's"):
        resolve_for_data(binding, pendulum_data)
    qp = settings_from_dict({**base, "model": {"hamiltonian": "polynomial-qp", "order": 2,
                                               "integrator": "implicit-midpoint", "dt": 0.05},
                             "prediction": {"integrator": "implicit-midpoint"}})
    model = build_model(resolve_for_data(qp, pendulum_data), pendulum_data)
    assert model.num_coefficients == PolynomialHamiltonian(2, 2).num_params == 14


def test_sweep_cells_carry_the_same_keys():
    from symplid.studies._paper import cell_data
    from symplid.workflow._sweep_spec import cell_settings, sweep_spec_from_dict

    spec = sweep_spec_from_dict({
        "base": {"system": "double-pendulum", "model.hamiltonian": "double-pendulum",
                 "prediction.integrator": "tao4", "dt": 0.05, "model.binding": 10.0},
        "sweep": {"grid": {"integrator": ["tao", "implicit-midpoint"]}},
    })
    assert [c.settings["integrator"] for c in spec.cells] == ["tao", "implicit-midpoint"]
    settings = cell_settings(spec.cells[0].settings)
    assert settings.model.hamiltonian == "double-pendulum" and settings.model.binding == 10.0
    assert settings.initial_state.x0 == (1.0, 0.5, 0.0, 0.0)  # the system's, known
    system, data = cell_data(spec.cells[0].settings)
    assert system.name == "double-pendulum" and data.values.shape == (40, 2)


def test_cli_simulates_the_double_pendulum_angles(tmp_path):
    from click.testing import CliRunner

    from symplid.cli import main
    from symplid.io import read_observations

    out = tmp_path / "dp.csv"
    result = CliRunner().invoke(main, ["simulate", "double-pendulum", "--out", str(out),
                                       "--num-obs", "8", "--t-end", "2"])
    assert result.exit_code == 0, result.output
    obs = read_observations(out)
    assert obs.names == ("q1", "q2") and obs.values.shape == (8, 2)
