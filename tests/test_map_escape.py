"""The MAP search leaves a spot where its own coordinates go flat (``_search.escaped``).

A parameter bounded below only is searched as u = log(θ − a); near its bound the gradient in u
is (θ − a)·∂/∂θ, so L-BFGS-B can stop with a dynamics parameter on its floor although log π
still rises along it. The search must then continue from a Newton point in θ. Checked on a
density whose maximum is known exactly, and on a Duffing oscillator observed in positions only
(a quartic coefficient whose collocation start lands on its bound) against its true values.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.integrate import solve_ivp

from symplid.inference.map import find_map
from symplid.model._data import Observations
from symplid.workflow._building import build_posterior
from symplid.workflow._fit import find_map_for
from symplid.workflow._plan import ModelPlan
from symplid.workflow._settings import settings_from_dict


class _Quadratic:
    """log π = −(a − 2)²/2 − (b − a)²/2 with a ≥ 0: the maximum is a = b = 2."""

    num_params = 2
    param_names = ("a", "b")
    param_groups = ("dynamics", "dynamics")
    lower = np.array([0.0, -np.inf])
    upper = np.array([np.inf, np.inf])

    def log_density(self, theta):
        return -0.5 * (theta[0] - 2.0) ** 2 - 0.5 * (theta[1] - theta[0]) ** 2


def test_a_start_on_the_bound_reaches_the_interior_maximum():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = find_map(_Quadratic(), init=np.array([0.0, 0.5]), num_starts=1)
    assert result.success, result.failure
    np.testing.assert_allclose(result.theta, [2.0, 2.0], atol=1e-6)
    assert result.starts[0].newton_decrement < 1e-3


def _duffing(k=1.5, a=0.8, q0=1.2, n=25, noise=0.03, seed=0) -> Observations:
    t = np.linspace(0.5, 30.0, n)
    sol = solve_ivp(lambda _, x: [x[1], -k * x[0] - a * x[0] ** 3], (0.0, 30.0), [q0, 0.0],
                    t_eval=t, method="DOP853", rtol=1e-12, atol=1e-12)
    rng = np.random.default_rng(seed)
    return Observations(t, (sol.y[0] + noise * rng.standard_normal(n))[:, None], ("q1",))


def test_duffing_from_positions_only_converges_near_the_truth():
    settings = settings_from_dict({
        "model": {"potential": "k*q1^2/2 + a*q1^4/4", "dt": 0.25,
                  "parameters": {"k": {"prior": "half-normal", "scale": 10.0},
                                 "a": {"prior": "half-normal", "scale": 10.0}}},
        "initial_state": {"mode": "learned"},
    })
    obs = _duffing()
    plan = ModelPlan.from_settings(settings, obs, "test")
    posterior = build_posterior(plan.settings, obs, plan.model(plan.settings, obs))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = find_map_for(plan.settings, posterior)
    assert result.success, result.failure
    names = list(result.param_names)
    sd = np.sqrt(np.diag(result.covariance))
    for name, truth in (("k", 1.5), ("a", 0.8), ("x0[0].q1", 1.2), ("x0[0].p1", 0.0)):
        i = names.index(name)
        assert abs(result.theta[i] - truth) < 3.0 * sd[i], (name, result.theta[i], sd[i])
