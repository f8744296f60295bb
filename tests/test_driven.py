"""Driven models: inputs between samples, their table at the nodes, the data files, the
likelihood against an exact Kalman filter, a MAP that recovers the input gain and the
friction, and the command line's one-line refusals."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from symplid import HamiltonianModel, Observations
from symplid.cli import main
from symplid.dynamics._forced import with_force
from symplid.dynamics._forcing import user_force
from symplid.dynamics._user_models import build_user_model
from symplid.io._inputfiles import read_driven_csv
from symplid.model._data import DataError
from symplid.model._inputs import AnalyticInputs, SampledInputs, node_table
from symplid.systems import SIGNALS
from symplid.workflow._fit import build_model, build_posterior, find_map_for
from symplid.workflow._settings import resolve_for_data, settings_from_dict


# ---------------------------------------------------------------------------- inputs
def test_each_rule_between_samples_is_exact_where_it_should_be():
    t = np.linspace(0.0, 4.0, 9)
    line = SampledInputs(t, 2.0 * t - 1.0, ("u1",), "linear")
    probe = np.array([0.1, 1.37, 3.99])
    np.testing.assert_allclose(line.evaluate(probe)[:, 0], 2.0 * probe - 1.0, rtol=1e-14)
    cubic = SampledInputs(t, t**3 - t, ("u1",), "cubic")  # not-a-knot: cubics exactly
    np.testing.assert_allclose(cubic.evaluate(probe)[:, 0], probe**3 - probe, atol=1e-12)
    hold = SampledInputs(t, np.arange(9.0), ("u1",), "zoh")
    np.testing.assert_array_equal(hold.evaluate(np.array([0.0, 0.49, 0.5, 3.9]))[:, 0],
                                  [0.0, 0.0, 1.0, 7.0])


def test_analytic_inputs_and_their_errors():
    sig = AnalyticInputs({"u1": "0.5*sin(1.3*t)", "u2": "2"})
    np.testing.assert_allclose(sig.evaluate(np.array([1.0, 2.0])),
                               [[0.5 * np.sin(1.3), 2.0], [0.5 * np.sin(2.6), 2.0]])
    with pytest.raises(DataError, match="function of t alone"):
        AnalyticInputs({"u1": "q1*t"})


def test_missing_input_values_and_short_inputs_are_one_line():
    with pytest.raises(DataError, match="no value at t = 1"):
        SampledInputs([0.0, 1.0, 2.0], [0.0, np.nan, 1.0])
    sig = SampledInputs([0.0, 1.0, 2.0], [0.0, 1.0, 1.0])
    with pytest.raises(DataError, match=r"cover t = 0 to 2 but the window .* 0 to 3"):
        node_table(sig, 0.0, np.array([1.0, 1.0, 1.0]), np.array([1, 1, 1]), (0.0, 1.0), 1)
    with pytest.raises(DataError, match=r"reads u1\.\.u2 but the data have 1"):
        node_table(sig, 0.0, np.array([1.0]), np.array([1]), (0.0, 1.0), 2)


def test_node_table_rows_are_the_substeps_of_each_gap():
    sig = AnalyticInputs({"u1": "t"})
    nodes = with_force("yoshida4").nodes
    times, values = node_table(sig, 1.0, np.array([0.5, 0.25]), np.array([1, 2]), nodes, 1)
    assert times.shape == (2, 2, 4) and values.shape == (2, 2, 4, 1)
    np.testing.assert_allclose(times[0, 0], 1.0 + 0.5 * np.asarray(nodes))
    np.testing.assert_allclose(times[1, 1], 1.75 + 0.25 * np.asarray(nodes))
    np.testing.assert_allclose(values[..., 0], times)


def test_a_data_file_with_a_denser_input_channel(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("t,q1,u1\n0,,0.0\n0.5,,0.5\n1,0.9,1.0\n1.5,,1.5\n2,1.1,2.0\n")
    obs = read_driven_csv(path)
    np.testing.assert_array_equal(obs.times, [1.0, 2.0])  # the input-only rows are no data
    assert obs.inputs.span == (0.0, 2.0) and obs.inputs.names == ("u1",)
    path.write_text("t,q1,u1\n0,,0.0\n1,0.9,\n2,1.1,2.0\n")
    with pytest.raises(DataError, match=r"line 3, column 'u1': the input value is missing"):
        read_driven_csv(path)


# ---------------------------------------------------------------------------- likelihood
def _kalman(times, ys, theta, x0, signal):
    """The exact log-likelihood of the linear driven oscillator q̈ = −k q − c q̇ + b u(t)
    observed in q: transition expm, the input's response by DOP853, one Kalman filter."""
    k, b, c, q_var, r_var = theta
    a_mat = np.array([[0.0, 1.0], [-k, -c]])
    m, p = np.asarray(x0, dtype=float), 1e-16 * np.eye(2)
    h = np.array([[1.0, 0.0]])
    ll, t_prev = 0.0, 0.0
    for t, y in zip(times, ys, strict=True):
        phi = expm(a_mat * (t - t_prev))
        drive = solve_ivp(lambda s, x: a_mat @ x + np.array([0.0, b * signal(s)]),
                          (t_prev, t), [0.0, 0.0], method="DOP853", rtol=1e-12,
                          atol=1e-13).y[:, -1]
        m, p = phi @ m + drive, phi @ p @ phi.T + q_var * np.eye(2)
        s = (h @ p @ h.T)[0, 0] + r_var
        e = y - m[0]
        ll += -0.5 * (math.log(2 * math.pi * s) + e * e / s)
        gain = (p @ h.T)[:, 0] / s
        m, p = m + gain * e, p - np.outer(gain, h @ p)
        t_prev = t
    return ll


