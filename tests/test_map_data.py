"""MAP on systems nobody tuned for: starts from the data, failures that say so.

Every target is a simulated system with a known truth: a Kepler orbit (positions only) in
days and in years, the same orbit with the initial state learned at the first observation,
and a Morse oscillator in units where its well depth is 4.7e-4. The failure checks run a
search that cannot converge and one stopped at a point that calls the orbit noise.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

import symplid
from symplid.cli import main
from symplid.dynamics._potentials import FunctionPotential
from symplid.inference.map import _checks as map_checks
from symplid.inference.map import _data_start, _paths
from symplid.inference.map._data_start import data_start
from symplid.inference.map._noise import difference_variance
from symplid.inference.map._paths import position_rows
from symplid.inference.map._result import MapConvergenceWarning, StartResult
from symplid.inference.map._space import SearchSpace
from symplid.inference.map._starts import default_start
from symplid.model._data import Observations
from symplid.model._params import ParameterSpace
from symplid.model._priors import HalfNormal, Laplace, Normal
from symplid.model._simulate import true_trajectory

GM_DAYS = 2.959122e-4  # AU³/day², the Sun
GM_YEARS = GM_DAYS * 365.25**2  # AU³/yr²
NOISE = 0.01  # AU


def kepler(unit: str, learn: bool = False, t0=0.0, prior=None):
    """A 2-D orbit (a = 1 AU, e = 0.2) seen in positions only, 25 times over one period."""
    gm, period = (GM_DAYS, 365.25) if unit == "days" else (GM_YEARS, 1.0)
    r = 0.8
    x0 = np.array([r, 0.0, 0.0, math.sqrt(gm * 1.2 / r)])
    pot = FunctionPotential(lambda q, c: -c[0] / jnp.sqrt(q[0] ** 2 + q[1] ** 2), dim=2,
                            num_params=1, names=("GM",))
    times = np.linspace(period / 25, period, 25)
    # simulated with the model's own leapfrog step: the truth is exactly the model
    states = true_trajectory(pot, np.array([gm]), x0, times, dt=period / 125)
    y = states[:, :2] + NOISE * np.random.default_rng(1).standard_normal((25, 2))
    model = symplid.HamiltonianModel(pot, dt=period / 125, observation="positions")
    data = Observations(times, y)
    if learn:
        return symplid.Posterior(model, data, prior, learn_initial_state=True, t0=t0), gm
    return symplid.Posterior(model, data, prior, x0=x0), gm


# ----------------------------------------------------------------------------- the start
def test_difference_variance_is_the_noise_of_a_smooth_signal():
    """Against the known variance of the added white noise (2000 points, 5 % tolerance)."""
    t = np.linspace(0.0, 20.0, 2000)
    noise = 0.03 * np.random.default_rng(0).standard_normal(t.size)
    assert difference_variance(np.sin(t) + noise) == pytest.approx(0.03**2, rel=0.05)
    assert difference_variance(np.sin(t)) < 1e-8  # no noise: (almost) nothing


def test_data_start_of_a_harmonic_oscillator_is_near_its_stiffness():
    """U = ½kq² with k = 40 (period ≈ 1): the collocation fit alone lands within 10 %."""
    pot = FunctionPotential(lambda q, c: 0.5 * c[0] * q[0] ** 2, dim=1, num_params=1,
                            names=("k",))
    times = np.linspace(0.05, 3.0, 60)
    states = true_trajectory(pot, np.array([40.0]), np.array([1.0, 0.0]), times, dt=1e-4)
    y = states[:, :1] + 0.01 * np.random.default_rng(4).standard_normal((60, 1))
    model = symplid.HamiltonianModel(pot, dt=0.01, observation="positions")
    post = symplid.Posterior(model, Observations(times, y), x0=np.array([1.0, 0.0]))
    found = data_start(post, default_start(post))
    assert found is not None
    assert found.theta[0] == pytest.approx(40.0, rel=0.1)
    # the difference estimate is biased upward by the signal (20 samples a period here)
    assert 0.5 * 0.01**2 < found.noise_var[0] < 3 * 0.01**2


def test_data_start_reads_only_models_that_measure_every_position():
    """A linear operator that measures q directly is read (its rows and factors); a function
    h, or a matrix that leaves a position unmeasured, falls back to the default start."""
    pot = symplid.Polynomial(dim=2, order=2)
    found = position_rows(symplid.HamiltonianModel(pot, observation=np.diag([2.0, 1, 1, 1])))
    assert found is not None
    np.testing.assert_array_equal(found[0], [0, 1, 2, 3])
    np.testing.assert_array_equal(found[1], [2.0, 1, 1, 1])
    assert position_rows(symplid.HamiltonianModel(pot, observation=lambda x: x[:2])) is None
    only_q1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    assert position_rows(symplid.HamiltonianModel(pot, observation=only_q1)) is None


def _bisected_spline(t: np.ndarray, y: np.ndarray, target: float):
    """The discrepancy principle's spline by 40 bisection steps on log λ over the same
    bracket (λ ∈ [1e-12, 1e6] × span³), the largest λ whose residual is within the target."""
    from scipy.interpolate import make_smoothing_spline

    span = t[-1] - t[0]
    lo, hi = math.log(1e-12 * span**3), math.log(1e6 * span**3)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        spline = make_smoothing_spline(t, y, lam=math.exp(mid))
        if np.mean((y - spline(t)) ** 2) > target:
            hi = mid
        else:
            lo = mid
    return make_smoothing_spline(t, y, lam=math.exp(lo))


def _series():
    """(t, y) of an orbit's coordinate (25 points), a noisy sine at irregular times (60) and
    a population cycle's logarithm (50)."""
    rng = np.random.default_rng(2)
    post, _ = kepler("days")
    orbit = (np.asarray(post.datasets[0].times), np.asarray(post.datasets[0].values)[:, 0])
    t = np.sort(rng.uniform(0.0, 12.0, 60))
    sine = (t, np.sin(t) + 0.05 * rng.standard_normal(t.size))
    t = np.linspace(0.6, 30.0, 50)
    cycle = (t, np.log(2.0 + np.sin(0.7 * t)) + 0.05 * rng.standard_normal(t.size))
    return [orbit, sine, cycle]


