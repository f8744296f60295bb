"""The spectral data start: a sum of sinusoids through sparse positions at uneven times.

* The smoother alone, against a known signal: two sinusoids (ω = 1.3 and 1.95) and an
  offset seen at 30 random times over 20 s with noise sd 0.05, two components sharing the
  frequencies. The frequencies must come back to within the periodogram's resolution, the
  path and its derivative must follow the true signal between the samples to well within
  the noise, and the residual variance must estimate the noise's.
* The MAP, against the exact flow: two coupled oscillators with a quartic term,
  U = k1 q1²/2 + k2 q2²/2 + c q1 q2 + d q1⁴/4, both positions seen at 30 random times over
  20 s (SciPy's DOP853). Every spline start ended 70 nats or more below the true
  parameters' mode, at stiffnesses half the truth; the spectral start finds it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from symplid.inference.map import find_map
from symplid.inference.map._data_start import data_start
from symplid.inference.map._paths import SMOOTHERS
from symplid.inference.map._spectral import SUBDIVISIONS, spectral_path, subdivided
from symplid.inference.map._starts import default_start
from symplid.io._datafiles import read_observations
from symplid.workflow._sensitivity import fit_posterior
from symplid.workflow._settings import settings_from_dict

OMEGA = (1.3, 1.95)


def _signal(t):
    q1 = 0.2 + 0.8 * np.cos(OMEGA[0] * t + 0.3) + 0.3 * np.sin(OMEGA[1] * t)
    q2 = -0.1 + 0.4 * np.cos(OMEGA[0] * t - 1.0) - 0.6 * np.cos(OMEGA[1] * t + 0.5)
    return np.column_stack([q1, q2])


def _velocity(t):
    v1 = -0.8 * OMEGA[0] * np.sin(OMEGA[0] * t + 0.3) + 0.3 * OMEGA[1] * np.cos(OMEGA[1] * t)
    v2 = -0.4 * OMEGA[0] * np.sin(OMEGA[0] * t - 1.0) + 0.6 * OMEGA[1] * np.sin(
        OMEGA[1] * t + 0.5)
    return np.column_stack([v1, v2])


@pytest.fixture(scope="module")
def sparse():
    rng = np.random.default_rng(4)
    t = np.sort(rng.uniform(0.0, 20.0, 30))
    return t, _signal(t) + rng.normal(0.0, 0.05, (t.size, 2))


def test_the_frequencies_and_the_path_come_back(sparse):
    t, y = sparse
    path = spectral_path(t, y)
    found = np.sort(path.frequencies)
    for omega in OMEGA:  # resolution of a 20 s record: π/20 ≈ 0.16
        assert np.min(np.abs(found - omega)) < 0.02, found
    between = np.linspace(t[0], t[-1], 400)
    assert np.sqrt(np.mean((path.values(between) - _signal(between)) ** 2)) < 0.05
    assert np.sqrt(np.mean((path.derivative(between) - _velocity(between)) ** 2)) < 0.1
    np.testing.assert_allclose(np.sqrt(path.residual_var), 0.05, rtol=0.5)


def test_missing_values_and_short_records(sparse):
    t, y = sparse
    holes = y.copy()
    holes[::4, 1] = np.nan
    path = spectral_path(t, holes)
    assert np.min(np.abs(np.sort(path.frequencies)[:, None] - np.array(OMEGA)), axis=0).max() < 0.05
    assert spectral_path(t[:4], y[:4]) is None


def test_the_nodes_hold_the_observations():
    t = np.array([0.0, 0.5, 2.0, 2.1])
    nodes = subdivided(t, 100)
    assert nodes.size == SUBDIVISIONS * (t.size - 1) + 1
    assert np.all(np.isin(t, nodes)) and np.all(np.diff(nodes) > 0)
    assert subdivided(t, 8).size == 2 * (t.size - 1) + 1  # as many as `most` allows
    np.testing.assert_array_equal(subdivided(t, 4), t)


def _coupled_posterior(folder):
    k1, k2, c, d = 2.0, 3.5, 0.8, 0.4

    def rhs(_t, x):
        q1, q2, p1, p2 = x
        return [p1, p2, -k1 * q1 - c * q2 - d * q1**3, -k2 * q2 - c * q1]

    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0.0, 20.0, 30))
    sol = solve_ivp(rhs, (0.0, 20.0), [1.0, -0.5, 0.0, 0.8], t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-12)
    values = sol.y[:2].T + rng.normal(0.0, 0.05, (t.size, 2))
    settings = settings_from_dict({
        "model": {"potential": "k1*q1^2/2 + k2*q2^2/2 + c*q1*q2 + d*q1^4/4", "dt": 0.05,
                  "parameters": {"k1": {"prior": "half-normal", "scale": 10},
                                 "k2": {"prior": "half-normal", "scale": 10},
                                 "c": {"prior": "normal", "loc": 0, "scale": 5},
                                 "d": {"prior": "normal", "loc": 0, "scale": 5}}},
        "initial_state": {"mode": "learned", "t0": 0.0},
    })
    data = folder / "coupled.csv"
    np.savetxt(data, np.c_[t, values], delimiter=",", header="t,q1,q2", comments="")
    post = fit_posterior(settings, read_observations(data), None, None)
    truth = np.array([k1, k2, c, d, 1e-6, 0.0025, 1.0, -0.5, 0.0, 0.8])
    return post, truth


def test_the_map_finds_the_mode_the_splines_miss(tmp_path):
    post, truth = _coupled_posterior(tmp_path)
    default = default_start(post)
    at_truth = float(post.log_density(truth))
    spline = data_start(post, default, smoother="spline")
    spectral = data_start(post, default, smoother="spectral")
    assert SMOOTHERS == ("spline", "rough", "spectral")
    # the spline's path is too flat: its stiffness k2 is far below the truth's 3.5
    assert spline.theta[1] < 2.0 and abs(spectral.theta[1] - 3.5) < 0.5
    result = find_map(post, seed=0, evidence="laplace", warn=False)
    assert result.log_posterior > at_truth - 1.0, (result.log_posterior, at_truth)
    sd = np.sqrt(np.diag(result.covariance))
    assert np.all(np.abs(result.theta[:4] - truth[:4]) < 4.0 * sd[:4]), (result.theta, sd)
    assert math.isfinite(result.log_posterior)
