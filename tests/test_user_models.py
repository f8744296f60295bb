"""A user's own model: expressions and files, their parameters, priors and bad input.

Expressions are compared with the same function written by hand in jax.numpy (values,
gradients, Hessians), truncated priors with numerical quadrature, and a fit of a
non-quadratic kinetic energy with the truth of its simulated data.
"""

from __future__ import annotations

import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from symplid.dynamics._hamiltonians import is_hamiltonian
from symplid.dynamics._separable import SeparablePotential
from symplid.dynamics._user_models import UserModelError, build_user_model, is_user_model
from symplid.model._data import Observations
from symplid.model._priors import HalfNormal, Laplace, LogNormal, Normal
from symplid.model._truncated import Truncated
from symplid.workflow._fit import build_model, build_posterior, find_map_for
from symplid.workflow._model_builder import build_model_family
from symplid.workflow._settings import (
    dump_settings,
    load_settings,
    merge_overrides,
    resolve_for_data,
    settings_from_dict,
)
from symplid.workflow._settings_schema import prior_spec
from symplid.workflow._validate import SettingsError

KEPLER = "-GM/sqrt(q1^2 + q2^2)"
LOTKA = "beta*exp(q1) - alpha*q1 + delta*exp(p1) - gamma*p1"


def test_expression_matches_the_hand_written_potential_and_its_derivatives():
    pot = build_user_model(KEPLER, "potential", 2, ["GM"])
    gm = jnp.array([3e-4])

    def by_hand(q):
        return -gm[0] / jnp.sqrt(q @ q)

    q = jnp.array([0.7, -1.1])
    np.testing.assert_allclose(pot.value(q, gm), by_hand(q), rtol=1e-15)
    np.testing.assert_allclose(pot.gradient(q, gm), jax.grad(by_hand)(q), rtol=1e-14)
    hess = jax.hessian(lambda x: pot.value(x, gm))(q)
    np.testing.assert_allclose(hess, jax.hessian(by_hand)(q), rtol=1e-13)
    batch = jnp.stack([q, 2 * q], axis=1)  # (d, batch): the filter's layout
    np.testing.assert_allclose(pot.value(batch, gm), [by_hand(q), by_hand(2 * q)], rtol=1e-15)


def test_separability_is_read_from_the_terms():
    lv = build_user_model(LOTKA, "hamiltonian", 1, ["alpha", "beta", "gamma", "delta"])
    assert isinstance(lv, SeparablePotential) and not is_hamiltonian(lv)
    c = jnp.array([1.1, 0.4, 0.4, 0.1])
    # q̇ = ∂H/∂p = δeᵖ − γ, and ∂H/∂q = βe^q − α
    np.testing.assert_allclose(lv.velocity(jnp.array([0.3]), c), [0.1 * math.exp(0.3) - 0.4])
    np.testing.assert_allclose(lv.gradient(jnp.array([0.2]), c), [0.4 * math.exp(0.2) - 1.1])
    mixed = build_user_model("0.5*(1 + a*q1^2)*p1^2 + 0.5*q1^2", "hamiltonian", 1, ["a"])
    assert is_hamiltonian(mixed)
    q, p, a = jnp.array([0.5]), jnp.array([0.8]), jnp.array([0.3])
    np.testing.assert_allclose(mixed.grad_q(q, p, a), [0.3 * 0.5 * 0.64 + 0.5], rtol=1e-14)
    np.testing.assert_allclose(mixed.grad_p(q, p, a), [(1 + 0.3 * 0.25) * 0.8], rtol=1e-14)