@pytest.mark.parametrize("which", [0, 1, 2])
def test_the_discrepancy_spline_is_the_bisections_with_fewer_fits(which, monkeypatch):
    """Brent's method on log λ gives the spline of a 40-step bisection (values and velocity
    within 1e-7 of the data's range) with at most 25 spline fits, not 41."""
    from scipy.interpolate import make_smoothing_spline

    t, y = _series()[which]
    fits = []
    monkeypatch.setattr(_paths, "make_smoothing_spline",
                        lambda *a, **k: fits.append(1) or make_smoothing_spline(*a, **k))
    spline, target = _paths.spline_fit(t, y)
    reference = _bisected_spline(t, y, target)
    size = np.ptp(y)
    np.testing.assert_allclose(spline(t), reference(t), rtol=0, atol=1e-7 * size)
    np.testing.assert_allclose(spline.derivative()(t), reference.derivative()(t), rtol=0,
                               atol=1e-7 * size / np.ptp(t))
    assert len(fits) <= 25


@pytest.mark.parametrize("target", [1e-300, 1e6])
def test_a_target_outside_the_bracket_gives_the_bisections_end(target, monkeypatch):
    """A noise target below every spline's residual gives the roughest spline of the bracket,
    one above them the smoothest: where the bisection ends."""
    t, y = _series()[1]
    monkeypatch.setattr(_paths, "noise_variance", lambda *_: target)
    spline, _ = _paths.spline_fit(t, y)
    np.testing.assert_allclose(spline(t), _bisected_spline(t, y, target)(t), rtol=0,
                               atol=1e-9)


def test_collocation_program_is_hamiltons_equations_and_their_jacobian():
    """The one compiled program against Kepler's equations written out in NumPy (∂H/∂p = p,
    −∂H/∂q = −GM q/|q|³) and its Jacobian against central differences."""
    post, gm = kepler("days", learn=True)
    rng = np.random.default_rng(3)
    n, d = 8, 2
    times = np.sort(rng.uniform(0.0, 100.0, n))
    q = rng.uniform(0.5, 1.0, (n, d))
    qdot = rng.normal(0.0, 0.02, (n, d))
    p_obs = np.full((n, d), np.nan)
    p_obs[2, 1] = 0.01
    path = _paths.Smoothed(times, q, qdot, p_obs, 0.0)
    dyn = np.array([0])
    program = _data_start._collocation_program(post.model, dyn, d)
    scales, data = _data_start._collocation_data([path])
    z = np.concatenate([[gm], rng.normal(0.0, 0.02, n * d)])
    r, jac, (g,) = (np.asarray(x) for x in program(z, np.array([1.0]), scales, data))

    p = z[1:].reshape(n, d)
    force = -z[0] * q / np.linalg.norm(q, axis=1, keepdims=True) ** 3
    h = np.diff(times)[:, None]
    v_scale, a_scale = scales
    expected = np.concatenate([((qdot - p) / v_scale).ravel(),
                               ((p[1:] - p[:-1] - 0.5 * h * (force[1:] + force[:-1]))
                                / (h * a_scale)).ravel(), [(p[2, 1] - 0.01) / v_scale]])
    np.testing.assert_allclose(r, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(g, force, rtol=1e-12)
    step = 1e-6 * np.maximum(np.abs(z), 1e-3)
    numeric = np.column_stack([
        (np.asarray(program(z + e, np.array([1.0]), scales, data)[0])
         - np.asarray(program(z - e, np.array([1.0]), scales, data)[0])) / (2 * e[k])
        for k, e in enumerate(np.diag(step))])
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-6 * np.abs(numeric).max())


