"""The compiled gradient of the likelihood equals ``jax.grad`` of the JAX tier.

The kernel's adjoint (Theorem 1, eqs 10–12: a forward sweep recording every gap, then one
reverse sweep with the adjoints of the update, the moments, Ψ and the Cholesky factor written
by hand) against reverse-mode autodiff of the JAX reference filter, an independent
implementation: near the truth and away from it on the paper's Hénon–Heiles workload, with
positions-only observation, a mass matrix and a basis of degree 6 (the adjoint's general
propagation), yoshida4 (and rk4 and Σ per substep, which keep the JAX tier's gradient),
diagonal and per-kind noise, and irregular times with missing values; its conventions off the
support (−∞ with a zero gradient for non-positive variances, NaN for a failed filter); ``vmap``
and ``jit``; and the Hessian, which stays the JAX tier's.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._potentials import Polynomial
from symplid.model import _kernel as compiled_kernel

pytestmark = pytest.mark.skipif(
    not compiled_kernel.available(),
    reason="the compiled kernel extension was not built (pip install builds it)",
)

RTOL = 1e-8  # per component (measured: ≤ 1e-10 on these cases)


def _assert_gradient_close(grad, expected) -> None:
    """Every component to RTOL relative, with a floor of 1e-12 of the largest component for
    components that cancel to near zero."""
    grad, expected = np.asarray(grad), np.asarray(expected)
    assert np.all(np.isfinite(expected))
    floor = 1e-12 * np.max(np.abs(expected), axis=-1, keepdims=True)
    error = np.abs(grad - expected) / (np.abs(expected) + floor)
    assert np.all(error <= RTOL), f"relative error {error.max():.2e}"


def _jax(model):
    """The same model on the JAX tier (``backend="auto"`` would pick the kernel itself)."""
    return dataclasses.replace(model, backend="jax")


def _grads(model, prepared, theta, x0):
    compiled = jax.grad(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))
    reference = jax.grad(lambda th: _jax(model).log_likelihood(th, prepared, x0))
    return compiled(theta), reference(theta)


SYSTEM = symplid.get_system("henon-heiles")


def _henon_heiles(observation="full", irregular=False, order=3, **options):
    """The paper's system and data (or a thinned, irregular copy with missing values), a
    model of it (its basis up to degree `order`), and θ at the truth."""
    potential = SYSTEM.potential if order == 3 else Polynomial(dim=2, order=order)
    model = symplid.HamiltonianModel(potential, dt=0.25, observation=observation, **options)
    if observation == "positions":  # positions 0.5 s apart (5 s apart the filter fails)
        data = symplid.simulate(SYSTEM, times=0.5 * np.arange(1, 41), seed=0)
        times, values = np.asarray(data.times), np.array(data.values)[:, :2]
    else:
        data = symplid.simulate(SYSTEM, seed=0)
        times, values = np.asarray(data.times), np.array(data.values)
    if irregular:  # gaps of 1 to 25 substeps, one value and one whole time missing
        times = np.cumsum([0.25, 1.0, 2.5, 0.5, 6.25, 1.75, 3.0, 0.25, 4.0])
        values = values[: times.size].copy()
        values[2, 1] = np.nan
        values[5, :] = np.nan
    prepared = model.prepare(symplid.Observations(times, values))
    coefficients = np.zeros(model.num_coefficients)  # the basis is ordered by degree
    coefficients[: SYSTEM.coefficients.size] = SYSTEM.coefficients
    theta = model.pack(
        coefficients,
        np.full(model.num_process_noise, 1e-6),
        np.full(model.num_obs_noise, 0.05**2),
    )
    return model, prepared, jnp.asarray(theta), SYSTEM.initial_state


CASES = {
    "paper": {},
    "positions": {"observation": "positions"},
    "mass-matrix": {"mass": ((2.0, 0.5), (0.5, 1.0))},
    "yoshida4": {"integrator": "yoshida4"},
    "rk4": {"integrator": "rk4"},  # the JAX tier's gradient (no compiled one for Runge–Kutta)
    "sigma-per-step": {"process_noise_per": "step"},  # the JAX tier's gradient too
    "diagonal": {"noise": "diagonal"},
    "per-kind": {"noise": "per-kind"},
    "irregular-masked": {"irregular": True},
    # 17 parameters; the general propagation (a mass matrix)
    "mass-diagonal": {"mass": ((2.0, 0.5), (0.5, 1.0)), "noise": "diagonal"},
    # 29 parameters; the general propagation (no compile-time table for degree 6)
    "degree-6": {"order": 6},
}


@pytest.mark.parametrize("name", CASES)
def test_gradient_equals_jax_grad(name):
    """Near the truth and at θ moved off it, the compiled gradient is jax.grad's to 1e-8."""
    model, prepared, theta, x0 = _henon_heiles(**CASES[name])
    assert compiled_kernel.describe(model, prepared)["likelihood_backend"] == "compiled"
    rng = np.random.default_rng(len(name))
    for point in (theta, theta * (1.0 + 0.02 * rng.standard_normal(theta.shape))):
        grad, expected = _grads(model, prepared, point, x0)
        _assert_gradient_close(grad, expected)


