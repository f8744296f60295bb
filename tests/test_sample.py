"""``sample`` and the chunked runner: determinism, interruption, thinning, layout, checks,
and the convergence summary."""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from sampler_targets import GammaVariance, Gaussian2D, MapResult
from symplid.inference._diagnostics import ConvergenceWarning, import_arviz, summary
from symplid.inference.samplers import dram
from symplid.sampling import (
    RunOptions,
    SamplingInterrupted,
    draws_array,
    overdispersed_starts,
    run_chains,
    sample,
)

az = import_arviz()

RUN = dict(num_draws=600, num_chains=3, seed=7, burn_in=300)
QUIET = RunOptions(progress=False)
CHUNK = 300  # one chunk length for every chunked run below, so they share one compilation


@pytest.fixture(scope="module")
def gaussian():
    return Gaussian2D()


@pytest.fixture(scope="module")
def reference_run(gaussian):
    """A DRAM run that the other runs are compared with (default chunking)."""
    return sample(gaussian, "dram", init=gaussian.map_result(), **RUN, options=QUIET)


def test_same_seed_same_draws_other_seed_other_draws(gaussian, reference_run):
    again = sample(gaussian, "dram", init=gaussian.map_result(), **RUN, options=QUIET)
    np.testing.assert_array_equal(draws_array(again), draws_array(reference_run))
    np.testing.assert_array_equal(again.sample_stats["lp"], reference_run.sample_stats["lp"])
    other = sample(gaussian, "dram", init=gaussian.map_result(), **{**RUN, "seed": 8},
                   options=QUIET)
    assert not np.array_equal(draws_array(other), draws_array(reference_run))


def test_draws_do_not_depend_on_the_chunk_size(gaussian, reference_run):
    chunked = sample(gaussian, "dram", init=gaussian.map_result(), **RUN,
                     options=RunOptions(progress=False, chunk_size=CHUNK))
    np.testing.assert_array_equal(draws_array(chunked), draws_array(reference_run))


def test_sequential_chains_give_the_same_draws(gaussian, reference_run):
    sequential = sample(gaussian, "dram", init=gaussian.map_result(),
                        **RUN, options=RunOptions(progress=False, chain_method="sequential"))
    np.testing.assert_allclose(draws_array(sequential), draws_array(reference_run),
                               rtol=1e-12, atol=1e-12)


def test_interrupted_run_keeps_its_draws(gaussian, reference_run):
    """Ctrl-C (simulated from the per-chunk callback) keeps the chunks already finished."""
    reports = []

    def stop_after_two_chunks(report):
        reports.append(report)
        if report.chunk == 1:
            raise KeyboardInterrupt

    with pytest.warns(SamplingInterrupted, match="interrupted after 600 of 900 iterations"):
        partial = sample(gaussian, "dram", init=gaussian.map_result(), **RUN,
                         options=RunOptions(progress=False, chunk_size=CHUNK,
                                            callback=stop_after_two_chunks))
    assert [r.iterations_done for r in reports] == [300, 600]
    assert partial.attrs["interrupted"] == 1 and partial.attrs["iterations"] == 600
    # 600 iterations minus 300 of burn-in: the first 300 draws of the full run, exactly.
    kept = draws_array(partial)
    assert kept.shape == (3, 300, 2)
    np.testing.assert_array_equal(kept, draws_array(reference_run)[:, :300])
    assert reference_run.attrs["interrupted"] == 0


def test_interrupt_during_burn_in_raises(gaussian):
    def stop(report):
        raise KeyboardInterrupt

    with pytest.warns(SamplingInterrupted), pytest.raises(KeyboardInterrupt, match="before"):
        sample(gaussian, "dram", init=gaussian.map_result(), **RUN,
               options=RunOptions(progress=False, chunk_size=CHUNK, callback=stop))


def test_thinning_keeps_every_kth_iteration(gaussian, reference_run):
    thinned = sample(gaussian, "dram", init=gaussian.map_result(),
                     **{**RUN, "num_draws": 200, "thin": 3},
                     options=RunOptions(progress=False, chunk_size=CHUNK))
    np.testing.assert_array_equal(draws_array(thinned), draws_array(reference_run)[:, 2::3])
    assert thinned.attrs["iterations"] == 300 + 600