# ----------------------------------------------------------------------------- the targets
@pytest.mark.slow
@pytest.mark.parametrize("unit", ["days", "years"])
def test_kepler_map_from_defaults_in_days_and_years(unit):
    """Defaults only: GM within 1 % of the truth and inside its 3-sd Laplace interval."""
    post, gm = kepler(unit)
    result = symplid.find_map(post, seed=0)
    assert result.success and result.failure == ""
    assert result.theta[0] == pytest.approx(gm, rel=0.01)
    assert abs(result.theta[0] - gm) <= 3 * result.std[0]
    assert math.isfinite(result.log_evidence) and result.log_evidence < result.log_posterior


@pytest.mark.slow
def test_learned_initial_state_at_first_observation_keeps_the_noise():
    """t0=None and a learned x0: Γ stays near the true 1e-4 (not its 1e-14 floor) and x0
    keeps an uncertainty of the noise's size (not 1e-7)."""
    post, gm = kepler("years", learn=True, t0=None)
    result = symplid.find_map(post, seed=0)
    names = list(post.param_names)
    assert result.success
    assert "obs_var" not in result.at_bounds
    assert 2e-5 < result.params["obs_var"] < 5e-4
    q1 = names.index("x0[0].q1")
    assert 1e-3 < result.std[q1] < 0.05
    assert abs(result.theta[0] - gm) <= 3 * result.std[0]


@pytest.mark.slow
def test_morse_oscillator_in_other_units_from_defaults():
    """U = D(1 − e^{−a(q − r0)})² with time in hundredths (D = 4.7e-4, a = 1.9, r0 = 0.74),
    40 positions: every parameter within 5 % and inside its 3-sd interval."""
    s = 100.0
    truth = np.array([4.7 / s**2, 1.9, 0.74])
    pot = FunctionPotential(
        lambda q, c: c[0] * (1 - jnp.exp(-c[1] * (q[0] - c[2]))) ** 2, dim=1, num_params=3,
        names=("D", "a", "r0"))
    x0 = np.array([truth[2] - 0.35, 0.0])
    times = s * np.linspace(0.08, 3.2, 40)
    states = true_trajectory(pot, truth, x0, times, dt=s * 1e-3)
    y = states[:, :1] + 0.01 * np.random.default_rng(2).standard_normal((40, 1))
    model = symplid.HamiltonianModel(pot, dt=s * 0.02, observation="positions")
    result = symplid.find_map(symplid.Posterior(model, Observations(times, y), x0=x0), seed=0)
    assert result.success
    np.testing.assert_allclose(result.theta[:3], truth, rtol=0.05)
    assert np.all(np.abs(result.theta[:3] - truth) <= 3 * result.std[:3])


@pytest.mark.slow
def test_double_pendulum_data_start_is_in_the_right_mode():
    """The double pendulum (angles only, non-separable H): L-BFGS-B from θ = 0 stops in a
    wrong mode 32 % off; the data start (no filter run) puts every ratio within 12 % of the
    truth, closer than θ = 0 does, in the mode the full search then converges in."""
    system = symplid.get_system("double-pendulum")
    data = symplid.simulate(system, seed=3)
    model = symplid.HamiltonianModel(system.potential, integrator="tao", dt=0.025,
                                     observation="positions")
    post = symplid.Posterior(model, data, x0=system.initial_state, P0=1e-8)
    found = data_start(post, default_start(post))
    assert found is not None
    error = np.abs(found.theta[:3] - system.coefficients)
    assert np.all(error < math.log(1.12))
    assert np.all(error <= np.abs(system.coefficients))  # θ = 0 is the default start


