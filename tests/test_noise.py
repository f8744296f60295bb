"""Observation-noise models (additive, multiplicative, both) and per-kind variances.

The multiplicative filter is checked against the exact moments of y = Hx∘(1 + ε) + η for a
Gaussian state pushed through a linear map (a harmonic oscillator's leapfrog steps are linear),
and those moments against a Monte-Carlo estimate that simulates the model draw by draw.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

import symplid
from symplid.filters._noise import OBSERVATION_NOISE
from symplid.inference._forecast import forecast_with_noise
from symplid.model._kernel import unsupported_reason

# A 1-D harmonic oscillator U = ½q²: leapfrog is a linear map, so the UKF's prediction is
# exact and the predicted state is Gaussian.
DT, NUM_STEPS = 0.1, 3
X0 = np.array([1.0, 0.5])
P0 = np.diag([0.04, 0.09])
PROC, OBS_VAR, REL_VAR = 1e-6, 0.01, 0.04


def _model(noise_model: str, **kw) -> symplid.HamiltonianModel:
    return symplid.HamiltonianModel(
        symplid.Polynomial(dim=1, order=2), dt=DT, observation_noise=noise_model, **kw
    )


def _theta(model: symplid.HamiltonianModel) -> np.ndarray:
    obs = [OBS_VAR] * model.num_obs_noise
    rel = [REL_VAR] * model.num_rel_noise
    return model.pack([0.0, 0.5], PROC, obs, rel)


def _leapfrog_matrix() -> np.ndarray:
    """The one-gap map of leapfrog on U = ½q², written out (kick, drift, kick)."""
    kick = np.array([[1.0, 0.0], [-0.5 * DT, 1.0]])
    drift = np.array([[1.0, DT], [0.0, 1.0]])
    return np.linalg.matrix_power(kick @ drift @ kick, NUM_STEPS)


def _exact_moments(noise_model: str) -> tuple[np.ndarray, np.ndarray]:
    """E[y], Cov[y] for x ~ N(A x0, A P0 Aᵀ + Σ), y = x∘(1 + ε) + η (module docstring)."""
    A = _leapfrog_matrix()
    m = A @ X0
    P = A @ P0 @ A.T + PROC * np.eye(2)
    cov = P.copy()
    entry = OBSERVATION_NOISE[noise_model]
    if entry.multiplicative:
        cov += np.diag(REL_VAR * (m**2 + np.diag(P)))
    if entry.additive:
        cov += OBS_VAR * np.eye(2)
    return m, cov


def _one_observation(y, mask=None) -> symplid.Observations:
    values = np.array([y], dtype=float)
    if mask is not None:
        values[0, ~np.asarray(mask)] = np.nan
    return symplid.Observations(np.array([DT * NUM_STEPS]), values, ("q1", "p1"))


@pytest.mark.parametrize("noise_model", ["additive", "multiplicative", "both"])
def test_one_step_likelihood_is_the_exact_gaussian_of_the_moments(noise_model):
    model = _model(noise_model, backend="jax")
    mean, cov = _exact_moments(noise_model)
    for y in (mean + np.array([0.1, -0.2]), mean - np.array([0.3, 0.05])):
        ll = model.log_likelihood(_theta(model), _one_observation(y), X0, P0)
        assert float(ll) == pytest.approx(multivariate_normal(mean, cov).logpdf(y), abs=1e-9)


def test_exact_moments_equal_monte_carlo_of_the_model():
    """Draw x0, push each draw through leapfrog, add process noise, multiply by (1 + ε) and
    add η: the sample mean and covariance match the moments the filter uses."""
    rng = np.random.default_rng(1)
    n = 400_000
    x = rng.multivariate_normal(X0, P0, size=n)
    q, p = x[:, 0], x[:, 1]
    for _ in range(NUM_STEPS):  # leapfrog on U = ½q², draw by draw
        p = p - 0.5 * DT * q
        q = q + DT * p
        p = p - 0.5 * DT * q
    x = np.stack([q, p], axis=1) + np.sqrt(PROC) * rng.standard_normal((n, 2))
    y = x * (1 + np.sqrt(REL_VAR) * rng.standard_normal((n, 2)))
    y = y + np.sqrt(OBS_VAR) * rng.standard_normal((n, 2))
    mean, cov = _exact_moments("both")
    standard_error = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(y.mean(axis=0) - mean) < 4 * standard_error)
    np.testing.assert_allclose(np.cov(y.T), cov, rtol=0.01, atol=5e-4)
    # and the filter's one-step log-likelihood is the Gaussian density of those MC moments
    model = _model("both", backend="jax")
    y_obs = mean + np.array([0.1, -0.2])
    ll = float(model.log_likelihood(_theta(model), _one_observation(y_obs), X0, P0))
    mc = multivariate_normal(y.mean(axis=0), np.cov(y.T)).logpdf(y_obs)
    assert ll == pytest.approx(mc, abs=0.02)


def test_missing_component_uses_the_marginal_of_the_observed_one():
    model = _model("multiplicative", backend="jax")
    mean, cov = _exact_moments("multiplicative")
    y = mean + np.array([0.2, 0.0])
    ll = model.log_likelihood(_theta(model), _one_observation(y, mask=[True, False]), X0, P0)
    expected = multivariate_normal(mean[:1], cov[:1, :1]).logpdf(y[:1])
    assert float(ll) == pytest.approx(expected, abs=1e-9)


@pytest.fixture(scope="module")
def series() -> symplid.Observations:
    """Eight noisy full-state observations of the oscillator, DT·NUM_STEPS apart."""
    A = _leapfrog_matrix()
    states = [X0]
    for _ in range(8):
        states.append(A @ states[-1])
    rng = np.random.default_rng(5)
    values = np.array(states[1:]) * (1 + 0.1 * rng.standard_normal((8, 2)))
    times = DT * NUM_STEPS * np.arange(1, 9)
    return symplid.Observations(times, values + 0.05 * rng.standard_normal((8, 2)), ("q1", "p1"))


def test_tiny_relative_variance_equals_additive_noise(series):
    """"both" with r → 0 is the additive model (the same numbers, not just close)."""
    additive = _model("additive", backend="jax")
    both = _model("both")
    theta = _theta(additive)
    a = additive.log_likelihood(theta, series, X0, P0)
    b = both.log_likelihood(np.concatenate([theta, [1e-300]]), series, X0, P0)
    assert float(a) == float(b)


def test_compiled_backend_declines_multiplicative_noise(hh):
    for name in ("multiplicative", "both"):
        model = symplid.HamiltonianModel(hh.potential, observation_noise=name)
        assert "observation noise" in unsupported_reason(model)
        assert model.likelihood_backend == "jax"
    default = symplid.HamiltonianModel(hh.potential)
    assert default.observation_noise == "additive"
    assert unsupported_reason(default) is None


def test_layout_names_groups_and_priors(hh_data):
    model = symplid.HamiltonianModel(
        symplid.Polynomial(2, 2), observation_noise="both", noise="per-kind"
    )
    assert model.param_names[-5:] == (
        "process_var", "obs_var[q]", "obs_var[p]", "obs_rel_var[q]", "obs_rel_var[p]"
    )
    post = symplid.Posterior(model, hh_data, x0=[0.2, -0.25, 0.3, -0.25])
    rel = post.space.indices("obs_rel_var")
    assert list(rel) == [model.num_params - 2, model.num_params - 1]
    assert all(post.space.lower[rel] == 0.0)
    assert post.space.priors[rel[0]] == symplid.HalfNormal(1.0)
    only = symplid.HamiltonianModel(symplid.Polynomial(2, 2), observation_noise="multiplicative")
    assert only.num_obs_noise == 0 and only.param_names[-1] == "obs_rel_var"
    with pytest.raises(ValueError, match="observation-noise model"):
        symplid.HamiltonianModel(symplid.Polynomial(2, 2), observation_noise="multiplictive")


def test_per_kind_equals_diagonal_with_repeated_variances(series):
    per_kind = _model("additive", noise="per-kind", backend="jax")
    diagonal = _model("additive", noise="diagonal", backend="jax")
    theta_k = per_kind.pack([0.0, 0.5], PROC, [0.002, 0.004])
    theta_d = diagonal.pack([0.0, 0.5], [PROC] * 2, [0.002, 0.004])
    a = per_kind.log_likelihood(theta_k, series, X0, P0)
    b = diagonal.log_likelihood(theta_d, series, X0, P0)
    assert float(a) == pytest.approx(float(b), rel=1e-13)
    compiled = _model("additive", noise="per-kind")
    if compiled.likelihood_backend == "compiled":  # the kernel reads the diagonal layout
        c = compiled.log_likelihood(theta_k, series, X0, P0)
        assert float(c) == pytest.approx(float(a), rel=1e-11)
    with pytest.raises(ValueError, match="per-kind"):
        _model("additive", noise="per-kind", observation=np.eye(2)[:1])


def test_multiplicative_likelihood_has_finite_gradient_and_minus_inf_for_bad_variance(series):
    model = _model("multiplicative")
    theta = _theta(model)
    f = model.log_likelihood_fn(series, X0, P0)
    value, grad = jax.value_and_grad(f)(jnp.asarray(theta))
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
    assert float(f(np.concatenate([theta[:-1], [-0.01]]))) == -np.inf


def test_simulated_multiplicative_noise_has_the_relative_variance(hh):
    times = np.linspace(0.5, 100.0, 400)
    clean = symplid.simulate(hh, times=times, noise_std=0.0)
    noisy = symplid.simulate(
        hh, times=times, observation_noise="multiplicative", rel_std=0.1, noise_std=0.05
    )
    ratio = noisy.values / clean.values - 1.0
    # 1600 draws of ε ~ N(0, 0.1²): the sample variance is within ~4 standard errors
    assert np.var(ratio) == pytest.approx(0.01, rel=4 * np.sqrt(2 / ratio.size))
    additive = symplid.simulate(hh, times=times, seed=3)
    assert np.array_equal(
        additive.values, symplid.simulate(hh, times=times, seed=3, rel_std=0.5).values
    )


def test_forecast_bands_use_the_noise_model():
    model = _model("both")
    theta = np.tile(_theta(model), (2000, 1))
    starts = np.tile(X0, (2000, 1))
    fc = forecast_with_noise(model, theta, starts, 0.0, np.array([0.3, 0.6]), seed=2)
    resid = fc.observations - fc.obs_means
    expected = OBS_VAR + REL_VAR * fc.obs_means**2
    # Var[y | x] = Γ + r h(x)²: the standardised residuals have unit variance
    z = resid / np.sqrt(expected)
    assert np.var(z) == pytest.approx(1.0, rel=0.06)
    np.testing.assert_allclose(fc.rel_var, REL_VAR)
    # the held-out density uses the same variance: for one draw it is a Gaussian's
    one = forecast_with_noise(model, theta[:1], starts[:1], 0.0, np.array([0.3]), seed=2)
    y = one.obs_means[0] + 0.1
    var = OBS_VAR + REL_VAR * one.obs_means[0] ** 2
    expected_lpd = np.sum(-0.5 * (np.log(2 * np.pi * var) + 0.01 / var))
    assert one.log_predictive_density(y) == pytest.approx(expected_lpd, rel=1e-12)


def test_a_registered_noise_model_is_a_setting_and_a_model():
    from symplid.filters._noise import ObservationNoise
    from symplid.workflow._settings import Settings, SettingsError, merge_overrides

    entry = ObservationNoise("proportional", False, True, "a toy entry")
    OBSERVATION_NOISE.register("proportional", entry)
    try:
        s = merge_overrides(Settings(), {"model.observation_noise": "Proportional"})
        assert s.model.observation_noise == "proportional"
        model = _model(s.model.observation_noise)
        assert model.noise_model is entry and model.param_names[-1] == "obs_rel_var"
    finally:
        OBSERVATION_NOISE.unregister("proportional")
    with pytest.raises(SettingsError, match="did you mean 'multiplicative'"):
        merge_overrides(Settings(), {"model.observation_noise": "multiplicatve"})


@pytest.mark.slow
def test_map_recovers_the_relative_variance():
    """Data with 10 % relative noise: the MAP of a multiplicative model finds r ≈ 0.01 and the
    potential, and the Laplace interval of r covers the truth."""
    from symplid.inference.map import find_map

    system = symplid.get_system("harmonic")
    times = np.linspace(0.5, 30.0, 60)
    obs = symplid.simulate(system, times=times, observation_noise="multiplicative",
                           rel_std=0.1, seed=4)
    model = symplid.HamiltonianModel(system.potential, observation_noise="multiplicative")
    post = symplid.Posterior(model, obs, x0=system.initial_state)
    result = find_map(post, seed=0, num_starts=2, warn=False)
    theta = dict(zip(post.param_names, result.theta, strict=True))
    assert theta["c[q1^2]"] == pytest.approx(0.5, abs=0.01)
    rel = theta["obs_rel_var"]
    sd = result.std[post.param_names.index("obs_rel_var")]
    assert abs(rel - 0.01) < 3 * sd and 0.005 < rel < 0.02


@pytest.mark.parametrize("observation", ["full", "positions"])
def test_settings_count_the_variances_the_model_lays_out(observation):
    """The settings' check of θ's size (before any model exists) agrees with the model."""
    from symplid.workflow._auto import num_noise_variances

    for name in OBSERVATION_NOISE:
        for noise in ("isotropic", "diagonal", "per-kind"):
            model = symplid.HamiltonianModel(symplid.Polynomial(2, 2), observation=observation,
                                             noise=noise, observation_noise=name)
            expected = model.num_params - model.num_coefficients
            assert num_noise_variances(noise, observation, name, 2) == expected
