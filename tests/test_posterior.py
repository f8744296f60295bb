"""The posterior: prior + likelihood, several trajectories, a learned initial state, bounds and
the unconstrained transform with its log-Jacobian.

Most checks run on the harmonic oscillator (state dimension 2: cheap to compile). With
leapfrog its dynamics are linear, so the UKF is exact and the exact Kalman filter of
``reference_filters.py`` is an independent second implementation of the likelihood.
"""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

import symplid
from reference_filters import kalman_loglik, numpy_leapfrog, numpy_substeps, polynomial_gradient
from symplid.model._data import DataError
from symplid.model._posterior import UNOBSERVED_SCALE_FACTOR, Posterior
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import HalfNormal, Laplace, LogNormal, Normal, Uniform

JITTER = 1e-12  # the model's default, added to every predicted covariance


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def osc():
    return symplid.get_system("harmonic")


@pytest.fixture(scope="module")
def osc_model(osc):
    return symplid.HamiltonianModel(osc.potential, integrator="leapfrog", dt=0.25, unroll=False)


@pytest.fixture(scope="module")
def osc_pos_model(osc):
    return symplid.HamiltonianModel(
        osc.potential, integrator="leapfrog", dt=0.25, observation="positions", unroll=False
    )


@pytest.fixture(scope="module")
def osc_theta(osc, osc_model):
    return osc_model.pack(osc.coefficients, 1e-3, 0.05**2)


@pytest.fixture(scope="module")
def osc_sets(osc):
    """Three trajectories: two on the same schedule (stacked and vmapped), one irregular."""
    regular = np.arange(1.0, 9.0)
    irregular = np.array([0.7, 1.5, 2.0, 3.1, 3.6, 4.5])
    x0s = [np.array([1.0, 0.0]), np.array([0.3, -0.8]), np.array([-0.5, 0.4])]
    data = [
        symplid.simulate(osc, times=regular, x0=x0s[0], seed=1),
        symplid.simulate(osc, times=regular, x0=x0s[1], seed=2),
        symplid.simulate(osc, times=irregular, x0=x0s[2], seed=3),
    ]
    return data, x0s


@pytest.fixture(scope="module")
def hh_post(hh, hh_data):
    model = symplid.HamiltonianModel(hh.potential, integrator="leapfrog", dt=0.25, unroll=False)
    return Posterior(model, hh_data, x0=hh.initial_state)


def _transitions(coefficients, times, dt, t0):
    """Leapfrog transition matrix of each gap, by the NumPy leapfrog applied to a basis."""
    exponents = np.array([[1], [2]])
    step = numpy_leapfrog(polynomial_gradient(exponents, coefficients))
    nums, sizes = numpy_substeps(times, dt, t0)
    out = []
    for m, h in zip(nums, sizes, strict=True):
        x = np.eye(2)
        for _ in range(m):
            x = step(x, h)
        out.append(x.T)  # rows were the images of the basis vectors
    return out


# ----------------------------------------------------------------------------- the density
def test_hh_density_is_prior_plus_likelihood(hh, hh_post, hh_loglik):
    """At the truth: scipy's prior densities plus the model's own likelihood function."""
    theta = hh_post.model.pack(hh.coefficients, 1e-6, 0.05**2)
    want_prior = np.sum(stats.laplace(scale=10.0).logpdf(theta[:9])) + np.sum(
        stats.halfnorm(scale=1.0).logpdf(theta[9:])
    )
    assert float(hh_post.log_prior(theta)) == pytest.approx(want_prior, rel=1e-12)
    # one vmapped call: the truth, then points outside the support or far from it
    bad = [theta * np.r_[np.ones(10), -1.0], theta * np.r_[np.ones(9), -1.0, 1.0],
           np.r_[np.full(9, 50.0), 1e-6, 1e-3], np.r_[np.full(9, -1e8), 1e30, 1e-300]]
    values = np.asarray(jax.vmap(hh_post.log_density)(jnp.asarray(np.stack([theta, *bad]))))
    assert values[0] == pytest.approx(want_prior + float(hh_loglik(theta)), rel=1e-10)
    assert not np.any(np.isnan(values))
    assert values[1] == values[2] == -np.inf


