"""DRAM: the delayed-rejection formula, the adaptive covariance, and the moments it samples."""

from __future__ import annotations

from decimal import Decimal, localcontext

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import symplid  # noqa: F401  (float64)
from sampler_targets import Banana, GammaVariance, Gaussian2D, MapResult, moment_z_scores
from symplid.inference.samplers import _dram_stages as dram_stages
from symplid.inference.samplers import dram
from symplid.sampling import RunOptions, draws_array, run_chains, sample

# ----------------------------------------------------------------------------------------
# Independent NumPy versions of the target and of the delayed-rejection formula
# (Haario et al. 2006, eq. for α2), evaluated in probability space, not in log space.


def banana_density_np(theta: np.ndarray, b: float = 1.0) -> float:
    x1, x2 = theta
    return float(np.exp(-0.5 * x1**2 - 0.5 * (x2 - b * (x1**2 - 1.0)) ** 2))


def alpha2_np(density, x, y1, y2, proposal_cov) -> float:
    def q1(start, end):
        return stats.multivariate_normal(mean=start, cov=proposal_cov).pdf(end)

    def alpha1(start, end):
        return min(1.0, density(end) / density(start))

    numerator = density(y2) * q1(y2, y1) * (1.0 - alpha1(y2, y1))
    denominator = density(x) * q1(x, y1) * (1.0 - alpha1(x, y1))
    return min(1.0, numerator / denominator)


def _stack_state(state: dram.DRAMState) -> dram.DRAMState:
    return jax.tree.map(lambda leaf: leaf[None], state)


# ----------------------------------------------------------------------------------------


def test_log1mexp_matches_high_precision():
    points = [-1e-300, -1e-20, -1e-8, -1e-3, -0.3, -np.log(2.0), -0.9, -5.0, -40.0, -700.0]
    values = np.asarray(dram.log1mexp(jnp.asarray(points)))
    for a, value in zip(points, values, strict=True):
        with localcontext() as context:
            context.prec = 400  # enough digits for 1 − e^(−1e-300)
            reference = float((1 - Decimal(a).exp()).ln())
        assert value == pytest.approx(reference, rel=1e-13, abs=1e-300)
    assert np.asarray(dram.log1mexp(jnp.asarray(0.0))) == -np.inf
    assert np.asarray(dram.log1mexp(jnp.asarray(-np.inf))) == 0.0


@pytest.fixture(scope="module")
def banana_step():
    target = Banana()
    return target, jax.jit(dram.build_kernel(target.log_density, dram.DRAMSettings()))


@pytest.mark.parametrize("start", [(0.3, -0.8), (1.5, 0.4), (-1.0, 1.2)])
def test_stage2_acceptance_matches_direct_formula(banana_step, start):
    """α2 reported by the kernel equals the textbook formula at the kernel's own proposals."""
    target, step = banana_step
    # A wide stage-1 proposal so that stage 1 rejects often and stage 2 runs.
    cov0 = np.array([[2.0, 0.5], [0.5, 3.0]])
    state = dram.init(jnp.asarray(start), target.log_density, jnp.asarray(cov0))
    proposal_cov = np.asarray(state.chol @ state.chol.T)
    checked = interior = 0
    for seed in range(60):
        _, info = step(jax.random.key(seed), state)
        if not bool(info.stage2_attempted):
            continue
        expected = alpha2_np(banana_density_np, np.asarray(start),
                             np.asarray(info.proposal1), np.asarray(info.proposal2),
                             proposal_cov)
        assert float(info.acceptance_rate2) == pytest.approx(expected, rel=1e-9, abs=1e-300)
        checked += 1
        interior += 0.0 < expected < 1.0
    assert checked >= 10 and interior >= 3