@pytest.mark.parametrize("integrator", ["rk4", "yoshida4"])
def test_the_driven_likelihood_is_the_exact_kalman_filter_of_a_linear_system(integrator):
    signal = SIGNALS["multisine"](seed=3, duration=20.0)
    times = np.linspace(0.5, 10.0, 20)
    rng = np.random.default_rng(0)
    ys = np.sin(times) + 0.1 * rng.standard_normal(times.size)
    pot = build_user_model("k*q1^2/2", "potential", 1, ("k",))
    model = HamiltonianModel(pot, integrator, dt=0.01, observation="positions",
                             force=user_force("b*u1 - c*p1", 1, ("b", "c"), 1))
    grid = np.linspace(0.0, 10.5, 4201)
    obs = Observations(times, ys, ("q1",),
                       inputs=SampledInputs(grid, signal(grid), ("u1",), "cubic"))
    theta = np.array([1.7, 0.8, 0.3, 1e-3, 0.01])
    x0 = np.array([0.2, -0.1])
    got = float(model.log_likelihood(jnp.asarray(theta), obs, jnp.asarray(x0)))
    want = _kalman(times, ys, theta, x0, signal)
    assert got == pytest.approx(want, abs=1e-5)  # leapfrog at this dt misses by 1e-2
    assert model.likelihood_backend == "jax"  # the compiled kernel declines a force


def test_a_force_is_refused_where_it_has_no_form():
    pot = build_user_model("k*q1^2/2", "potential", 1, ("k",))
    force = user_force("b*u1", 1, ("b",), 1)
    with pytest.raises(ValueError, match="no separate damping"):
        HamiltonianModel(pot, force=force, damping=True)
    with pytest.raises(ValueError, match="not 'step'"):
        HamiltonianModel(pot, force=force, process_noise_per="step")
    with pytest.raises(ValueError, match="no forced form"):
        HamiltonianModel(pot, "tao", force=force)


def test_a_model_without_a_force_keeps_its_layout_and_integrator():
    pot = build_user_model("k*q1^2/2", "potential", 1, ("k",))
    free = HamiltonianModel(pot)
    assert free.force is None and free.integrator.name == "leapfrog"
    assert "force" not in free.layout and free.num_dynamics_params == 1


# ---------------------------------------------------------------------------- a fit
def _duffing_record(num: int, free: bool = False, seed: int = 0):
    truth = {"k1": 1.0, "k3": 0.5, "c": 0.2, "b": 1.0}
    u = SIGNALS["multisine"](seed=seed, duration=num * 0.25 + 1)
    drive = (lambda t: 0.0) if free else u

    def rhs(t, x):
        return [x[1], -x[0] - 0.5 * x[0] ** 3 - 0.2 * x[1] + drive(t)]

    t = 0.25 * np.arange(1, num + 1)
    sol = solve_ivp(rhs, (0, t[-1]), [1.0, 0.0] if free else [0.0, 0.0], t_eval=t,
                    method="DOP853", rtol=1e-11, atol=1e-11)
    y = sol.y[0] + 0.05 * np.random.default_rng(seed + 1).standard_normal(num)
    grid = np.arange(0, 5 * num + 1) * 0.05
    values = np.zeros(grid.size) if free else u(grid)
    return truth, Observations(t, y, ("q1",), inputs=SampledInputs(grid, values, ("u1",),
                                                                  "cubic"))


