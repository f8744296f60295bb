"""Fitting in standardised coordinates (model.standardise) and reporting in the user's units.

The map q' = q/a, p' = p/a, c'_α = c_α a^{|α|−2}, variances over a² is an exact symmetry of
the model: the likelihood of the user's data is the standardised one times a^−N. A fit of
data scaled by 1000 must then give the unscaled fit's coefficients, mapped.
"""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import symplid
from symplid.workflow._compare import fit_candidates
from symplid.workflow._scaling import (
    Scaling,
    position_scale,
    resolve_standardise,
    scaling_for,
)
from symplid.workflow._settings import Settings, SettingsError, merge_overrides, resolve_for_data

SCALE = 1000.0


@pytest.fixture(scope="module")
def well():
    """The quartic double well, 20 full-state observations, and the same data × 1000."""
    system = symplid.get_system("double-well")
    obs = symplid.simulate(system, times=np.arange(1.0, 21.0), noise_std=0.05, seed=0)
    big = symplid.Observations(obs.times, obs.values * SCALE, obs.names)
    return system, obs, big


def _settings(x0, **extra) -> Settings:
    overrides = {"initial_state.x0": list(x0), "model.noise": "isotropic", "model.order": 4,
                 "map.num_starts": 2, "model.dt": 0.25, **extra}
    return merge_overrides(Settings(), overrides)


def test_likelihood_maps_exactly(well):
    """log p(y | θ) = log p'(y' | θ') − N log a for the standardised data and parameters."""
    system, obs, big = well
    s = resolve_for_data(_settings(system.initial_state * SCALE, **{"model.standardise": "on"}),
                         big)
    scaling = scaling_for(s, big)
    assert scaling.scale == pytest.approx(SCALE * position_scale(obs), rel=1e-12)
    model = symplid.HamiltonianModel(system.potential, noise="per-kind", backend="jax")
    theta_std = model.pack(system.coefficients * [1.0, 1.0, 1.1, 0.9], 1e-4, [0.01, 0.02])
    groups = model.param_groups
    theta_user = theta_std * scaling.factors(groups)
    # the quartic coefficient, a variance: a^{4-2}... mapped as written in the module docstring
    a = scaling.scale
    np.testing.assert_allclose(scaling.factors(groups), [a, 1.0, 1 / a, 1 / a**2, a**2, a**2,
                                                         a**2])
    x0 = system.initial_state * SCALE
    ll_user = model.log_likelihood(theta_user, big, x0, 1e-4 * a**2)
    ll_std = model.log_likelihood(theta_std, scaling.observations(big), x0 / a, 1e-4)
    expected = float(ll_std) + scaling.log_likelihood_shift(big)
    assert float(ll_user) == pytest.approx(expected, rel=1e-10)
    assert scaling.log_likelihood_shift(big) == -big.values.size * math.log(a)


def test_map_result_covariance_and_hessian_map_consistently():
    scaling = Scaling(7.0, (1, 2, 3))
    groups = ("coefficients",) * 3 + ("process_var", "obs_rel_var", "initial_state")
    f = scaling.factors(groups)
    np.testing.assert_allclose(f, [7.0, 1.0, 1 / 7.0, 49.0, 1.0, 7.0])
    rng = np.random.default_rng(0)
    root = rng.standard_normal((6, 6))
    cov = root @ root.T + np.eye(6)
    from symplid.inference.map._result import MapResult

    result = MapResult(np.ones(6), -3.0, True, "ok", 1, (), np.linalg.inv(cov), cov, False,
                       2.0, tuple("abcdef"))
    obs = symplid.Observations(np.arange(1.0, 4.0), np.ones((3, 2)), ("q1", "p1"))
    user = scaling.map_result(result, groups, obs)
    np.testing.assert_allclose(user.theta, f)
    np.testing.assert_allclose(np.linalg.inv(user.hessian), user.covariance, rtol=1e-10)
    assert user.log_evidence == pytest.approx(2.0 - 6 * math.log(7.0))
    assert user.log_posterior == pytest.approx(-3.0 - 6 * math.log(7.0) - np.sum(np.log(f)))


@pytest.mark.slow
def test_scaled_data_give_the_mapped_coefficients_and_order_four_converges(well):
    system, obs, big = well
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        unit = fit_candidates(obs, _settings(system.initial_state, **{"model.standardise": "on"}),
                              progress=False)[0]
        scaled = fit_candidates(big, _settings(system.initial_state * SCALE), progress=False)[0]
    assert scaled.settings.model.standardise == "on"  # "auto": a ≈ 1000 is far from 1
    assert scaled.map_result.success and unit.map_result.success
    degrees = np.array([1, 2, 3, 4])
    coeffs_unit = unit.map_result.theta[:4]
    coeffs_big = scaled.map_result.theta[:4]
    np.testing.assert_allclose(coeffs_big, coeffs_unit * SCALE ** (2.0 - degrees), rtol=1e-5)
    variances = slice(4, 6)
    np.testing.assert_allclose(scaled.map_result.theta[variances],
                               unit.map_result.theta[variances] * SCALE**2, rtol=1e-5)
    # the double well is found: U = −½q² + ¼q⁴ in the data's units
    assert coeffs_unit[1] == pytest.approx(-0.5, abs=0.05)
    assert coeffs_unit[3] == pytest.approx(0.25, abs=0.03)
    n = obs.values.size
    assert scaled.log_likelihood == pytest.approx(unit.log_likelihood - n * math.log(SCALE),
                                                  abs=1e-4)
    assert scaled.map_result.log_evidence == pytest.approx(
        unit.map_result.log_evidence - n * math.log(SCALE), abs=1e-3)


