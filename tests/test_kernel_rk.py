"""Runge–Kutta propagators in the compiled kernel equal the JAX reference filter (Theorem 1).

The kernel advances Runge–Kutta sigma points in register blocks when the processor has
AVX-512, the method two or four stages, there is no mass matrix and the potential's basis is
a common one (d ≤ 2 up to order 5, d = 3 up to order 3), and sweeps them through memory
otherwise (here a mass matrix, forward Euler, d = 4 and order 6). Both
paths must give the JAX backend's log-likelihood to rounding, for one θ (sigma points in the
lanes of one vector and a lone scalar lane) and for vmap batches of 8 and 16 (one vector per
sigma point, eight θ per vector).
"""

from __future__ import annotations

import dataclasses

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

TIMES = np.array([0.7, 1.5, 2.0, 3.1])  # gaps of 3, 4, 2 and 5 substeps at dt = 0.25
TOL = 1e-12  # as test_kernel.py

# (d, order, integrator, mass, Σ per): the register path (fixed tables) and the memory path.
CASES = [
    (2, 3, "rk2-midpoint", None, "gap"),  # the paper's cubic Hénon–Heiles basis
    (2, 3, "rk2-heun", ((2.0, 0.5), (0.5, 1.0)), "gap"),
    (2, 3, "rk4", None, "gap"),
    (2, 5, "rk2-midpoint", None, "step"),
    (1, 4, "euler", (1.5,), "gap"),
    (3, 2, "rk4", (1.0, 2.0, 3.0), "gap"),
    (3, 3, "rk4", None, "gap"),  # d = 3 in register blocks
    (1, 6, "rk2-midpoint", None, "gap"),  # order 6: no compile-time table
    (4, 2, "rk4", None, "step"),  # d = 4: no compile-time table
]


def _problem(case, rng: np.random.Generator):
    d, order, integrator, mass, per = case
    model = symplid.HamiltonianModel(
        Polynomial(d, order),
        integrator=integrator,
        dt=0.25,
        mass=mass,
        process_noise_per=per,
        backend="compiled",
    )
    values = 0.3 * rng.standard_normal((TIMES.size, model.obs_dim))
    values[1, 0] = np.nan  # one missing component
    prepared = model.prepare(symplid.Observations(TIMES, values))
    potential = model.hamiltonian
    bowl = np.array([0.5 if sum(e) == 2 and max(e) == 2 else 0.0 for e in potential.exponents])
    thetas = [
        model.pack(
            bowl + 0.05 * rng.standard_normal(potential.num_params),
            np.exp(rng.uniform(-8, -3)),
            np.exp(rng.uniform(-5, -2)),
        )
        for _ in range(16)
    ]
    x0 = 0.2 * rng.standard_normal(model.state_dim)
    return model, prepared, jnp.asarray(np.array(thetas)), x0


def _close(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return bool(np.all(np.abs(a - b) <= TOL * np.maximum(1.0, np.abs(b))))


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"d{c[0]}-l{c[1]}-{c[2]}-{c[4]}")
def test_runge_kutta_kernel_equals_jax(case):
    rng = np.random.default_rng(CASES.index(case))
    model, prepared, thetas, x0 = _problem(case, rng)
    reference = dataclasses.replace(model, backend="jax")
    assert model.likelihood_backend == "compiled" and reference.likelihood_backend == "jax"
    P0 = 1e-4 * np.eye(model.state_dim)

    def batch(m, ths):
        return jax.vmap(lambda th: m.log_likelihood(th, prepared, x0, P0))(ths)

    expected = batch(reference, thetas)
    assert np.all(np.isfinite(expected))
    assert _close(batch(model, thetas), expected)  # two groups of eight
    assert _close(batch(model, thetas[3:11]), expected[3:11])  # one group
    for i in (0, 7):  # one θ
        assert _close(model.log_likelihood(thetas[i], prepared, x0, P0), expected[i])
