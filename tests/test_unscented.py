"""The UKF log marginal likelihood (Theorem 1) against independent implementations.

* On a quadratic potential leapfrog is affine, so the UKF must equal the exact Kalman filter
  (written in NumPy in ``reference_filters.py``) whatever α, β, κ.
* On Hénon–Heiles it must equal filterpy's ``UnscentedKalmanFilter`` and the plain NumPy UKF
  of ``reference_filters.py`` for the same α, β, κ.
* Autodiff, vmap and the failure modes (−∞, never NaN, never an exception).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

import symplid
from reference_filters import (
    kalman_loglik,
    numpy_leapfrog,
    numpy_substeps,
    numpy_ukf_loglik,
    polynomial_gradient,
)

RTOL = 1e-8


# --------------------------------------------------------------------------- helpers
def leapfrog_affine_step(A: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
    """Leapfrog (eqs 5–6) for U = ½qᵀAq + bᵀq as an affine map, in homogeneous coordinates.

    With g(q) = Aq + b: q⁺ = (I − ½h²A)q + hp − ½h²b and
    p⁺ = (−hA + ¼h³A²)q + (I − ½h²A)p + (¼h³A − hI)b. Returns the (2d+1)×(2d+1) matrix
    [[F, c], [0, 1]].
    """
    d = A.shape[0]
    eye = np.eye(d)
    out = np.eye(2 * d + 1)
    out[:d, :d] = eye - 0.5 * h * h * A
    out[:d, d : 2 * d] = h * eye
    out[:d, -1] = -0.5 * h * h * b
    out[d : 2 * d, :d] = -h * A + 0.25 * h**3 * A @ A
    out[d : 2 * d, d : 2 * d] = eye - 0.5 * h * h * A
    out[d : 2 * d, -1] = (0.25 * h**3 * A - h * eye) @ b
    return out


def exact_quadratic_loglik(coeffs, q_var, r_var, x0, P0, times, dt, ys, H, per="gap"):
    """Exact Kalman log-likelihood for Polynomial(2, 2) coefficients integrated by leapfrog."""
    c1, c2, c11, c12, c22 = coeffs  # basis q1, q2, q1², q1q2, q2²
    A = np.array([[2 * c11, c12], [c12, 2 * c22]])
    b = np.array([c1, c2])
    num, sizes = numpy_substeps(times, dt)
    n = 4
    transitions, offsets, qs = [], [], []
    for k in range(len(num)):
        step = leapfrog_affine_step(A, b, sizes[k])
        gap = np.linalg.matrix_power(step, num[k])
        transitions.append(gap[:n, :n])
        offsets.append(gap[:n, -1])
        if per == "gap":
            qs.append(q_var * np.eye(n))
        else:  # noise after each substep: Σ_j F^j Q F^jᵀ
            f = step[:n, :n]
            acc = np.zeros((n, n))
            for j in range(num[k]):
                fj = np.linalg.matrix_power(f, j)
                acc += q_var * fj @ fj.T
            qs.append(acc)
    return kalman_loglik(x0, P0, transitions, qs, H, r_var * np.eye(H.shape[0]), ys, offsets)


def hh_numpy_ukf(model, theta, data, x0, P0, **kwargs):
    """The NumPy UKF for a polynomial-potential model, with the model's own settings."""
    coeffs, proc, obs = (np.asarray(a) for a in model.split(theta))
    inv_mass = None if model.mass is None else np.linalg.inv(model.mass)
    step = numpy_leapfrog(
        polynomial_gradient(np.array(model.hamiltonian.exponents), coeffs), inv_mass
    )
    num, sizes = numpy_substeps(data.times, model.dt)
    return numpy_ukf_loglik(
        step, x0, P0, num, sizes, data.values, proc, obs, H=model.observation_matrix,
        alpha=model.alpha, beta=model.beta, kappa=model.kappa, jitter=model.jitter,
        process_noise_per=model.process_noise_per, **kwargs,
    )


