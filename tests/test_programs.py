"""One compiled program per model structure and data shape, whatever the data's values.

Two data sets of the same shape must lower to the same program (the text XLA compiles, and
so the key of JAX's persistent compilation cache), also when the data place a learned initial
state's prior; the log density must still be the priors' own (each prior object's density,
summed by hand) plus the likelihood.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from symplid.dynamics._potentials import Polynomial
from symplid.model._data import Observations
from symplid.model._posterior import Posterior
from symplid.model._priors import Laplace, Normal
from symplid.model._statespace import HamiltonianModel


def _data(seed: int, n: int = 12) -> Observations:
    rng = np.random.default_rng(seed)
    t = np.linspace(0.5, 6.0, n)
    values = np.stack([np.cos(t), -np.sin(t)], axis=1) * (1.0 + 0.3 * seed)
    return Observations(t, values + 0.05 * rng.standard_normal((n, 2)), ("q1", "p1"))


def _posterior(obs: Observations, **kwargs) -> Posterior:
    model = HamiltonianModel(Polynomial(1, 2), dt=0.25, backend="jax")
    return Posterior(model, obs, learn_initial_state=True, **kwargs)


def _program(posterior: Posterior) -> str:
    theta = np.asarray(posterior.space.interior_point())
    fn = jax.jit(jax.value_and_grad(lambda t, d: posterior.log_density_with(d, t)))
    return fn.lower(theta, posterior.data).as_text()


@pytest.mark.parametrize(("offset", "t0"), [(None, 0.0), (Laplace(0.0, 0.7), 0.0),
                                           (None, None)])
def test_two_data_sets_of_one_shape_lower_to_one_program(offset, t0):
    """Also with the state at the first observation (t0=None: y_1 enters its own update)."""
    a, b = (_posterior(_data(seed), initial_state_prior=offset, t0=t0) for seed in (0, 1))
    assert a.priors[-2:] != b.priors[-2:]  # the data place the initial state's prior
    assert _program(a) == _program(b)


def test_the_log_density_is_the_priors_own_plus_the_likelihood():
    for offset, t0 in ((None, 0.0), (Laplace(0.0, 0.7), 0.0), (Normal(0.0, 2.0), None)):
        posterior = _posterior(_data(1), initial_state_prior=offset, t0=t0)
        theta = np.asarray(posterior.space.interior_point()) + 0.01
        by_hand = sum(float(p.log_density(v)) for p, v in zip(posterior.priors, theta,
                                                                strict=True))
        assert float(posterior.log_prior(theta)) == pytest.approx(by_hand, rel=1e-13)
        expected = by_hand + float(posterior.log_likelihood(theta))
        assert float(posterior.log_density(theta)) == pytest.approx(expected, rel=1e-13)
        assert float(posterior.log_density_with(posterior.data, theta)) == pytest.approx(
            expected, rel=1e-13)
        outside = theta.copy()
        outside[posterior.param_names.index("process_var")] = -1.0
        assert float(posterior.log_density(outside)) == -np.inf


def test_a_known_initial_state_keeps_its_data_as_before():
    posterior = Posterior(HamiltonianModel(Polynomial(1, 2), dt=0.25), _data(0),
                          x0=np.array([1.0, 0.0]))
    assert len(posterior.data) == posterior.num_trajectories  # nothing placed by the data


def test_a_model_at_another_dt_with_as_many_substeps_runs_the_same_program():
    """dt reaches the filter through the substeps of each gap (arguments) and their most
    (the loop): dt = 0.3 splits the gaps of 0.5 in two like dt = 0.25, dt = 0.2 in three."""
    from symplid.model._programs import compiled

    potential = Polynomial(1, 2)
    obs = _data(0)
    models = {dt: HamiltonianModel(potential, dt=dt, backend="jax") for dt in (0.25, 0.3, 0.2)}
    programs = {dt: compiled(m, m.prepare(obs)) for dt, m in models.items()}
    assert programs[0.25] is programs[0.3]
    assert programs[0.2] is not programs[0.25]
    theta, x0 = np.array([0.5, 0.1, 1e-3, 1e-2]), np.array([1.0, 0.0])
    alone = HamiltonianModel(Polynomial(1, 2), dt=0.3, backend="jax")  # its own programs
    assert float(models[0.3].log_likelihood(theta, obs, x0)) == float(
        alone.log_likelihood(theta, obs, x0))
