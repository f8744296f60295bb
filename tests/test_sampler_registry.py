"""A sampler defined and registered here, in the test file alone, runs through ``sample``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from sampler_targets import MapResult
from symplid.inference._diagnostics import import_arviz
from symplid.inference.samplers import SAMPLERS, SamplerKernel, SamplerSpec
from symplid.sampling import RunOptions, draws_array, sample

az = import_arviz()


class Gaussian1D:
    """N(1.5, 0.8²) over one parameter."""

    num_params = 1
    param_names = ("x",)
    lower = np.array([-np.inf])
    upper = np.array([np.inf])
    mean, sd = 1.5, 0.8

    def log_density(self, theta):
        return -0.5 * ((theta[0] - self.mean) / self.sd) ** 2


@dataclass(frozen=True)
class IndependentSettings:
    loc: float = 1.0
    scale: float = 1.5


class IndependentState(NamedTuple):
    position: jax.Array
    logdensity: jax.Array


class IndependentInfo(NamedTuple):
    is_accepted: jax.Array


def build_independent(posterior, settings, num_warmup, batch_logdensity) -> SamplerKernel:
    """Independent Metropolis–Hastings with the proposal N(loc, scale²) in every coordinate."""
    logdensity = posterior.log_density

    def log_q(x):
        return -0.5 * jnp.sum(((x - settings.loc) / settings.scale) ** 2)

    def init_states(thetas, cov):
        return IndependentState(thetas, batch_logdensity(thetas))

    def step(key, state):
        k1, k2 = jax.random.split(key)
        proposal = settings.loc + settings.scale * jax.random.normal(k1, state.position.shape)
        value = logdensity(proposal)
        log_alpha = value - state.logdensity + log_q(state.position) - log_q(proposal)
        accept = jnp.log(jax.random.uniform(k2)) < log_alpha
        new = IndependentState(jnp.where(accept, proposal, state.position),
                               jnp.where(accept, value, state.logdensity))
        return new, IndependentInfo(accept)

    def record(state, info):
        return {"theta": state.position, "lp": state.logdensity, "accepted": info.is_accepted}

    def final_attrs(states):
        return {"independent_proposal": [settings.loc, settings.scale]}

    return SamplerKernel(init_states, step, record, final_attrs)


@pytest.fixture
def independent():
    SAMPLERS.register("independent-mh", SamplerSpec(IndependentSettings, build_independent),
                      aliases=("imh",))
    try:
        yield "independent-mh"
    finally:
        SAMPLERS.unregister("independent-mh")
    assert "independent-mh" not in SAMPLERS


def test_a_registered_sampler_runs_through_sample(independent):
    assert independent in SAMPLERS.names()
    target = Gaussian1D()
    init = MapResult(np.array([target.mean]), np.array([[target.sd**2]]),
                     np.array([[target.sd**-2]]), 0.0)
    idata = sample(target, "imh", num_draws=4000, num_chains=4, seed=3, init=init,
                   settings={"scale": 1.2}, options=RunOptions(progress=False))
    assert idata.attrs["method"] == "independent-mh"
    assert idata.attrs["independent_proposal"] == [1.0, 1.2]
    assert idata.posterior["x"].shape == (4, 4000)
    x = draws_array(idata)[..., 0]
    mcse = float(az.mcse(x, method="mean"))
    assert abs(float(x.mean()) - target.mean) < 4 * mcse
    assert 0.2 < float(idata.sample_stats["accepted"].mean()) < 1.0
    with pytest.raises(ValueError, match=r"unknown independent-mh setting\(s\) \['scal'\]"):
        sample(target, "imh", num_draws=10, init=init, settings={"scal": 1.0},
               options=RunOptions(progress=False))


def test_unknown_sampler_lists_the_registered_ones(independent):
    with pytest.raises(ValueError, match=r"did you mean .independent-mh.*dram, nuts"):
        sample(Gaussian1D(), "independent-m", init=None)


def test_the_runner_keywords_live_in_the_options_object():
    """``sample`` takes the sampler's arguments and one RunOptions (no more than ten)."""
    import inspect

    assert len(inspect.signature(sample).parameters) <= 10
    target = Gaussian1D()
    init = MapResult(np.array([target.mean]), np.array([[target.sd**2]]),
                     np.array([[target.sd**-2]]), 0.0)
    with pytest.raises(TypeError, match="progress"):
        sample(target, "dram", num_draws=50, init=init, progress=False)
