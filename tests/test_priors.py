"""Priors: densities against scipy.stats, supports, sampling, round trips, the group spec."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import symplid  # noqa: F401  (float64)
from symplid.model._prior_spec import PriorSpec, log_density_sum
from symplid.model._priors import (
    HalfNormal,
    Laplace,
    LogNormal,
    LogUniform,
    Normal,
    Uniform,
    as_prior,
    parse_prior,
    prior_from_dict,
)

# Each prior with its scipy.stats twin (an independent implementation of the same law).
CASES = [
    (Laplace(0.0, 10.0), stats.laplace(loc=0.0, scale=10.0)),
    (Laplace(-1.5, 0.3), stats.laplace(loc=-1.5, scale=0.3)),
    (Normal(0.7, 2.0), stats.norm(loc=0.7, scale=2.0)),
    (HalfNormal(1.0), stats.halfnorm(scale=1.0)),
    (HalfNormal(0.05), stats.halfnorm(scale=0.05)),
    (Uniform(-2.0, 3.0), stats.uniform(loc=-2.0, scale=5.0)),
    (LogNormal(-1.0, 0.5), stats.lognorm(s=0.5, scale=math.exp(-1.0))),
    (LogUniform(1e-8, 1.0), stats.loguniform(1e-8, 1.0)),
    (LogUniform(0.3, 7.0), stats.loguniform(0.3, 7.0)),
]
IDS = [repr(p) for p, _ in CASES]


@pytest.mark.parametrize(("prior", "ref"), CASES, ids=IDS)
def test_log_density_matches_scipy(prior, ref):
    lo, hi = ref.support()
    inside = ref.ppf(np.linspace(0.001, 0.999, 41))
    outside = [x for x in (lo - 1.0, hi + 1.0, -50.0, 50.0) if np.isfinite(x) and ref.pdf(x) == 0]
    x = np.concatenate([inside, outside])
    got = np.asarray(prior.log_density(jnp.asarray(x)))
    want = ref.logpdf(x)
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], rtol=1e-12,
                               atol=1e-12)
    assert np.all(got[~np.isfinite(want)] == -np.inf)


@pytest.mark.parametrize(("prior", "ref"), CASES, ids=IDS)
def test_support_and_moments_match_scipy(prior, ref):
    assert prior.support == pytest.approx(ref.support())
    assert prior.mean == pytest.approx(ref.mean(), rel=1e-12, abs=1e-12)
    assert prior.std == pytest.approx(ref.std(), rel=1e-12)
    assert prior.median == pytest.approx(ref.median(), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize(("prior", "ref"), CASES, ids=IDS)
def test_samples_follow_the_law(prior, ref):
    draws = np.asarray(prior.sample(jax.random.key(3), (4000,)))
    assert draws.dtype == np.float64
    lo, hi = prior.support
    assert np.all((draws >= lo) & (draws <= hi))
    # Kolmogorov–Smirnov against the scipy CDF; a fixed key makes this deterministic.
    assert stats.kstest(draws, ref.cdf).pvalue > 1e-3


@pytest.mark.parametrize(("prior", "ref"), CASES, ids=IDS)
def test_gradient_finite_everywhere(prior, ref):
    """−∞ outside the support but a finite gradient (no NaN) at every point, in or out."""
    grad = jax.vmap(jax.grad(prior.log_density))
    x = jnp.array([-100.0, -1.0, 0.0, 1e-300, 0.5, 2.9, 100.0])
    g = np.asarray(grad(x))
    assert np.all(np.isfinite(g))
    jitted = np.asarray(jax.jit(prior.log_density)(x))
    assert not np.any(np.isnan(jitted))


@pytest.mark.parametrize(("prior", "ref"), CASES, ids=IDS)
def test_round_trips(prior, ref):
    assert prior_from_dict(prior.to_dict()) == prior
    assert parse_prior(repr(prior)) == prior
    assert as_prior(prior.to_dict()) == prior


def test_text_and_settings_forms():
    assert parse_prior("laplace(0, 10)") == Laplace(0.0, 10.0)
    assert parse_prior("half-normal(scale=0.5)") == HalfNormal(0.5)
    assert parse_prior("HalfNormal(2)") == HalfNormal(2.0)
    assert parse_prior("uniform(low=-1, high=1)") == Uniform(-1.0, 1.0)
    # The settings file writes log-normal parameters as loc and scale.
    lognormal = {"family": "log-normal", "loc": 1.0, "scale": 0.2}
    assert prior_from_dict(lognormal) == LogNormal(1.0, 0.2)
    assert prior_from_dict({"family": "LogNormal", "mu": 1.0}) == LogNormal(1.0, 1.0)
    assert Laplace().to_dict() == {"family": "laplace", "loc": 0.0, "scale": 10.0}
    assert parse_prior("log-uniform(1e-8, 0.01)") == LogUniform(1e-8, 0.01)
    assert parse_prior("LogUniform(low=1e-6, high=1)") == LogUniform(1e-6, 1.0)


def test_log_uniform_bounded_is_the_narrower_log_uniform():
    """A log-uniform cut to [c, d] inside its range and renormalised is log-uniform on [c, d]:
    the truncation's CDF and quantile checked against scipy's law of the narrower range."""
    from symplid.model._truncated import Truncated

    cut = Truncated(LogUniform(1e-8, 1.0), 1e-4, 1e-2)
    ref = stats.loguniform(1e-4, 1e-2)
    x = ref.ppf(np.linspace(0.01, 0.99, 17))
    np.testing.assert_allclose(np.asarray(cut.log_density(jnp.asarray(x))), ref.logpdf(x),
                               rtol=1e-10)
    draws = np.asarray(cut.sample(jax.random.key(5), (3000,)))
    assert stats.kstest(draws, ref.cdf).pvalue > 1e-3


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: Laplace(0.0, 0.0), "scale must be"),
        (lambda: Normal(0.0, -1.0), "scale must be"),
        (lambda: HalfNormal(math.inf), "scale must be"),
        (lambda: Uniform(1.0, 1.0), "low .* less than high"),
        (lambda: LogNormal(math.nan, 1.0), "mu must be finite"),
        (lambda: LogUniform(0.0, 1.0), "low must be a finite number > 0"),
        (lambda: LogUniform(2.0, 1.0), "low .* less than high"),
        (lambda: prior_from_dict({"family": "cauchy"}), "unknown prior family 'cauchy'"),
        (lambda: prior_from_dict({"family": "normal", "sigma": 1.0}), "unknown parameter 'sigma'"),
        (lambda: prior_from_dict({"loc": 1.0}), "'family' key"),
        (lambda: prior_from_dict({"family": "normal", "loc": "a"}), "loc must be a number"),
        (lambda: parse_prior("laplace 0 10"), "cannot read a prior"),
        (lambda: parse_prior("normal(0, 1, 2)"), "too many arguments"),
    ],
)
def test_bad_priors_raise_clear_errors(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_log_density_sum():
    priors = [Laplace(0.0, 10.0), HalfNormal(1.0), Uniform(0.0, 2.0)]
    theta = jnp.array([0.3, 0.4, 1.5])
    want = (stats.laplace(scale=10.0).logpdf(0.3) + stats.halfnorm().logpdf(0.4)
            + stats.uniform(0.0, 2.0).logpdf(1.5))
    assert float(log_density_sum(priors, theta)) == pytest.approx(want, rel=1e-12)
    assert float(log_density_sum(priors, jnp.array([0.3, -0.4, 1.5]))) == -np.inf
    with pytest.raises(ValueError, match="3 priors"):
        log_density_sum(priors, jnp.zeros(2))


def test_log_density_sum_of_shared_priors_matches_scipy_in_batches():
    """Parameters sharing one prior (a network's weights) are evaluated as one vector; the
    sum must still be each parameter's own term, in any interleaving and for a batch of θ."""
    shared, other = Normal(0.0, 1.0), Laplace(0.5, 2.0)
    priors = [shared, other, shared, shared, HalfNormal(3.0), other, Normal(0.0, 1.0)]
    refs = [stats.norm(), stats.laplace(0.5, 2.0), stats.norm(), stats.norm(),
            stats.halfnorm(scale=3.0), stats.laplace(0.5, 2.0), stats.norm()]
    theta = np.random.default_rng(3).uniform(0.1, 2.0, size=(5, len(priors)))
    want = [sum(r.logpdf(v) for r, v in zip(refs, row, strict=True)) for row in theta]
    got = np.asarray(log_density_sum(priors, jnp.asarray(theta)))
    np.testing.assert_allclose(got, want, rtol=1e-12)
    theta[2, 4] = -1.0  # off the half-normal's support: that row alone is −∞
    got = np.asarray(log_density_sum(priors, jnp.asarray(theta)))
    assert got[2] == -np.inf and np.all(np.isfinite(np.delete(got, 2)))


def test_prior_spec_defaults_are_the_papers():
    spec = PriorSpec()
    assert spec.coefficients == Laplace(0.0, 10.0)
    assert spec.process_var == HalfNormal(1.0)
    assert spec.obs_var == HalfNormal(1.0)
    assert spec.initial_state is None
    assert spec.group_prior("obs_var") == HalfNormal(1.0)
    with pytest.raises(ValueError, match="unknown group"):
        spec.group_prior("variances")


def test_prior_spec_from_dict_and_round_trip():
    spec = PriorSpec.from_dict({
        "coefficients": "normal(0, 3)",
        "variances": {"family": "log-normal", "loc": -5.0, "scale": 2.0},
        "q1^2": Normal(0.5, 0.1),
        "initial_state": Laplace(0.0, 0.2),
    })
    assert spec.coefficients == Normal(0.0, 3.0)
    assert spec.process_var == spec.obs_var == LogNormal(-5.0, 2.0)
    # A coefficient's bare monomial (its old name) is read as its θ name c[...].
    assert spec.overrides == {"c[q1^2]": Normal(0.5, 0.1)}
    assert spec.initial_state == Laplace(0.0, 0.2)
    assert PriorSpec.from_dict(spec.to_dict()) == spec
    spec.check_names(["c[q1]", "c[q1^2]"])
    spec.check_names(["q1", "q1^2"])
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) 'c\[q1\^2\]'"):
        spec.check_names(["c[q1]", "c[q2]"])


def test_prior_spec_rejects_bad_entries():
    with pytest.raises(ValueError, match="any real value"):
        PriorSpec(initial_state=HalfNormal(1.0))
    with pytest.raises(ValueError, match="prior of coefficients"):
        PriorSpec(coefficients="laplace(0, -1)")
    with pytest.raises(TypeError, match="expected a Prior"):
        PriorSpec(process_var=3.0)