def test_hh_layout(hh_post):
    assert hh_post.num_params == 11
    assert hh_post.param_names[:3] == ("c[q1]", "c[q2]", "c[q1^2]")
    assert hh_post.param_names[-2:] == ("process_var", "obs_var")
    assert hh_post.param_groups == ("coefficients",) * 9 + ("process_var", "obs_var")
    assert isinstance(hh_post.lower, np.ndarray) and isinstance(hh_post.upper, np.ndarray)
    np.testing.assert_array_equal(hh_post.lower, [-np.inf] * 9 + [0.0, 0.0])
    np.testing.assert_array_equal(hh_post.upper, [np.inf] * 11)
    assert hh_post.priors[0] == Laplace(0.0, 10.0) and hh_post.priors[-1] == HalfNormal(1.0)
    json.dumps(hh_post.to_dict())


def test_gradient_matches_finite_differences(osc_model, osc_theta, osc_sets):
    """Through the stacked (vmapped) path: two trajectories on one schedule."""
    data, x0s = osc_sets
    post = Posterior(osc_model, data[:2], x0=x0s[:2])
    value_and_grad = post.value_and_grad()
    theta = jnp.asarray(osc_theta).at[0].set(0.02)  # off the Laplace prior's kink at 0
    value, grad = value_and_grad(theta)
    eps = 1e-6 * np.maximum(np.abs(np.asarray(theta)), 1e-3)
    fd = []
    for i in range(theta.shape[0]):
        e = jnp.zeros(theta.shape[0]).at[i].set(eps[i])
        up, down = float(value_and_grad(theta + e)[0]), float(value_and_grad(theta - e)[0])
        fd.append((up - down) / (2 * eps[i]))
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-5)
    # out of bounds: −∞ with a finite (zero) gradient
    value, grad = value_and_grad(theta.at[2].set(-1e-3))
    assert float(value) == -np.inf
    assert np.all(np.isfinite(np.asarray(grad)))


# ----------------------------------------------------------------------------- several trajectories
def test_several_trajectories_sum(osc_model, osc_theta, osc_sets):
    data, x0s = osc_sets
    P0s = [None, 1e-4, np.diag([1e-3, 2e-3])]
    t0s = [0.0, -0.5, 0.3]
    post = Posterior(osc_model, data, x0=x0s, P0=P0s, t0=t0s)
    want = sum(
        float(osc_model.log_likelihood(osc_theta, d, x, P, t))
        for d, x, P, t in zip(data, x0s, P0s, t0s, strict=True)
    )
    assert float(post.log_likelihood(osc_theta)) == pytest.approx(want, rel=1e-10)
    assert post.num_trajectories == 3


def test_several_trajectories_with_learned_initial_states(osc_model, osc_theta, osc_sets):
    data, x0s = osc_sets
    post = Posterior(osc_model, data, learn_initial_state=True)
    assert post.num_params == 4 + 3 * 2
    assert post.param_names[4:] == ("x0[0].q1", "x0[0].p1", "x0[1].q1", "x0[1].p1",
                                    "x0[2].q1", "x0[2].p1")
    theta = np.concatenate([osc_theta, *x0s])
    want = sum(float(osc_model.log_likelihood(osc_theta, d, x)) for d, x in zip(data, x0s,
                                                                                strict=True))
    assert float(post.log_likelihood(theta)) == pytest.approx(want, rel=1e-10)
    np.testing.assert_array_equal(np.asarray(post.initial_state(theta, 1)), x0s[1])
    assert post.initial_state_slice(2) == slice(8, 10)


# ----------------------------------------------------------------------------- learned x0
def test_learned_initial_state_prior_centred_on_first_observation(osc_model, osc_sets):
    data = osc_sets[0][0]
    post = Posterior(osc_model, data, learn_initial_state=True)
    s = max(np.std(data.values[:, 0]), np.std(data.values[:, 1]))
    assert post.priors[4:] == (Normal(data.values[0, 0], s), Normal(data.values[0, 1], s))
    np.testing.assert_array_equal(post.initial_state_centres()[0], data.values[0])
    assert post.param_groups[4:] == ("initial_state", "initial_state")