def test_stage2_log_acceptance_edge_cases():
    x, y1, y2 = jnp.array([0.0, 0.0]), jnp.array([1.0, -0.5]), jnp.array([0.1, 0.05])
    chol = jnp.linalg.cholesky(jnp.array([[1.0, 0.3], [0.3, 2.0]]))
    proposal_cov = np.asarray(chol @ chol.T)

    compiled = jax.jit(dram.stage2_log_acceptance)

    def log_alpha2(lx, ly1, ly2):
        return float(compiled(x, lx, y1, ly1, y2, ly2, chol))

    # y2 outside the support (−∞) or broken (NaN, +∞): never accepted, never NaN.
    for bad in (-jnp.inf, jnp.nan, jnp.inf):
        assert log_alpha2(-1.0, -3.0, bad) == -np.inf
    # π(y1) ≥ π(y2): 1 − α1(y2, y1) = 0, so α2 = 0.
    assert log_alpha2(-1.0, -0.5, -0.7) == -np.inf
    # y1 outside the support: α1 = 0 at both ends, α2 = min(1, π(y2) q1(y2,y1) / π(x) q1(x,y1)).
    for ly1 in (-jnp.inf, jnp.nan):
        densities = {0: np.exp(-1.0), 2: np.exp(-1.3)}
        expected = min(1.0, densities[2] * stats.multivariate_normal(y2, proposal_cov).pdf(y1)
                       / (densities[0] * stats.multivariate_normal(x, proposal_cov).pdf(y1)))
        assert np.exp(log_alpha2(-1.0, ly1, -1.3)) == pytest.approx(expected, rel=1e-12)
    # Log space: shifting every log density by −1e5 (where exp underflows) changes nothing.
    base = log_alpha2(-1.0, -2.5, -1.2)
    assert np.isfinite(base) and base < 0
    assert log_alpha2(-1.0 - 1e5, -2.5 - 1e5, -1.2 - 1e5) == pytest.approx(base, abs=1e-9)


def test_recursive_moments_and_adaptation_start():
    """Running mean/cov equal NumPy's over all states; adaptation starts at 200 states."""
    target = Gaussian2D()
    settings = dram.DRAMSettings(nugget=1e-6)
    cov0 = np.array([[0.5, 0.1], [0.1, 0.8]])
    start = np.array([0.2, -1.0])
    state = _stack_state(dram.init(jnp.asarray(start), target.log_density, jnp.asarray(cov0),
                                   settings))

    def record(state, info):
        return {"position": state.position, "mean": state.mean, "cov": state.cov,
                "count": state.count, "chol": state.chol}

    run = run_chains(dram.build_kernel(target.log_density, settings), state,
                     jax.random.key(3), 600, record=record, options=RunOptions(progress=False))
    draws = {name: value[0] for name, value in run.draws.items()}
    chain = np.vstack([start, draws["position"]])
    s_d = 2.4**2 / 2
    for steps in (1, 2, 197, 198, 199, 200, 600):
        states = chain[: steps + 1]  # the start and the states after `steps` iterations
        i = steps - 1
        assert draws["count"][i] == steps + 1
        np.testing.assert_allclose(draws["mean"][i], states.mean(axis=0), rtol=1e-12,
                                   atol=1e-13)
        np.testing.assert_allclose(draws["cov"][i], np.cov(states.T), rtol=1e-10, atol=1e-13)
        if steps + 1 < settings.adapt_start:
            expected = s_d * cov0
        else:
            expected = s_d * (np.cov(states.T) + settings.nugget * np.diag(np.diag(cov0)))
        chol = draws["chol"][i]
        np.testing.assert_allclose(chol @ chol.T, expected, rtol=1e-10, err_msg=f"{steps=}")


def test_far_start_reaches_the_mode():
    """Started 30 standard deviations away with a poor proposal, the chain finds the mass."""
    target = Gaussian2D()
    start = np.array([30.0, -60.0])
    state = _stack_state(dram.init(jnp.asarray(start), target.log_density, jnp.eye(2)))

    def record(state, info):
        return {"position": state.position, "lp": state.logdensity}

    run = run_chains(dram.build_kernel(target.log_density), state, jax.random.key(11), 10_000,
                     record=record, burn_in=0, options=RunOptions(progress=False))
    lp = run.draws["lp"][0]
    assert lp[0] < -400
    # −2·lp is χ²(2) at equilibrium: its mean over the second half is about 2.
    assert np.mean(-2.0 * lp[5000:]) == pytest.approx(2.0, abs=0.3)
    draws = run.draws["position"][:, 5000:]
    scores = moment_z_scores(draws, target.mean, target.cov)
    assert max(abs(z) for z in scores.values()) < 4, scores


