"""Simulation-based calibration: the rank statistics on cases with known answers, the study's
simulator, and a tiny ``symplid study sbc`` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from symplid.model._simulate import true_trajectory
from symplid.studies._claims_stats import RANK_DRAWS, rank_uniformity, truth_rank
from symplid.studies._sbc import PRIORS, THIN_DRAWS, X0, draw_truth, sbc_spec, simulate_model
from symplid.studies._sbc_report import ESS_MIN, ecdf_band, ecdf_inside


def _conjugate_ranks(n: int, seed: int, shift: float = 0.0, scale: float = 1.0) -> np.ndarray:
    """Ranks of θ̃ ~ N(0, 1) among draws from the exact posterior of y ~ N(θ̃, 0.5²)
    (N(0.8·y, 0.2), Gaussian conjugacy), the posterior moved by ``shift`` posterior sds and
    its sd scaled by ``scale`` (0, 1: the exact posterior)."""
    rng = np.random.default_rng(seed)
    ranks = np.empty(n, dtype=int)
    for i in range(n):
        theta = rng.standard_normal()
        y = theta + 0.5 * rng.standard_normal()
        mean, sd = 0.8 * y, np.sqrt(0.2)
        draws = mean + shift * sd + scale * sd * rng.standard_normal(RANK_DRAWS)
        ranks[i] = truth_rank(draws, theta, RANK_DRAWS)
    return ranks


def test_exact_posterior_gives_uniform_ranks():
    ranks = _conjugate_ranks(400, seed=1)
    assert rank_uniformity(ranks, RANK_DRAWS)["p_value"] > 0.01
    assert ecdf_inside(ranks)


@pytest.mark.parametrize(("shift", "scale"), [(0.5, 1.0), (0.0, 0.6), (0.0, 1.6)],
                         ids=["biased", "overconfident", "underconfident"])
def test_wrong_posteriors_give_ranks_the_tests_reject(shift, scale):
    ranks = _conjugate_ranks(400, seed=2, shift=shift, scale=scale)
    assert rank_uniformity(ranks, RANK_DRAWS)["p_value"] < 1e-3
    assert not ecdf_inside(ranks)


def test_ecdf_band_holds_uniform_ranks_95_percent_of_the_time():
    """The band is simultaneous: over independent sets of uniform ranks (not those it was
    simulated from), about 95 % lie wholly inside it; the pointwise binomial band would hold
    far fewer."""
    n, sets = 100, 600
    _, lower, upper = ecdf_band(n)
    rng = np.random.default_rng(123)
    inside = 0
    for _ in range(sets):
        r = rng.integers(0, RANK_DRAWS + 1, n)
        ecdf = np.cumsum(np.bincount(r, minlength=RANK_DRAWS + 1))[:RANK_DRAWS] / n
        inside += bool(np.all((ecdf >= lower - 1e-12) & (ecdf <= upper + 1e-12)))
    assert 0.92 <= inside / sets <= 0.98


def test_truth_is_drawn_from_the_fit_prior():
    """Each parameter of θ̃ over replications follows its prior (KS against scipy.stats)."""
    from scipy import stats

    from symplid.model._priors import LogNormal, LogUniform, Normal

    def reference(prior):
        if isinstance(prior, Normal):
            return stats.norm(prior.loc, prior.scale)
        if isinstance(prior, LogUniform):
            return stats.loguniform(prior.low, prior.high)
        assert isinstance(prior, LogNormal)
        return stats.lognorm(s=prior.sigma, scale=np.exp(prior.mu))

    draws = [draw_truth(s) for s in range(300)]
    for name, prior in PRIORS.items():
        values = [d[name] for d in draws]
        assert stats.kstest(values, reference(prior).cdf).pvalue > 1e-3, name
    assert "process_var" not in draw_truth(0, "none")


def test_simulator_without_noise_is_the_models_path():
    """With Σ = Γ = 0 the gap-by-gap simulation is the propagator's path over all gaps at once
    (the same leapfrog at the same dt); with Σ > 0 the increments x_k − Ψ(x_{k−1}) have
    variance Σ."""
    cell = {"seed": 4, "num_obs": 30, "obs_interval": 1.0, "dt": 0.1}
    truth = {"c[q1]": 0.01, "c[q1^2]": 0.5, "c[q1^3]": -0.02, "c[q1^4]": 0.1, "obs_var": 0.0}
    obs = simulate_model(truth, cell)
    from symplid.dynamics._potentials import Polynomial

    # one potential object: its propagator is compiled once, not once per gap below
    quartic = Polynomial(1, 4)
    whole = true_trajectory(quartic, [0.01, 0.5, -0.02, 0.1], X0, obs.times, dt=0.1)
    np.testing.assert_allclose(obs.values, whole, rtol=0, atol=1e-12)
    noisy = simulate_model({**truth, "process_var": 1e-4}, {**cell, "num_obs": 400})
    steps = []
    for k in range(1, 400):
        t0, t1 = noisy.times[k - 1], noisy.times[k]
        ahead = true_trajectory(quartic, [0.01, 0.5, -0.02, 0.1], noisy.values[k - 1],
                                [t1], dt=0.1, t0=t0)[0]
        steps.append(noisy.values[k] - ahead)
    var = np.var(np.asarray(steps), axis=0)
    assert np.all(np.abs(var / 1e-4 - 1) < 0.25)


def test_simulator_is_the_fits_propagator():
    """Noise-free data simulated at θ̃ lie exactly on the path the fit's deterministic
    likelihood integrates at θ̃ (the model built by the study, not the simulator's own
    integrator): its log-likelihood at a tiny Γ is the exact Gaussian value of zero residuals,
    and a 1 % change of c[q1^2] moves the path off the data."""
    import math

    import jax.numpy as jnp

    from symplid.model._posterior import Posterior
    from symplid.model._prior_spec import PriorSpec
    from symplid.studies._sbc import _param_names, _settings
    from symplid.workflow._fit import build_model

    cell = {"seed": 3, "likelihood": "none", "sampler": "dram", "num_obs": 20,
            "obs_interval": 1.0, "dt": 0.1, "budget": "quick"}
    truth = {**draw_truth(3, "none"), "obs_var": 0.0}
    obs = simulate_model(truth, cell)
    settings = _settings(cell)
    names = _param_names("none")
    posterior = Posterior(build_model(settings, obs), obs,
                          prior=PriorSpec(overrides={n: PRIORS[n] for n in names}),
                          x0=np.asarray(X0), P0=settings.initial_state.p0_var, t0=0.0)
    var = 1e-10
    theta = np.array([truth[n] for n in names[:-1]] + [var])
    exact = -0.5 * obs.values.size * math.log(2 * math.pi * var)
    assert float(posterior.log_likelihood(jnp.asarray(theta))) == pytest.approx(exact, abs=1e-6)
    theta[1] *= 1.01
    assert float(posterior.log_likelihood(jnp.asarray(theta))) < exact - 1e3


def _ar1_ranks(n: int, rho: float, num: int, seed: int) -> tuple[np.ndarray, float]:
    """Ranks of θ̃ ~ N(0, 1) among ``num`` draws thinned evenly from two stationary AR(1)
    chains of 2,000 (correlation ``rho``) whose marginal is N(0, 1), the exact posterior of a
    prior-only model; and the ESS of the last pair of chains."""
    import arviz as az
    from scipy.signal import lfilter

    rng = np.random.default_rng(seed)
    ranks = np.empty(n, dtype=int)
    for i in range(n):
        theta = rng.standard_normal()
        e = rng.standard_normal((2, 2000)) * np.sqrt(1 - rho**2)
        e[:, 0] = rng.standard_normal(2)
        chains = lfilter([1.0], [1.0, -rho], e, axis=1)
        ranks[i] = truth_rank(chains, theta, num)
    return ranks, float(az.ess(chains))


def test_ess_floor_makes_thinned_ranks_uniform():
    """The study's thinning against the ESS: draws of the right posterior that are
    autocorrelated give non-uniform ranks when the ESS is far below the draws counted (about
    9 here), and uniform ones at the ESS the study requires of a converged replication (≥ 50),
    among RANK_DRAWS = 99 draws and among THIN_DRAWS."""
    ranks, ess = _ar1_ranks(400, 0.998, RANK_DRAWS, seed=0)
    assert ess < 15
    assert rank_uniformity(ranks, RANK_DRAWS)["p_value"] < 0.01 and not ecdf_inside(ranks)
    for num in (RANK_DRAWS, THIN_DRAWS):
        ranks, ess = _ar1_ranks(400, 0.975, num, seed=1)
        assert ESS_MIN <= ess < 80
        assert rank_uniformity(ranks, num)["p_value"] > 0.01 and ecdf_inside(ranks, num)


def test_spec_rejects_bad_options():
    with pytest.raises(ValueError, match="replications"):
        sbc_spec(0)
    with pytest.raises(ValueError, match="likelihoods"):
        sbc_spec(2, ("step",))
    with pytest.raises(ValueError, match="samplers"):
        sbc_spec(2, samplers=("hmc",))
    assert len(sbc_spec(3).cells) == 6
    cells = sbc_spec(3, samplers=("dram", "nuts")).cells
    assert len(cells) == 12 and len({c.id for c in cells}) == 12
    assert [c.settings["sampler"] for c in cells[::6]] == ["dram", "nuts"]


@pytest.mark.slow
def test_sbc_study_end_to_end(tmp_path):
    from click.testing import CliRunner

    from symplid.cli import main

    out = tmp_path / "sbc"
    result = CliRunner().invoke(main, ["study", "sbc", "--out", str(out), "--replications", "2",
                                       "--budget", "quick", "--samplers", "dram,nuts",
                                       "--workers", "1", "--no-progress"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "sbc.json").read_text())["summary"]
    assert set(summary) == {"dram", "nuts"}
    for sampler in summary:
        assert summary[sampler]["gap"]["replications"] == 2
        assert set(summary[sampler]["gap"]["params"]) == set(PRIORS)
        # the deterministic likelihood has no Σ: no rank of it is tested
        assert set(summary[sampler]["none"]["params"]) == set(PRIORS) - {"process_var"}
    assert (out / "report.md").exists()
    # one figure per sampler and likelihood with converged replications, named apart
    assert {p.name for p in (out / "figures").iterdir()} <= {
        "sbc_ranks_gap.png", "sbc_ranks_none.png", "sbc_ranks_nuts_gap.png",
        "sbc_ranks_nuts_none.png"}
    bad = CliRunner().invoke(main, ["study", "sbc", "--out", str(out), "--likelihoods", "step"])
    assert bad.exit_code == 2 and "likelihoods" in bad.output
    bad = CliRunner().invoke(main, ["study", "sbc", "--out", str(out), "--samplers", "hmc"])
    assert bad.exit_code == 2 and "samplers" in bad.output