_SETTINGS = {
    "model": {"potential": "k1*q1^2/2 + k3*q1^4/4", "force": "b*u1 - c*p1", "dt": 0.125,
              "parameters": {"k1": {"prior": "half-normal", "scale": 5},
                             "k3": {"prior": "normal", "loc": 0, "scale": 2},
                             "c": {"prior": "half-normal", "scale": 1},
                             "b": {"prior": "normal", "loc": 0, "scale": 5}}},
    "initial_state": {"x0": [0.0, 0.0]}, "map": {"num_starts": 2},
}


@pytest.mark.filterwarnings("ignore:the MAP sits on a bound")
def test_the_map_recovers_the_input_gain_and_the_friction():
    truth, obs = _duffing_record(60)
    s = resolve_for_data(settings_from_dict(_SETTINGS), obs)
    model = build_model(s, obs)
    assert model.param_names[:4] == ("k1", "k3", "c", "b")  # H's, then the force's, as declared
    result = find_map_for(s, build_posterior(s, obs, model))
    sd = np.sqrt(np.diag(result.covariance))
    for i, name in enumerate(model.param_names[:4]):
        assert abs(result.theta[i] - truth[name]) < 2.5 * sd[i], (name, result.theta[i], sd[i])


@pytest.mark.filterwarnings("ignore:the MAP sits on a bound")
def test_the_free_decay_cannot_tell_the_input_gain():
    """Without excitation the likelihood does not depend on b: its Laplace sd is the
    prior's (5), against a few hundredths from the multisine record."""
    _, obs = _duffing_record(60, free=True)
    data = {**_SETTINGS, "initial_state": {"x0": [1.0, 0.0]}}
    s = resolve_for_data(settings_from_dict(data), obs)
    model = build_model(s, obs)
    result = find_map_for(s, build_posterior(s, obs, model))
    b = model.param_names.index("b")
    assert math.sqrt(result.covariance[b, b]) > 2.0


# ---------------------------------------------------------------------------- command line
def test_the_command_line_refuses_missing_inputs_in_one_line(tmp_path):
    (tmp_path / "m.toml").write_text('[model]\npotential = "k*q1^2/2"\nforce = "b*u1"\n'
                                     '[model.parameters]\nk = { prior = "half-normal" }\n'
                                     'b = { prior = "normal" }\n')
    (tmp_path / "d.csv").write_text("t,q1,u1\n0,,0\n1,0.5,\n2,0.4,1\n")
    result = CliRunner().invoke(main, ["fit", str(tmp_path / "d.csv"), "--config",
                                       str(tmp_path / "m.toml"), "--out",
                                       str(tmp_path / "run")])
    assert result.exit_code == 2
    assert "the input value is missing" in result.output
    assert len(result.output.strip().splitlines()) == 1
    (tmp_path / "d.csv").write_text("t,q1\n1,0.5\n2,0.4\n")
    result = CliRunner().invoke(main, ["fit", str(tmp_path / "d.csv"), "--config",
                                       str(tmp_path / "m.toml"), "--out",
                                       str(tmp_path / "run")])
    assert result.exit_code == 2 and "no input columns" in result.output


def test_the_power_balance_matches_an_independent_energy_budget():
    """ΔH and the input's and the friction's work over each gap against DOP853 with the
    works integrated as two more state components."""
    from symplid.inference._driven import power_balance

    k, b, c = 1.7, 0.8, 0.3
    signal = SIGNALS["multisine"](seed=3, duration=20.0)
    pot = build_user_model("k*q1^2/2", "potential", 1, ("k",))
    model = HamiltonianModel(pot, "rk4", dt=0.01, observation="positions",
                             force=user_force("b*u1 - c*p1", 1, ("b", "c"), 1))
    grid = np.linspace(0.0, 10.5, 4201)
    sig = SampledInputs(grid, signal(grid), ("u1",), "cubic")
    times = np.array([1.0, 2.5, 4.0, 6.0])
    x0 = np.array([0.2, -0.1])
    got = power_balance(model, sig, np.array([k, b, c]), x0, 0.0, times, 0.005, "rk4")

    def rhs(t, x):
        q, p = x[0], x[1]
        return [p, -k * q - c * p + b * signal(t), p * b * signal(t), -c * p * p]

    sol = solve_ivp(rhs, (0.0, 6.0), [*x0, 0.0, 0.0], t_eval=np.concatenate([[0.0], times]),
                    method="DOP853", rtol=1e-12, atol=1e-12).y
    energy = 0.5 * sol[1] ** 2 + 0.5 * k * sol[0] ** 2
    np.testing.assert_allclose(got["dH"], np.diff(energy), atol=1e-5)
    np.testing.assert_allclose(got["work_input"], np.diff(sol[2]), atol=1e-5)
    np.testing.assert_allclose(got["work_other"], np.diff(sol[3]), atol=1e-5)
    assert np.abs(got["residual"]).max() < 1e-5