# --------------------------------------------------------------------------- exact Kalman
QUAD_TIMES = np.array([0.3, 1.0, 1.25, 2.6, 3.0, 4.45])  # 2, 3, 1, 6, 2, 6 substeps
QUAD_COEFFS = np.array([0.1, -0.05, 0.5, 0.2, 0.7])  # A = [[1, .2], [.2, 1.4]], b = (.1, −.05)
QUAD_X0 = np.array([0.3, -0.2, 0.1, 0.4])


@pytest.mark.parametrize(
    ("observation", "per", "ukf_settings"),
    [
        ("full", "gap", (1.0, 2.0, 0.0)),
        ("positions", "gap", (1.0, 2.0, 0.0)),
        ("full", "step", (0.5, 2.0, 1.0)),
        ("positions", "step", (1.0, 0.0, 2.0)),
    ],
)
def test_ukf_equals_exact_kalman_on_quadratic_potential(observation, per, ukf_settings):
    alpha, beta, kappa = ukf_settings
    model = symplid.HamiltonianModel(
        symplid.Polynomial(2, 2), integrator="leapfrog", dt=0.25, observation=observation,
        process_noise_per=per, alpha=alpha, beta=beta, kappa=kappa, jitter=0.0,
    )
    rng = np.random.default_rng(42)
    H = model.observation_matrix
    ys = rng.normal(scale=0.5, size=(len(QUAD_TIMES), H.shape[0]))
    ys[3, 1] = np.nan  # one missing value
    data = symplid.Observations(QUAD_TIMES, ys)
    P0 = np.diag([0.02, 0.03, 0.01, 0.05])
    theta = model.pack(QUAD_COEFFS, 3e-3, 0.02)
    got = float(model.log_likelihood(theta, data, x0=QUAD_X0, P0=P0))
    exact = exact_quadratic_loglik(
        QUAD_COEFFS, 3e-3, 0.02, QUAD_X0, P0, QUAD_TIMES, 0.25, ys, H, per
    )
    assert np.isfinite(exact)
    assert got == pytest.approx(exact, rel=RTOL)


def test_exact_kalman_reference_is_itself_consistent():
    """The reference Kalman filter equals the joint Gaussian density of all observations."""
    rng = np.random.default_rng(0)
    n, T = 2, 4
    F = [np.array([[1.0, 0.3], [-0.2, 0.9]]) * (1 + 0.1 * k) for k in range(T)]
    c = [rng.normal(size=n) for _ in range(T)]
    Q, R, H = 0.1 * np.eye(n), 0.2 * np.eye(1), np.array([[1.0, 0.5]])
    x0, P0 = np.array([0.5, -0.5]), 0.3 * np.eye(n)
    ys = rng.normal(size=(T, 1))
    # Stack x_1..x_T: mean and covariance by brute-force propagation.
    means, blocks = [], {}
    m, P = x0, P0
    gains = []
    for k in range(T):
        m = F[k] @ m + c[k]
        P = F[k] @ P @ F[k].T + Q
        means.append(m)
        gains.append(F[k])
        blocks[(k, k)] = P
    for i in range(T):
        for j in range(i + 1, T):
            prod = np.eye(n)
            for k in range(i + 1, j + 1):
                prod = F[k] @ prod
            blocks[(j, i)] = prod @ blocks[(i, i)]
            blocks[(i, j)] = blocks[(j, i)].T
    cov_x = np.block([[blocks[(i, j)] for j in range(T)] for i in range(T)])
    big_h = np.kron(np.eye(T), H)
    mean_y = big_h @ np.concatenate(means)
    cov_y = big_h @ cov_x @ big_h.T + np.kron(np.eye(T), R)
    from scipy.stats import multivariate_normal

    joint = multivariate_normal(mean_y, cov_y).logpdf(ys.ravel())
    assert kalman_loglik(x0, P0, F, Q, H, R, ys, c) == pytest.approx(joint, rel=1e-12)