@pytest.fixture(scope="module", params=["gaussian", "banana", "gamma"])
def dram_run(request):
    target = {"gaussian": Gaussian2D, "banana": Banana, "gamma": GammaVariance}[request.param]()
    idata = sample(target, "dram", num_draws=8000, num_chains=4, seed=5,
                   init=target.map_result(), burn_in=2000, options=RunOptions(progress=False))
    return target, idata


def test_dram_moments_within_monte_carlo_error(dram_run):
    target, idata = dram_run
    draws = draws_array(idata)
    scores = moment_z_scores(draws, target.mean, target.cov)
    assert max(abs(z) for z in scores.values()) < 4, scores
    stage1 = float(idata.sample_stats["stage1_accepted"].mean())
    assert 0.1 < stage1 < 0.7
    # Stage 2 runs exactly when stage 1 rejects, and only then can it accept.
    stats_ = idata.sample_stats
    np.testing.assert_array_equal(stats_["stage2_attempted"], ~stats_["stage1_accepted"])
    assert not np.any(stats_["stage2_accepted"] & stats_["stage1_accepted"])
    np.testing.assert_array_equal(stats_["accepted"],
                                  stats_["stage1_accepted"] | stats_["stage2_accepted"])


def test_dram_stays_in_support(dram_run):
    target, idata = dram_run
    draws = draws_array(idata)
    assert np.all(np.isfinite(draws))
    assert np.all(draws > target.lower) and np.all(draws < target.upper)
    lp = np.asarray(jax.vmap(target.log_density)(jnp.asarray(draws.reshape(-1, 2))))
    np.testing.assert_allclose(idata.sample_stats["lp"].values.ravel(), lp, rtol=1e-12)


def test_nan_log_density_is_a_rejection():
    """A log density that returns NaN outside its support is treated as −∞."""

    class NaNOutside(GammaVariance):
        def log_density(self, theta):
            value = super().log_density(theta)
            return jnp.where(jnp.isfinite(value), value, jnp.nan)

    target = NaNOutside()
    settings = dram.DRAMSettings(gamma=4.0)  # a wide second stage, to hit v < 0 often
    state = _stack_state(dram.init(jnp.array([0.0, 0.2]), target.log_density,
                                   jnp.diag(jnp.array([1.0, 4.0])), settings))

    def record(state, info):
        return {"position": state.position, "lp": state.logdensity,
                "y1": info.proposal1, "mean": state.mean, "cov": state.cov}

    run = run_chains(dram.build_kernel(target.log_density, settings), state,
                     jax.random.key(0), 2000, record=record, options=RunOptions(progress=False))
    assert np.any(run.draws["y1"][..., 1] < 0)  # proposals did leave the support
    for name in ("position", "lp", "mean", "cov"):
        assert np.all(np.isfinite(run.draws[name])), name
    assert np.all(run.draws["position"][..., 1] > 0)


def test_without_delayed_rejection_stage2_never_runs():
    target = Gaussian2D()
    idata = sample(target, "dram", num_draws=500, num_chains=2, seed=0,
                   init=target.map_result(), settings={"delayed_rejection": False},
                   options=RunOptions(progress=False))
    assert not idata.sample_stats["stage2_attempted"].any()
    np.testing.assert_array_equal(idata.sample_stats["accepted"],
                                  idata.sample_stats["stage1_accepted"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"adapt_start": 0}, "adapt_start"), ({"gamma": 0.0}, "gamma"),
     ({"nugget": -1.0}, "nugget"), ({"scale": float("nan")}, "scale"),
     ({"adapt_stop": -3}, "adapt_stop")],
)
def test_settings_are_validated(kwargs, message):
    with pytest.raises(ValueError, match=message):
        dram.DRAMSettings(**kwargs)


def test_init_checks_shapes():
    with pytest.raises(ValueError, match="cov must have shape"):
        dram.init(jnp.zeros(3), lambda x: -jnp.sum(x**2), jnp.eye(2))
    with pytest.raises(ValueError, match="1-D"):
        dram.init(jnp.zeros((2, 2)), lambda x: -jnp.sum(x**2), jnp.eye(2))


