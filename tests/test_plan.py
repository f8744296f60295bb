"""The run's model is built once (``ModelPlan``): a user's expression is parsed once.

SymPy's parser is counted (``parse_expression`` of the user-model module); the plan's checks
are compared with the settings' checks made without it (the same resolved settings, the same
one-line errors), and the models built on the plan with models built from scratch (the same
log-likelihood, bit for bit).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from symplid.dynamics import _user_models as user_models
from symplid.model._data import Observations
from symplid.workflow._building import build_model
from symplid.workflow._plan import ModelPlan
from symplid.workflow._settings import (
    dump_settings,
    load_settings,
    merge_overrides,
    resolve_for_data,
    settings_from_dict,
)
from symplid.workflow._validate import SettingsError

PENDULUM = {
    "model": {"potential": "k*(1 - cos(q1))", "dt": 0.1,
              "parameters": {"k": {"prior": "half-normal", "scale": 5.0}}},
    "initial_state": {"x0": [1.0, 0.0]},
}


def _pendulum(n: int = 20) -> Observations:
    t = np.linspace(0.3, 6.0, n)
    sol = solve_ivp(lambda _, x: [x[1], -2.0 * np.sin(x[0])], (0, 6.0), [1.0, 0.0], t_eval=t,
                    rtol=1e-11, atol=1e-12)
    rng = np.random.default_rng(0)
    return Observations(t, sol.y.T + 0.02 * rng.standard_normal((n, 2)), ("q1", "p1"))


@pytest.fixture
def parses(monkeypatch) -> list[str]:
    """Every text the user-model module hands to SymPy's parser, in order."""
    seen: list[str] = []
    original = user_models.parse_expression

    def counted(text, *args, **kwargs):
        seen.append(text)
        return original(text, *args, **kwargs)

    monkeypatch.setattr(user_models, "parse_expression", counted)
    return seen


def test_a_run_parses_its_expression_once(parses, tmp_path):
    obs = _pendulum()
    plan = ModelPlan.from_settings(settings_from_dict(PENDULUM), obs)
    assert parses == ["k*(1 - cos(q1))"]
    s = plan.settings
    half = dataclasses.replace(s, model=dataclasses.replace(s.model, dt=s.model.dt / 2))
    none = dataclasses.replace(s, model=dataclasses.replace(s.model, process_noise_per="none"))
    models = [plan.model(x, obs) for x in (s, half, none)]
    assert parses == ["k*(1 - cos(q1))"]  # the refits' models ask the plan
    assert all(m.hamiltonian is plan.family for m in models)
    assert models[1].dt == s.model.dt / 2 and models[2].deterministic
    # the report and the held-out scores read the settings back from the run folder
    reread = load_settings(dump_settings(s, tmp_path / "settings.toml"))
    assert plan.model(reread, obs).hamiltonian is plan.family
    other = merge_overrides(s, {"model.potential": "k*(1 - cos(q1)) + 0*q1"})
    assert plan.family_for(other) is not plan.family  # another expression: built anew
    assert len(parses) == 2


def test_the_plan_resolves_as_the_settings_did_and_its_model_computes_the_same():
    obs = _pendulum()
    given = settings_from_dict(PENDULUM)
    plan = ModelPlan.from_settings(given, obs)
    assert plan.settings == resolve_for_data(given, obs)
    assert plan.settings.model.observation == "full" and plan.dim == 1
    fresh = build_model(plan.settings, obs)  # its own parse, its own object
    mine = plan.model(plan.settings, obs)
    assert fresh.hamiltonian is not mine.hamiltonian
    theta = np.array([2.0, 1e-4, 4e-4, 4e-4])
    x0 = np.array([1.0, 0.0])
    assert float(mine.log_likelihood(theta, obs, x0)) == float(
        fresh.log_likelihood(theta, obs, x0))


def test_a_plan_of_a_bad_model_says_what_is_wrong_in_one_line(parses):
    obs = _pendulum(5)
    bad = settings_from_dict({**PENDULUM, "model": {
        "hamiltonian": "0.5*(1 + a*q1^2)*p1^2 + q1^2", "integrator": "yoshida4",
        "parameters": {"a": {"prior": "half-normal"}}}})
    with pytest.raises(SettingsError, match="needs a separable H"):
        ModelPlan.from_settings(bad, obs, "s.toml")
    unknown = settings_from_dict({**PENDULUM, "model": {
        "potential": "k*(1 - cos(q3))", "parameters": {"k": {"prior": "half-normal"}}}})
    with pytest.raises(SettingsError, match="uses coordinate 3"):
        ModelPlan.from_settings(unknown, obs, "s.toml")