# --------------------------------------------------------------------------- filterpy
def filterpy_loglik(model, theta, data, x0, P0):
    """filterpy's UKF with the model's α, β, κ, over gaps of ⌈gap/dt⌉ leapfrog substeps."""
    coeffs, proc, obs = (np.asarray(a) for a in model.split(theta))
    step = numpy_leapfrog(polynomial_gradient(np.array(model.hamiltonian.exponents), coeffs))

    def fx(x, dt, num):
        x = x[None, :]
        for _ in range(num):
            x = step(x, dt)
        return x[0]

    n = model.state_dim
    points = MerweScaledSigmaPoints(n, alpha=model.alpha, beta=model.beta, kappa=model.kappa)
    ukf = UnscentedKalmanFilter(dim_x=n, dim_z=n, dt=1.0, hx=lambda x: x, fx=fx, points=points)
    ukf.x, ukf.P, ukf.Q, ukf.R = np.array(x0, dtype=float), np.array(P0), proc, obs
    num, sizes = numpy_substeps(data.times, model.dt)
    total = 0.0
    for k in range(len(num)):
        ukf.predict(dt=sizes[k], num=int(num[k]))
        # Redraw sigma points at the predicted (m, P) (with Q), as the library does.
        ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
        ukf.update(data.values[k])
        total += ukf.log_likelihood
    return total


def test_filterpy_square_root_is_lower_cholesky_columns():
    """filterpy's default sqrt is scipy's upper factor U, and its rows are the columns of L."""
    P = np.array([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 0.5]])
    points = MerweScaledSigmaPoints(3, alpha=1.0, beta=2.0, kappa=0.0)
    sig = points.sigma_points(np.zeros(3), P)
    L = np.linalg.cholesky(P)
    np.testing.assert_allclose(sig[1:4], np.sqrt(3.0) * L.T, rtol=1e-14)
    np.testing.assert_allclose(sig[4:], -np.sqrt(3.0) * L.T, rtol=1e-14)


@pytest.mark.parametrize("ukf_settings", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_ukf_equals_filterpy_on_henon_heiles(hh, hh_data, ukf_settings):
    alpha, beta, kappa = ukf_settings
    model = symplid.HamiltonianModel(
        hh.potential, "leapfrog", dt=0.25, alpha=alpha, beta=beta, kappa=kappa, jitter=0.0
    )
    theta = model.pack(hh.coefficients, 1e-5, 0.05**2)
    P0 = 1e-6 * np.eye(4)
    got = float(model.log_likelihood(theta, hh_data, x0=hh.initial_state, P0=P0))
    expected = filterpy_loglik(model, theta, hh_data, hh.initial_state, P0)
    assert got == pytest.approx(expected, rel=RTOL)


# --------------------------------------------------------------------------- NumPy UKF
def test_ukf_equals_numpy_ukf_on_the_papers_problem(hh, hh_model, hh_data, hh_theta, hh_loglik):
    expected = hh_numpy_ukf(hh_model, hh_theta, hh_data, hh.initial_state, 1e-16 * np.eye(4))
    assert float(hh_loglik(jnp.asarray(hh_theta))) == pytest.approx(expected, rel=RTOL)
    # The same through the public method (P0=None means a known initial state).
    assert float(
        hh_model.log_likelihood(hh_theta, hh_data, x0=hh.initial_state)
    ) == pytest.approx(expected, rel=RTOL)


def test_ukf_equals_numpy_ukf_with_gaps_and_missing(
    hh_model, small_data, small_theta, small_x0, small_P0, small_loglik
):
    expected = hh_numpy_ukf(hh_model, small_theta, small_data, small_x0, small_P0)
    assert float(small_loglik(jnp.asarray(small_theta))) == pytest.approx(expected, rel=RTOL)


VARIANTS = {
    "per-step": {"process_noise_per": "step"},
    "positions": {"observation": "positions"},
    "mass-and-ukf-settings": {
        "mass": np.array([[1.5, 0.2], [0.2, 0.8]]),
        "alpha": 0.7,
        "kappa": 1.0,
    },
}


@pytest.fixture(scope="module")
def variant_models(hh):
    """One model per variant, shared across tests so that each compiles once."""
    return {
        name: symplid.HamiltonianModel(hh.potential, "leapfrog", dt=0.25, **settings)
        for name, settings in VARIANTS.items()
    }


@pytest.fixture(scope="module")
def positions_data(hh, small_data):
    data = symplid.simulate(hh, times=small_data.times, seed=2, observation="positions")
    values = np.array(data.values)
    values[4, 0] = np.nan
    return symplid.Observations(data.times, values)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_ukf_equals_numpy_ukf_variants(
    variant, variant_models, small_data, positions_data, small_theta, small_x0, small_P0
):
    model = variant_models[variant]
    data = positions_data if variant == "positions" else small_data
    got = float(model.log_likelihood(small_theta, data, x0=small_x0, P0=small_P0))
    expected = hh_numpy_ukf(model, small_theta, data, small_x0, small_P0)
    assert got == pytest.approx(expected, rel=RTOL)


# --------------------------------------------------------------------------- autodiff, vmap
def test_grad_matches_central_differences(small_theta, small_loglik, small_grad):
    theta = np.asarray(small_theta)
    grad = np.asarray(small_grad(jnp.asarray(theta)))
    assert np.all(np.isfinite(grad))
    fd = np.empty_like(theta)
    for i in range(theta.size):
        h = 1e-5 * abs(theta[i])
        up, down = theta.copy(), theta.copy()
        up[i] += h
        down[i] -= h
        fd[i] = (float(small_loglik(jnp.asarray(up))) - float(small_loglik(jnp.asarray(down)))) / (
            2 * h
        )
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(grad)))


