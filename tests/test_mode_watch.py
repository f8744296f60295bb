"""The MAP searched again where the chains climb above it (``symplid.workflow._mode_watch``).

The runner's best visited point is checked against the draws it returns (burn-in 0, every
iteration kept: the same maximum of log π, at the same θ); the watch against a Gaussian
whose MAP is handed in 3 sds off its mode (the chains climb above it); and a whole fit whose
first MAP search is made to end off the mode against the same fit from the true MAP.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sampler_targets import Gaussian2D, MapResult
from symplid.model._data import Observations
from symplid.sampling import RunOptions, sample
from symplid.workflow import _fit as fit_module
from symplid.workflow._mode_watch import MODE_MARGIN, HigherModeFound, mode_watch
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data

QUIET = RunOptions(progress=False, chunk_size=500)


def test_the_best_point_is_the_highest_draw():
    target, reports = Gaussian2D(), []
    options = dataclasses.replace(QUIET, callback=reports.append)
    idata = sample(target, "dram", num_draws=1500, num_chains=3, seed=4, burn_in=0,
                   init=target.map_result(), options=options)
    lp = idata.sample_stats["lp"].values  # (chain, draw): every iteration, burn-in 0
    best_lp, best_theta = reports[-1].best
    assert best_lp == pytest.approx(lp.max(), abs=1e-12)
    chain, draw = np.unravel_index(np.argmax(lp), lp.shape)
    theta = np.stack([idata.posterior["a"].values, idata.posterior["b"].values], axis=-1)
    np.testing.assert_allclose(best_theta, theta[chain, draw], rtol=0, atol=1e-12)
    assert [r.best[0] for r in reports] == sorted(r.best[0] for r in reports)


def test_chains_started_off_the_mode_stop_the_run():
    target = Gaussian2D()
    off = target.mean + np.array([3.0, 0.0])  # 3 sds along a: log π far below the mode's 0
    log_off = float(target.log_density(off))
    start = MapResult(off, target.cov.copy(), np.linalg.inv(target.cov), log_off)
    options = RunOptions(progress=False, chunk_size=200, callback=mode_watch(log_off))
    with pytest.raises(HigherModeFound) as found:
        sample(target, "dram", num_draws=4000, num_chains=4, seed=1, init=start,
               options=options)
    assert found.value.log_posterior > log_off + MODE_MARGIN
    assert float(target.log_density(found.value.theta)) == pytest.approx(
        found.value.log_posterior, abs=1e-10)
    # From the true mode nothing is higher: the same run ends normally.
    options = dataclasses.replace(options, callback=mode_watch(0.0))
    sample(target, "dram", num_draws=2000, num_chains=4, seed=1, init=target.map_result(),
           options=options)


def _harmonic(n: int = 30) -> Observations:
    t = np.linspace(0.5, 15.0, n)
    rng = np.random.default_rng(7)
    return Observations(t, (np.cos(t) + 0.05 * rng.standard_normal(n))[:, None], ("q1",))


def test_a_fit_whose_map_search_ends_low_searches_again(monkeypatch):
    obs = _harmonic()
    settings = resolve_for_data(merge_overrides(Settings(), {
        "model.potential": "k*q1^2/2", "model.dt": 0.1,
        "model.parameters.k": {"prior": "half-normal", "scale": 5.0},
        "initial_state.x0": [1.0, 0.0], "map.sensitivity": False, "map.num_starts": 2,
        "map.evidence": "laplace", "sampler.num_chains": 4, "sampler.num_iterations": 4000,
        "sampler.burn_in": 2000}), obs)
    real = fit_module.find_map_for
    calls: list[int] = []

    def first_ends_low(settings, posterior, start=None):
        found = real(settings, posterior, start)
        calls.append(1)
        if len(calls) > 1:
            return found
        low = found.theta.copy()
        low[0] *= 1.15  # k 15 % off: tens of nats below the mode with 30 points
        log_low = float(posterior.log_density(low))
        return dataclasses.replace(found, theta=low, log_posterior=log_low)

    monkeypatch.setattr(fit_module, "find_map_for", first_ends_low)
    outcome = fit_module.fit(obs, settings, progress=False)
    assert len(calls) == 2 and len(outcome.map_refound) == 1
    record = outcome.map_refound[0]
    assert record["chains_log_posterior"] > record["first_map_log_posterior"] + MODE_MARGIN
    truth = real(settings, outcome.posterior)
    assert outcome.map_result.log_posterior == pytest.approx(truth.log_posterior, abs=1e-3)
    np.testing.assert_allclose(outcome.map_result.theta, truth.theta, rtol=1e-3, atol=1e-8)
    assert outcome.summary["map_refound"] == [record]
