"""Damped Hamiltonians (issue 12, part 2): the conformally symplectic splitting, the damped
Runge–Kutta baseline, the damped model, its evidence and the damped pendulum.

Every check compares against something independent: the defining identity JᵀΩJ = e^{−γh}Ω of
a conformally symplectic map, the closed-form damped harmonic oscillator, SciPy's ODE solver
and matrix exponential, the undamped leapfrog, and the simulated truth.
"""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
from click.testing import CliRunner

import symplid
from symplid.cli import main
from symplid.dynamics._damping import (
    bind_dynamics,
    damped_dynamics,
    is_damped,
    with_damping,
)
from symplid.dynamics._integrators import (
    Integrator,
    get_integrator,
    leapfrog_step,
    make_dynamics,
)
from symplid.dynamics._systems import damped_pendulum
from symplid.dynamics._trajectory import solve
from symplid.inference._forecast import forecast_with_noise
from symplid.inference._predict import forecast_from_filter, predict_trajectory
from symplid.model import _kernel as kernel
from symplid.model._prior_spec import PriorSpec
from symplid.model._simulate import simulate
from symplid.studies._paper import ApproachResult, analyse_approach, cell_data, truth_path
from symplid.workflow._compare import comparison_table, fit_candidates
from symplid.workflow._scaling import Scaling
from symplid.workflow._settings import settings_from_dict, settings_to_dict
from symplid.workflow._sweep import cell_settings, sweep_spec_from_dict
from symplid.workflow._validate import SettingsError

HH = symplid.get_system("henon-heiles")


def omega_form(d: int) -> np.ndarray:
    return np.block([[np.zeros((d, d)), np.eye(d)], [-np.eye(d), np.zeros((d, d))]])


def step_jacobian(integrator, dynamics, x, h):
    d = x.shape[0] // 2

    def step(x):
        q, p = integrator.step(dynamics, x[:d], x[d:], h)
        return jnp.concatenate([q, p])

    return np.asarray(jax.jacfwd(step)(jnp.asarray(x)))


# ----------------------------------------------------------------------------- the step
@pytest.mark.parametrize("name", ["leapfrog", "yoshida4"])
def test_conformal_splitting_contracts_the_symplectic_form_by_exp_minus_gamma_h(name):
    gamma, h = 0.3, 0.1
    dynamics = damped_dynamics(make_dynamics(HH.potential, jnp.asarray(HH.coefficients)), gamma)
    x = np.array([0.2, -0.25, 0.3, -0.25])
    jac = step_jacobian(with_damping(name), dynamics, x, h)
    omega = omega_form(2)
    np.testing.assert_allclose(jac.T @ omega @ jac, math.exp(-gamma * h) * omega, atol=1e-13)
    # The Runge–Kutta baseline does not have the property (the test can fail).
    rk = step_jacobian(with_damping("rk4"), dynamics, x, h)
    assert np.max(np.abs(rk.T @ omega @ rk - math.exp(-gamma * h) * omega)) > 1e-9


def test_a_damped_integrator_is_given_its_rate_by_name():
    """γ is an argument of its own (the model's layout places it in θ), never the last entry
    of the parameters: without it a damped integrator refuses; with it, zero damping is the
    undamped flow exactly."""
    pot = symplid.Polynomial(1, 2)
    c = jnp.asarray(pot.coefficients_from({"q1^2": 0.5}))
    integ = with_damping("leapfrog")
    with pytest.raises(TypeError, match="gamma"):
        bind_dynamics(integ, pot, c)
    x = jnp.asarray([1.0, 0.0])
    damped = solve(integ, bind_dynamics(integ, pot, c, gamma=0.0), x, 0.1, 50, every=50)
    plain = symplid.get_integrator("leapfrog")
    undamped = solve(plain, bind_dynamics(plain, pot, c), x, 0.1, 50, every=50)
    np.testing.assert_array_equal(np.asarray(damped), np.asarray(undamped))