def test_vmap_over_16_theta_equals_loop(small_theta, small_loglik, hh_model):
    rng = np.random.default_rng(16)
    thetas = np.tile(small_theta, (16, 1))
    thetas[:, : hh_model.num_coefficients] += rng.normal(
        scale=0.02, size=(16, hh_model.num_coefficients)
    )
    thetas[:, hh_model.variance_slice] *= rng.uniform(0.5, 2.0, size=(16, 2))
    thetas[3, -1] = -0.01  # one invalid θ in the batch
    batched = np.asarray(jax.jit(jax.vmap(small_loglik))(jnp.asarray(thetas)))
    looped = np.array([float(small_loglik(jnp.asarray(t))) for t in thetas])
    assert batched[3] == -np.inf and looped[3] == -np.inf
    ok = np.arange(16) != 3
    assert np.all(np.isfinite(batched[ok]))
    np.testing.assert_allclose(batched[ok], looped[ok], rtol=1e-11)


# --------------------------------------------------------------------------- failures
@pytest.mark.parametrize("which", [-2, -1])
def test_negative_variance_gives_minus_inf(small_theta, small_loglik, which):
    theta = np.array(small_theta)
    theta[which] = -abs(theta[which])
    assert float(small_loglik(jnp.asarray(theta))) == -np.inf


def test_blow_up_gives_minus_inf_not_nan(hh, hh_theta, hh_loglik, small_theta, small_loglik):
    # A steep cubic term: the trajectory escapes over the saddle and overflows.
    escaping = np.array(hh_theta)
    escaping[8] = -5.0  # q2³
    huge = np.array(hh_theta)
    huge[:9] = 50.0
    huge_small = np.concatenate([huge[:9], small_theta[9:]])
    for fn, theta in ((hh_loglik, escaping), (hh_loglik, huge), (small_loglik, huge_small)):
        value = float(fn(jnp.asarray(theta)))
        assert value == -np.inf  # not NaN, and no exception
    # The NumPy reference agrees that this is not a finite likelihood.
    model = symplid.HamiltonianModel(hh.potential, "leapfrog", dt=0.25)
    data = symplid.simulate(hh, seed=0)
    with np.errstate(all="ignore"):
        assert hh_numpy_ukf(model, escaping, data, hh.initial_state, 1e-16 * np.eye(4)) == -np.inf


