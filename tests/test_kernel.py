"""The compiled likelihood kernel equals the JAX reference filter (Theorem 1, eqs 10–12).

Random θ over d = 1..3, orders 2..5, every integrator, irregular gaps (2 to 5 substeps),
missing values, full-state and positions-only observation, isotropic and diagonal noise, Σ per
gap and per substep, with and without a mass matrix; θ far from the truth, where the
likelihood is rugged and the reference itself is ill-conditioned; −∞ for non-positive
variances; vmap
equals a loop; the kernel runs inside a compiled ``fori_loop``; the gradient is the JAX tier's;
and without the shared library everything falls back to JAX with one warning.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._integrators import symplectic_integrator
from symplid.dynamics._potentials import FunctionPotential, Polynomial
from symplid.model import _kernel as compiled_kernel

pytestmark = pytest.mark.skipif(
    not compiled_kernel.available(),
    reason="the compiled kernel extension was not built (pip install builds it)",
)

TIMES = np.array([0.7, 1.5, 2.0, 3.1, 3.6])  # gaps of 3, 4, 2, 5 and 2 substeps at dt = 0.25
TOL = 1e-12

_THREE_OF_FOUR = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.5, 0.0), (0.0, 0.0, 0.0, 1.0))
_ONE_OF_SIX = ((1.0, 1.0, 0.0, 0.0, 0.0, 0.5),)

# (d, order, integrator, noise, Σ per, observation, mass): every integrator, d = 1..3,
# orders 2..5, and each option at least once, observation matrices included.
CASES = [
    (1, 2, "leapfrog", "isotropic", "gap", "full", None),
    (2, 3, "yoshida4", "diagonal", "step", "positions", None),
    (3, 4, "euler", "isotropic", "gap", "full", (1.0, 2.0, 3.0)),
    (1, 5, "rk2-midpoint", "diagonal", "gap", "full", None),
    (2, 4, "rk2-heun", "isotropic", "step", "full", ((2.0, 0.5), (0.5, 1.0))),
    (3, 2, "rk4", "diagonal", "gap", "positions", None),
    (2, 5, "leapfrog", "isotropic", "gap", "full", None),
    # general linear observations (neither the state nor its positions): run-time sizes
    (2, 3, "leapfrog", "isotropic", "gap", _THREE_OF_FOUR, None),
    (3, 2, "rk4", "diagonal", "step", _ONE_OF_SIX, (1.0, 2.0, 3.0)),
]


def _problem(case, rng: np.random.Generator, num_theta: int = 9):
    d, order, integrator, noise, per, observation, mass = case
    model = symplid.HamiltonianModel(
        Polynomial(d, order),
        integrator=integrator,
        dt=0.25,
        noise=noise,
        process_noise_per=per,
        observation=observation if isinstance(observation, str) else np.array(observation),
        mass=mass,
    )
    values = 0.3 * rng.standard_normal((TIMES.size, model.obs_dim))
    values[1, 0] = np.nan  # one missing component
    values[3, :] = np.nan  # one time with nothing observed
    prepared = model.prepare(symplid.Observations(TIMES, values))
    return (
        model,
        prepared,
        _random_thetas(model, rng, num_theta),
        0.2 * rng.standard_normal(model.state_dim),
    )


def _random_thetas(model, rng: np.random.Generator, count: int) -> jax.Array:
    """Random coefficients around a confining quadratic bowl, random positive variances."""
    potential = model.hamiltonian
    bowl = np.array([0.5 if sum(e) == 2 and max(e) == 2 else 0.0 for e in potential.exponents])
    thetas = [
        model.pack(
            bowl + 0.05 * rng.standard_normal(potential.num_params),
            np.exp(rng.uniform(-8, -3, model.num_process_noise)),
            np.exp(rng.uniform(-5, -2, model.num_obs_noise)),
        )
        for _ in range(count)
    ]
    return jnp.asarray(np.array(thetas))


def _jax(model):
    """The same model on the JAX tier (``backend="auto"`` would pick the kernel itself)."""
    return dataclasses.replace(model, backend="jax")


def _close(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return bool(np.all(np.abs(a - b) <= TOL * np.maximum(1.0, np.abs(b))))


def _assert_equals_reference(model, prepared, thetas, x0):
    """The kernel's values, for the batch and for its first θ alone, are the JAX filter's."""
    P0 = 1e-4 * np.eye(model.state_dim)
    reference = jax.vmap(lambda th: _jax(model).log_likelihood(th, prepared, x0, P0))(thetas)
    batched = jax.vmap(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0, P0))(
        thetas
    )
    assert np.all(np.isfinite(reference))
    assert _close(batched, reference)
    single = compiled_kernel.log_likelihood(model, prepared, thetas[0], x0, P0)
    assert _close(single, reference[0])


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"d{c[0]}-l{c[1]}-{c[2]}-{c[3]}-{c[4]}")
def test_equals_jax_reference(case):
    """Nine random θ (a batch of eight and a single) and one by one equal the JAX filter."""
    rng = np.random.default_rng(CASES.index(case))
    _assert_equals_reference(*_problem(case, rng))


# Compositions of leapfrog steps the library does not register: four weights (the most whose
# merged kicks the kernel folds into scaled coefficient tables) and Suzuki's five (more: the
# kernel kicks with the force instead).
_SUZUKI = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
COMPOSITIONS = {
    "four-weights": symplectic_integrator("four-weights", 2, (0.2, 0.3, 0.3, 0.2), "test"),
    "suzuki5": symplectic_integrator(
        "suzuki5", 4, (_SUZUKI, _SUZUKI, 1.0 - 4.0 * _SUZUKI, _SUZUKI, _SUZUKI), "test"
    ),
}


@pytest.mark.parametrize(
    "d, order, name",
    [(1, 4, "four-weights"), (2, 3, "suzuki5"), (3, 4, "suzuki5"), (3, 4, "four-weights")],
)
def test_custom_compositions_equal_jax_reference(d, order, name):
    """A user's composition, with few weights or many, equals the JAX filter."""
    case = (d, order, COMPOSITIONS[name], "isotropic", "gap", "full", None)
    _assert_equals_reference(*_problem(case, np.random.default_rng(10 * d + order)))


