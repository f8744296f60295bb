"""Observations validation, and the simulator against independent integrations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import symplid
from symplid import DataError, Observations


def test_valid_observations_and_mask():
    values = np.array([[1.0, np.nan], [2.0, 3.0], [np.nan, 4.0]])
    obs = Observations([0.5, 1.0, 2.5], values, names=("q1", "q2"))
    assert obs.num_times == len(obs) == 3
    assert obs.dim == 2
    np.testing.assert_array_equal(obs.mask, [[True, False], [True, True], [False, True]])
    assert obs.names == ("q1", "q2")
    # Stored read-only, so that a prepared filter input cannot change behind its back.
    with pytest.raises(ValueError, match="read-only"):
        obs.values[0, 0] = 5.0
    one_d = Observations([1.0, 2.0], [0.1, 0.2])
    assert one_d.values.shape == (2, 1)
    sub = obs.subset([0, 2])
    np.testing.assert_array_equal(sub.times, [0.5, 2.5])
    assert sub.names == ("q1", "q2")


@pytest.mark.parametrize(
    ("times", "values", "names", "message"),
    [
        ([0.0, 2.0, 1.0], np.zeros((3, 2)), None, r"strictly increasing: t\[1\] = 2 .* t\[2\] = 1"),
        ([0.0, 1.0, 1.0], np.zeros((3, 2)), None, r"strictly increasing: t\[1\] = 1"),
        ([0.0, np.nan], np.zeros((2, 2)), None, "times must be finite"),
        ([0.0, np.inf], np.zeros((2, 2)), None, "times must be finite"),
        ([0.0, 1.0], [[0.0, np.inf], [1.0, 2.0]], None, "values contain inf"),
        ([0.0, 1.0], [[0.0, -np.inf], [1.0, 2.0]], None, "values contain inf"),
        ([0.0, 1.0, 2.0], np.zeros((2, 2)), None, "3 times but 2 rows of values"),
        ([0.0, 1.0], np.full((2, 3), np.nan), None, "every value is missing"),
        ([0.0, 1.0], np.zeros((2, 2)), ("q1", "q2", "p1"), "3 names for 2 observed components"),
        ([[0.0, 1.0]], np.zeros((2, 2)), None, "times must be one-dimensional"),
        ([0.0, 1.0], np.zeros((2, 2, 1)), None, r"values must have shape \(n, d_y\)"),
        ([], np.zeros((0, 2)), None, "there are no observations"),
        (["a", "b"], np.zeros((2, 2)), None, "times must be numbers"),
    ],
)
def test_validation_messages(times, values, names, message):
    with pytest.raises(DataError, match=message):
        Observations(times, values, names)


def test_data_error_is_a_value_error():
    assert issubclass(DataError, ValueError)


def test_simulate_defaults_are_the_papers_experiment(hh):
    data = symplid.simulate(hh, seed=0)
    np.testing.assert_allclose(data.times, 5.0 * np.arange(1, 21))
    assert data.values.shape == (20, 4)
    assert data.names == ("q1", "q2", "p1", "p2")
    positions = symplid.simulate("henon-heiles", seed=0, observation="positions")
    assert positions.values.shape == (20, 2) and positions.names == ("q1", "q2")


def test_simulate_is_reproducible_by_seed(hh):
    times = np.array([0.5, 1.0, 2.5])
    a = symplid.simulate(hh, times=times, seed=7)
    b = symplid.simulate(hh, times=times, seed=7)
    c = symplid.simulate(hh, times=times, seed=8)
    np.testing.assert_array_equal(a.values, b.values)
    assert np.max(np.abs(a.values - c.values)) > 1e-3


def test_simulate_noise_has_the_requested_std(hh):
    times = np.linspace(0.1, 40.0, 400)
    std = 0.05
    data = symplid.simulate(hh, times=times, noise_std=std, seed=3)
    truth = symplid.true_trajectory(hh.potential, hh.coefficients, hh.initial_state, times)
    residuals = (data.values - truth).ravel()
    n = residuals.size  # 1600 independent N(0, std²) draws
    # Sample std has relative standard error 1/sqrt(2n) ≈ 1.8 %; allow 4 standard errors.
    assert np.std(residuals) == pytest.approx(std, rel=4 / np.sqrt(2 * n))
    assert abs(np.mean(residuals)) < 4 * std / np.sqrt(n)
    # Without noise the data are the trajectory itself.
    clean = symplid.simulate(hh, times=times, noise_std=0.0, seed=3)
    np.testing.assert_array_equal(clean.values, truth)


def _henon_heiles_rhs(_t, x):
    q1, q2, p1, p2 = x
    return [p1, p2, -(q1 + 2 * q1 * q2), -(q2 + q1**2 - q2**2)]


def test_true_trajectory_matches_an_accurate_ode_solution(hh):
    times = np.array([0.3, 1.7, 2.0, 6.25, 15.0])  # irregular, not multiples of dt
    states = symplid.true_trajectory(hh.potential, hh.coefficients, hh.initial_state, times)
    sol = solve_ivp(
        _henon_heiles_rhs,
        (0.0, times[-1]),
        hh.initial_state,
        method="DOP853",
        t_eval=times,
        rtol=1e-12,
        atol=1e-14,
    )
    # Leapfrog at dt = 1e-3 has a global error of order dt² = 1e-6.
    np.testing.assert_allclose(states, sol.y.T, atol=1e-5, rtol=0)
    # ... and converges: a finer step moves the answer by much less than that.
    finer = symplid.true_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, times, dt=2.5e-4
    )
    assert np.max(np.abs(finer - sol.y.T)) < np.max(np.abs(states - sol.y.T)) / 8


def test_true_trajectory_checks_x0(hh):
    with pytest.raises(ValueError, match=r"x0 must have shape \(4,\)"):
        symplid.true_trajectory(hh.potential, hh.coefficients, [0.1, 0.2], [1.0])


def test_simulate_rejects_bad_settings(hh):
    with pytest.raises(ValueError, match="noise_std"):
        symplid.simulate(hh, noise_std=-1.0)
    with pytest.raises(ValueError, match="observation"):
        symplid.simulate(hh, observation="momenta")
