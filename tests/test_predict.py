"""Tests of symplid.inference._predict against independent references.

References: the simulator's own fine integration (``true_trajectory``), ``numpy.quantile`` on
paths integrated one at a time, closed-form harmonic-oscillator solutions, and the analytic
Hénon–Heiles Hamiltonian (eq. 15).
"""

from __future__ import annotations

import numpy as np
import pytest

import symplid
from symplid.inference._predict import (
    forecast_from_filter,
    hamiltonian_along,
    posterior_predictive,
    predict_trajectory,
    prediction_horizon,
    time_grid,
)


@pytest.fixture(scope="module")
def hh():
    return symplid.get_system("henon-heiles")


def henon_heiles_energy(states: np.ndarray) -> np.ndarray:
    """H = ½(p1² + p2²) + ½q1² + ½q2² + q1²q2 − ⅓q2³, written out (eq. 15)."""
    q1, q2, p1, p2 = np.moveaxis(states, -1, 0)
    return 0.5 * (p1**2 + p2**2) + 0.5 * q1**2 + 0.5 * q2**2 + q1**2 * q2 - q2**3 / 3.0


# ------------------------------------------------------------------ predict_trajectory
@pytest.mark.parametrize("integrator", ["leapfrog", "rk2-midpoint"])
def test_trajectory_matches_true_trajectory(hh, integrator):
    times, states = predict_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, 20.0, dt=0.01, integrator=integrator
    )
    assert times.shape == (2001,) and states.shape == (2001, 4)
    np.testing.assert_allclose(times, 0.01 * np.arange(2001), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(states[0], hh.initial_state)
    ref = symplid.true_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, times[1:], dt=0.01, integrator=integrator
    )
    np.testing.assert_allclose(states[1:], ref, rtol=0, atol=1e-11)


def test_trajectory_every_and_model_input(hh):
    _, full = predict_trajectory(hh.potential, hh.coefficients, hh.initial_state, 5.03, dt=0.01)
    # 503 steps stored every 10: steps 0, 10, ..., 500 and the last one, 503.
    times, sub = predict_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, 5.03, dt=0.01, every=10
    )
    np.testing.assert_allclose(times, np.r_[0.01 * np.arange(0, 501, 10), 5.03], atol=1e-12)
    np.testing.assert_allclose(sub, full[np.r_[np.arange(0, 501, 10), 503]], atol=1e-13)
    model = symplid.HamiltonianModel(hh.potential, integrator="rk2", dt=0.25)
    theta = model.pack(hh.coefficients, 1e-6, 0.05**2)
    _, via_model = predict_trajectory(model, theta, hh.initial_state, 5.03, dt=0.01)
    np.testing.assert_array_equal(via_model, full)


def test_trajectory_starts_at_t0(hh):
    times, states = predict_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, 12.0, dt=0.01, t0=10.0
    )
    assert times[0] == 10.0 and times[-1] == pytest.approx(12.0)
    _, ref = predict_trajectory(hh.potential, hh.coefficients, hh.initial_state, 2.0, dt=0.01)
    np.testing.assert_allclose(states, ref, atol=1e-13)


def test_time_grid_when_dt_does_not_divide():
    times, n, h = time_grid(0.0, 1.0, 0.3)
    assert n == 4 and h == pytest.approx(0.25)
    np.testing.assert_allclose(times, [0.0, 0.25, 0.5, 0.75, 1.0])
    times, n, h = time_grid(0.0, 100.0, 0.25, every=20)
    assert n == 400 and h == 0.25 and times.shape == (21,)