def test_without_process_noise_the_driven_likelihood_follows_one_path():
    """process_noise_per='none': the Gaussian terms around the forced path, which the
    forced path solver gives independently of the likelihood's loop."""
    from symplid.dynamics._forced import bind_forced, forced_solve_gaps
    from symplid.model._inputs import node_table

    signal = AnalyticInputs({"u1": "sin(0.7*t)"})
    times = np.linspace(0.5, 5.0, 10)
    ys = np.cos(times)
    pot = build_user_model("k*q1^2/2", "potential", 1, ("k",))
    force = user_force("b*u1 - c*p1", 1, ("b", "c"), 1)
    model = HamiltonianModel(pot, "leapfrog", dt=0.1, observation="positions",
                             process_noise_per="none", force=force)
    obs = Observations(times, ys, ("q1",), inputs=signal)
    theta = np.array([1.3, 0.5, 0.2, 0.01])
    x0 = np.array([1.0, 0.0])
    got = float(model.log_likelihood(jnp.asarray(theta), obs, jnp.asarray(x0)))
    prepared = model.prepare(obs)
    nodes, inputs = node_table(signal, 0.0, np.asarray(prepared.inputs.step_size),
                               np.asarray(prepared.inputs.num_steps), model.integrator.nodes, 1)
    path = forced_solve_gaps(model.integrator, bind_forced(pot, force, jnp.asarray(theta[:3])),
                             jnp.asarray(x0), prepared.inputs.step_size,
                             prepared.inputs.num_steps, nodes, inputs, prepared.max_steps)
    resid = ys - np.asarray(path)[:, 0]
    want = float(np.sum(-0.5 * (resid**2 / 0.01 + np.log(2 * np.pi * 0.01))))
    assert got == pytest.approx(want, rel=1e-12)


def test_simulate_writes_a_driven_record_that_dop853_reproduces(tmp_path):
    from symplid import get_system
    from symplid.io._inputfiles import read_driven_csv

    out = tmp_path / "sim.csv"
    result = CliRunner().invoke(main, ["simulate", "double-well", "--out", str(out), "--force",
                                       "0.8*u1 - 0.1*p1", "--input", "chirp", "--t-end", "10",
                                       "--num-obs", "20", "--noise-std", "0"])
    assert result.exit_code == 0, result.output
    obs = read_driven_csv(out, (), "cubic")
    sys_ = get_system("double-well")
    u = SIGNALS["chirp"](duration=11.0)
    coeffs = np.asarray(sys_.coefficients, dtype=float)

    def rhs(t, x):
        d = x.size // 2
        grad = np.asarray(sys_.potential.gradient(jnp.asarray(x[:d]), coeffs))
        return np.concatenate([x[d:], -grad + 0.8 * u(t) - 0.1 * x[d:]])

    want = solve_ivp(rhs, (0.0, 10.0), np.asarray(sys_.initial_state, dtype=float),
                     t_eval=obs.times, method="DOP853", rtol=1e-12, atol=1e-12).y.T
    np.testing.assert_allclose(obs.values, want[:, : obs.dim], atol=1e-9)
    np.testing.assert_allclose(obs.inputs.evaluate(obs.times)[:, 0], u(obs.times), atol=1e-12)


def test_inputs_from_settings_and_a_run_folder_round_trip(tmp_path):
    from symplid.workflow._driven import read_driven, read_run_inputs, write_run_inputs

    data = tmp_path / "d.csv"
    data.write_text("t,q1\n1,0.5\n2,0.4\n")
    settings = settings_from_dict({"model": {"force": "u1"},
                                   "inputs": {"expressions": ["0.5*sin(1.3*t)"]}})
    obs = read_driven([data], settings)
    np.testing.assert_allclose(obs.inputs.evaluate(np.array([2.0]))[:, 0], 0.5 * np.sin(2.6))
    (tmp_path / "u.csv").write_text("t,u1\n0,0\n1,1\n2,4\n3,9\n")
    settings = settings_from_dict({"model": {"force": "u1"},
                                   "inputs": {"file": str(tmp_path / "u.csv"),
                                              "interpolation": "zoh"}})
    obs = read_driven([data], settings)
    assert obs.inputs.evaluate(np.array([1.5]))[0, 0] == 1.0
    write_run_inputs(tmp_path, obs)
    back = read_run_inputs(tmp_path, Observations(obs.times, obs.values, obs.names), settings)
    np.testing.assert_array_equal(back.inputs.values, obs.inputs.values)
    assert back.inputs.interpolation == "zoh"