@pytest.fixture(scope="module")
def paper():
    """The paper's workload: Hénon–Heiles, cubic U, leapfrog dt = 0.25, 20 observations."""
    system = symplid.get_system("henon-heiles")
    model = symplid.HamiltonianModel(system.potential, integrator="leapfrog", dt=0.25)
    prepared = model.prepare(symplid.simulate(system, seed=0))
    theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
    return model, prepared, theta, system.initial_state


def test_paper_workload_and_invalid_variances(paper):
    model, prepared, theta, x0 = paper
    reference = _jax(model).log_likelihood(theta, prepared, x0)
    assert _close(compiled_kernel.log_likelihood(model, prepared, theta, x0), reference)
    for bad in (0.0, -1e-3, np.nan):
        for index in (model.num_coefficients, model.num_params - 1):
            value = compiled_kernel.log_likelihood(model, prepared, theta.at[index].set(bad), x0)
            assert value == -np.inf


@pytest.mark.parametrize("integrator", ["leapfrog", "yoshida4", "rk2-midpoint", "rk4"])
def test_far_from_truth_equals_jax_to_its_conditioning(integrator):
    """32 θ up to ~e^±1 from the truth on the paper's workload (a third give −∞, a third are
    so rugged that the JAX filter moves by more than 1e-13 relative when θ moves by 1e-14):
    the kernel (one θ and batched) equals the JAX filter to 1e-12 relative, or to ten times
    the reference's own change under that perturbation where it is larger; −∞ where it is."""
    system = symplid.get_system("henon-heiles")
    model = symplid.HamiltonianModel(system.potential, integrator=integrator, dt=0.25)
    data = symplid.simulate(system, seed=0)
    prepared, x0 = model.prepare(data), system.initial_state
    theta = jnp.asarray(model.pack(system.coefficients, 1e-6, 0.05**2))
    thetas = theta * jnp.exp(0.3 * jax.random.normal(jax.random.key(3), (32, theta.shape[0])))
    reference = jax.vmap(lambda th: _jax(model).log_likelihood(th, prepared, x0))
    want = np.asarray(reference(thetas))
    moved = np.zeros_like(want)
    for k in range(3):
        nudge = 1.0 + 1e-14 * jax.random.normal(jax.random.key(10 + k), thetas.shape)
        moved = np.maximum(moved, np.abs(np.asarray(reference(thetas * nudge)) - want))
    kernel = jax.vmap(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))
    batched = np.asarray(kernel(thetas))
    single = np.array([compiled_kernel.log_likelihood(model, prepared, th, x0) for th in thetas])
    finite = np.isfinite(want)
    strict = moved <= 1e-13 * np.abs(want)
    assert 8 <= np.sum(finite) < 32 and np.sum(finite & strict) >= 4  # both regimes present
    tolerance = np.maximum(TOL * np.maximum(1.0, np.abs(want)), 10.0 * moved)
    for got in (batched, single):
        assert np.array_equal(np.isfinite(got), finite)
        assert np.all(got[~finite] == -np.inf)
        assert np.all(np.abs(got - want)[finite] <= tolerance[finite])