def test_harmonic_with_mass_is_exact():
    """H = p²/(2m) + kq²/2 has q = cos ωt, p = −mω sin ωt with ω = √(k/m)."""
    pot = symplid.Polynomial(1, 2)
    m, k = 2.0, 0.5
    omega = np.sqrt(k / m)
    times, states = predict_trajectory(
        pot, [0.0, k / 2], [1.0, 0.0], 10.0, dt=1e-3, integrator="rk4", mass=[[m]]
    )
    np.testing.assert_allclose(states[:, 0], np.cos(omega * times), atol=1e-10)
    np.testing.assert_allclose(states[:, 1], -m * omega * np.sin(omega * times), atol=1e-10)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"dt": 0.0}, "dt must be positive"),
        ({"t_end": -1.0}, "must be after t0"),
        ({"x0": [0.1, 0.2]}, "x0 must have shape"),
        ({"coefficients": np.zeros(8)}, "expected 9 coefficients"),
        ({"integrator": "rk3"}, "unknown integrator"),
        ({"every": 0}, "every must be a positive integer"),
    ],
)
def test_trajectory_bad_input(hh, kwargs, message):
    args = {
        "coefficients": hh.coefficients,
        "x0": hh.initial_state,
        "t_end": 1.0,
        "dt": 0.01,
        "integrator": "leapfrog",
        "every": 1,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        predict_trajectory(
            hh.potential,
            args["coefficients"],
            args["x0"],
            args["t_end"],
            dt=args["dt"],
            integrator=args["integrator"],
            every=args["every"],
        )


# ------------------------------------------------------------------ posterior_predictive
@pytest.fixture(scope="module")
def draws(hh):
    rng = np.random.default_rng(1)
    return hh.coefficients + 0.01 * rng.standard_normal((7, hh.potential.num_params))


def test_posterior_predictive_matches_loop(hh, draws):
    levels = (0.1, 0.5, 0.9)
    pp = posterior_predictive(
        hh.potential, draws, hh.initial_state, 10.0, dt=0.01, quantiles=levels,
        num_paths=3, seed=5, every=25, batch_size=3,
    )
    loop = np.stack([
        predict_trajectory(hh.potential, c, hh.initial_state, 10.0, dt=0.01, every=25)[1]
        for c in draws
    ])
    assert pp.times.shape == (41,) and pp.num_draws == 7 and pp.every == 25
    np.testing.assert_allclose(pp.quantiles, np.quantile(loop, levels, axis=0), atol=1e-12)
    np.testing.assert_allclose(pp.median, np.median(loop, axis=0), atol=1e-12)
    np.testing.assert_allclose(pp.lower, pp.quantiles[0])
    assert pp.paths.shape == (3, 41, 4) and len(set(pp.path_indices)) == 3
    np.testing.assert_allclose(pp.paths, loop[pp.path_indices], atol=1e-12)
    np.testing.assert_array_equal(pp.finite_fraction, 1.0)


def test_posterior_predictive_draw_layouts_and_seed(hh, draws):
    model = symplid.HamiltonianModel(hh.potential)
    theta = np.column_stack([draws, np.full(7, 1e-6), np.full(7, 0.0025)])
    chains = np.stack([theta[:6:2], theta[1:6:2]])  # (2 chains, 3 draws, 11)
    a = posterior_predictive(model, chains, hh.initial_state, 2.0, num_paths=6, seed=0)
    b = posterior_predictive(hh.potential, draws[:6], hh.initial_state, 2.0, num_paths=6, seed=0)
    # chain-major flattening: row r of `chains` is draws[[0, 2, 4, 1, 3, 5]][r]
    order = np.array([0, 2, 4, 1, 3, 5])
    np.testing.assert_allclose(a.quantiles, b.quantiles, atol=1e-13)
    for path, row in zip(a.paths, a.path_indices, strict=True):
        _, ref = predict_trajectory(hh.potential, draws[order[row]], hh.initial_state, 2.0,
                                    every=a.every)
        np.testing.assert_allclose(path, ref, atol=1e-12)
    again = posterior_predictive(hh.potential, draws[:6], hh.initial_state, 2.0, seed=0)
    np.testing.assert_array_equal(again.path_indices, b.path_indices)
    # max_draws takes a seeded random subset of the draws.
    sub = posterior_predictive(hh.potential, draws, hh.initial_state, 2.0, max_draws=4, seed=3)
    assert sub.num_draws == 4 and sub.paths.shape[0] == 4


def test_posterior_predictive_default_every(hh, draws):
    pp = posterior_predictive(hh.potential, draws[:2], hh.initial_state, 200.0, dt=0.01)
    assert pp.every == 10 and pp.times.shape == (2001,) and pp.times[-1] == pytest.approx(200.0)


def test_posterior_predictive_leaves_out_diverging_paths(hh, draws):
    """A draw with a huge cubic term escapes to infinity; the band is over the finite ones."""
    bad = draws.copy()
    bad[0, 5] = 50.0  # q1³ coefficient: unbounded below, the path blows up
    pp = posterior_predictive(
        hh.potential, bad, hh.initial_state, 30.0, dt=0.05, integrator="leapfrog", every=20
    )
    assert pp.finite_fraction[0] == 1.0 and pp.finite_fraction[-1] == pytest.approx(6 / 7)
    finite = np.stack([
        predict_trajectory(hh.potential, c, hh.initial_state, 30.0, dt=0.05, every=20)[1]
        for c in bad[1:]
    ])
    np.testing.assert_allclose(pp.upper[-1], np.quantile(finite[:, -1], 0.975, axis=0))


def test_posterior_predictive_bad_input(hh, draws):
    with pytest.raises(ValueError, match="quantiles"):
        posterior_predictive(hh.potential, draws, hh.initial_state, 1.0, quantiles=(0.0, 0.5))
    with pytest.raises(ValueError, match="draws must have shape"):
        posterior_predictive(hh.potential, draws[0], hh.initial_state, 1.0)
    with pytest.raises(ValueError, match="x0 must have shape"):
        posterior_predictive(hh.potential, draws, np.zeros((3, 4)), 1.0)
    with pytest.raises(ValueError, match="max_draws"):
        posterior_predictive(hh.potential, draws, hh.initial_state, 1.0, max_draws=0)


# ------------------------------------------------------------------ hamiltonian_along
def test_hamiltonian_along_matches_formula(hh, draws):
    _, states = predict_trajectory(hh.potential, hh.coefficients, hh.initial_state, 5.0)
    np.testing.assert_allclose(
        hamiltonian_along(hh.potential, hh.coefficients, states),
        henon_heiles_energy(states),
        atol=1e-15,
    )
    assert henon_heiles_energy(hh.initial_state) == pytest.approx(0.12271, abs=1e-5)
    # one coefficient vector per path (vmap) agrees with a loop
    pp = posterior_predictive(  # same shapes as test_posterior_predictive_matches_loop
        hh.potential, draws, hh.initial_state, 10.0, num_paths=7, every=25, batch_size=3
    )
    batch = hamiltonian_along(hh.potential, draws[pp.path_indices], pp.paths)
    loop = [hamiltonian_along(hh.potential, draws[i], p)
            for i, p in zip(pp.path_indices, pp.paths, strict=True)]
    np.testing.assert_allclose(batch, np.stack(loop), atol=1e-15)


def test_leapfrog_energy_error_is_bounded_and_second_order(hh):
    """Leapfrog conserves a modified Hamiltonian: |H − H0| stays O(dt²) over 200 s, no drift."""
    errors = {}
    for dt in (0.02, 0.01):
        _, states = predict_trajectory(hh.potential, hh.coefficients, hh.initial_state, 200.0, dt)
        h = hamiltonian_along(hh.potential, hh.coefficients, states)
        dev = np.abs(h - h[0])
        quarter = dev.shape[0] // 4
        assert dev[-quarter:].max() < 2.0 * dev[:quarter].max()  # no secular growth
        errors[dt] = dev.max()
    assert errors[0.01] < 1e-5
    assert errors[0.02] / errors[0.01] == pytest.approx(4.0, rel=0.15)


def test_rk2_at_learning_step_gains_energy(hh):
    """Fig. 2b: RK2 at Δt = 0.25 pumps energy in (the paper's H reaches about 0.2 by 100 s)."""
    _, states = predict_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, 100.0, dt=0.25, integrator="rk2"
    )
    h = hamiltonian_along(hh.potential, hh.coefficients, states)
    assert h[-1] > 0.17 and np.all(np.diff(h[::40]) > 0)