@pytest.mark.parametrize(("text", "message"), [
    ("GM*q1 + x", "unknown symbol 'x'"),
    ("__import__('os').system('true') + GM*q1", "unknown symbol '__import__'"),
    ("GM*q1.real", "'.' is not allowed"),
    ("GM*q1[0]", "'[' is not allowed"),
    ("GM*q1 + lambda_(q1)", "unknown symbol 'lambda_'"),
    ("GM*q1 + 'q1'", "is not allowed"),
    ("GM*q3", "uses coordinate 3"),
    ("q1^2", "do not appear"),
    ("GM*q1*p1", "cannot use the momenta"),
    ("GM*(q1", "cannot read"),
])
def test_bad_expressions_are_refused_with_one_line(text, message):
    with pytest.raises(UserModelError, match=re.escape(message)) as info:
        build_user_model(text, "potential", 2, ["GM"])
    assert "\n" not in str(info.value)


def test_registered_names_and_expressions_are_told_apart():
    assert not is_user_model("polynomial") and not is_user_model("double-pendulum")
    assert not is_user_model("kepler")  # a misspelt family: the registry answers it
    assert is_user_model(KEPLER) and is_user_model("q1") and is_user_model("file:m.py:U")


def test_a_file_model_reads_its_parameters_by_name(tmp_path):
    (tmp_path / "m.py").write_text(
        "import jax.numpy as jnp\n"
        "def H(q, p, params):\n"
        "    return params['beta']*jnp.exp(q[0]) - params['alpha']*q[0] "
        "+ params['delta']*jnp.exp(p[0]) - params['gamma']*p[0]\n"
        "def U(q, params):\n    return float(q[0]) * params['k']\n")
    names = ["alpha", "beta", "gamma", "delta"]
    from_file = build_user_model(f"file:{tmp_path / 'm.py'}:H", "hamiltonian", 1, names)
    from_text = build_user_model(LOTKA, "hamiltonian", 1, names)
    c, q, p = jnp.array([1.1, 0.4, 0.4, 0.1]), jnp.array([0.3]), jnp.array([1.2])
    np.testing.assert_allclose(from_file.grad_p(q, p, c), from_text.velocity(p, c), rtol=1e-14)
    np.testing.assert_allclose(from_file.grad_q(q, p, c), from_text.gradient(q, c), rtol=1e-14)
    with pytest.raises(UserModelError, match="not a JAX-traceable"):
        build_user_model(f"file:{tmp_path / 'm.py'}:U", "potential", 1, ["k"])
    with pytest.raises(UserModelError, match="does not define a function 'V'"):
        build_user_model(f"file:{tmp_path / 'm.py'}:V", "potential", 1, ["k"])
    with pytest.raises(UserModelError, match="no such file"):
        build_user_model(f"file:{tmp_path / 'none.py'}:U", "potential", 1, ["k"])


@pytest.mark.parametrize("prior", [Normal(0.5, 1.0), Laplace(0.0, 2.0), HalfNormal(1.0),
                                   LogNormal(0.0, 0.5)])
def test_a_truncated_prior_integrates_to_one(prior):
    truncated = Truncated(prior, 0.2, 3.0)
    mass, _ = quad(lambda x: math.exp(float(truncated.log_density(x))), 0.2, 3.0)
    assert mass == pytest.approx(1.0, rel=1e-8)
    draws = np.asarray(truncated.sample(jax.random.key(0), (20000,)))
    assert draws.min() >= 0.2 and draws.max() <= 3.0
    mean, _ = quad(lambda x: x * math.exp(float(truncated.log_density(x))), 0.2, 3.0)
    assert draws.mean() == pytest.approx(mean, abs=4 * draws.std() / math.sqrt(draws.size))
    assert truncated.mean == pytest.approx(mean, rel=1e-3)


PENDULUM_SETTINGS = {
    "model": {"potential": "k*(1 - cos(q1))", "dt": 0.1,
              "parameters": {"k": {"prior": "normal", "loc": 1.0, "scale": 2.0, "lower": 0.0,
                                   "initial": 1.5}}},
    "initial_state": {"x0": [1.0, 0.0]},
}