def test_auto_rule_and_errors(well):
    system, obs, big = well
    unit = resolve_for_data(_settings(system.initial_state), obs).model
    assert unit.standardise == "off"  # a ≈ 0.8: the data are fitted as given
    assert resolve_for_data(_settings(system.initial_state * SCALE), big).model.standardise == "on"
    # a model whose coefficients are not a polynomial's is left as it is, or refused when asked
    neural = SimpleNamespace(potential="neural", hamiltonian="separable", standardise="auto")
    assert resolve_standardise(neural, big) == "off"
    pendulum = SimpleNamespace(potential="polynomial", hamiltonian="pendulum", standardise="on")
    with pytest.raises(ValueError, match="not separable"):
        resolve_standardise(pendulum, big)
    with pytest.raises(SettingsError, match=r"model\.standardise"):
        merge_overrides(Settings(), {"model.standardise": "yes"})


@pytest.mark.slow
def test_fit_writes_the_run_in_the_data_units(well, tmp_path):
    """symplid fit on data × 1000: one line says it standardises, and the MAP, the draws and
    the run folder are in the data's units (U = −½q² + ¼q⁴ becomes −½q² + ¼·10⁻⁶ q⁴)."""
    from symplid.workflow._fit import fit
    from symplid.workflow._results import RunFolder

    system, _, big = well
    s = merge_overrides(Settings(), {
        "initial_state.x0": list(system.initial_state * SCALE), "model.order": 4,
        "model.dt": 0.25, "map.num_starts": 2, "sampler.num_iterations": 400,
        "sampler.burn_in": 200, "sampler.num_chains": 1,
    })
    notes: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        outcome = fit(big, s, out=tmp_path / "run", progress=False, status=notes.append)
    assert any("model.standardise" in n for n in notes)
    assert any("model.noise" in n for n in notes)  # q and p columns: one variance per kind
    theta = dict(zip(outcome.posterior.param_names, outcome.map_result.theta, strict=True))
    assert theta["c[q1^2]"] == pytest.approx(-0.5, abs=0.06)
    assert theta["c[q1^4]"] * SCALE**2 == pytest.approx(0.25, abs=0.03)
    assert 0.2 < theta["obs_var[q]"] / (0.05 * SCALE) ** 2 < 5
    draws = outcome.idata.posterior["c[q1^4]"].values * SCALE**2
    assert np.median(draws) == pytest.approx(0.25, abs=0.04)
    scale = outcome.summary["standardised_scale"]
    assert scale == pytest.approx(position_scale(big)) == outcome.idata.attrs["standardised_scale"]
    folder = RunFolder(tmp_path / "run", "r")
    assert folder.read_settings().model.standardise == "on"
    np.testing.assert_allclose(folder.read_map()["theta"], outcome.map_result.theta)


def test_a_model_states_its_own_scaling_law(well):
    """``HamiltonianModel.standardised(a)``, from Python without settings: the map θ = D θ'
    under which the likelihood of data × a is the standardised one times a^−N (the exact
    symmetry of the module docstring), the same D the fit's scaling uses."""
    system, obs, _ = well
    a = 37.0
    big = symplid.Observations(obs.times, obs.values * a, obs.names)
    model = symplid.HamiltonianModel(system.potential, noise="per-kind", backend="jax")
    to_user = model.standardised(a)
    np.testing.assert_array_equal(to_user.scale, Scaling(a, (1, 2, 3, 4)).factors(
        model.param_groups))
    np.testing.assert_allclose(system.potential.standardised(a), [a, 1.0, 1 / a, 1 / a**2],
                               rtol=1e-15)
    theta_std = model.pack(system.coefficients * [1.0, 1.0, 1.1, 0.9], 1e-4, [0.01, 0.02])
    theta_user = to_user.from_unconstrained(theta_std)
    x0 = system.initial_state
    ll_user = model.log_likelihood(theta_user, big, x0 * a, 1e-4 * a**2)
    ll_std = model.log_likelihood(theta_std, obs, x0, 1e-4)
    assert float(ll_user) == pytest.approx(float(ll_std) - big.values.size * math.log(a),
                                           rel=1e-10)
    with pytest.raises(ValueError, match="scaling law"):
        symplid.HamiltonianModel(symplid.FunctionPotential(lambda q, c: c[0] * q[0] ** 2, 1, 1),
                                 backend="jax").standardised(a)