def test_inference_data_layout(gaussian, reference_run, tmp_path):
    idata = reference_run
    assert list(idata.posterior.data_vars) == ["a", "b"]
    assert idata.posterior["a"].dims == ("chain", "draw")
    assert idata.posterior["a"].shape == (3, 600)
    assert {"lp", "accepted", "stage1_accepted", "stage2_accepted",
            "stage2_attempted"} <= set(idata.sample_stats.data_vars)
    attrs = idata.attrs
    assert attrs["method"] == "dram" and attrs["seed"] == 7
    assert list(attrs["param_names"]) == ["a", "b"]
    settings = json.loads(attrs["settings"])
    assert settings["burn_in"] == 300 and settings["kernel"]["gamma"] == 0.01
    assert settings["kernel"]["adapt_start"] == 200
    np.testing.assert_array_equal(attrs["map_theta"], gaussian.mean)
    np.testing.assert_allclose(attrs["hessian"], np.linalg.inv(gaussian.cov))
    adapted = np.asarray(attrs["dram_adapted_covariance"])
    assert adapted.shape == (3, 2, 2)
    assert np.all(np.linalg.eigvalsh(adapted) > 0)
    np.testing.assert_array_equal(draws_array(idata)[..., 1], idata.posterior["b"].values)

    path = tmp_path / "posterior.nc"
    idata.to_netcdf(str(path))
    loaded = az.from_netcdf(str(path))
    np.testing.assert_array_equal(draws_array(loaded), draws_array(idata))
    np.testing.assert_allclose(loaded.attrs["hessian"], attrs["hessian"])
    assert json.loads(loaded.attrs["settings"]) == settings


def test_chunks_compile_once(gaussian):
    """Every chunk has the same length (the last one discards its surplus), so the kernel
    is traced while compiling the first chunk and never again."""
    traces = []

    def logdensity(theta):
        traces.append(1)
        return gaussian.log_density(theta)

    after_first_chunk = []

    def callback(report):
        if report.chunk == 0:
            after_first_chunk.append(len(traces))

    state = jax.vmap(lambda p: dram.init(p, gaussian.log_density, jnp.eye(2)))(
        jnp.zeros((2, 2)))
    run = run_chains(dram.build_kernel(logdensity), state, jax.random.key(0), 1050,
                     record=lambda s, i: {"x": s.position},
                     options=RunOptions(chunk_size=100, progress=False, callback=callback))
    # 11 chunks of 96 iterations, the last with 90 of them kept.
    assert run.draws["x"].shape == (2, 1050, 2)
    assert after_first_chunk[0] > 0
    assert len(traces) == after_first_chunk[0]


def test_overdispersed_starts(gaussian):
    target = GammaVariance()
    batch = jax.jit(jax.vmap(target.log_density))
    center, cov = np.array([0.0, 1.0]), np.diag([1.0, 4.0])  # wide: many draws have v < 0
    starts = overdispersed_starts(jax.random.key(1), batch, center, cov, 50, spread=2.0)
    assert starts.shape == (50, 2)
    assert np.all(starts[:, 1] > 0) and np.all(np.isfinite(batch(jnp.asarray(starts))))
    assert len(np.unique(starts[:, 0])) == 50
    again = overdispersed_starts(jax.random.key(1), batch, center, cov, 50, spread=2.0)
    np.testing.assert_array_equal(starts, again)
    np.testing.assert_array_equal(
        overdispersed_starts(jax.random.key(1), batch, center, cov, 4, spread=0.0),
        np.tile(center, (4, 1)))
    # Their spread around the centre is about `spread` times the MAP standard deviation.
    wide = overdispersed_starts(jax.random.key(2), jax.jit(jax.vmap(gaussian.log_density)),
                                gaussian.mean, gaussian.cov, 4000, spread=2.0)
    np.testing.assert_allclose(np.cov(wide.T), 4.0 * gaussian.cov, rtol=0.1)


def test_start_falls_back_to_the_map_with_a_warning():
    def spike(theta):  # finite only within 1e-12 of the origin
        return jnp.where(jnp.max(jnp.abs(theta)) < 1e-12, 0.0, -jnp.inf)

    with pytest.warns(UserWarning, match="start at the MAP"):
        starts = overdispersed_starts(jax.random.key(0), jax.jit(jax.vmap(spike)),
                                      np.zeros(2), np.eye(2), 3, max_tries=5)
    np.testing.assert_array_equal(starts, np.zeros((3, 2)))


def test_explicit_initial_positions(gaussian):
    starts = np.array([[5.0, 5.0], [-5.0, 0.0], [0.0, -9.0]])
    idata = sample(gaussian, "dram", init=gaussian.map_result(), **{**RUN, "burn_in": 0},
                   options=RunOptions(progress=False, chunk_size=CHUNK, initial_positions=starts))
    # The first draw is one DRAM step from its start: a few proposal scales at most.
    first = draws_array(idata)[:, 0]
    assert np.all(np.linalg.norm(first - starts, axis=1) < 8.0)
    assert json.loads(idata.attrs["settings"])["explicit_initial_positions"] is True
    np.testing.assert_array_equal(idata.attrs["initial_positions"], starts)