# ------------------------------------------------------------------ prediction_horizon
def rotation_state(omega: float, times: np.ndarray) -> np.ndarray:
    """(q, p) = (cos ωt, −sin ωt): the flow of H = ω(p² + q²)/2, i.e. m = 1/ω, k = ω."""
    return np.column_stack([np.cos(omega * times), -np.sin(omega * times)])


def horizon_closed_form(delta: float, threshold: float) -> float:
    """|X_ω(t) − X_1(t)| = 2|sin(δt/2)| with δ = ω − 1: first reaches ε at 2 arcsin(ε/2)/|δ|."""
    return 2.0 * np.arcsin(threshold / 2.0) / abs(delta)


def test_prediction_horizon_closed_form_on_grid():
    times = np.linspace(0.0, 40.0, 40001)
    omega, eps = 1.01, 0.1
    expect = horizon_closed_form(omega - 1.0, eps)
    got = prediction_horizon(
        times, rotation_state(omega, times), rotation_state(1.0, times), eps, component=None
    )
    assert expect <= got <= expect + 1e-3
    # one component: |cos ωt − cos t| ≤ 2|sin(δt/2)|, and equality (up to the envelope) is
    # reached within half a period of the fast factor sin((ω+1)t/2) after it.
    got_q = prediction_horizon(times, rotation_state(omega, times), rotation_state(1.0, times), eps)
    assert expect <= got_q <= expect + 2 * np.pi / (omega + 1.0) + 1e-3