def test_parameters_table_round_trips_and_gives_bounded_priors(tmp_path):
    s = settings_from_dict(PENDULUM_SETTINGS)
    (param,) = s.model.parameters
    assert param.name == "k" and param.lower == 0.0 and param.initial == 1.5
    assert isinstance(param.bounded_prior, Truncated)
    assert param.bounded_prior.support == (0.0, math.inf)
    assert load_settings(dump_settings(s, tmp_path / "s.toml")) == s
    assert prior_spec(s).overrides["k"] == param.bounded_prior
    again = merge_overrides(s, {"model.parameters.k.scale": 3.0})
    assert again.model.parameters[0].prior == Normal(1.0, 3.0)


@pytest.mark.parametrize(("table", "message"), [
    ({"k": {"scale": 1.0}}, "has no prior"),
    ({"k": {"prior": "gamma", "scale": 1.0}}, "k"),
    ({"k": {"prior": "half-normal", "loc": 1.0}}, "loc"),
    ({"k": {"prior": "half-normal", "initial": -1.0}}, "initial"),
    ({"q1": {"prior": "normal"}}, "not a usable parameter name"),
    ({"k": {"prior": "uniform", "low": 0, "high": 1, "lower": 5}}, "no probability"),
])
def test_bad_parameter_declarations_name_the_key(table, message):
    data = {**PENDULUM_SETTINGS, "model": {**PENDULUM_SETTINGS["model"], "parameters": table}}
    with pytest.raises(SettingsError, match=message) as info:
        settings_from_dict(data, source="s.toml")
    assert str(info.value).startswith("s.toml: model.parameters.")


def _pendulum_data(n: int = 30) -> Observations:
    t = np.linspace(0.3, 9.0, n)
    sol = solve_ivp(lambda _, x: [x[1], -2.0 * np.sin(x[0])], (0, 9.0), [1.0, 0.0], t_eval=t,
                    rtol=1e-11, atol=1e-12)
    rng = np.random.default_rng(3)
    return Observations(t, sol.y.T + 0.02 * rng.standard_normal((n, 2)), ("q1", "p1"))


def test_the_model_and_posterior_use_the_declared_parameters():
    obs = _pendulum_data()
    s = resolve_for_data(settings_from_dict(PENDULUM_SETTINGS), obs)
    posterior = build_posterior(s, obs, build_model(s, obs))
    assert posterior.param_names[0] == "k" and posterior.param_groups[0] == "parameters"
    assert posterior.lower[0] == 0.0 and posterior.space.bijectors[0] == "log"
    # the prior of k is Normal(1, 2) cut at 0 and renormalised by P(k > 0) = Φ(1/2)
    mass = 0.5 * (1 + math.erf(0.5 / math.sqrt(2)))
    expected = float(Normal(1.0, 2.0).log_density(1.5)) - math.log(mass)
    assert float(posterior.priors[0].log_density(1.5)) == pytest.approx(expected, rel=1e-12)
    assert float(posterior.log_prior(np.array([-0.1, 0.1, 0.1, 0.1]))) == -math.inf


def test_a_singular_potential_gives_minus_infinity_not_an_error():
    t = np.linspace(1.0, 4.0, 4)
    obs = Observations(t, np.zeros((4, 2)), ("q1", "q2"))
    s = resolve_for_data(settings_from_dict({
        "model": {"potential": KEPLER, "dt": 0.25,
                  "parameters": {"GM": {"prior": "half-normal"}}},
        "initial_state": {"x0": [0.0, 0.0, 0.0, 0.0]}}), obs)
    posterior = build_posterior(s, obs, build_model(s, obs))
    assert float(posterior.log_likelihood(np.array([1.0, 0.1, 0.1]))) == -math.inf
    assert float(posterior.log_density(np.array([1.0, 0.1, 0.1]))) == -math.inf


