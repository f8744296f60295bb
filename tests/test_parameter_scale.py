"""DRAM on a user model's parameters: the natural scale and the log scale
(``DRAMSettings(parameter_scale=...)``; the default, ``"prior"``, takes the log scale for a
log-normal prior and the natural one for the others).

Two targets with known answers, each in the group of a user's declared parameters
(``"parameters"``), bounded below by 0:

* k ~ Gamma(3, 0.5), independent of a variance v ~ Gamma(2, 1e-3): on either scale the chains
  must reproduce E k = 1.5, E log k = ψ(3) + log 0.5 and E v within Monte-Carlo error (by the
  effective sample size), and the run must record the scale it used;
* a straight ridge, as data leave when a potential is linear in its coefficients
  (U = a q²/2 + b q⁴/4 seen at one amplitude pins a + 0.8 b): a, b ≥ 0 with
  a + 0.8 b ~ N(2, 0.02²), each half-normal(5). On the natural scale the adapted proposal
  follows the ridge; on the log scale the ridge bends near its ends and the proposal cannot.
"""

from __future__ import annotations

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import digamma

from sampler_targets import MapResult
from symplid.inference._diagnostics import import_arviz
from symplid.inference.samplers._dram import DRAMSettings
from symplid.inference.samplers._registry import LogScale, log_scale_entries
from symplid.model._params import USER_GROUP, ParameterSpace
from symplid.model._priors import HalfNormal, LogNormal
from symplid.model._truncated import bounded
from symplid.sampling import RunOptions, sample
from symplid.sampling._api import draws_array
from symplid.sampling._resume import checkpoint_arrays, resume_sampling
from symplid.sampling._run import SamplingInterrupted
from symplid.workflow._settings import Settings, merge_overrides


def _gamma_logpdf(x, shape, scale):
    safe = jnp.where(x > 0, x, 1.0)
    return jnp.where(x > 0, (shape - 1.0) * jnp.log(safe) - safe / scale, -jnp.inf)


class GammaTarget:
    """k ~ Gamma(3, 0.5) (a declared parameter) and v ~ Gamma(2, 1e-3) (a variance)."""

    num_params = 2
    param_names = ("k", "obs_var")
    param_groups = (USER_GROUP, "obs_var")
    lower = np.array([0.0, 0.0])
    upper = np.array([np.inf, np.inf])

    def log_density(self, theta):
        return _gamma_logpdf(theta[0], 3.0, 0.5) + _gamma_logpdf(theta[1], 2.0, 1e-3)


class RidgeTarget:
    """a, b ≥ 0, half-normal(5) each, with a + 0.8 b ~ N(2, 0.02²)."""

    num_params = 2
    param_names = ("a", "b")
    param_groups = (USER_GROUP, USER_GROUP)
    lower = np.array([0.0, 0.0])
    upper = np.array([np.inf, np.inf])

    def log_density(self, theta):
        a, b = theta[0], theta[1]
        lp = -0.5 * ((a + 0.8 * b - 2.0) / 0.02) ** 2 - 0.5 * (a**2 + b**2) / 25.0
        return jnp.where((a > 0) & (b > 0), lp, -jnp.inf)


def _run(target, init, scale, num_draws=4000, seed=3):
    return sample(target, "dram", num_draws=num_draws, num_chains=4, seed=seed, init=init,
                  settings={"parameter_scale": scale}, options=RunOptions(progress=False))


def _ess(values):
    az = import_arviz()
    return float(az.ess(az.convert_to_dataset(values))["x"].values)


@pytest.fixture(scope="module")
def gamma_runs():
    init = MapResult(np.array([1.0, 2e-3]), np.diag([0.75, 2e-6]), None, 0.0)
    return {scale: _run(GammaTarget(), init, scale) for scale in ("natural", "log")}


@pytest.mark.parametrize("scale", ["natural", "log"])
def test_either_scale_reproduces_the_moments(gamma_runs, scale):
    idata = gamma_runs[scale]
    assert idata.attrs["dram_parameter_scale"] == scale
    assert idata.attrs["dram_log_scale"] == (["k", "obs_var"] if scale == "log" else ["obs_var"])
    draws = draws_array(idata)
    k, v = draws[..., 0], draws[..., 1]
    assert np.all(k > 0) and np.all(v > 0)
    for values, exact in ((k, 1.5), (np.log(k), digamma(3.0) + math.log(0.5)), (v, 2e-3)):
        error = float(values.std()) / math.sqrt(_ess(values))
        assert abs(float(values.mean()) - exact) < 4.0 * error, (scale, values.mean(), exact)


