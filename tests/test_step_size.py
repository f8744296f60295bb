"""The learning step chosen from the data (``model.dt = "auto"``, symplid.workflow._step_size).

Two pendulums U = k(1 − cos q), the second 100 times faster (k·10⁴, gaps / 100), positions
only, no process noise and a known initial state at rest: the second problem is the first in
another time unit, exactly (the prior on k is scaled with it). Their data come from SciPy's
DOP853, independent of symplid's integrators. The step the search chooses must scale with
the system (exactly 1/100), never exceed the data's gap, and pass the check it claims: the
MAP at the chosen step lies within the threshold's Richardson bound of the MAP at a step eight
times smaller (an independent reference the search never computed).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import symplid
from symplid.workflow._building import build_model
from symplid.workflow._fit import find_map_for
from symplid.workflow._settings import Settings, merge_overrides, resolve_for_data
from symplid.workflow._step_size import (
    THRESHOLD_SD,
    _halvings,
    choose_step,
    first_candidate,
    map_at_step,
    smallest_gap,
    step_lines,
)
from symplid.workflow._validate import SettingsError

K_SLOW = 2.0


def _pendulum(speed: float, seed: int = 0) -> symplid.Observations:
    """40 noisy angles of a pendulum with k = K_SLOW·speed², from (1, 0), every 0.25/speed."""
    k = K_SLOW * speed**2
    times = 0.25 / speed * np.arange(1, 41)
    sol = solve_ivp(lambda _t, x: [x[1], -k * np.sin(x[0])], (0.0, times[-1]), [1.0, 0.0],
                    t_eval=times, method="DOP853", rtol=1e-11, atol=1e-13)
    q = sol.y[0] + 0.05 * np.random.default_rng(seed).standard_normal(times.size)
    return symplid.Observations(times, q[:, None], ("q1",))


def _settings(speed: float, obs: symplid.Observations) -> Settings:
    settings = merge_overrides(Settings(), {
        "model.potential": "k*(1 - cos(q1))",
        "model.parameters.k": {"prior": "half-normal", "scale": 5.0 * speed**2},
        "model.dt": "auto", "model.process_noise_per": "none", "model.standardise": "off",
        "initial_state.x0": [1.0, 0.0], "map.num_starts": 1})
    return resolve_for_data(settings, obs)


def test_smallest_gap_over_trajectories_and_from_t0():
    a = symplid.Observations(np.array([0.5, 1.0, 1.25, 2.0]), np.zeros((4, 1)), ("q1",))
    b = symplid.Observations(np.array([3.0, 3.1, 3.5]), np.zeros((3, 1)), ("q1",))
    assert smallest_gap(a) == pytest.approx(0.25)
    assert smallest_gap([a, b]) == pytest.approx(0.1)
    assert smallest_gap(a, t0=0.45) == pytest.approx(0.05)  # t0 → first observation


def test_first_candidate_is_the_smallest_gap_unless_one_close_pair_sets_it():
    regular = symplid.Observations(0.25 * np.arange(1, 9), np.zeros((8, 1)), ("q1",))
    assert first_candidate(regular) == smallest_gap(regular) == pytest.approx(0.25)
    # one pair 0.005 apart among gaps of 0.5: a quarter of the median gap, not the pair's
    times = np.sort(np.r_[0.5 * np.arange(1, 21), 3.005])
    irregular = symplid.Observations(times, np.zeros((times.size, 1)), ("q1",))
    assert smallest_gap(irregular) == pytest.approx(0.005)
    assert first_candidate(irregular) == pytest.approx(0.5 / 4)


def test_a_close_pair_of_times_does_not_set_the_step_of_every_gap():
    """The slow pendulum's record with one extra observation 0.002 after another: the search
    starts at a quarter of the median gap and its step passes the check (the pair's own gap
    would have meant 125 substeps per gap)."""
    obs = _pendulum(1.0)
    times = np.sort(np.r_[obs.times, obs.times[9] + 0.002])
    k = K_SLOW
    sol = solve_ivp(lambda _t, x: [x[1], -k * np.sin(x[0])], (0.0, times[-1]), [1.0, 0.0],
                    t_eval=times, method="DOP853", rtol=1e-11, atol=1e-13)
    q = sol.y[0] + 0.05 * np.random.default_rng(0).standard_normal(times.size)
    close = symplid.Observations(times, q[:, None], ("q1",))
    choice = choose_step(_settings(1.0, close), close, search=find_map_for)
    record = choice.record
    assert record["smallest_gap"] == pytest.approx(0.002)
    assert record["first_candidate"] == pytest.approx(0.25 / 4)
    assert record["passed"] and record["dt"] <= record["first_candidate"]
    assert record["dt"] > 10 * record["smallest_gap"]
    assert abs(choice.theta[0] - K_SLOW) < 0.1


def test_halvings_follow_the_integrators_order():
    # a move of m sds shrinks by 2^p per halving: the fewest halvings below the threshold
    assert _halvings(4.09, 2) == 3  # 4.09/4² > 0.1 ≥ 4.09/4³
    assert _halvings(1.5, 4) == 1  # 1.5/16 < 0.1
    assert _halvings(1e9, 2) == 3  # never more than MAX_JUMP at once
    assert _halvings(0.11, 2) == 1


def test_settings_take_auto_and_refuse_other_words():
    s = merge_overrides(Settings(), {"model.dt": " Auto "})
    assert s.model.dt == "auto"
    with pytest.raises(SettingsError, match=r"model.dt must be a number or 'auto'"):
        merge_overrides(Settings(), {"model.dt": "fast"})
    obs = _pendulum(1.0)
    with pytest.raises(ValueError, match="chosen by the fit"):
        build_model(_settings(1.0, obs), obs)


@pytest.fixture(scope="module")
def chosen():
    """The step chosen for each pendulum: speed → (obs, settings, StepChoice)."""
    out = {}
    for speed in (1.0, 100.0):
        obs = _pendulum(speed)
        settings = _settings(speed, obs)
        out[speed] = obs, settings, choose_step(settings, obs, search=find_map_for)
    return out


def test_auto_step_scales_with_the_systems_time_scale(chosen):
    (_, _, slow), (fast_obs, _, fast) = chosen[1.0], chosen[100.0]
    for choice in (slow, fast):
        record = choice.record
        assert record["passed"], record
        assert record["largest_shift_sd"] <= THRESHOLD_SD
        assert record["dt"] <= record["smallest_gap"]
        assert record["dt"] < record["smallest_gap"]  # leapfrog at the gap biases k here
        assert choice.settings.model.dt == record["dt"]
        assert record["refits"] >= 2
    # the fast pendulum is the slow one in a unit of time 100 times smaller
    assert fast.record["dt"] == pytest.approx(slow.record["dt"] / 100, rel=1e-9)
    assert fast.theta[0] == pytest.approx(slow.theta[0] * 1e4, rel=1e-5)
    assert fast.record["smallest_gap"] == pytest.approx(smallest_gap(fast_obs))


def test_auto_step_passes_an_independent_finer_check(chosen):
    obs, settings, choice = chosen[1.0]
    dt = choice.record["dt"]
    at_dt, _ = map_at_step(settings, obs, dt, choice.theta, hessian=True)
    finer, _ = map_at_step(settings, obs, dt / 8, choice.theta)
    sd = float(np.sqrt(at_dt.covariance[0, 0]))
    # Richardson: θ(dt) − θ(0) ≈ move(dt → dt/2)·2^p/(2^p − 1) = 0.1·4/3 sds at most
    assert abs(finer.theta[0] - at_dt.theta[0]) / sd <= THRESHOLD_SD * 4 / 3 * 1.2
    assert abs(at_dt.theta[0] - K_SLOW) < 3 * sd  # and the truth is where it should be
    # at the data's gap (the step a fixed dt ≥ 0.25 gives) the bias is many sds
    coarse, _ = map_at_step(settings, obs, 0.25, choice.theta)
    assert abs(coarse.theta[0] - finer.theta[0]) / sd > 1.0


def test_report_lines_name_the_step_and_its_check(chosen):
    record = chosen[1.0][2].record
    text = "\n".join(step_lines(record))
    assert f"dt = {record['dt']:.4g}" in text and "leapfrog, order 2" in text
    assert "Warning" not in text
    failed = {**record, "passed": False}
    assert "Warning" in "\n".join(step_lines(failed))


@pytest.mark.slow
def test_fit_with_dt_auto_records_the_step_everywhere(tmp_path):
    """``symplid fit --dt auto``: the fit's line, summary.json, settings.toml, the report and
    the step-size check (the search's last halving, not a second refit) agree."""
    import json

    from click.testing import CliRunner

    from symplid.cli import main

    def run(*args):
        return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)

    data, out = tmp_path / "harmonic.csv", tmp_path / "run"
    assert run("simulate", "harmonic", "--out", data, "--num-obs", "15", "--t-end", "15",
               "--noise-std", "0.02", "--seed", "3").exit_code == 0
    result = run("fit", data, "--out", out, "--order", "2", "--x0", "1,0", "--dt", "auto",
                 "--iterations", "600", "--burn-in", "300", "--chains", "2", "--no-progress")
    assert result.exit_code == 0, result.output
    record = json.loads((out / "summary.json").read_text())["learning_step"]
    assert record["passed"] and record["dt"] <= record["smallest_gap"] == pytest.approx(1.0)
    assert f"dt = {record['dt']:.4g} (auto, leapfrog" in result.output
    assert f"dt = {record['dt']!r}" in (out / "settings.toml").read_text()
    checks = json.loads((out / "diagnostics.json").read_text())["step_size"]
    assert checks["shifts"] == pytest.approx(record["shifts"])
    assert checks["dt_refit"] == pytest.approx(record["dt"] / 2)
    assert "## Learning step" in (out / "report.md").read_text()
    bad = run("fit", data, "--out", tmp_path / "bad", "--dt", "fast", "--no-progress")
    assert bad.exit_code == 2 and "model.dt must be a number or 'auto'" in bad.output


@pytest.mark.slow
def test_compare_shares_one_chosen_step(chosen):
    """``compare`` with dt = "auto" chooses the step once (the settings' own model) and every
    candidate uses it: here the same step as the search on its own."""
    from symplid.workflow._compare import fit_candidates

    obs, settings, choice = chosen[1.0]
    fits = fit_candidates(obs, settings, integrators=["leapfrog", "yoshida4"], progress=False)
    assert [f.settings.model.dt for f in fits] == [choice.record["dt"]] * 2