def test_learned_initial_state_positions_only(osc, osc_pos_model):
    data = symplid.simulate(osc, times=np.arange(1.0, 9.0), observation="positions", seed=4)
    post = Posterior(osc_pos_model, data, learn_initial_state=True, initial_state_prior=0.2)
    # q measured: centred on y_1; p not measured: centred on 0, three times wider
    assert post.priors[4] == Normal(data.values[0, 0], 0.2)
    assert post.priors[5] == Normal(0.0, UNOBSERVED_SCALE_FACTOR * 0.2)
    post = Posterior(osc_pos_model, data, learn_initial_state=True,
                     initial_state_prior=Laplace(0.0, 0.1))
    wide = Laplace(0.0, UNOBSERVED_SCALE_FACTOR * 0.1)
    assert post.priors[4:] == (Laplace(data.values[0, 0], 0.1), wide)


def test_initial_state_prior_forms(osc_model, osc_sets):
    data = osc_sets[0][0]
    y1 = data.values[0]
    post = Posterior(osc_model, data, learn_initial_state=True,
                     initial_state_prior=[Normal(0.0, 0.1), "laplace(0.5, 0.2)"])
    assert post.priors[4:] == (Normal(y1[0], 0.1), Laplace(y1[1] + 0.5, 0.2))
    spec = PriorSpec(initial_state=Normal(0.0, 0.3), overrides={"x0[0].p1": Normal(7.0, 1.0)})
    post = Posterior(osc_model, data, prior=spec, learn_initial_state=True)
    assert post.priors[4:] == (Normal(y1[0], 0.3), Normal(7.0, 1.0))  # override is absolute
    post = Posterior(osc_model, data, x0=[2.0, 3.0], learn_initial_state=True,
                     initial_state_prior=0.5)
    assert post.priors[4:] == (Normal(2.0, 0.5), Normal(3.0, 0.5))  # x0 given = the centre
    with pytest.raises(ValueError, match="normal or laplace"):
        Posterior(osc_model, data, learn_initial_state=True, initial_state_prior=HalfNormal(1))
    with pytest.raises(ValueError, match="3 priors given for a 2-component state"):
        Posterior(osc_model, data, learn_initial_state=True,
                  initial_state_prior=[Normal(0, 1)] * 3)


@pytest.mark.parametrize("learn", [False, True])
def test_initial_state_at_first_observation_matches_kalman_filter(osc, osc_pos_model, learn):
    """t0=None: N(x0, P0) sits at t_1 and y_1 updates it. With linear dynamics the UKF is
    exact, so the exact Kalman filter (first gap of length zero) gives the same number."""
    times = np.array([2.0, 2.7, 3.5, 4.0, 5.1, 5.6])
    data = symplid.simulate(osc, times=times, observation="positions", seed=5)
    x1 = np.array([0.4, -0.9])
    P0 = np.diag([0.02, 0.05])
    theta = osc_pos_model.pack(osc.coefficients, 1e-3, 0.04**2)
    if learn:
        post = Posterior(osc_pos_model, data, P0=P0, t0=None, learn_initial_state=True)
        value = float(post.log_likelihood(np.r_[theta, x1]))
    else:
        post = Posterior(osc_pos_model, data, x0=x1, P0=P0, t0=None)
        value = float(post.log_likelihood(theta))
    F = [np.eye(2), *_transitions(osc.coefficients, times[1:], 0.25, times[0])]
    Q = [np.zeros((2, 2))] + [(1e-3 + JITTER) * np.eye(2)] * (len(times) - 1)
    want = kalman_loglik(x1, P0, F, Q, np.array([[1.0, 0.0]]), 0.04**2 * np.eye(1),
                         data.values)
    assert value == pytest.approx(want, rel=1e-9)