# --------------------------------------------------------------------------- options
def test_process_noise_per_step_differs_from_per_gap(
    variant_models, small_data, small_theta, small_x0, small_P0, small_loglik
):
    per_gap = float(small_loglik(jnp.asarray(small_theta)))
    step_model = variant_models["per-step"]
    per_step = float(step_model.log_likelihood(small_theta, small_data, small_x0, small_P0))
    assert np.isfinite(per_step)
    assert abs(per_step - per_gap) > 1e-6 * abs(per_gap)


def test_process_noise_per_step_equals_per_gap_with_one_substep(hh, hh_model, variant_models):
    times = np.array([0.2, 0.45, 0.6, 0.85, 1.05, 1.3])  # every gap ≤ dt: one substep each
    data = symplid.simulate(hh, times=times, seed=4)
    theta = hh_model.pack(hh.coefficients, 1e-4, 0.05**2)
    P0 = 1e-4 * np.eye(4)
    per_gap = float(hh_model.log_likelihood(theta, data, hh.initial_state, P0))
    step_model = variant_models["per-step"]
    per_step = float(step_model.log_likelihood(theta, data, hh.initial_state, P0))
    assert per_step == pytest.approx(per_gap, rel=1e-12)


def test_function_observation_equals_matrix_and_positions(
    hh, variant_models, positions_data, small_theta, small_x0, small_P0
):
    matrix = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    values = {}
    for label, obs in (
        ("positions", None),
        ("matrix", matrix),
        ("function", lambda x: jnp.asarray(matrix) @ x),
    ):
        model = (
            variant_models["positions"]
            if obs is None
            else symplid.HamiltonianModel(hh.potential, "leapfrog", dt=0.25, observation=obs)
        )
        values[label] = float(model.log_likelihood(small_theta, positions_data, small_x0, small_P0))
    assert np.isfinite(values["positions"])
    assert values["matrix"] == pytest.approx(values["positions"], rel=1e-12)
    assert values["function"] == pytest.approx(values["positions"], rel=1e-9)


def test_diagonal_noise(hh, hh_model, small_data, small_theta, small_x0, small_P0, small_loglik):
    model = symplid.HamiltonianModel(hh.potential, "leapfrog", dt=0.25, noise="diagonal")
    assert model.num_params == 9 + 4 + 4
    assert model.param_names[9] == "process_var[0]" and model.param_names[-1] == "obs_var[3]"
    coeffs, q_var, r_var = small_theta[:9], small_theta[9], small_theta[10]
    fn = jax.jit(model.log_likelihood_fn(small_data, small_x0, small_P0))
    # Equal variances: the same as the isotropic model.
    equal = model.pack(coeffs, np.full(4, q_var), np.full(4, r_var))
    isotropic = float(small_loglik(jnp.asarray(small_theta)))
    assert float(fn(jnp.asarray(equal))) == pytest.approx(isotropic, rel=1e-12)
    # Unequal variances: the NumPy UKF with diagonal Σ and Γ.
    unequal = model.pack(coeffs, q_var * np.array([0.5, 1, 2, 4]), r_var * np.array([1, 3, 0.5, 2]))
    expected = hh_numpy_ukf(model, unequal, small_data, small_x0, small_P0)
    assert float(fn(jnp.asarray(unequal))) == pytest.approx(expected, rel=RTOL)
    # One negative entry is enough for −∞.
    bad = unequal.copy()
    bad[11] = -1e-6
    assert float(fn(jnp.asarray(bad))) == -np.inf


def test_filter_result_terms_sum_to_loglik(hh_model, small_data, small_theta, small_x0, small_P0):
    result = hh_model.filter(small_theta, small_data, small_x0, small_P0)
    assert result.filtered_means.shape == (6, 4) and result.predicted_covs.shape == (6, 4, 4)
    assert float(jnp.sum(result.log_likelihood_terms)) == pytest.approx(
        float(result.log_likelihood), rel=1e-14
    )