def test_rayleigh_damping_with_a_mass_matrix_uses_the_matrix_exponential():
    mass = np.array([[2.0, 0.5], [0.5, 1.0]])
    inv_mass = np.linalg.inv(mass)
    gamma, t = 0.4, 0.7
    dyn = damped_dynamics(make_dynamics(HH.potential, jnp.asarray(HH.coefficients), inv_mass),
                          gamma, jnp.asarray(inv_mass))
    p = np.array([0.3, -0.8])
    expected = scipy.linalg.expm(-gamma * t * inv_mass) @ p
    np.testing.assert_allclose(dyn.damp(jnp.asarray(p), t), expected, rtol=1e-13)
    # Phase-space volume contracts by det exp(−γhM⁻¹) = e^{−γh tr M⁻¹} per step.
    jac = step_jacobian(with_damping("leapfrog"), dyn, np.array([0.2, -0.1, 0.3, 0.4]), 0.1)
    assert np.linalg.det(jac) == pytest.approx(math.exp(-gamma * 0.1 * np.trace(inv_mass)),
                                               rel=1e-12)


@pytest.mark.parametrize("name", ["leapfrog", "yoshida4"])
def test_zero_damping_is_the_undamped_integrator_exactly(name):
    base = get_integrator(name)
    undamped = make_dynamics(HH.potential, jnp.asarray(HH.coefficients))
    damped = damped_dynamics(undamped, 0.0)
    q, p = jnp.asarray([0.2, -0.25]), jnp.asarray([0.3, -0.25])
    for a, b in zip(base.step(undamped, q, p, 0.25), with_damping(name).step(damped, q, p, 0.25),
                    strict=True):
        np.testing.assert_array_equal(a, b)


def damped_oscillator(t, gamma, omega=1.0):
    """q̈ + γq̇ + ω²q = 0 from (1, 0): the exact (q, p) at times t (underdamped)."""
    wd = math.sqrt(omega**2 - gamma**2 / 4)
    decay = np.exp(-gamma * t / 2)
    q = decay * (np.cos(wd * t) + gamma / (2 * wd) * np.sin(wd * t))
    p = -decay * np.sin(wd * t) * omega**2 / wd
    return np.stack([q, p], axis=-1)