@pytest.mark.slow
def test_short_dram_run_on_the_papers_posterior(hh, hh_model, hh_data, hh_theta):
    """Hénon–Heiles, leapfrog at dt = 0.25 (the paper's posterior): a short DRAM run from
    near the truth with a rough diagonal proposal adapts to a finite, positive-definite
    covariance, accepts at a sane rate and keeps every draw inside the support."""
    from symplid.model._posterior import Posterior

    posterior = Posterior(hh_model, hh_data, x0=hh.initial_state)
    # Rough scales: about the Laplace standard deviations at the MAP (coefficients ~0.02,
    # process variance ~4e-6, observation variance ~4e-4).
    scales = np.r_[np.full(9, 0.02), 4e-6, 4e-4]
    rough = MapResult(np.asarray(hh_theta), np.diag(scales**2), np.diag(scales**-2), 0.0)
    idata = sample(posterior, "dram", num_draws=1000, num_chains=2, seed=0, init=rough,
                   burn_in=500, settings=dram.DRAMSettings(variance_scale="natural"),
                   options=RunOptions(init_spread=0.5, progress=False))  # the paper's, in θ
    adapted = np.asarray(idata.attrs["dram_adapted_covariance"])
    assert np.all(np.isfinite(adapted))
    assert np.all(np.linalg.eigvalsh(adapted) > 0)
    # The adapted covariance has learned the scales, within an order of magnitude or two.
    ratio = np.sqrt(np.diagonal(adapted, axis1=1, axis2=2)) / scales
    assert np.all((ratio > 0.01) & (ratio < 100)), ratio
    stats_ = idata.sample_stats
    assert 0.02 < float(stats_["stage1_accepted"].mean()) < 0.6
    assert 0.2 < float(stats_["accepted"].mean()) < 0.99
    draws = draws_array(idata)
    assert np.all(np.isfinite(draws)) and np.all(draws[..., 9:] > 0)
    assert np.all(np.isfinite(stats_["lp"]))


# ----------------------------------------------------------------------------------------
# The kernel's small-matrix linear algebra (unrolled, so that a chunk compiles to one
# kernel) equals LAPACK's.


@pytest.mark.parametrize("dim", [1, 2, 5, 11, 16])
def test_unrolled_linear_algebra_equals_lapack(dim):
    from jax.scipy.linalg import solve_triangular

    rng = np.random.default_rng(dim)
    a = rng.normal(size=(dim, dim))
    sd = np.sqrt(np.logspace(-8, 0, dim))  # scales as different as the paper's parameters'
    cov = jnp.asarray(sd[:, None] * (a @ a.T / dim + 0.1 * np.eye(dim)) * sd[None, :])
    nugget = 1e-10 * jnp.diag(cov)
    factor = 2.4**2 / dim

    chol = dram._proposal_chol(cov, nugget, factor)
    lapack = jnp.linalg.cholesky(factor * (0.5 * (cov + cov.T) + jnp.diag(nugget)))
    scale = np.max(np.abs(np.asarray(lapack)))
    np.testing.assert_allclose(chol, lapack, rtol=0, atol=1e-12 * scale)
    assert np.all(np.triu(np.asarray(chol), 1) == 0.0)

    start, end = jnp.asarray(rng.normal(size=dim)), jnp.asarray(rng.normal(size=dim))
    white = solve_triangular(lapack, end - start, lower=True)
    np.testing.assert_allclose(
        dram_stages._log_q1(lapack, start, end), -0.5 * jnp.sum(white**2), rtol=1e-12
    )
    z = jnp.asarray(rng.normal(size=dim))
    from symplid.filters._linalg import matmul

    np.testing.assert_allclose(matmul(lapack, z), lapack @ z, rtol=1e-12, atol=1e-15 * scale)


def test_unrolled_cholesky_of_a_non_positive_definite_matrix_is_not_finite():
    cov = jnp.asarray(np.diag([1.0, -1.0, 1.0]))
    chol = dram._proposal_chol(cov, jnp.zeros(3), 1.0)
    assert not np.all(np.isfinite(np.asarray(chol)))