@pytest.mark.filterwarnings("ignore:the MAP sits on a bound")
def test_a_fit_recovers_a_non_quadratic_kinetic_parameter():
    """H = (cosh p − 1)/a + ½q²: the mass-like a lives in T alone; the MAP finds it."""
    a_true = 0.6
    t = np.linspace(0.4, 12.0, 30)
    sol = solve_ivp(lambda _, x: [np.sinh(x[1]) / a_true, -x[0]], (0, 12.0), [0.5, 0.0],
                    t_eval=t, method="DOP853", rtol=1e-12, atol=1e-12)
    rng = np.random.default_rng(1)
    obs = Observations(t, sol.y.T + 0.01 * rng.standard_normal((t.size, 2)), ("q1", "p1"))
    s = resolve_for_data(settings_from_dict({
        "model": {"hamiltonian": "(cosh(p1) - 1)/a + q1^2/2", "dt": 0.05,
                  "parameters": {"a": {"prior": "log-normal", "mu": 0.0, "sigma": 1.0}}},
        "initial_state": {"x0": [0.5, 0.0]}, "map": {"num_starts": 2}}), obs)
    model = build_model(s, obs)
    assert isinstance(model.hamiltonian, SeparablePotential)
    assert s.model.integrator == "leapfrog"  # separable: explicit leapfrog, no Tao
    result = find_map_for(s, build_posterior(s, obs, model))
    a, sd = result.theta[0], math.sqrt(result.covariance[0, 0])
    assert abs(a - a_true) < 4 * sd and sd < 0.05 * a_true


def test_a_non_separable_expression_picks_a_non_separable_integrator():
    obs = _pendulum_data(5)
    s = resolve_for_data(settings_from_dict({
        "model": {"hamiltonian": "0.5*(1 + a*q1^2)*p1^2 + q1^2",
                  "parameters": {"a": {"prior": "half-normal"}}},
        "initial_state": {"x0": [1.0, 0.0]}}), obs)
    assert s.model.integrator == "tao" and s.prediction.integrator == "tao"
    assert is_hamiltonian(build_model_family(1, s.model))
    with pytest.raises(SettingsError, match="needs a separable H"):
        resolve_for_data(merge_overrides(s, {"model.integrator": "yoshida4"}), obs)


def test_kinetic_and_parameters_need_a_user_model():
    with pytest.raises(SettingsError, match=r"model\.parameters declares"):
        resolve_for_data(settings_from_dict({
            "model": {"parameters": {"a": {"prior": "normal"}}},
            "initial_state": {"x0": [1.0, 0.0]}}), _pendulum_data(5))
    with pytest.raises(SettingsError, match=r"model\.kinetic"):
        resolve_for_data(settings_from_dict({
            "model": {"kinetic": "cosh(p1)"}, "initial_state": {"x0": [1.0, 0.0]}}),
            _pendulum_data(5))



def test_a_sweep_cell_sets_a_user_model_by_dotted_keys():
    from symplid.workflow._sweep_spec import cell_settings

    s = cell_settings({"model.potential": "k*(1 - cos(q1))",
                       "model.parameters.k": {"prior": "half-normal", "scale": 5.0},
                       "model.parameters.k.initial": 1.0}, experiment="paper")
    assert s.model.potential == "k*(1 - cos(q1))"
    assert s.model.parameters[0].initial == 1.0 and s.model.parameters[0].prior == HalfNormal(5)


def test_a_model_file_is_found_from_the_settings_files_folder(tmp_path, monkeypatch):
    (tmp_path / "m.py").write_text("def U(q, params):\n    return params['k'] * q[0] ** 2\n")
    (tmp_path / "s.toml").write_text('[model]\npotential = "file:m.py:U"\n'
                                     '[model.parameters]\nk = { prior = "half-normal" }\n')
    monkeypatch.chdir(tmp_path.parent)
    s = load_settings(tmp_path / "s.toml")
    assert s.model.potential == f"file:{(tmp_path / 'm.py').resolve()}:U"
    with pytest.raises(SettingsError, match="not a usable parameter name"):
        settings_from_dict({"model": {"potential": "lambda*q1",
                                      "parameters": {"lambda": {"prior": "normal"}}}})