@pytest.mark.parametrize(("name", "order"), [("leapfrog", 2), ("yoshida4", 4), ("rk4", 4)])
def test_damped_energy_decays_as_the_exact_solution(name, order):
    gamma, t_end = 0.2, 20.0
    pot = symplid.Polynomial(1, 2)
    c = jnp.asarray(pot.coefficients_from({"q1^2": 0.5}))
    integ = with_damping(name)
    errors = []
    for n in (400, 800):
        dyn = bind_dynamics(integ, pot, c, gamma=gamma)
        path = np.asarray(solve(integ, dyn, jnp.asarray([1.0, 0.0]), t_end / n, n, every=n // 20))
        times = np.linspace(0.0, t_end, 21)
        exact = damped_oscillator(times, gamma)
        energy = 0.5 * np.sum(path**2, axis=-1)
        exact_energy = 0.5 * np.sum(exact**2, axis=-1)
        errors.append(np.max(np.abs(energy - exact_energy)))
        assert np.max(np.abs(path - exact)) < 1e-3
    # The energy falls by about e^{−γt} (1/2 → 0.01 at t = 20), and the error falls with the
    # step at the method's order.
    assert exact_energy[-1] < 0.05 * exact_energy[0]
    assert errors[0] / errors[1] == pytest.approx(2.0**order, rel=0.15)


def test_damped_pendulum_truth_matches_an_ode_solver():
    system = symplid.get_system("damped-pendulum")
    assert system.damping > 0
    times = np.linspace(0.5, 10.0, 20)
    obs = simulate(system, times=times, noise_std=0.0)
    w2, g = float(system.coefficients[0]), system.damping

    def rhs(t, x):
        return [x[1], -w2 * math.sin(x[0]) - g * x[1]]

    ref = scipy.integrate.solve_ivp(rhs, (0, 10), system.initial_state, t_eval=times,
                                    rtol=1e-12, atol=1e-12, method="DOP853")
    np.testing.assert_allclose(obs.values, ref.y.T, atol=1e-6)


# ----------------------------------------------------------------------------- the model
def test_damped_model_layout_and_backends():
    model = symplid.HamiltonianModel(symplid.Polynomial(1, 4), damping=True)
    assert model.param_names == (
        "c[q1]", "c[q1^2]", "c[q1^3]", "c[q1^4]", "gamma", "process_var", "obs_var"
    )
    assert model.param_groups == ("coefficients",) * 4 + ("damping", "process_var", "obs_var")
    assert is_damped(model.integrator) and model.integrator.base.name == "leapfrog"
    theta = model.pack([0.0, 0.5, 0.0, -0.04], 1e-4, 0.01, gamma=0.1)
    assert float(model.damping_rate(theta)) == 0.1
    _, proc, obs = model.split(theta)
    assert float(proc[0, 0]) == 1e-4 and float(obs[0, 0]) == 0.01
    with pytest.raises(ValueError, match="needs a damping rate"):
        model.pack([0.0, 0.5, 0.0, -0.04], 1e-4, 0.01)
    step_only = Integrator("mine", 2, True, leapfrog_step)
    with pytest.raises(ValueError, match="'mine' cannot be damped"):
        symplid.HamiltonianModel(symplid.Polynomial(1, 4), integrator=step_only, damping=True)
    with pytest.raises(ValueError, match="pass damping=True"):
        symplid.HamiltonianModel(symplid.Polynomial(1, 4), integrator=model.integrator)
    # The compiled kernel declines, so "auto" falls back to the JAX reference.
    assert "damped" in kernel.unsupported_reason(model)
    assert model.likelihood_backend == "jax"
    assert symplid.HamiltonianModel(symplid.Polynomial(1, 4)).likelihood_backend != "jax" or (
        not kernel.available()
    )
    with pytest.raises(ValueError, match="damped"):
        symplid.HamiltonianModel(symplid.Polynomial(1, 4), damping=True, backend="compiled")
    # γ is bounded below by 0 and gets its own prior group.
    obs_data = simulate("damped-pendulum", times=[0.5, 1.0, 1.5])
    post = symplid.Posterior(model, obs_data, x0=[1.0, 0.0])
    i = post.param_names.index("gamma")
    assert post.param_groups[i] == "damping" and post.lower[i] == 0.0
    assert post.priors[i] == PriorSpec().damping


def test_damped_theta_with_the_observation_noise_models():
    """γ sits after the coefficients whatever the noise: then Σ, Γ per kind, relative r."""
    model = symplid.HamiltonianModel(
        symplid.Polynomial(1, 2), damping=True, noise="per-kind", observation_noise="both"
    )
    assert model.param_names == (
        "c[q1]", "c[q1^2]", "gamma", "process_var", "obs_var[q]", "obs_var[p]",
        "obs_rel_var[q]", "obs_rel_var[p]",
    )
    assert model.param_groups == (
        "coefficients", "coefficients", "damping", "process_var", "obs_var", "obs_var",
        "obs_rel_var", "obs_rel_var",
    )
    theta = model.pack([0.0, 0.5], 1e-4, [0.01, 0.02], [0.03, 0.04], gamma=0.1)
    assert float(model.damping_rate(theta)) == pytest.approx(0.1)
    _, proc, obs = model.split(theta)
    np.testing.assert_allclose(np.diag(proc), [1e-4, 1e-4])
    np.testing.assert_allclose(np.diag(obs), [0.01, 0.02])
    np.testing.assert_allclose(model.relative_variances(theta), [0.03, 0.04])
    only_rel = symplid.HamiltonianModel(
        symplid.Polynomial(1, 2), damping=True, observation_noise="multiplicative"
    )
    assert only_rel.param_names[2:] == ("gamma", "process_var", "obs_rel_var")
    theta = only_rel.pack([0.0, 0.5], 1e-4, obs_rel_var=0.01, gamma=0.2)
    assert float(only_rel.damping_rate(theta)) == pytest.approx(0.2)
    np.testing.assert_allclose(only_rel.relative_variances(theta), [0.01, 0.01])


def test_standardising_leaves_gamma_unchanged():
    """q' = q/a, p' = p/a keeps ṗ' = −∂U'/∂q' − γ M⁻¹p': the likelihood maps exactly with γ's
    factor 1 (log p(y | θ) = log p'(y' | θ') − N log a)."""
    system = damped_pendulum(gamma=0.1)
    obs = simulate(system, times=np.arange(0.5, 8.0, 0.5), noise_std=0.02, seed=2)
    a = 300.0
    big = symplid.Observations(obs.times, obs.values * a, obs.names)
    model = symplid.HamiltonianModel(symplid.Polynomial(1, 4), dt=0.25, damping=True)
    scaling = Scaling(a, (1, 2, 3, 4))
    factors = scaling.factors(model.param_groups)
    assert factors[model.param_names.index("gamma")] == 1.0
    theta_std = model.pack([0.0, 0.5, 0.0, -0.04], 1e-4, 4e-4, gamma=0.1)
    theta_user = theta_std * factors
    x0 = np.asarray(system.initial_state)
    ll_user = model.log_likelihood(theta_user, big, x0 * a, 1e-6 * a**2)
    ll_std = model.log_likelihood(theta_std, scaling.observations(big), x0, 1e-6)
    expected = float(ll_std) + scaling.log_likelihood_shift(big)
    assert float(ll_user) == pytest.approx(expected, rel=1e-9)


def test_zero_damping_likelihood_is_the_undamped_one_exactly(hh, hh_data):
    damped = symplid.HamiltonianModel(hh.potential, dt=0.25, damping=True)
    undamped = symplid.HamiltonianModel(hh.potential, dt=0.25, backend="jax")
    theta = undamped.pack(hh.coefficients, 1e-6, 0.05**2)
    theta_damped = damped.pack(hh.coefficients, 1e-6, 0.05**2, gamma=0.0)
    ll = undamped.log_likelihood(theta, hh_data, hh.initial_state)
    assert float(damped.log_likelihood(theta_damped, hh_data, hh.initial_state)) == float(ll)
    damped_more = damped.pack(hh.coefficients, 1e-6, 0.05**2, gamma=0.05)
    assert float(damped.log_likelihood(damped_more, hh_data, hh.initial_state)) < float(ll)


def test_predictions_and_noisy_forecasts_of_a_damped_model_follow_the_damped_flow():
    gamma = 0.2
    model = symplid.HamiltonianModel(symplid.Polynomial(1, 2), dt=0.05, damping=True)
    theta = model.pack([0.0, 0.5], 0.0, 0.01, gamma=gamma)
    times, path = predict_trajectory(model, theta, [1.0, 0.0], 10.0, dt=0.01)
    np.testing.assert_allclose(path, damped_oscillator(times, gamma), atol=1e-4)
    # The learned model's own propagator (dt = 0.05, no process noise) with rk4 as well.
    rk = symplid.HamiltonianModel(symplid.Polynomial(1, 2), dt=0.05, damping=True,
                                  integrator="rk4")
    grid = np.arange(1.0, 11.0)
    for m in (model, rk):
        fc = forecast_with_noise(m, theta[None], np.array([[1.0, 0.0]]), 0.0, grid, seed=0)
        np.testing.assert_allclose(fc.states[0], damped_oscillator(grid, gamma), atol=2e-3)


def test_forecast_from_the_filter_of_a_damped_model_continues_the_damped_flow():
    gamma = 0.2
    model = symplid.HamiltonianModel(symplid.Polynomial(1, 2), dt=0.1, damping=True)
    times = np.arange(1.0, 6.0)
    data = symplid.Observations(times, damped_oscillator(times, gamma), ("q1", "p1"))
    theta = np.tile(model.pack([0.0, 0.5], 1e-10, 1e-8, gamma=gamma), (4, 1))
    band = forecast_from_filter(model, theta, data, [1.0, 0.0], 15.0, dt=0.01, num_paths=0)
    exact = damped_oscillator(band.times, gamma)
    np.testing.assert_allclose(band.median, exact, atol=2e-3)
    assert band.integrator == "damped-leapfrog"


def test_damping_needs_a_separable_h_and_a_scheme():
    """A non-separable H(q, p; θ) has no −γM⁻¹p; Tao's and the implicit midpoint's steps have
    no scheme to damp. Each is a one-line error, from the model and from the settings."""
    from symplid.dynamics._hamiltonians import PolynomialHamiltonian
    from symplid.workflow._settings import resolve_for_data

    with pytest.raises(ValueError, match="needs a separable H"):
        symplid.HamiltonianModel(PolynomialHamiltonian(1, 2), integrator="rk4", damping=True)
    for name in ("tao", "implicit-midpoint", "gauss4"):
        with pytest.raises(ValueError, match=f"'{name}' cannot be damped"):
            symplid.HamiltonianModel(symplid.Polynomial(1, 2), integrator=name, damping=True)
    obs = simulate("damped-pendulum", times=np.arange(0.5, 10.0, 0.5))
    s = settings_from_dict({"model": {"damping": True, "hamiltonian": "mlp"},
                            "sampler": {"method": "nuts"}, "initial_state": {"x0": [1.0, 0.0]}})
    with pytest.raises(SettingsError, match=r"model\.damping"):
        resolve_for_data(s, obs)


def test_settings_key_and_prior_of_damping():
    s = settings_from_dict(
        {"model": {"damping": True}, "priors": {"damping": {"prior": "half-normal", "scale": 0.3}}}
    )
    assert s.model.damping is True and s.priors.damping == symplid.HalfNormal(0.3)
    assert settings_from_dict(settings_to_dict(s)) == s
    assert s.priors.prior_spec(False).damping == symplid.HalfNormal(0.3)
    with pytest.raises(SettingsError, match=r"model\.damping must be true or false"):
        settings_from_dict({"model": {"damping": "yes"}})


def test_a_sweep_varies_damping_by_its_settings_key():
    spec = sweep_spec_from_dict({
        "base": {"system": "damped-pendulum", "num_obs": 4, "obs_interval": 0.5},
        "sweep": {"grid": {"model.damping": [False, True]}},
    })
    models = [cell_settings(c.settings).model for c in spec.cells]
    assert [m.damping for m in models] == [False, True]
    system, data = cell_data(spec.cells[1].settings)
    assert system.damping == 0.1
    np.testing.assert_array_equal(data.values, simulate(system, times=data.times).values)


def test_paper_metrics_of_a_damped_fit_predict_with_its_gamma():
    # A sweep cell of the paper's experiment with model.damping = true: the MAP path of the
    # horizon metric is integrated with the learned γ (γ = 0: exactly the undamped metrics).
    names = (*HH.potential.param_names, "gamma", "process_var", "obs_var")
    truth_t, truth = truth_path(HH, 60.0, 0.01)

    def metrics(theta):
        theta = np.asarray(theta, dtype=float)
        keep = [i for i, n in enumerate(names) if n != "gamma" or len(theta) == len(names)]
        used = tuple(names[i] for i in keep)
        result = ApproachResult("x", "leapfrog", theta, np.tile(theta, (1, 2, 1)), used, {})
        return analyse_approach(result, HH, truth_t, truth, 60.0, 0.01)

    plain = metrics([*HH.coefficients, 1e-6, 0.0025])
    zero = metrics([*HH.coefficients, 0.0, 1e-6, 0.0025])
    damped = metrics([*HH.coefficients, 0.05, 1e-6, 0.0025])
    assert "gamma_map" not in plain and zero["gamma_map"] == 0.0
    assert zero["prediction_horizon_s"] == plain["prediction_horizon_s"] == 60.0
    assert zero["hamiltonian_rel_error"] == plain["hamiltonian_rel_error"]
    # γ = 0.05 shrinks the q1 swing of ~0.2 by e^{−γt/2}: off by 0.1 well before t = 60.
    assert damped["prediction_horizon_s"] < 30.0


# ----------------------------------------------------------------------------- identification
def _fits(gamma: float):
    """MAP of the undamped and the damped quartic model on damped-pendulum data with γ."""
    system = damped_pendulum(gamma=gamma)
    obs = simulate(system, times=np.arange(1.0, 21.0), seed=1)
    settings = settings_from_dict({
        "model": {"order": 4, "dt": 0.5},
        "initial_state": {"x0": list(system.initial_state)},
        "map": {"num_starts": 1},
    })
    return fit_candidates(obs, settings, progress=False, dampings=[False, True])


@pytest.fixture(scope="module")
def damped_fits():
    return _fits(0.1)


@pytest.fixture(scope="module")
def undamped_fits():
    return _fits(0.0)


@pytest.mark.slow
def test_gamma_is_recovered_from_damped_pendulum_data(damped_fits):
    fit = damped_fits[1]
    assert fit.damping
    names = list(fit.posterior.param_names)
    i = names.index("gamma")
    gamma, sd = fit.map_result.theta[i], math.sqrt(fit.map_result.covariance[i, i])
    assert abs(gamma - 0.1) < 3 * sd and sd < 0.02
    # The coefficients are the Taylor series of ω²(1 − cos q): ½ q² − q⁴/24 (ω² = 1).
    c = dict(zip(names, fit.map_result.theta, strict=True))
    assert c["c[q1^2]"] == pytest.approx(0.5, abs=0.03)
    assert c["c[q1^4]"] == pytest.approx(-1 / 24, abs=0.04)
    table = comparison_table(damped_fits)
    assert bool(table.loc[0, "damping"]) and table.loc[0, "gamma"] == pytest.approx(gamma)


@pytest.mark.slow
def test_evidence_prefers_no_damping_on_undamped_data(undamped_fits):
    undamped, damped = undamped_fits
    assert damped.damping and not undamped.damping
    assert undamped.map_result.log_evidence > damped.map_result.log_evidence + 2.0
    i = list(damped.posterior.param_names).index("gamma")
    assert damped.map_result.theta[i] < 0.01
    assert not comparison_table(undamped_fits).loc[0, "damping"]


# ----------------------------------------------------------------------------- command line
def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.slow
def test_cli_simulates_fits_with_damping_scores_holdout_and_forecasts(tmp_path):
    data = tmp_path / "pendulum.csv"
    result = run("simulate", "damped-pendulum", "--out", data, "--num-obs", "16", "--t-end", "16")
    assert result.exit_code == 0, result.output
    out = tmp_path / "fit"
    result = run(
        "fit", data, "--out", out, "--order", "2", "--dt", "0.5", "--damping", "--x0", "1,0",
        "--holdout", "0.25", "--iterations", "300", "--burn-in", "150", "--chains", "2",
        "--no-progress",
    )
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert 0 < summary["holdout"]["coverage_95"] <= 1
    names = json.loads((out / "map.json").read_text())["param_names"]
    assert "gamma" in names
    result = run("predict", out, "--from", "end", "--t-end", "20")
    assert result.exit_code == 0, result.output
    assert (out / "forecast.npz").exists()
