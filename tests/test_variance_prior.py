"""The data-scaled log-uniform prior of the process variance and its MAP homotopy start."""

from __future__ import annotations

import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from symplid.inference.map._homotopy import half_normal_start
from symplid.model._data import Observations
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import LogUniform
from symplid.model._simulate import simulate
from symplid.model._variance_prior import data_variance_scale, process_variance_prior


def test_scale_is_the_mean_component_variance_missing_values_skipped():
    values = np.array([[0.0, 1.0], [2.0, np.nan], [4.0, 3.0], [6.0, 7.0]])
    obs = Observations(times=[1.0, 2.0, 3.0, 4.0], values=values)
    want = 0.5 * (np.var([0, 2, 4, 6], ddof=1) + np.var([1, 3, 7], ddof=1))
    assert data_variance_scale(obs) == pytest.approx(want, rel=1e-14)
    # two trajectories are pooled per component
    other = Observations(times=[1.0, 2.0], values=[[10.0, 0.0], [12.0, 2.0]])
    pooled = 0.5 * (np.var([0, 2, 4, 6, 10, 12], ddof=1) + np.var([1, 3, 7, 0, 2], ddof=1))
    assert data_variance_scale([obs, other]) == pytest.approx(pooled, rel=1e-14)


def test_prior_spans_eight_decades_below_the_scale_and_falls_back_on_flat_data():
    obs = simulate("harmonic", noise_std=0.05, seed=1)
    b = data_variance_scale(obs)
    assert process_variance_prior(obs) == LogUniform(b * 1e-8, b)
    assert process_variance_prior(obs, decades=3).support == pytest.approx((b * 1e-3, b))
    flat = Observations(times=[1.0, 2.0], values=[[1.0], [1.0]])
    assert data_variance_scale(flat) == 1.0
    with pytest.raises(ValueError, match="decades"):
        process_variance_prior(obs, decades=0.0)


@pytest.mark.slow
def test_half_normal_start_only_for_a_log_uniform_sigma_and_inside_its_support():
    from symplid.dynamics._potentials import Polynomial
    from symplid.model._posterior import Posterior
    from symplid.model._statespace import HamiltonianModel

    obs = simulate("harmonic", noise_std=0.05, seed=1)
    model = HamiltonianModel(Polynomial(1, 2), integrator="leapfrog", dt=0.1)
    half = Posterior(model, obs, x0=[1.0, 0.0])
    assert half_normal_start(half, num_starts=1) is None
    prior = process_variance_prior(obs)
    scaled = half.with_prior(PriorSpec(process_var=prior))
    start = half_normal_start(scaled, num_starts=1)
    assert start is not None and start.shape == (scaled.num_params,)
    sigma = start[list(scaled.param_groups).index("process_var")]
    assert prior.low < sigma < prior.high
    assert np.isfinite(float(scaled.log_density(start)))
    # the coefficients are the half-normal MAP's: the harmonic truth c[q1^2] = 0.5
    assert start[list(scaled.param_names).index("c[q1^2]")] == pytest.approx(0.5, abs=0.02)