def test_learned_initial_state_at_first_observation_meets_y1_through_process_noise(
        osc, osc_pos_model):
    """A learned x0 at t_1 with the default (point) P0: y_1 updates N(x0, Σ), so the exact
    Kalman filter with a first gap of length zero *and* one process-noise increment Σ gives
    the same number (the learned-initial-state corner: y_1 never has variance Γ alone)."""
    times = np.array([2.0, 2.7, 3.5, 4.0, 5.1, 5.6])
    data = symplid.simulate(osc, times=times, observation="positions", seed=5)
    x1 = np.array([0.4, -0.9])
    theta = osc_pos_model.pack(osc.coefficients, 1e-3, 0.04**2)
    post = Posterior(osc_pos_model, data, t0=None, learn_initial_state=True)
    value = float(post.log_likelihood(np.r_[theta, x1]))
    F = [np.eye(2), *_transitions(osc.coefficients, times[1:], 0.25, times[0])]
    Q = [1e-3 * np.eye(2)] + [(1e-3 + JITTER) * np.eye(2)] * (len(times) - 1)
    want = kalman_loglik(x1, 1e-16 * np.eye(2), F, Q, np.array([[1.0, 0.0]]),
                         0.04**2 * np.eye(1), data.values)
    assert value == pytest.approx(want, rel=1e-9)


def test_learned_x0_equals_model_likelihood(osc_model, osc_theta, osc_sets):
    data = osc_sets[0]
    post = Posterior(osc_model, data[2], learn_initial_state=True, t0=0.1, P0=1e-4)
    x = np.array([-0.45, 0.35])
    want = float(osc_model.log_likelihood(osc_theta, data[2], x, 1e-4, 0.1))
    assert float(post.log_likelihood(np.r_[osc_theta, x])) == pytest.approx(want, rel=1e-12)


# ----------------------------------------------------------------------------- transforms
@pytest.fixture(scope="module")
def bounded_post(osc_model, osc_sets):
    """Every kind of bound: q1 in (−1, 1) (logit), q1^2 free (identity), variances (log)."""
    spec = PriorSpec(obs_var=LogNormal(-6.0, 1.0), overrides={"q1": Uniform(-1.0, 1.0)})
    return Posterior(osc_model, osc_sets[0][0], prior=spec, x0=osc_sets[1][0])


def test_bounds_follow_the_priors(bounded_post):
    np.testing.assert_array_equal(bounded_post.lower, [-1.0, -np.inf, 0.0, 0.0])
    np.testing.assert_array_equal(bounded_post.upper, [1.0, np.inf, np.inf, np.inf])


def test_transform_round_trip_and_jacobian(bounded_post):
    post = bounded_post
    theta = jnp.array([0.3, 0.5, 1e-3, 2e-3])
    z = post.to_unconstrained(theta)
    np.testing.assert_allclose(np.asarray(post.from_unconstrained(z)), theta, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(z)[1:], [0.5, math.log(1e-3), math.log(2e-3)],
                               rtol=1e-13)
    for zz in (z, jnp.array([-3.0, 2.0, 4.0, -30.0]), jnp.array([10.0, -1.0, 0.0, 1.0])):
        jac = np.asarray(jax.jacfwd(post.from_unconstrained)(zz))
        assert np.allclose(jac, np.diag(np.diag(jac)))  # elementwise transform
        want = float(np.sum(np.log(np.abs(np.diag(jac)))))
        assert float(post.log_abs_det_jacobian(zz)) == pytest.approx(want, rel=1e-10, abs=1e-10)
        lhs = float(post.log_density_unconstrained(zz))
        rhs = float(post.log_density(post.from_unconstrained(zz))) + want
        assert lhs == pytest.approx(rhs, rel=1e-10) or lhs == rhs == -np.inf