# ----------------------------------------------------------------------------- failures
@pytest.mark.slow
def test_a_stuck_map_is_failed_and_has_no_evidence():
    """Started where the force is zero and the process noise follows the data, with three
    iterations: not converged, said so, and no evidence."""
    post, _ = kepler("days")
    with pytest.warns(MapConvergenceWarning, match="the MAP search failed"):
        result = symplid.find_map(post, num_starts=1, init=default_start(post), maxiter=3)
    assert not result.success
    assert result.failure.startswith("did not converge")
    assert math.isnan(result.log_evidence) and math.isnan(result.log_evidence_laplace)
    assert "failed" in repr(result)
    again = type(result).from_dict(result.to_dict())
    assert again.failure == result.failure


@pytest.mark.slow
def test_a_map_that_calls_the_orbit_noise_is_failed():
    """An optimum with a force far too weak (a tight prior holds GM at 3 against 39.5) and
    little process noise: it fits the orbit as noise of the orbit's size, explains nothing,
    and is not a success (its evidence is kept: it is an optimum of that model)."""
    post, _ = kepler("years", prior={"GM": Normal(3.0, 0.01), "process_var": HalfNormal(1e-6)})
    with pytest.warns(MapConvergenceWarning, match="explains the motion as noise"):
        result = symplid.find_map(post, seed=0, num_starts=2)
    assert not result.success
    assert "times the noise the data show" in result.failure
    assert result.params["obs_var"] > 100 * NOISE**2
    assert math.isfinite(result.log_evidence)


def _start(theta, start=None, success=True) -> StartResult:
    theta = np.asarray(theta, dtype=float)
    return StartResult(theta if start is None else np.asarray(start, dtype=float), theta,
                       1.0, success, "CONVERGENCE", 5, 6, 0.1)


def test_judge_names_each_way_a_point_is_not_a_map():
    """Each failure of map_checks on a hand-made point whose answer is known."""
    space = SearchSpace.of(ParameterSpace.from_priors(
        ["c", "obs_var"], ["coefficients", "obs_var"],
        [Laplace(0.0, 10.0), HalfNormal(1.0)],
    ), 1e-14)
    groups = ("coefficients", "obs_var")
    good, pd = _start([1.0, 0.01], start=[0.0, 0.1]), np.eye(2)
    noise = np.array([0.01])
    assert map_checks.judge(good, (good,), pd, space, groups, noise) == ""
    stuck = _start([1.0, 0.01])
    assert map_checks.judge(stuck, (stuck,), pd, space, groups, noise).startswith(
        "did not move")
    # a point handed in as init (a previous MAP) may stay put
    assert map_checks.judge(stuck, (stuck,), pd, space, groups, noise, given_start=True) == ""
    saddle = np.diag([1.0, -1.0])
    assert map_checks.judge(good, (good,), saddle, space, groups, noise).startswith(
        "is not a maximum")
    loud = _start([1.0, 0.5], start=[0.0, 0.1])  # sd 0.71 against sd 0.1: 7 times
    assert "7 times" in map_checks.judge(loud, (loud,), pd, space, groups, noise)
    not_conv = _start([1.0, 0.01], start=[0.0, 0.1], success=False)
    assert map_checks.judge(not_conv, (not_conv,), pd, space, groups, noise).startswith(
        "did not converge")
    assert not map_checks.is_optimum("did not converge (x)")
    assert map_checks.is_optimum("has an observation noise ...")


@pytest.mark.slow
def test_fit_stops_before_sampling_when_the_map_fails(tmp_path: Path, monkeypatch):
    """symplid fit with a MAP search that cannot converge (one iteration): one line on
    stderr, exit code 2, no draws and a folder marked failed."""
    from symplid.workflow import _fit as fit_module

    runner = CliRunner()
    data = tmp_path / "h.csv"
    made = runner.invoke(main, ["simulate", "harmonic", "--out", str(data), "--num-obs", "15",
                                "--t-end", "15", "--noise-std", "0.02", "--seed", "3"])
    assert made.exit_code == 0, made.output
    monkeypatch.setattr(fit_module, "find_map",
                        functools.partial(symplid.find_map, maxiter=1))
    out = tmp_path / "run"
    result = runner.invoke(main, ["fit", str(data), "--out", str(out), "--order", "2",
                                  "--x0", "1,0", "--dt", "0.25", "--iterations", "400",
                                  "--burn-in", "200", "--chains", "2", "--no-progress",
                                  "--no-report"])
    assert result.exit_code == 2, result.output
    err = result.stderr.strip()
    assert err.count("\n") == 0, err
    assert err.startswith("symplid: error: the MAP search failed")
    assert "Try more starts" in err
    assert "map.num_starts" in err and "find_map(" not in err  # settings terms, no Python
    assert not (out / "posterior.nc").exists() and not (out / "summary.json").exists()
    assert "failed" in (out / ".incomplete").read_text()
