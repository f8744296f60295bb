"""Neural models from settings and the command line: the "mlp" family, its prior, its MAP path."""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

import symplid
from symplid.cli import main
from symplid.dynamics._families import POTENTIAL_FAMILIES
from symplid.dynamics._neural import MLPPotential
from symplid.io import write_observations
from symplid.model._priors import Laplace, Normal
from symplid.workflow._fit import build_model, build_posterior, find_map_for
from symplid.workflow._model_builder import build_model_family, model_family
from symplid.workflow._settings import (
    Settings,
    SettingsError,
    merge_overrides,
    resolve_for_data,
    settings_from_dict,
)

X0 = [0.2, -0.25, 0.3, -0.25]


def mlp_settings(**model) -> Settings:
    return settings_from_dict({
        "model": {"potential": "mlp", "dt": 0.25, **model},
        "sampler": {"method": "nuts"},
        "initial_state": {"x0": X0},
    })


def test_mlp_family_builds_the_network_the_settings_describe():
    s = mlp_settings(width=5, depth=1, activation="softplus", network_seed=4)
    U = build_model_family(2, s.model)
    assert isinstance(U, MLPPotential)
    assert (U.width, U.depth, U.activation, U.seed) == (5, 1, "softplus", 4)
    assert U.num_params == 2 * 5 + 5 + 5  # w0, b0, w1 (no final bias)
    np.testing.assert_array_equal(
        U.initial_coefficients(), MLPPotential(2, 5, 1, seed=4).initial_coefficients()
    )
    assert POTENTIAL_FAMILIES.canonical("neural") == "mlp"
    h = settings_from_dict({"model": {"hamiltonian": "mlp", "width": 3, "depth": 1},
                            "sampler": {"method": "nuts"}})
    H = build_model_family(2, h.model)
    assert isinstance(H, symplid.MLPHamiltonian) and H.num_params == 3 * 4 + 3 + 3
    assert model_family(h.model).neural and h.priors.coefficients == Normal(0.0, 1.0)
    with pytest.raises(SettingsError, match=r"model\.width"):
        mlp_settings(width=0)
    with pytest.raises(SettingsError, match=r"did you mean 'mlp'\?"):
        settings_from_dict({"model": {"potential": "mpl"}})


def test_weight_prior_is_the_family_default_unless_given():
    assert mlp_settings().priors.coefficients == Normal(0.0, 1.0)
    assert Settings().priors.coefficients == Laplace(0.0, 10.0)  # the paper's, unchanged
    given = settings_from_dict({
        "model": {"potential": "mlp"}, "sampler": {"method": "nuts"},
        "priors": {"coefficients": {"prior": "normal", "scale": 0.3}},
    })
    assert given.priors.coefficients == Normal(0.0, 0.3)
    # switching the family on the command line switches an untouched default prior ...
    s = merge_overrides(Settings(), {"model.potential": "mlp", "sampler.method": "nuts"})
    assert s.priors.coefficients == Normal(0.0, 1.0)
    back = merge_overrides(s, {"model.potential": "polynomial"})
    assert back.priors.coefficients == Laplace(0.0, 10.0)
    # ... but not one the user chose
    kept = merge_overrides(given, {"model.potential": "polynomial"})
    assert kept.priors.coefficients == Normal(0.0, 0.3)
    both = merge_overrides(Settings(), {"model.potential": "mlp", "sampler.method": "nuts",
                                        "priors.coefficients.scale": 2.0})
    assert both.priors.coefficients == Laplace(0.0, 2.0)


def test_dram_is_refused_for_network_weights_in_one_line():
    with pytest.raises(SettingsError, match=r'use sampler\.method = "nuts"') as err:
        settings_from_dict({"model": {"potential": "mlp"}})
    assert "\n" not in str(err.value)


def test_parameter_count_warning_counts_the_built_model(hh_data):
    def count_warning(settings):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            resolve_for_data(settings, hh_data)
        return [str(w.message) for w in caught if "parameters" in str(w.message)]

    values = int(np.sum(hh_data.mask))  # 20 times × 4 components
    # q and p columns: model.noise = "auto" gives one process and two observation variances
    small = mlp_settings(width=8, depth=1)  # 8·2 + 8 + 8 weights + 3 variances = 35
    assert values > 35 and count_warning(small) == []
    big = mlp_settings(width=32, depth=1)  # 32·2 + 32 + 32 + 3 = 131
    assert values < 131
    (message,) = count_warning(big)
    assert f"131 parameters ('mlp') for {values} data values" in message
    assert count_warning(Settings(initial_state=small.initial_state)) == []  # 9 + 3


def test_a_non_separable_network_needs_a_non_separable_propagator(hh_data):
    def settings(integrator):
        return settings_from_dict({
            "model": {"hamiltonian": "mlp", "width": 3, "depth": 1, "integrator": integrator},
            "prediction": {"integrator": integrator},
            "sampler": {"method": "nuts"}, "initial_state": {"x0": X0}})

    with pytest.raises(SettingsError,
                       match=r"model\.integrator 'leapfrog' needs a separable H"):
        resolve_for_data(settings("leapfrog"), hh_data)
    assert resolve_for_data(settings("implicit-midpoint"), hh_data).model.hamiltonian == "mlp"