def test_value_and_grad_is_one_call_with_the_kernels_value():
    """value_and_grad's value is the compiled value (to rounding), its gradient jax.grad's,
    and the gradient goes through the compiled gradient's custom call, not the JAX filter."""
    model, prepared, theta, x0 = _henon_heiles()

    def f(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0)

    value, grad = jax.value_and_grad(f)(theta)
    assert abs(value - f(theta)) <= 1e-12 * abs(f(theta))
    _assert_gradient_close(grad, _grads(model, prepared, theta, x0)[1])
    program = jax.jit(jax.value_and_grad(f)).lower(theta).as_text()
    assert compiled_kernel.GRADIENT_TARGET_NAME in program
    assert "while" not in program  # no JAX filter (its gap loop) in the program


@pytest.mark.parametrize("integrator, compiled", [("yoshida4", True), ("rk2-midpoint", False)])
def test_which_gradient_a_propagator_gets(integrator, compiled):
    """Compositions get the compiled gradient; Runge–Kutta methods keep the JAX tier's."""
    model, prepared, theta, x0 = _henon_heiles(integrator=integrator)
    program = jax.jit(
        jax.grad(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))
    ).lower(theta).as_text()
    assert (compiled_kernel.GRADIENT_TARGET_NAME in program) == compiled


def test_vmap_of_the_gradient_equals_a_loop():
    model, prepared, theta, x0 = _henon_heiles()
    thetas = theta * (1.0 + 0.01 * np.random.default_rng(1).standard_normal((5, theta.size)))

    def grad(th):
        return jax.grad(lambda t: compiled_kernel.log_likelihood(model, prepared, t, x0))(th)

    batched = jax.jit(jax.vmap(grad))(thetas)
    for row, th in zip(batched, thetas, strict=True):
        np.testing.assert_array_equal(row, grad(th))
        _assert_gradient_close(row, _grads(model, prepared, th, x0)[1])


def test_hessian_is_the_jax_tiers():
    """Second derivatives are the JAX reference's: jax.hessian of the compiled likelihood
    equals jax.hessian of the JAX tier."""
    model, prepared, theta, x0 = _henon_heiles()
    compiled = jax.hessian(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))
    reference = jax.hessian(lambda th: _jax(model).log_likelihood(th, prepared, x0))
    np.testing.assert_allclose(compiled(theta), reference(theta), rtol=1e-9, atol=1e-9)


def test_off_the_support_matches_the_jax_tier():
    """As jax.grad of the JAX tier: non-positive variances give −∞ and a zero gradient; a NaN
    in θ, or a filter that fails (a coefficient so large the trajectories blow up), −∞ and
    NaN."""
    model, prepared, theta, x0 = _henon_heiles()
    bad_thetas = [theta.at[model.num_coefficients].set(0.0),
                  theta.at[model.num_params - 1].set(-1e-3),
                  theta.at[model.num_params - 1].set(np.nan),
                  theta.at[0].set(np.nan),
                  theta.at[0].set(50.0)]
    for bad in bad_thetas:
        value, grad = jax.value_and_grad(
            lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0)
        )(bad)
        expected_value, expected = jax.value_and_grad(
            lambda th: _jax(model).log_likelihood(th, prepared, x0)
        )(bad)
        assert value == expected_value == -np.inf
        np.testing.assert_array_equal(np.isnan(grad), np.isnan(expected))
        np.testing.assert_array_equal(np.nan_to_num(grad), np.nan_to_num(expected))


def test_gradient_in_x0_stays_the_jax_tiers():
    """Derivatives in anything but θ (here x0) are the reference's."""
    model, prepared, theta, x0 = _henon_heiles()
    x0 = jnp.asarray(x0)
    compiled = jax.grad(lambda x: compiled_kernel.log_likelihood(model, prepared, theta, x))
    reference = jax.grad(lambda x: _jax(model).log_likelihood(theta, prepared, x))
    np.testing.assert_allclose(compiled(x0), reference(x0), rtol=1e-10, atol=1e-10)


def compiled_gradients() -> list[list[float]]:
    """The compiled gradient at the truth for the paper's case and off it."""
    model, prepared, theta, x0 = _henon_heiles()
    grad = jax.grad(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))
    return [np.asarray(grad(point)).tolist() for point in (theta, 1.01 * theta)]


@pytest.mark.slow
def test_the_general_propagation_gives_the_same_gradient():
    """With SYMPLID_KERNEL_ISA=baseline the adjoint propagates the paper's model by its
    general (run-time) force program instead of the compile-time one (AVX2): same gradient."""
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1])\n"
        "import test_kernel_gradient as t\n"
        "from symplid.model import _kernel as kernel\n"
        "print(json.dumps({'isa': kernel.instruction_set(), 'grads': t.compiled_gradients()}))\n"
    )
    env = dict(os.environ, SYMPLID_KERNEL_ISA="baseline", JAX_ENABLE_X64="1")
    folder = os.path.dirname(os.path.abspath(__file__))
    done = subprocess.run(
        [sys.executable, "-c", code, folder], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["isa"] == "baseline"
    model, prepared, theta, x0 = _henon_heiles()
    for point, grad in zip((theta, 1.01 * theta), result["grads"], strict=True):
        _assert_gradient_close(grad, _grads(model, prepared, point, x0)[1])
        np.testing.assert_allclose(grad, compiled_gradients()[0 if point is theta else 1],
                                   rtol=1e-10)