def test_the_natural_scale_follows_a_straight_ridge():
    """Same budget and seed: the smaller ESS of a and b is far larger on the natural scale
    (measured: 2,265 against 32), and both runs agree on E a within their errors."""
    init = MapResult(np.array([1.0, 1.25]), np.array([[0.3, -0.37], [-0.37, 0.47]]), None,
                     0.0)
    runs = {scale: draws_array(_run(RidgeTarget(), init, scale)) for scale in ("natural", "log")}
    ess = {scale: min(_ess(d[..., 0]), _ess(d[..., 1])) for scale, d in runs.items()}
    assert ess["natural"] > 10.0 * ess["log"], ess
    means = {scale: float(d[..., 0].mean()) for scale, d in runs.items()}
    errors = {scale: float(runs[scale][..., 0].std()) / math.sqrt(_ess(runs[scale][..., 0]))
              for scale in runs}
    assert abs(means["natural"] - means["log"]) < 4.0 * math.hypot(*errors.values()), means


def test_the_settings_choose_the_entries():
    """By default a declared parameter moves on its prior's scale: log θ for a log-normal
    prior (bounded or not), θ for a half-normal; the variances on log v."""
    assert DRAMSettings().parameter_scale == Settings().sampler.parameter_scale == "prior"
    with pytest.raises(ValueError, match="parameter_scale must be one of 'prior', 'natural'"):
        DRAMSettings(parameter_scale="logarithmic")
    settings = merge_overrides(Settings(), {"sampler.parameter_scale": "log"})
    assert settings.sampler.parameter_scale == "log"
    space = ParameterSpace.from_priors(
        ("k", "m", "mb", "obs_var"), (USER_GROUP, USER_GROUP, USER_GROUP, "obs_var"),
        (HalfNormal(5.0), LogNormal(0.0, 1.0), bounded(LogNormal(0.0, 1.0), lower=0.5),
         HalfNormal(1.0)))
    expected = {("prior", "log"): [False, True, True, True],
                ("natural", "log"): [False, False, False, True],
                ("log", "log"): [True, True, True, True],
                ("prior", "natural"): [False, True, True, False]}
    for (parameters, variances), mask in expected.items():
        chosen = DRAMSettings(parameter_scale=parameters, variance_scale=variances)
        np.testing.assert_array_equal(log_scale_entries(space, chosen), mask)
    target = GammaTarget()  # no priors: a declared parameter stays natural under "prior"
    np.testing.assert_array_equal(LogScale(target).mask, [False, True])
    np.testing.assert_array_equal(
        LogScale(target, DRAMSettings(parameter_scale="log")).mask, [True, True])


def test_a_run_recorded_before_the_setting_resumes_on_the_log_scale(tmp_path):
    """A run written before ``parameter_scale`` existed moved a user's parameters as log θ,
    and its checkpoint holds log θ: resumed without the setting in its record, it continues
    on that scale, bit for bit the uninterrupted run."""
    init = MapResult(np.array([1.0, 2e-3]), np.diag([0.75, 2e-6]), None, 0.0)
    budget = {"num_draws": 150, "num_chains": 2, "seed": 3, "burn_in": 90, "init": init,
              "settings": {"parameter_scale": "log"}}

    def stop_at_120(report):
        if report.iterations_done == 120:
            raise KeyboardInterrupt

    full = sample(GammaTarget(), "dram", **budget,
                  options=RunOptions(chunk_size=40, progress=False))
    with pytest.warns(SamplingInterrupted):
        part, checkpoint = sample(GammaTarget(), "dram", **budget,
                                  options=RunOptions(chunk_size=40, progress=False,
                                                     callback=stop_at_120, return_state=True))
    record = json.loads(part.attrs["settings"])
    del record["kernel"]["parameter_scale"]
    part.attrs["settings"] = json.dumps(record)
    resumed = resume_sampling(GammaTarget(), part, checkpoint_arrays(checkpoint),
                              options=RunOptions(chunk_size=40, progress=False))
    np.testing.assert_array_equal(draws_array(resumed), draws_array(full))