@pytest.mark.parametrize("i", [0, 1, 2, 3])
def test_change_of_variables_by_numerical_integration(bounded_post, i):
    """Push parameter i's prior to z with the log-Jacobian and integrate it numerically: the
    mass below z = a must be the prior's CDF at θ(a) (scipy), whatever the constant."""
    post = bounded_post
    prior = post.priors[i]
    ref = {0: stats.uniform(-1.0, 2.0), 1: stats.laplace(scale=10.0), 2: stats.halfnorm(),
           3: stats.lognorm(s=1.0, scale=math.exp(-6.0))}[i]
    base = jnp.zeros(4)

    @jax.jit
    def log_density(t):
        z = base.at[i].set(t)
        return prior.log_density(post.from_unconstrained(z)[i]) + post.log_abs_det_jacobian(z)

    def density(t: float) -> float:
        return math.exp(float(log_density(t)))

    centre = float(post.to_unconstrained(jnp.full(4, prior.median))[i])
    total = sum(integrate.quad(density, lo, hi, limit=200, epsabs=0)[0]
                for lo, hi in ((-np.inf, centre), (centre, np.inf)))
    for a in (centre - 1.0, centre, centre + 0.7):
        below = integrate.quad(density, -np.inf, a, limit=200, epsabs=0)[0]
        theta_a = float(post.from_unconstrained(base.at[i].set(a))[i])
        assert below / total == pytest.approx(ref.cdf(theta_a), rel=1e-6)


def test_upper_bounded_transform(osc_model, osc_sets):
    # No shipped prior is bounded above only; the transform still handles (−∞, b). The bounds
    # are set by hand on a throwaway posterior to check that branch of the mapping.
    post = Posterior(osc_model, osc_sets[0][0], x0=osc_sets[1][0])
    post.lower = np.array([-np.inf, -np.inf, 0.0, 0.0])
    post.upper = np.array([2.0, np.inf, np.inf, np.inf])
    theta = jnp.array([1.5, 0.2, 0.1, 0.3])
    z = post.to_unconstrained(theta)
    assert float(z[0]) == pytest.approx(math.log(0.5))
    np.testing.assert_allclose(np.asarray(post.from_unconstrained(z)), theta, rtol=1e-13)
    jac = np.asarray(jax.jacfwd(post.from_unconstrained)(z))
    assert float(post.log_abs_det_jacobian(z)) == pytest.approx(
        float(np.sum(np.log(np.abs(np.diag(jac))))), rel=1e-12
    )


# ----------------------------------------------------------------------------- errors
def test_errors_name_the_problem(osc, osc_model, osc_sets):
    data, x0s = osc_sets
    d = data[0]
    with pytest.raises(ValueError, match="x0 is required"):
        Posterior(osc_model, d)
    with pytest.raises(ValueError, match=r"x0 of trajectory 0 must have shape \(2,\)"):
        Posterior(osc_model, d, x0=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"shape \(2,\) for one trajectory or \(3, 2\)"):
        Posterior(osc_model, data, x0=x0s[0])
    with pytest.raises(DataError, match="trajectory 0: t0 = 1 must be before"):
        Posterior(osc_model, d, x0=x0s[0], t0=1.0)
    with pytest.raises(ValueError, match="t0: 2 entries given for 3 trajectories"):
        Posterior(osc_model, data, x0=x0s, t0=[0.0, 0.0])
    with pytest.raises(ValueError, match="P0 of trajectory 0 must be positive semi-definite"):
        Posterior(osc_model, d, x0=x0s[0], P0=np.diag([1.0, -1.0]))
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) 'c\[q3\]'"):
        Posterior(osc_model, d, x0=x0s[0], prior={"q3": Normal(0, 1)})
    with pytest.raises(TypeError, match=r"data\[1\] must be a symplid.Observations"):
        Posterior(osc_model, [d, d.values], x0=x0s[:2])
    with pytest.raises(DataError, match="empty list"):
        Posterior(osc_model, [], x0=x0s[0])
    with pytest.raises(DataError, match="one observation"):
        Posterior(osc_model, d.subset(slice(0, 1)), x0=x0s[0], t0=None)
    with pytest.raises(ValueError, match=r"θ must have shape \(4,\)"):
        Posterior(osc_model, d, x0=x0s[0]).log_density(jnp.zeros(5))
