"""A fast motion sampled a few times a period: the MAP's rougher data start and the step that
resolves the motion (``symplid.inference.map._data_start``, ``symplid.workflow._step_size``).

A Morse oscillator U = D(1 − e^(−a q))² with D = 2, a = 1.3 (small oscillations: ω = a√(2D)
= 2.6, a period of 2.4), from (0.6, 0.4): 25 positions 0.8 apart (3.5 a period) with noise sd
0.04, from SciPy's DOP853, independent of symplid's integrators. The model-free noise
estimate of these data is 37 times the noise variance, so the spline it sets is nearly flat
and the data start sees a slow motion; at the data's gap leapfrog is unstable at the true
parameters (ω·dt > 2 where the well is steep). The references: the true parameters, the
fastest rate of the true motion (the largest √U''(q) along the exact path), and the MAP
searched from the true parameters.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import symplid
from symplid.inference.map import fastest_rate
from symplid.inference.map._data_start import data_start
from symplid.inference.map._starts import default_start
from symplid.workflow._fit import find_map_for
from symplid.workflow._sensitivity import fit_posterior
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data
from symplid.workflow._step_size import RESOLVE, choose_step, map_at_step

D, A, X0, NOISE = 2.0, 1.3, (0.6, 0.4), 0.04


def _force(q: np.ndarray) -> np.ndarray:
    e = np.exp(-A * q)
    return -2.0 * D * A * e * (1.0 - e)


def _curvature(q: np.ndarray) -> np.ndarray:
    """U''(q) of the Morse potential."""
    e = np.exp(-A * q)
    return 2.0 * D * A**2 * (2.0 * e**2 - e)


@pytest.fixture(scope="module")
def morse():
    times = np.linspace(0.0, 20.0, 26)[1:]
    sol = solve_ivp(lambda _t, x: [x[1], _force(x[0])], (0.0, 20.0), list(X0), method="DOP853",
                    rtol=1e-11, atol=1e-12, dense_output=True)
    q = sol.sol(times)[0] + NOISE * np.random.default_rng(7).standard_normal(times.size)
    obs = symplid.Observations(times, q[:, None], ("q1",))
    settings = resolve_for_data(merge_overrides(Settings(), {
        "model.potential": "D*(1 - exp(-a*q1))^2",
        "model.parameters.D": {"prior": "half-normal", "scale": 10.0},
        "model.parameters.a": {"prior": "half-normal", "scale": 5.0},
        "initial_state.mode": "learned", "initial_state.t0": 0.0}), obs)
    fine = sol.sol(np.linspace(0.0, 20.0, 20_001))[0]
    return obs, settings, float(np.sqrt(np.max(_curvature(fine))))


def test_the_rougher_data_start_sees_the_fast_motion(morse):
    obs, settings, true_rate = morse
    at = merge_overrides(settings, {"model.dt": 0.1})
    posterior = fit_posterior(at, obs, None, None)
    default = default_start(posterior)
    smooth = data_start(posterior, default)
    rough = data_start(posterior, default, smoother="rough")
    assert smooth.rate < 0.7 * A * np.sqrt(2 * D)  # slower than the small oscillations
    assert 0.75 < rough.rate / true_rate < 1.3
    assert fastest_rate(posterior) == max(smooth.rate, rough.rate)
    names = list(posterior.param_names)
    assert abs(rough.theta[names.index("a")] - A) < abs(smooth.theta[names.index("a")] - A)


def test_the_default_starts_find_the_mode_the_true_parameters_lead_to(morse):
    obs, settings, _ = morse
    at = merge_overrides(settings, {"model.dt": 0.1})
    found, posterior = map_at_step(at, obs, 0.1, search=find_map_for)
    names = list(posterior.param_names)
    truth = np.array([D, A, 1e-8, NOISE**2, *X0])
    assert names[:4] == ["D", "a", "process_var", "obs_var"]
    reference, _ = map_at_step(at, obs, 0.1, init=truth)
    assert found.log_posterior == pytest.approx(reference.log_posterior, abs=1e-3)
    # the two starts without the rougher one end in the slow motion's mode, far below
    slow, _ = map_at_step(merge_overrides(at, {"map.num_starts": 2}), obs, 0.1,
                          search=find_map_for)
    assert slow.log_posterior < found.log_posterior - 20


def test_auto_step_starts_where_the_motion_is_resolved(morse):
    obs, settings, _ = morse
    choice = choose_step(settings, obs, search=find_map_for)
    record = choice.record
    assert record["smallest_gap"] == pytest.approx(0.8)
    rate, first = record["fastest_rate"], record["first_candidate"]
    assert rate * first <= RESOLVE < 2 * rate * first  # the gap halved until resolved
    assert record["passed"] and record["dt"] <= first
    sds = np.sqrt(np.diag(_laplace(choice, obs)))
    theta = np.asarray(choice.theta)
    assert abs(theta[0] - D) < 3 * sds[0] and abs(theta[1] - A) < 3 * sds[1]


def _laplace(choice, obs) -> np.ndarray:
    """The Laplace covariance of the MAP at the chosen step, in the data's units."""
    result, _ = map_at_step(choice.settings, obs, choice.settings.model.dt, init=choice.theta,
                            hessian=True)
    return np.asarray(result.covariance)
