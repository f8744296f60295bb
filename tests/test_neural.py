"""Neural potentials (Equinox MLP) and their MAP + Gauss–Newton Laplace approximation."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._integrators import get_integrator, make_dynamics
from symplid.dynamics._neural import MLPPotential
from symplid.dynamics._trajectory import propagate
from symplid.inference.map._neural import find_map_neural, ggn_precision, neural_posterior


@pytest.fixture(scope="module")
def mlp():
    return MLPPotential(dim=2, width=16, depth=2, seed=3)


def test_layout_names_and_initial_weights(mlp):
    assert mlp.num_params == 2 * 16 + 16 + 16 * 16 + 16 + 16
    assert len(mlp.param_names) == mlp.num_params == len(set(mlp.param_names))
    assert mlp.param_names[:3] == ("w0[0,0]", "w0[0,1]", "w0[1,0]")
    assert mlp.param_names[32] == "b0[0]" and mlp.param_names[-1] == "w2[0,15]"
    w = mlp.initial_coefficients()
    w[0] = 123.0  # a copy
    assert mlp.initial_coefficients()[0] != 123.0
    net = mlp.network(mlp.initial_coefficients())
    w1 = mlp.initial_coefficients()[48:304]
    np.testing.assert_array_equal(np.ravel(net.layers[1].weight), w1)
    assert isinstance(mlp, symplid.Potential)
    np.testing.assert_array_equal(
        MLPPotential(2, 16, 2, seed=3).initial_coefficients(), mlp.initial_coefficients()
    )
    with pytest.raises(ValueError, match="width"):
        MLPPotential(2, width=0)
    with pytest.raises(ValueError, match="did you mean 'tanh'"):
        MLPPotential(2, activation="tahn")
    with pytest.raises(ValueError, match="weights"):
        mlp.value(jnp.zeros(2), jnp.zeros(3))


def test_force_is_the_gradient_of_the_energy(mlp):
    w = jnp.asarray(mlp.initial_coefficients()) * 1.7
    q = jnp.asarray(np.random.default_rng(0).normal(size=(2, 5, 3)))
    force = mlp.gradient(q, w)
    assert force.shape == q.shape and mlp.value(q, w).shape == (5, 3)
    auto = jax.vmap(jax.vmap(jax.grad(lambda x: mlp.value(x, w)), 1, 1), 2, 2)(q)
    np.testing.assert_allclose(force, auto, rtol=1e-12, atol=1e-14)
    x = q[:, 0, 0]
    eps = 1e-6
    fd = [
        (mlp.value(x + eps * e, w) - mlp.value(x - eps * e, w)) / (2 * eps) for e in jnp.eye(2)
    ]
    np.testing.assert_allclose(mlp.gradient(x, w), jnp.stack(fd), rtol=1e-7, atol=1e-9)


def test_leapfrog_propagator_is_symplectic(mlp):
    """JᵀΩJ = Ω for Ψ = three leapfrog substeps with the MLP force (eqs 5–6, 14)."""
    w = jnp.asarray(mlp.initial_coefficients())
    dynamics = make_dynamics(mlp, w)
    leapfrog = get_integrator("leapfrog")

    def psi(x):
        q, p = propagate(leapfrog, dynamics, x[:2], x[2:], 0.25, 3, 3, masked=False)
        return jnp.concatenate([q, p])

    J = jax.jacfwd(psi)(jnp.array([0.2, -0.25, 0.3, -0.25]))
    omega = jnp.block([[jnp.zeros((2, 2)), jnp.eye(2)], [-jnp.eye(2), jnp.zeros((2, 2))]])
    np.testing.assert_allclose(J.T @ omega @ J, omega, atol=1e-10)
    assert not np.allclose(J, np.eye(4), atol=1e-3)  # the map is not trivial


def test_plugs_into_the_model_and_posterior(mlp):
    hh = symplid.get_system("henon-heiles")
    data = symplid.simulate(hh, seed=0)
    model = symplid.HamiltonianModel(mlp, "leapfrog", dt=0.25)
    post = neural_posterior(model, data, x0=hh.initial_state, weight_scale=0.5)
    assert post.priors[0] == symplid.Normal(0.0, 0.5)
    theta = np.concatenate([mlp.initial_coefficients(), [1e-4, 2.5e-3]])
    assert np.isfinite(float(post.log_density(theta)))


def test_import_symplid_does_not_import_equinox():
    code = "import sys, symplid; print('equinox' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_gauss_newton_laplace_agrees_with_the_exact_hessian():
    """A tiny MLP (width 8, depth 1) fitted to a harmonic oscillator: the GGN variances of the
    weights against the inverse of the exact Hessian (central differences of the compiled
    gradient) at the same MAP.

    Not against NUTS: an MLP posterior has exact symmetries (a tanh unit's sign flip, the
    permutation of units), so it is multimodal with identical modes, and a Laplace
    approximation around one mode is not comparable with posterior variances that mix them.
    The weights pinned by the data differ by the residual curvature GGN drops (up to a factor
    2 here); those the prior decides agree closely.
    """
    sho = symplid.get_system("harmonic")
    data = symplid.simulate(sho, times=0.5 * np.arange(1, 41), noise_std=0.05, seed=0)
    U = MLPPotential(1, width=8, depth=1, seed=0)
    model = symplid.HamiltonianModel(U, "leapfrog", dt=0.25)
    post = neural_posterior(model, data, x0=sho.initial_state, weight_scale=1.0)
    fit = find_map_neural(
        post, adam_steps=300, learning_rate=2e-2, lbfgs_steps=500, laplace=None, polish="scipy"
    )
    assert fit.history[-1] < fit.history[0] - 50
    q = np.linspace(-0.8, 0.8, 5)[None]
    np.testing.assert_allclose(U.gradient(q, fit.theta[: U.num_params])[0], q[0], atol=0.1)

    nc = U.num_params
    precision = ggn_precision(post, fit.theta)
    assert np.all(np.linalg.eigvalsh(precision) > 0)
    value_and_grad = post.value_and_grad(unconstrained=True)  # weights: z = θ
    z = np.asarray(post.to_unconstrained(fit.theta))
    eps = 1e-5
    hessian = np.empty((nc, nc))
    for i in range(nc):
        e = np.zeros_like(z)
        e[i] = eps
        hessian[i] = -(value_and_grad(z + e)[1] - value_and_grad(z - e)[1])[:nc] / (2 * eps)
    hessian = 0.5 * (hessian + hessian.T)
    ratio = np.sqrt(np.diag(np.linalg.inv(precision[:nc, :nc])) / np.diag(np.linalg.inv(hessian)))
    assert np.all((ratio > 0.8) & (ratio < 2.0)), ratio
    assert np.sum(np.abs(ratio - 1) < 0.05) >= nc // 2, ratio


def test_fit_settings_are_checked(mlp):
    hh = symplid.get_system("henon-heiles")
    model = symplid.HamiltonianModel(mlp, "leapfrog", dt=0.25)
    post = neural_posterior(model, symplid.simulate(hh, seed=0), x0=hh.initial_state)
    with pytest.raises(ValueError, match="polish"):
        find_map_neural(post, polish="bfgs")
    with pytest.raises(ValueError, match="laplace"):
        find_map_neural(post, laplace="kfac")
    with pytest.raises(ValueError, match="init"):
        find_map_neural(post, init=np.zeros(3))
    with pytest.raises(ValueError, match="weight_scale"):
        neural_posterior(model, symplid.simulate(hh, seed=0), x0=hh.initial_state, weight_scale=0)