def test_vmap_over_16_equals_loop_and_shared_x0(paper):
    model, prepared, theta, x0 = paper
    thetas = theta * (1 + 1e-2 * jax.random.normal(jax.random.key(1), (16, theta.shape[0])))
    thetas = thetas.at[3, -1].set(-1.0)  # an invalid member inside a group of eight

    def fn(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0)

    batched = jax.jit(jax.vmap(fn))(thetas)
    looped = jnp.stack([fn(th) for th in thetas])
    assert batched[3] == -np.inf
    np.testing.assert_array_equal(batched, looped)
    # Batching over the initial state as well (per-member x0) still matches one by one.
    x0s = x0 + 1e-3 * jax.random.normal(jax.random.key(2), (16, x0.shape[0]))
    both = jax.vmap(lambda th, m: compiled_kernel.log_likelihood(model, prepared, th, m))(
        thetas, x0s
    )
    single = compiled_kernel.log_likelihood(model, prepared, thetas[5], x0s[5])
    assert both[5] == single


def test_inside_compiled_fori_loop(paper):
    model, prepared, theta, x0 = paper

    @jax.jit
    def total(th):
        def body(i, acc):
            return acc + compiled_kernel.log_likelihood(model, prepared, th * (1 + 1e-3 * i), x0)

        return jax.lax.fori_loop(0, 4, body, 0.0)

    expected = sum(
        _jax(model).log_likelihood(theta * (1 + 1e-3 * i), prepared, x0) for i in range(4)
    )
    assert _close(total(theta), expected)


def test_gradient_equals_jax_tier(paper):
    model, prepared, theta, x0 = paper
    grad = jax.grad(lambda th: compiled_kernel.log_likelihood(model, prepared, th, x0))(theta)
    expected = jax.grad(lambda th: _jax(model).log_likelihood(th, prepared, x0))(theta)
    np.testing.assert_allclose(grad, expected, rtol=1e-12, atol=1e-12)


def test_unsupported_models_use_jax(paper):
    _, prepared, _, _ = paper
    potential = FunctionPotential(lambda q, c: c[0] * jnp.sum(q**2), dim=2, num_params=1)
    model = symplid.HamiltonianModel(potential, integrator="leapfrog", dt=0.25)
    assert "FunctionPotential" in compiled_kernel.unsupported_reason(model, prepared)
    nonlinear = symplid.HamiltonianModel(Polynomial(2, 3), observation=lambda x: x[:2] ** 2)
    assert "function" in compiled_kernel.unsupported_reason(nonlinear)
    assert compiled_kernel.describe(nonlinear)["likelihood_backend"] == "jax"
    paper_model = symplid.HamiltonianModel(Polynomial(2, 3), integrator="leapfrog", dt=0.25)
    assert compiled_kernel.unsupported_reason(paper_model, prepared) is None
    assert compiled_kernel.describe(paper_model)["likelihood_backend"] == "compiled"
    small = model.prepare(symplid.Observations(TIMES, np.zeros((TIMES.size, 4))))
    th = jnp.array([0.5, 1e-4, 1e-2])
    assert compiled_kernel.log_likelihood(model, small, th, np.zeros(4)) == pytest.approx(
        float(model.log_likelihood(th, small, np.zeros(4))), rel=1e-14
    )


def test_fallback_without_library(paper, monkeypatch):
    """A missing shared library: the JAX result, and one warning however many calls."""
    model, prepared, theta, x0 = paper
    monkeypatch.setattr(compiled_kernel._Library, "handle", None)
    monkeypatch.setattr(compiled_kernel._Library, "error", "pretend it was not built")
    monkeypatch.setattr(compiled_kernel._Library, "warned", False)
    assert not compiled_kernel.available()
    assert compiled_kernel.describe(model, prepared)["likelihood_backend"] == "jax"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = compiled_kernel.log_likelihood(model, prepared, theta, x0)
        second = compiled_kernel.log_likelihood(model, prepared, theta, x0)
    assert len([w for w in caught if "compiled likelihood kernel" in str(w.message)]) == 1
    expected = model.log_likelihood(theta, prepared, x0)
    assert first == expected and second == expected


def test_loader_failure_is_reported(monkeypatch):
    """A library that cannot be found leaves available() False with the reason kept."""
    monkeypatch.setattr(compiled_kernel, "_library_path", lambda: None)
    monkeypatch.setattr(compiled_kernel._Library, "loaded", False)
    monkeypatch.setattr(compiled_kernel._Library, "handle", None)
    monkeypatch.setattr(compiled_kernel._Library, "error", None)
    assert not compiled_kernel.available()
    assert "not built" in compiled_kernel._Library.error
