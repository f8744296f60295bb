"""The learning step a fit chooses when none is given (``model.dt = "auto"``, the default).

Data from SciPy's DOP853 at tight tolerances, never from symplid's integrators. Each fit is a
user's: no ``model.dt`` anywhere in its settings. What the step is for: the truths inside the
fit's 95 % posterior intervals.

* Two pendulums U = k(1 − cos q) whose time scales are 100 times apart (k = 2 in seconds,
  k = 2·10⁴ in hundredths of a second; the same angles): the chosen step scales with the
  system.
* An elastic pendulum (a stiff spring swinging under gravity, positions only, learned initial
  state), which the old fixed default dt = 0.25 fitted with k = 40 outside its interval.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import symplid
from symplid.workflow._fit import fit
from symplid.workflow._settings import Settings, merge_overrides

K_SLOW = 2.0
#: A short sampler and no checks beyond the step's own: the step search is what is tested.
SHORT = {"sampler.num_iterations": 3000, "sampler.burn_in": 1000, "sampler.num_chains": 2,
         "map.sensitivity": False, "map.evidence": "laplace", "map.num_starts": 2}


def _interval(outcome, name: str) -> tuple[float, float]:
    draws = np.asarray(outcome.idata.posterior[name]).ravel()
    lo, hi = np.quantile(draws, [0.025, 0.975])
    return float(lo), float(hi)


def _pendulum(speed: float) -> symplid.Observations:
    """40 angles (noise sd 0.05) of a pendulum with k = K_SLOW·speed², from (1, 0)."""
    k = K_SLOW * speed**2
    times = 0.25 / speed * np.arange(1, 41)
    sol = solve_ivp(lambda _t, x: [x[1], -k * np.sin(x[0])], (0.0, times[-1]), [1.0, 0.0],
                    t_eval=times, method="DOP853", rtol=1e-12, atol=1e-13)
    q = sol.y[0] + 0.05 * np.random.default_rng(0).standard_normal(times.size)
    return symplid.Observations(times, q[:, None], ("q1",))


@pytest.mark.slow
def test_the_default_step_scales_with_the_system_and_holds_the_truth():
    steps = {}
    for speed in (1.0, 100.0):
        settings = merge_overrides(Settings(), {
            "model.potential": "k*(1 - cos(q1))",
            "model.parameters.k": {"prior": "half-normal", "scale": 5.0 * speed**2},
            "initial_state.x0": [1.0, 0.0], **SHORT})
        assert settings.model.dt == "auto"  # the default: nothing about the step is given
        outcome = fit(_pendulum(speed), settings, progress=False)
        record = outcome.learning_step
        assert record["passed"] and record["dt"] == outcome.settings.model.dt
        assert record["dt"] < record["smallest_gap"]  # the gap itself biases k here
        lo, hi = _interval(outcome, "k")
        assert lo < K_SLOW * speed**2 < hi, (speed, lo, hi)
        steps[speed] = record["dt"]
    # the fast pendulum is the slow one in a unit of time 100 times smaller: both steps are
    # the gap (exactly 100 times apart) halved n times, the same n but for one halving at
    # most (the default prior on the process variance Σ is not rescaled with the time unit)
    halvings = np.log2(steps[1.0] / steps[100.0] / 100)
    assert abs(halvings - round(halvings)) < 1e-9 and abs(round(halvings)) <= 1, steps


ELASTIC = {"k": 40.0, "L": 1.0, "g": 9.81}


def _elastic_pendulum() -> symplid.Observations:
    """30 positions 0.2 s apart (noise sd 0.02) of a unit mass on a spring (k = 40, rest
    length L = 1) swinging under g = 9.81, from q = (0.8, −1.0) at rest at t = 0."""
    k, length, g = ELASTIC["k"], ELASTIC["L"], ELASTIC["g"]

    def field(_t, x):
        pull = k * (np.hypot(x[0], x[1]) - length) / np.hypot(x[0], x[1])
        return [x[2], x[3], -pull * x[0], -pull * x[1] - g]

    times = 0.2 * np.arange(1, 31)
    sol = solve_ivp(field, (0.0, times[-1]), [0.8, -1.0, 0.0, 0.0], t_eval=times,
                    method="DOP853", rtol=1e-12, atol=1e-12)
    q = sol.y[:2].T + 0.02 * np.random.default_rng(0).standard_normal((times.size, 2))
    return symplid.Observations(times, q, ("q1", "q2"))


@pytest.mark.long
def test_the_elastic_pendulum_from_the_defaults_holds_k_and_l():
    """Positions only, the initial state learned, no dt given: k = 40 and L = 1 inside their
    95 % intervals (at the old default dt = 0.25 k's interval was [34.9, 37.2])."""
    settings = merge_overrides(Settings(), {
        "model.potential": "k/2*(sqrt(q1^2 + q2^2) - L)^2 + 9.81*q2",
        "model.parameters.k": {"prior": "half-normal", "scale": 100.0},
        "model.parameters.L": {"prior": "half-normal", "scale": 5.0},
        "initial_state.mode": "learned", "initial_state.t0": "first", **SHORT})
    outcome = fit(_elastic_pendulum(), settings, progress=False)
    assert outcome.learning_step["passed"]
    for name in ("k", "L"):
        lo, hi = _interval(outcome, name)
        assert lo < ELASTIC[name] < hi, (name, lo, hi)


def test_a_neural_family_keeps_the_former_step_unchecked(hh_data):
    """A network's MAP is too costly to refit: "auto" gives it min(smallest gap, 0.25) and
    says that it is unchecked (no fit is made to choose it)."""
    from symplid.workflow._settings import resolve_for_data
    from symplid.workflow._step_size import UNSEARCHED_STEP, choose_step, step_line

    settings = merge_overrides(Settings(), {
        "model.potential": "mlp", "model.width": 4, "model.depth": 1, "sampler.method": "nuts",
        "initial_state.x0": [0.2, -0.25, 0.3, -0.25]})
    for obs, want in ((hh_data, UNSEARCHED_STEP),  # gaps of 5: the former fixed step
                      (symplid.Observations(hh_data.times / 100, hh_data.values,
                                            hh_data.names), 0.05)):  # gaps of 0.05
        choice = choose_step(resolve_for_data(settings, obs), obs)
        assert choice.settings.model.dt == choice.record["dt"] == pytest.approx(want)
        assert not choice.record["passed"] and choice.theta is None
        assert "unchecked" in step_line(choice.record)


@pytest.mark.long
def test_the_double_pendulum_map_from_the_defaults_is_near_the_truth():
    """The built-in double pendulum (angles only, 40 every 0.25 s, Tao's method, known
    initial state), no dt given: the fit's MAP at the chosen step is within 3 Laplace sds of
    each true ratio (measured: 1.6–1.8 sds at the chosen dt = 1/64)."""
    from symplid.workflow._fit import find_map_for
    from symplid.workflow._plan import ModelPlan
    from symplid.workflow._step_size import choose_step

    system = symplid.get_system("double-pendulum")
    obs = symplid.simulate(system, seed=3)
    settings = merge_overrides(Settings(), {
        "model.hamiltonian": "double-pendulum", "model.integrator": "tao",
        "prediction.integrator": "tao4", "map.evidence": "laplace",
        "initial_state.x0": [float(v) for v in system.initial_state]})
    plan = ModelPlan.from_settings(settings, obs)
    step = choose_step(plan.settings, obs, search=find_map_for, plan=plan)
    assert step.record["passed"]
    result = find_map_for(step.settings, step.posterior, step.theta)  # the fit's own MAP
    sd = np.sqrt(np.diag(result.covariance))[:3]
    z = (np.asarray(result.theta)[:3] - system.coefficients) / sd
    assert np.all(np.abs(z) < 3), z
