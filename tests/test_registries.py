"""Registries are the one source of every choice: entries registered from this file alone work
through ``fit`` settings and the command line.

A toy integrator (symplectic Euler, a genuinely different one-step method), a toy prior family
(Cauchy) and a toy sampler (independent Metropolis–Hastings) are registered here, used by one
``symplid fit`` run, and each is checked against an independent computation: the run's MAP is
where the toy model's own posterior peaks (and leapfrog's likelihood there is different), its
log prior is SciPy's Cauchy log density, and its draws come from the toy sampler.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats

import symplid
from symplid.cli import main
from symplid.dynamics._integrators import INTEGRATORS, Dynamics, Integrator
from symplid.inference._diagnostics import import_arviz
from symplid.inference.samplers import SAMPLERS, SamplerKernel, SamplerSpec
from symplid.io import read_observations
from symplid.model._priors import PRIOR_FAMILIES, Prior
from symplid.model._statespace import HamiltonianModel
from symplid.workflow._fit import build_model, build_posterior
from symplid.workflow._results import RunFolder, read_json


def symplectic_euler(dynamics: Dynamics, q, p, dt):
    """p⁺ = p − Δt ∂U(q), q⁺ = q + Δt M⁻¹p⁺ (first order, symplectic)."""
    p_next = p - dt * dynamics.grad_potential(q)
    return q + dt * dynamics.velocity(p_next), p_next


@dataclasses.dataclass(frozen=True)
class Cauchy(Prior):
    """Cauchy(loc, scale): a heavy-tailed family the library does not ship."""

    family = "toy-cauchy"
    loc: float = 0.0
    scale: float = 1.0

    def log_density(self, x):
        z = (x - self.loc) / self.scale
        return -jnp.log(math.pi * self.scale * (1.0 + z * z))

    @property
    def support(self):
        return (-math.inf, math.inf)

    def sample(self, key, shape=()):
        return self.loc + self.scale * jax.random.cauchy(key, shape)

    @property
    def mean(self):
        return math.nan

    @property
    def std(self):
        return math.inf

    @property
    def median(self):
        return self.loc


@dataclasses.dataclass(frozen=True)
class IMHSettings:
    scale: float = 3.0  # proposal sd around the MAP, in units of the Laplace sd


class IMHState(NamedTuple):
    position: jax.Array
    logdensity: jax.Array


def build_imh(posterior, settings, num_warmup, batch_logdensity) -> SamplerKernel:
    """Independent Metropolis–Hastings with a wide Gaussian proposal centred on the MAP."""
    centre: list[jax.Array] = []
    chol: list[jax.Array] = []

    def init_states(thetas, cov):
        centre.append(thetas[0])
        chol.append(settings.scale * jnp.linalg.cholesky(cov))
        return IMHState(thetas, batch_logdensity(thetas))

    def log_q(x):
        z = jax.scipy.linalg.solve_triangular(chol[0], x - centre[0], lower=True)
        return -0.5 * jnp.sum(z * z)

    def step(key, state):
        k1, k2 = jax.random.split(key)
        proposal = centre[0] + chol[0] @ jax.random.normal(k1, state.position.shape)
        value = posterior.log_density(proposal)
        log_alpha = value - state.logdensity + log_q(state.position) - log_q(proposal)
        accept = jnp.log(jax.random.uniform(k2)) < log_alpha
        new = IMHState(
            jnp.where(accept, proposal, state.position),
            jnp.where(accept, value, state.logdensity),
        )
        return new, accept

    def record(state, accepted):
        return {"theta": state.position, "lp": state.logdensity, "imh_accepted": accepted}

    def final_attrs(states):
        return {"imh_scale": settings.scale}

    return SamplerKernel(init_states, step, record, final_attrs)


@pytest.fixture
def toys():
    INTEGRATORS.register(
        "toy-symplectic-euler",
        Integrator("toy-symplectic-euler", 1, True, symplectic_euler, "symplectic Euler"),
    )
    PRIOR_FAMILIES.register("toy-cauchy", Cauchy)
    SAMPLERS.register("toy-imh", SamplerSpec(IMHSettings, build_imh))
    try:
        yield
    finally:
        INTEGRATORS.unregister("toy-symplectic-euler")
        PRIOR_FAMILIES.unregister("toy-cauchy")
        SAMPLERS.unregister("toy-imh")


def cli(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.mark.slow
def test_toys_registered_here_drive_a_fit_from_the_command_line(toys, tmp_path):
    data = tmp_path / "harmonic.csv"
    assert cli("simulate", "harmonic", "--out", data, "--seed", "3").exit_code == 0
    # the help wraps its lines, at a hyphen too: read it as one line, unbroken
    help_text = " ".join(cli("fit", "--help").output.split()).replace("- ", "-")
    assert "toy-symplectic-euler" in help_text and "toy-imh" in help_text

    out = tmp_path / "run"
    result = cli(
        "fit", data, "--out", out, "--order", "2", "--x0", "1,0", "--dt", "0.1",
        "--integrator", "toy-symplectic-euler", "--method", "toy-imh",
        "--set", "priors.coefficients.prior=toy-cauchy",
        "--set", "priors.coefficients.scale=2",
        "--iterations", "600", "--burn-in", "100", "--chains", "2", "--no-progress",
    )
    assert result.exit_code == 0, result.output

    folder = RunFolder(out, "r")
    settings = folder.read_settings()
    assert settings.model.integrator == "toy-symplectic-euler"
    assert settings.sampler.method == "toy-imh"
    assert settings.priors.coefficients == Cauchy(0.0, 2.0)

    # The posterior of those settings really uses the toy integrator and prior.
    obs = read_observations(data)
    model = build_model(settings, obs)
    posterior = build_posterior(settings, obs, model)
    assert model.integrator.step is symplectic_euler
    theta = np.asarray(read_json(out / "map.json")["theta"], dtype=float)
    log_prior = float(posterior.log_density(theta) - posterior.log_likelihood(theta))
    nc = model.num_coefficients
    expected = stats.cauchy(0.0, 2.0).logpdf(theta[:nc]).sum()
    expected += stats.halfnorm(scale=1.0).logpdf(theta[nc:]).sum()
    assert log_prior == pytest.approx(expected, rel=1e-10)

    # The MAP is a stationary point of the toy model's posterior, not of leapfrog's.
    _, grad = posterior.value_and_grad()(jnp.asarray(theta))
    free = theta[nc:] > 1e-9  # variances on their floor are held at a bound
    coeff_grad = np.asarray(grad)[:nc]
    assert np.max(np.abs(coeff_grad)) < 1e-3 * max(1.0, float(np.max(np.abs(theta[:nc]))))
    assert free.any()
    leapfrog = HamiltonianModel(model.hamiltonian, integrator="leapfrog", dt=0.1,
                                observation=model.observation, noise=model.noise)
    x0 = np.array([1.0, 0.0])
    toy_ll = float(model.log_likelihood(theta, obs, x0))
    assert toy_ll == pytest.approx(float(posterior.log_likelihood(theta)), rel=1e-12)
    assert abs(float(leapfrog.log_likelihood(theta, obs, x0)) - toy_ll) > 1e-3

    # The draws come from the toy sampler.
    idata = import_arviz().from_netcdf(out / "posterior.nc")
    assert idata.attrs["method"] == "toy-imh"
    assert idata.attrs["imh_scale"] == 3.0
    accepted = np.asarray(idata.sample_stats["imh_accepted"])
    assert accepted.shape == (2, 500)
    assert 0.0 < accepted.mean() < 1.0
    assert symplid.samplers.SAMPLERS.canonical("toy-imh") == "toy-imh"
