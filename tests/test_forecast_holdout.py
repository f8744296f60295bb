"""Forecasts from the end of the data with process noise, and held-out scores (issue 11).

The noisy forecast is checked against mathematics (the spread that process noise adds to a
harmonic oscillator, whose flow is a rotation; the log predictive density of one draw in closed
form), and the held-out score against its promise: on data from the model itself, the 95 %
band of new observations holds about 95 % of the held-out values.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.stats import norm

from symplid.cli import main
from symplid.dynamics._potentials import Polynomial
from symplid.inference._forecast import forecast_with_noise
from symplid.model._statespace import HamiltonianModel
from symplid.workflow._results import RunFolder

TINY = ["--iterations", "600", "--burn-in", "300", "--chains", "2", "--no-progress"]
TINY += ["--dt", "0.25"]  # a fixed step: the step search is test_step_size.py's
TINY += ["--set", "map.sensitivity=false"]  # the MAP refits: test_fit_diagnostics.py


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def harmonic_model(dt=0.05):
    return HamiltonianModel(Polynomial(1, 2), integrator="leapfrog", dt=dt)


def test_process_noise_spreads_like_a_random_walk_on_a_rotation():
    # U = ½q²: the flow over a gap is (nearly) a rotation, which keeps an isotropic covariance
    # isotropic; noise σ² I added after each of k gaps gives Var(q_k) = k σ² exactly for a
    # rotation (leapfrog at dt = 0.05 is one to O(dt²)). 4000 draws: the sample variance has
    # relative sd √(2/4000) ≈ 2.2 %, so 10 % is > 4 sd.
    model = harmonic_model()
    S, var = 4000, 1e-3
    theta = np.tile(model.pack([0.0, 0.5], [var], [0.01]), (S, 1))
    starts = np.tile([1.0, 0.0], (S, 1))
    times = np.arange(1.0, 11.0)
    fc = forecast_with_noise(model, theta, starts, 0.0, times, seed=3)
    k = np.arange(1, 11)
    assert np.var(fc.states[:, :, 0], axis=0) == pytest.approx(k * var, rel=0.1)
    # The mean follows cos t; the new observations add Γ = 0.01 to the state's spread.
    assert np.mean(fc.states[:, :, 0], axis=0) == pytest.approx(np.cos(times), abs=0.01)
    obs_var = np.var(fc.observations[:, :, 0], axis=0)
    assert obs_var == pytest.approx(k * var + 0.01, rel=0.1)


def test_log_predictive_density_of_one_draw_is_the_gaussian_density():
    model = harmonic_model()
    theta = model.pack([0.0, 0.5], [0.0], [0.04])[None]
    fc = forecast_with_noise(model, theta, np.array([[1.0, 0.0]]), 0.0, [1.0, 2.0], seed=0)
    y = fc.obs_means[0] + np.array([[0.1, -0.2], [np.nan, 0.3]])
    expected = norm.logpdf([0.1, -0.2, 0.3], scale=0.2).sum()
    assert fc.log_predictive_density(y) == pytest.approx(expected, rel=1e-10)


@pytest.fixture(scope="module")
def holdout_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("holdout")
    data = root / "h.csv"
    result = run("simulate", "harmonic", "--out", data, "--num-obs", "60", "--t-end", "30",
                 "--noise-std", "0.05", "--seed", "11")
    assert result.exit_code == 0, result.output
    out = root / "run"
    result = run("fit", data, "--out", out, "--order", "2", "--x0", "1,0",
                 "--holdout", "0.34", *TINY)
    assert result.exit_code == 0, result.output
    return out, result.output


def test_holdout_scores_a_well_specified_model(holdout_run):
    out, output = holdout_run
    assert "held out 20 times" in output and "coverage" in output
    summary = json.loads((out / "summary.json").read_text())
    h = summary["holdout"]
    assert h["num_values"] == 40 and set(h) >= {"rmse", "coverage_95", "log_predictive_density"}
    # 40 held-out values: under independence the coverage has sd √(.95·.05/40) ≈ 0.034; the
    # shared θ and state correlate them, so the tolerance is wide (0.8 is > 4 sd below 0.95).
    assert h["coverage_95"] >= 0.8
    # Well specified: the error is the observation noise (0.05), not a drifting model.
    assert h["rmse"] < 0.1
    # And the density is close to that of the noise alone, Σ log N(ε; 0, 0.05²) ≈ 40·1.38.
    assert h["log_predictive_density"] > 40 * (norm.logpdf(0, scale=0.05) - 1.5)
    assert (out / "figures" / "holdout.png").exists() and (out / "heldout.csv").exists()
    assert RunFolder(out, "r").is_complete
    data = (out / "data.csv").read_text().strip().splitlines()
    assert len(data) == 1 + 40  # the fit saw the first 40 times only


def test_predict_from_end(holdout_run):
    out, _ = holdout_run
    result = run("predict", out, "--from", "end", "--t-end", "25")
    assert result.exit_code == 0, result.output
    fc = np.load(out / "forecast.npz")
    assert fc["times"][0] > 19.5 and fc["times"][-1] == pytest.approx(25.0)
    lower, upper = fc["obs_quantiles"][0], fc["obs_quantiles"][-1]
    assert np.all(upper > lower)
    # The band of a new observation is wider than the state's (observation noise added).
    assert np.all(upper - lower > fc["state_quantiles"][-1] - fc["state_quantiles"][0])
    assert (out / "figures" / "forecast.png").exists() and RunFolder(out, "r").is_complete
    bad = run("predict", out, "--from", "end", "--t-end", "5")
    assert bad.exit_code == 2 and "after the last observation" in bad.output
    assert RunFolder(out, "r").is_complete


def test_holdout_split_errors(tmp_path):
    from symplid.model._data import Observations
    from symplid.workflow._forecasting import split_holdout

    obs = Observations(np.arange(1.0, 11.0), np.zeros((10, 2)), ("q1", "p1"))
    train, test = split_holdout(obs, fraction=0.3)
    assert train.num_times == 7 and test.times[0] == 8.0
    train, test = split_holdout(obs, after=4.5)
    assert train.num_times == 4 and test.num_times == 6
    with pytest.raises(ValueError, match="both parts"):
        split_holdout(obs, after=20.0)
    with pytest.raises(ValueError, match="one of"):
        split_holdout(obs, 0.2, 3.0)
