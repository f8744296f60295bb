"""The baseline objectives (HNN's eq. 1, least squares through Euler/RK4/leapfrog steps).

Checked against mathematics: on noise-free, densely sampled Hénon–Heiles data each objective
recovers the exact cubic coefficients with an error that falls with the sampling step h as
h^order (HNN and Euler 1, leapfrog 2, RK4 4), and with noisy data the error shrinks as the data
grow.
"""

from __future__ import annotations

import numpy as np
import pytest

import symplid
from symplid.dynamics._integrators import INTEGRATORS
from symplid.inference import _baselines as baselines
from symplid.model._simulate import true_trajectory

ORDERS = {"hnn": 1, "euler": 1, "leapfrog": 2, "rk4": 4}


@pytest.fixture(scope="module")
def hh():
    return symplid.get_system("henon-heiles")


def _exact_data(hh, h: float, span: float = 20.0) -> symplid.Observations:
    """Noise-free states every h; the truth by Yoshida's 4th-order method at dt = 1e-3."""
    times = h * np.arange(1, round(span / h) + 1)
    states = true_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, times, dt=1e-3, integrator="yoshida4"
    )
    return symplid.Observations(times, states)


@pytest.fixture(scope="module")
def exact(hh):
    return {h: _exact_data(hh, h) for h in (0.2, 0.1)}


@pytest.mark.parametrize("objective", list(ORDERS))
def test_recovers_exact_coefficients_to_the_integrators_order(hh, exact, objective):
    errors = {
        h: np.max(np.abs(baselines.fit(hh.potential, data, objective) - hh.coefficients))
        for h, data in exact.items()
    }
    assert errors[0.1] < 0.06 * 0.5 ** (ORDERS[objective] - 1)
    measured = np.log2(errors[0.2] / errors[0.1])
    assert abs(measured - ORDERS[objective]) < 0.3, (objective, errors, measured)


def test_hnn_is_one_euler_step_and_closed_form_matches_lbfgs(hh, exact):
    data = exact[0.1]
    closed = baselines.fit(hh.potential, data, "hnn")
    iterative = baselines.fit(hh.potential, data, "hnn", method="lbfgs")
    euler = baselines.fit(hh.potential, data, "euler", method="lbfgs")
    np.testing.assert_allclose(iterative, closed, atol=1e-7)
    np.testing.assert_allclose(euler, closed, atol=1e-7)  # equal gaps: the same minimiser


def test_substeps_option_irregular_times(hh):
    """With dt, each gap takes ⌈gap/dt⌉ leapfrog steps: irregular sparse data still fit well."""
    rng = np.random.default_rng(0)
    times = np.cumsum(rng.uniform(0.3, 0.7, size=60))
    states = true_trajectory(
        hh.potential, hh.coefficients, hh.initial_state, times, dt=1e-3, integrator="yoshida4"
    )
    data = symplid.Observations(times, states)
    one_step = baselines.fit(hh.potential, data, "leapfrog")
    fine = baselines.fit(hh.potential, data, "leapfrog", dt=0.05)
    err_one = np.max(np.abs(one_step - hh.coefficients))
    err_fine = np.max(np.abs(fine - hh.coefficients))
    assert err_fine < 2e-3 and err_fine < 0.2 * err_one


def test_consistent_as_noisy_data_grow(hh):
    """Fixed gap 0.1, σ = 0.01: ten times more pairs, a clearly smaller error (median of 3)."""
    span = {200: 20.0, 2000: 200.0}
    errors = {}
    for n, t_end in span.items():
        times = 0.1 * np.arange(1, n + 1)
        assert times[-1] == pytest.approx(t_end)
        states = true_trajectory(
            hh.potential, hh.coefficients, hh.initial_state, times, dt=1e-3,
            integrator="yoshida4",
        )
        errs = []
        for seed in range(3):
            noise = np.random.default_rng(seed).normal(size=states.shape)
            data = symplid.Observations(times, states + 0.01 * noise)
            errs.append(np.max(np.abs(baselines.fit(hh.potential, data, "rk4") - hh.coefficients)))
        errors[n] = np.median(errs)
    assert errors[2000] < 0.5 * errors[200], errors


def test_registry_and_new_objective(hh, exact):
    assert set(ORDERS) <= set(baselines.OBJECTIVES.names())
    with pytest.raises(ValueError, match="did you mean 'leapfrog'"):
        baselines.fit(hh.potential, exact[0.2], "lepfrog")
    assert "yoshida4" in INTEGRATORS
    baselines.OBJECTIVES.register("yoshida4-test", baselines.step_objective("yoshida4"))
    try:
        coef = baselines.fit(hh.potential, exact[0.2], "yoshida4-test")
        assert np.max(np.abs(coef - hh.coefficients)) < 1e-3
    finally:
        baselines.OBJECTIVES.unregister("yoshida4-test")


def test_mlp_potential_fits_through_the_same_interface():
    """Any potential with the Potential interface: a tiny MLP on a harmonic oscillator."""
    from symplid.dynamics._neural import MLPPotential

    sho = symplid.get_system("harmonic")
    times = 0.1 * np.arange(1, 101)
    states = true_trajectory(sho.potential, sho.coefficients, sho.initial_state, times)
    U = MLPPotential(1, width=8, depth=1, seed=0)
    data = symplid.Observations(times, states)
    weights = baselines.fit(U, data, "leapfrog", maxiter=3000)
    assert weights.shape == (U.num_params,)
    q = np.linspace(-0.9, 0.9, 7)[None]
    np.testing.assert_allclose(np.asarray(U.gradient(q, weights))[0], q[0], atol=0.02)


def test_data_errors(hh, exact):
    data = exact[0.2]
    positions = symplid.Observations(data.times, data.values[:, :2])
    with pytest.raises(symplid.DataError, match="positions only"):
        baselines.fit(hh.potential, positions, "hnn")
    with pytest.raises(symplid.DataError, match="at least 2 observations"):
        baselines.fit(hh.potential, data.subset(slice(0, 1)), "rk4")
    values = np.array(data.values[:3])
    values[1, 0] = np.nan
    with pytest.raises(symplid.DataError, match="missing"):
        baselines.fit(hh.potential, symplid.Observations(data.times[:3], values), "euler")
    with pytest.raises(ValueError, match="method"):
        baselines.fit(hh.potential, data, "rk4", method="newton")
    with pytest.raises(ValueError, match="lstsq"):
        baselines.fit(hh.potential, data, "rk4", method="lstsq")


def test_missing_values_drop_their_pairs(hh, exact):
    data = exact[0.1]
    values = np.array(data.values)
    values[50, 3] = np.nan
    holed = symplid.Observations(data.times, values)
    pairs = baselines.Pairs(hh.potential, holed, None)
    assert pairs.num_pairs == data.num_times - 1 - 2 and pairs.num_dropped == 2
    coef = baselines.fit(hh.potential, holed, "leapfrog")
    assert np.max(np.abs(coef - hh.coefficients)) < 5e-3
