"""NUTS through BlackJAX: moments, the unconstrained transform, and its sample statistics."""

from __future__ import annotations

import blackjax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from blackjax.adaptation.base import get_filter_adapt_info_fn

import symplid  # noqa: F401  (float64)
from sampler_targets import Banana, GammaVariance, Gaussian2D, moment_z_scores
from symplid.inference.samplers import nuts
from symplid.sampling import RunOptions, draws_array, sample

TARGETS = {"gaussian": Gaussian2D, "banana": Banana, "gamma": GammaVariance}


@pytest.fixture(scope="module", params=list(TARGETS))
def nuts_run(request):
    target = TARGETS[request.param]()
    idata = sample(target, "nuts", num_draws=1500, num_chains=4, seed=2,
                   init=target.map_result(), burn_in=400, options=RunOptions(progress=False))
    return target, idata


def test_nuts_moments_within_monte_carlo_error(nuts_run):
    target, idata = nuts_run
    scores = moment_z_scores(draws_array(idata), target.mean, target.cov)
    assert max(abs(z) for z in scores.values()) < 4, scores


def test_nuts_sample_stats(nuts_run):
    target, idata = nuts_run
    stats_ = idata.sample_stats
    assert stats_["diverging"].dtype == bool
    assert stats_["diverging"].shape == (4, 1500)
    # The banana's x1⁴ tails are stiff for one global step size: a few divergences there.
    allowed = 0.02 if isinstance(target, Banana) else 0.0
    assert float(stats_["diverging"].mean()) <= allowed
    assert 0.6 < float(stats_["acceptance_rate"].mean()) < 0.99
    assert np.all(stats_["n_steps"] >= 1)
    # One step size per chain, constant over its draws.
    np.testing.assert_array_equal(stats_["step_size"].values,
                                  stats_["step_size"].values[:, :1].repeat(1500, axis=1))


def test_nuts_draws_and_lp_are_in_the_constrained_space(nuts_run):
    """``lp`` is log π(θ) at the reported θ (the Jacobian removed), θ inside the support."""
    target, idata = nuts_run
    draws = draws_array(idata).reshape(-1, 2)
    assert np.all(draws > target.lower) and np.all(draws < target.upper)
    lp = np.asarray(jax.vmap(target.log_density)(jnp.asarray(draws)))
    np.testing.assert_allclose(idata.sample_stats["lp"].values.ravel(), lp,
                               rtol=1e-10, atol=1e-10)


def test_initial_mass_matrix_is_the_laplace_covariance_pushed_forward(nuts_run):
    """For v → log v the Laplace covariance Σ becomes J Σ Jᵀ with J = diag(1, 1/v̂)."""
    target, idata = nuts_run
    map_result = target.map_result()
    jac = np.diag([1.0, 1.0 / map_result.theta[1]]) if isinstance(target, GammaVariance) \
        else np.eye(2)
    expected = jac @ map_result.covariance @ jac.T
    np.testing.assert_allclose(idata.attrs["unconstrained_map_covariance"], expected,
                               rtol=1e-12)


def test_init_uses_the_given_mass_matrix_and_step_size():
    target = GammaVariance()
    imm = np.array([[1.0, 0.1], [0.1, 0.5]])
    dense = nuts.init(jnp.zeros(2), target.log_density_unconstrained, imm, step_size=0.3)
    np.testing.assert_array_equal(dense.inverse_mass_matrix, imm)
    assert float(dense.step_size) == 0.3
    diagonal = nuts.init(jnp.zeros(2), target.log_density_unconstrained, imm,
                         nuts.NUTSSettings(dense_mass=False))
    np.testing.assert_array_equal(diagonal.inverse_mass_matrix, np.diag(imm))
    assert float(diagonal.step_size) == nuts.NUTSSettings().initial_step_size
    with pytest.raises(ValueError, match="inverse_mass_matrix must have shape"):
        nuts.init(jnp.zeros(3), target.log_density_unconstrained, imm)


def test_in_kernel_warmup_equals_blackjax_window_adaptation():
    """The one-iteration-at-a-time adaptation reproduces ``blackjax.window_adaptation``.

    Fed the same per-iteration keys, both must end at the same step size, inverse mass
    matrix and position, bit for bit up to rounding.
    """
    target, num_steps, key, dense = Banana(), 200, jax.random.key(4), True
    imm0 = jnp.array([[1.0, 0.2], [0.2, 2.0]])
    z0 = jnp.array([0.5, -0.5])
    adaptation = blackjax.window_adaptation(
        blackjax.nuts, target.log_density, is_mass_matrix_diagonal=not dense,
        initial_inverse_mass_matrix=imm0 if dense else jnp.diag(imm0),
        initial_step_size=0.5, target_acceptance_rate=0.8,
        adaptation_info_fn=get_filter_adapt_info_fn(),
    )
    reference, _ = adaptation.run(key, z0, num_steps=num_steps)

    settings = nuts.NUTSSettings(dense_mass=dense, initial_step_size=0.5)
    step = nuts.build_kernel(target.log_density, settings, num_warmup=num_steps)
    state = nuts.init(z0, target.log_density, imm0, settings)
    final, _ = jax.jit(lambda s, k: jax.lax.scan(lambda c, x: step(x, c), s, k))(
        state, jax.random.split(key, num_steps))

    np.testing.assert_allclose(final.step_size, reference.parameters["step_size"], rtol=1e-12)
    np.testing.assert_allclose(final.inverse_mass_matrix,
                               reference.parameters["inverse_mass_matrix"], rtol=1e-12)
    np.testing.assert_allclose(final.hmc.position, reference.state.position, rtol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"target_acceptance_rate": 1.0}, "target_acceptance_rate"),
     ({"max_num_doublings": 0}, "max_num_doublings"),
     ({"divergence_threshold": 0.0}, "divergence_threshold"),
     ({"initial_step_size": -1.0}, "initial_step_size")],
)
def test_settings_are_validated(kwargs, message):
    with pytest.raises(ValueError, match=message):
        nuts.NUTSSettings(**kwargs)


def test_pushed_forward_covariance_is_capped_near_a_bound():
    """A MAP variance at 1e-8 with Laplace sd 0.7 would get a log-scale variance of 5e15."""
    from symplid.model._params import MAX_UNCONSTRAINED_VARIANCE, pushforward_covariance

    target = GammaVariance()
    cov = np.array([[1.0, 0.3], [0.3, 0.5]])
    capped = pushforward_covariance(target.to_unconstrained, np.array([0.0, 1e-8]), cov)
    assert capped[0, 0] == 1.0 and capped[1, 1] == pytest.approx(MAX_UNCONSTRAINED_VARIANCE)
    correlation = capped[0, 1] / np.sqrt(capped[0, 0] * capped[1, 1])
    assert correlation == pytest.approx(0.3 / np.sqrt(0.5))
    # Exactly on the bound: the push-forward is infinite; the cap, uncorrelated.
    on_bound = pushforward_covariance(target.to_unconstrained, np.array([0.0, 0.0]), cov)
    np.testing.assert_array_equal(on_bound, np.diag([1.0, MAX_UNCONSTRAINED_VARIANCE]))