def test_prediction_horizon_of_integrated_oscillator():
    """The same case integrated by leapfrog through the mass matrix (m = 1/ω, k = ω)."""
    pot = symplid.Polynomial(1, 2)
    omega, eps = 0.98, 0.1

    def run(w):
        return predict_trajectory(pot, [0.0, w / 2], [1.0, 0.0], 30.0, dt=1e-3, mass=[1.0 / w])

    times, wrong = run(omega)
    _, right = run(1.0)
    np.testing.assert_allclose(right, rotation_state(1.0, times), atol=1e-5)
    got = prediction_horizon(times, wrong, right, eps, component=[0, 1])
    assert got == pytest.approx(horizon_closed_form(omega - 1.0, eps), abs=2e-3)


def test_prediction_horizon_edge_cases():
    t = np.linspace(0, 10, 11)
    x = np.zeros((11, 2))
    assert prediction_horizon(t, x, x) == 10.0  # never leaves: the end
    y = x.copy()
    y[4, 0] = np.nan  # a non-finite prediction counts as leaving
    assert prediction_horizon(t, y, x) == 4.0
    y = x.copy()
    y[7, 1] = 0.5
    assert prediction_horizon(t, y, x, component=0) == 10.0
    assert prediction_horizon(t, y, x, component=1) == 7.0
    with pytest.raises(ValueError, match="component"):
        prediction_horizon(t, y, x, component=2)
    with pytest.raises(ValueError, match="share the time axis"):
        prediction_horizon(t[:-1], y, x)
    with pytest.raises(ValueError, match="threshold"):
        prediction_horizon(t, y, x, threshold=0.0)


# ------------------------------------------------------------------ forecast_from_filter
def test_forecast_from_filter_tracks_truth():
    """With nearly noiseless data the last filtered state is the true one, so the forecast
    of the true model follows the true trajectory after the data."""
    sysm = symplid.get_system("harmonic")
    data = symplid.simulate(sysm, times=np.arange(1.0, 6.0), noise_std=1e-4, seed=0)
    model = symplid.HamiltonianModel(sysm.potential, integrator="leapfrog", dt=0.1)
    rng = np.random.default_rng(0)
    coeffs = sysm.coefficients + np.array([0.0, 1e-3]) * rng.standard_normal((6, 1))
    theta = np.column_stack([coeffs, np.full(6, 1e-10), np.full(6, 1e-8)])
    fc = forecast_from_filter(
        model, theta, data, sysm.initial_state, t_end=8.0, num_paths=4, seed=0, every=10
    )
    assert fc.times[0] == 5.0 and fc.times[-1] == pytest.approx(8.0)
    truth = symplid.true_trajectory(sysm.potential, sysm.coefficients, sysm.initial_state,
                                    fc.times)
    np.testing.assert_allclose(fc.median, truth, atol=5e-3)
    assert np.all(fc.lower <= fc.upper) and fc.num_draws == 6
    np.testing.assert_array_equal(fc.finite_fraction, 1.0)
    # each sample path is its draw's model integrated from a point near the data's last state
    row = fc.path_indices[0]
    _, ref = predict_trajectory(model, theta[row], fc.paths[0, 0], 8.0, t0=5.0, every=10)
    np.testing.assert_allclose(fc.paths[0], ref, atol=1e-12)
