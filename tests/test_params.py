"""The parameter space of θ: bijectors, log-Jacobian, bounds, MAP search space, push-forward."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from symplid.inference.map._space import SearchSpace
from symplid.model._params import (
    MAX_UNCONSTRAINED_VARIANCE,
    ParameterProperties,
    ParameterSpace,
)
from symplid.model._priors import HalfNormal, Laplace, Normal, Uniform


@pytest.fixture(scope="module")
def space():
    """One parameter of each bijector: free, a variance, bounded above only, an interval."""
    return ParameterSpace([
        ParameterProperties("c", "coefficients", Laplace(0.0, 10.0), -math.inf, math.inf),
        ParameterProperties("v", "process_var", HalfNormal(1.0), 0.0, math.inf),
        ParameterProperties("u", "other", None, -math.inf, 2.0),
        ParameterProperties("w", "other", Uniform(-1.0, 3.0), -1.0, 3.0),
    ])


def test_bijectors_follow_the_bounds(space):
    assert space.bijectors == ("identity", "log", "log-upper", "logit")
    assert space.names == ("c", "v", "u", "w") and space.size == len(space) == 4
    np.testing.assert_array_equal(space.indices("other"), [2, 3])


def test_round_trip(space):
    z = jnp.array([0.7, -3.0, 1.2, -0.4])
    theta = space.from_unconstrained(z)
    assert float(theta[1]) > 0 and float(theta[2]) < 2 and -1 < float(theta[3]) < 3
    np.testing.assert_allclose(np.asarray(space.to_unconstrained(theta)), z, rtol=1e-13)
    batch = jax.vmap(space.from_unconstrained)(jnp.stack([z, 2 * z]))
    np.testing.assert_allclose(np.asarray(batch[0]), np.asarray(theta), rtol=1e-15)


@pytest.mark.parametrize("z", [[0.7, -3.0, 1.2, -0.4], [-5.0, 4.0, -2.0, 6.0]])
def test_log_jacobian_matches_autodiff(space, z):
    z = jnp.asarray(z)
    jac = np.asarray(jax.jacfwd(space.from_unconstrained)(z))
    assert np.allclose(jac, np.diag(np.diag(jac)))  # elementwise bijectors
    want = float(np.linalg.slogdet(jac)[1])
    assert float(space.log_abs_det_jacobian(z)) == pytest.approx(want, rel=1e-12)


def test_bounds_from_priors_and_positive_groups():
    space = ParameterSpace.from_priors(
        ["a", "s", "t"], ["coefficients", "obs_var", "coefficients"],
        [Normal(0.0, 1.0), Normal(0.0, 1.0), Uniform(0.0, 5.0)],
    )
    np.testing.assert_array_equal(space.lower, [-np.inf, 0.0, 0.0])
    np.testing.assert_array_equal(space.upper, [np.inf, np.inf, 5.0])
    assert space.bijectors == ("identity", "log", "logit")
    assert bool(space.in_bounds(jnp.array([3.0, 0.1, 1.0])))
    assert not bool(space.in_bounds(jnp.array([3.0, -0.1, 1.0])))
    assert float(space.log_prior(jnp.array([3.0, -0.1, 1.0]))) == -np.inf
    inside = space.interior_point()
    assert bool(space.in_bounds(jnp.asarray(inside))) and inside[1] > 0
    with pytest.raises(ValueError, match="no positive values"):
        ParameterSpace.from_priors(["s"], ["process_var"], [Uniform(-2.0, -1.0)])


def test_search_space_bounds_and_floor(space):
    search = SearchSpace.of(space, 1e-14)
    np.testing.assert_array_equal(search.log, [False, True, False, False])
    assert search.bounds() == [(None, None), (math.log(1e-14), None), (None, 2.0), (-1.0, 3.0)]
    theta = np.array([0.3, 1e-20, 1.0, 2.0])  # the variance below the floor
    u = search.to_u(theta)
    assert u[1] == math.log(1e-14)
    np.testing.assert_array_equal(search.at_bounds(u), [False, True, False, False])
    np.testing.assert_allclose(np.asarray(search.to_theta(jnp.asarray(u))),
                               [0.3, 1e-14, 1.0, 2.0], rtol=1e-13)
    assert search.on_lower_side(u, 1)


def test_space_of_a_posterior_like_object():
    class Like:
        param_names = ("a", "b")
        lower = np.array([-np.inf, 0.0])
        upper = np.array([np.inf, np.inf])

    space = ParameterSpace.of(Like())
    assert space.bijectors == ("identity", "log") and space.priors == (None, None)
    wider = space.with_bounds([-1.0, 0.0], [1.0, np.inf])
    assert wider.bijectors == ("logit", "log")


def test_pushforward_covariance_is_the_delta_method(space):
    theta = np.array([0.5, 0.2, 1.0, 0.0])
    cov = np.diag([0.04, 1e-4, 0.01, 0.09])
    cov_z = space.pushforward_covariance(theta, cov)
    jac = np.asarray(jax.jacfwd(space.to_unconstrained)(jnp.asarray(theta)))
    np.testing.assert_allclose(cov_z, jac @ cov @ jac.T, rtol=1e-12)
    assert np.all(np.diag(cov_z) <= MAX_UNCONSTRAINED_VARIANCE)