def test_fit_path_for_a_network_is_the_scalable_one(hh_data):
    s = merge_overrides(mlp_settings(width=4, depth=1),
                        {"map.adam_steps": 150, "map.lbfgs_steps": 3000})
    assert model_family(s.model).neural and not model_family(Settings().model).neural
    model = build_model(s, hh_data)
    posterior = build_posterior(s, hh_data, model)
    assert model.likelihood_backend == "jax"  # the compiled kernel is for polynomials
    result = find_map_for(s, posterior)
    assert isinstance(result, symplid.MapResult) and result.param_names == posterior.param_names
    # a climb to near a maximum: far higher than the start, the gradient mostly gone
    vg = posterior.value_and_grad(unconstrained=True)
    z0 = jnp.asarray(posterior.to_unconstrained(result.starts[0].start))
    z1 = jnp.asarray(posterior.to_unconstrained(result.theta))
    (v0, g0), (v1, g1) = vg(z0), vg(z1)
    assert float(v1) > float(v0) + 10.0
    assert np.linalg.norm(g1) < 1e-3 * np.linalg.norm(g0)
    # its Laplace covariance is the inverse of the Gauss–Newton precision, and the evidence
    # is log π(θ*) + ½ log det(2πΣ)
    from symplid.inference.map._neural import ggn_precision

    np.testing.assert_allclose(
        np.linalg.inv(ggn_precision(posterior, result.theta)), result.covariance,
        rtol=1e-6, atol=1e-12,
    )
    _, logdet = np.linalg.slogdet(2 * np.pi * result.covariance)
    assert result.log_evidence == pytest.approx(result.log_posterior + 0.5 * logdet)


def test_cli_refuses_dram_and_names_the_option(tmp_path):
    write_observations(symplid.simulate("henon-heiles"), tmp_path / "hh.csv")
    out = CliRunner().invoke(main, ["fit", str(tmp_path / "hh.csv"), "--out",
                                    str(tmp_path / "run"), "--potential", "mlp", "--x0",
                                    ",".join(map(str, X0))])
    assert out.exit_code == 2
    assert "--method nuts" in out.output and "Traceback" not in out.output
    bad = CliRunner().invoke(main, ["fit", str(tmp_path / "hh.csv"), "--out",
                                    str(tmp_path / "run"), "--potential", "mpl"])
    assert bad.exit_code == 2 and "mlp" in bad.output


# ----------------------------------------------------------------------------- MLPHamiltonian
@pytest.fixture(scope="module")
def mlp_h():
    return symplid.MLPHamiltonian(dim=2, width=6, depth=1, seed=2)


def test_mlp_hamiltonian_gradients_are_those_of_its_value(mlp_h):
    import jax

    from symplid.dynamics._hamiltonians import is_hamiltonian

    assert is_hamiltonian(mlp_h) and mlp_h.num_params == 6 * 4 + 6 + 6
    assert len(set(mlp_h.param_names)) == mlp_h.num_params
    w = jnp.asarray(mlp_h.initial_coefficients()) * 1.5
    rng = np.random.default_rng(1)
    q, p = jnp.asarray(rng.normal(size=(2, 3))), jnp.asarray(rng.normal(size=(2, 3)))
    assert mlp_h.value(q, p, w).shape == (3,) and mlp_h.grad_q(q, p, w).shape == (2, 3)
    for k in range(3):
        gq, gp = jax.grad(lambda a, b: mlp_h.value(a, b, w), (0, 1))(q[:, k], p[:, k])
        np.testing.assert_allclose(mlp_h.grad_q(q, p, w)[:, k], gq, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(mlp_h.grad_p(q, p, w)[:, k], gp, rtol=1e-12, atol=1e-14)
    # and central differences, which share nothing with autodiff
    eps = 1e-6
    x, y = q[:, 0], p[:, 0]
    fd_p = [(mlp_h.value(x, y + eps * e, w) - mlp_h.value(x, y - eps * e, w)) / (2 * eps)
            for e in jnp.eye(2)]
    np.testing.assert_allclose(mlp_h.grad_p(x, y, w), jnp.stack(fd_p), rtol=1e-6, atol=1e-9)
    # non-separable: ∂H/∂p depends on q
    assert not np.allclose(mlp_h.grad_p(q[:, :1], p[:, :1], w),
                           mlp_h.grad_p(q[:, 1:2], p[:, :1], w))


def test_mlp_hamiltonian_model_likelihood_and_symplectic_propagator(mlp_h, hh_data):
    import jax

    from symplid.dynamics._integrators import make_dynamics
    from symplid.dynamics._trajectory import propagate

    model = symplid.HamiltonianModel(mlp_h, integrator="implicit-midpoint", dt=0.5)
    assert model.likelihood_backend == "jax"
    theta = model.pack(0.3 * mlp_h.initial_coefficients(), 1e-4, 0.05**2)
    ll = model.log_likelihood(theta, hh_data, X0, 1e-8)
    assert np.isfinite(float(ll))
    # Ψ over one gap (3 implicit-midpoint steps) of a strongly non-linear H: JᵀΩJ = Ω
    w = jnp.asarray(3.0 * mlp_h.initial_coefficients())
    dyn = make_dynamics(mlp_h, w, None)

    def flow(x):
        q, p = propagate(model.integrator, dyn, x[:2], x[2:], jnp.asarray(0.4),
                         jnp.asarray(3), 3)
        return jnp.concatenate([q, p])

    J = jax.jacfwd(flow)(jnp.asarray(X0))
    omega = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.eye(2), np.zeros((2, 2))]])
    np.testing.assert_allclose(J.T @ omega @ J, omega, atol=1e-8)
    # forward Euler on the same H breaks it (the check can fail)
    euler = symplid.HamiltonianModel(mlp_h, integrator="euler", dt=0.5).integrator

    def flow_euler(x):
        q, p = propagate(euler, dyn, x[:2], x[2:], jnp.asarray(0.4), jnp.asarray(3), 3)
        return jnp.concatenate([q, p])

    J1 = jax.jacfwd(flow_euler)(jnp.asarray(X0))
    assert np.max(np.abs(J1.T @ omega @ J1 - omega)) > 1e-4