class _NoDensity:
    num_params = 2
    param_names = ("a", "b")


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"method": "hmc"}, ValueError, "unknown sampler"),
        ({"num_draws": 0}, ValueError, "num_draws"),
        ({"num_chains": 1.5}, ValueError, "num_chains"),
        ({"burn_in": -1}, ValueError, "burn_in"),
        ({"options": dict(init_spread=-1.0)}, ValueError, "init_spread"),
        ({"settings": {"gama": 0.02}}, ValueError, r"unknown dram setting\(s\) \['gama'\]"),
        ({"settings": 3}, TypeError, "settings must be"),
        ({"init": object()}, TypeError, "init lacks .theta"),
        ({"init": MapResult(np.zeros(3), np.eye(3), np.eye(3), 0.0)}, ValueError,
         r"init.theta must have shape \(2,\)"),
        ({"init": MapResult(np.zeros(2), np.array([[1.0, 2.0], [2.0, 1.0]]), np.eye(2), 0.0)},
         ValueError, "not positive definite"),
        ({"options": dict(initial_positions=np.zeros((3, 2)))}, ValueError,
         "initial_positions"),
        ({"options": dict(chain_method="parallel")}, ValueError, "chain_method"),
    ],
)
def test_bad_arguments_are_named(gaussian, kwargs, error, message):
    arguments = dict(method="dram", num_draws=10, num_chains=2, seed=0,
                     init=gaussian.map_result(), options=RunOptions(progress=False))
    with pytest.raises(error, match=message):
        if "options" in kwargs:  # RunOptions checks its own values
            kwargs = {"options": RunOptions(progress=False, **kwargs["options"])}
        arguments.update(kwargs)
        sample(gaussian, **arguments)


def test_posterior_interface_is_checked():
    with pytest.raises(TypeError, match="posterior lacks log_density"):
        sample(_NoDensity(), "dram", init=Gaussian2D().map_result())
    with pytest.raises(TypeError, match="to_unconstrained"):
        class DensityOnly(_NoDensity):
            def log_density(self, theta):
                return -jnp.sum(theta**2)

        sample(DensityOnly(), "nuts", init=Gaussian2D().map_result())


def test_init_outside_support_is_refused():
    target = GammaVariance()
    bad = MapResult(np.array([0.0, -1.0]), np.eye(2), np.eye(2), 0.0)
    with pytest.raises(ValueError, match=r"log density at init\.theta is not finite"):
        sample(target, "dram", num_draws=10, init=bad, options=RunOptions(progress=False))


# ---------------------------------------------------------------------------- summary


def _idata(draws: np.ndarray, **stats):
    return az.from_dict(posterior={"a": draws[..., 0], "b": draws[..., 1]},
                        sample_stats=stats or None)


def test_summary_quiet_on_independent_draws(capsys):
    draws = np.random.default_rng(0).normal(size=(4, 1000, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        table = summary(_idata(draws))
    assert {"r_hat", "ess_bulk", "ess_tail", "mean", "sd"} <= set(table.columns)
    assert list(table.index) == ["a", "b"]
    # ArviZ's numbers, unrounded.
    np.testing.assert_allclose(table.loc["a", "mean"], draws[..., 0].mean())
    assert table["ess_bulk"].min() > 3000 and table["r_hat"].max() < 1.01
    assert "ess_tail" in capsys.readouterr().out


def test_summary_warns_on_disagreeing_chains():
    rng = np.random.default_rng(1)
    draws = rng.normal(size=(4, 500, 2))
    draws[2:, :, 0] += 3.0  # two chains stuck elsewhere in `a`
    with pytest.warns(ConvergenceWarning, match=r"R-hat above 1.01 .*: a \("):
        summary(_idata(draws), show=False)


def test_summary_warns_on_low_ess():
    rng = np.random.default_rng(2)
    # A slowly mixing AR(1) chain: ESS of a few dozen out of 4 × 300 draws.
    noise = rng.normal(size=(4, 300, 2))
    draws = np.zeros_like(noise)
    for t in range(1, 300):
        draws[:, t] = 0.99 * draws[:, t - 1] + noise[:, t]
    with pytest.warns(ConvergenceWarning, match="bulk ESS below 400"):
        summary(_idata(draws), show=False)


def test_summary_reports_divergences(capsys):
    draws = np.random.default_rng(3).normal(size=(4, 1000, 2))
    diverging = np.zeros((4, 1000), dtype=bool)
    diverging[1, 10] = True
    with pytest.warns(ConvergenceWarning, match="1 divergent NUTS transition"):
        summary(_idata(draws, diverging=diverging))
    assert "NUTS divergences: 1 of 4000" in capsys.readouterr().out
