"""Every instruction-set variant of the compiled kernel gives the same numbers.

The kernel is compiled for AVX-512, AVX2 and the baseline target, each in its own translation
unit, with floating-point contraction (fused multiply-adds where the instruction set has
them), and the widest variant the processor supports runs. ``SYMPLID_KERNEL_ISA`` selects a
narrower one, read once per process: a subprocess evaluates a few models with each narrower
variant, and its values must equal this process's (the widest variant's) and the JAX tier's
to 1e-12 relative (not bit for bit: the variants round differently). The models cover the
AVX-512 register path (the paper's leapfrog, RK4, d = 3) and the general path (a mass matrix,
forward Euler, d = 3 at degree 4), for one θ and a vmap batch of eight.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

import symplid
from symplid.dynamics._potentials import Polynomial
from symplid.model import _kernel as compiled_kernel

pytestmark = pytest.mark.skipif(
    not compiled_kernel.available(),
    reason="the compiled kernel extension was not built (pip install builds it)",
)

# (d, order, integrator, mass): register path first, then the general path.
CASES = [
    (2, 3, "leapfrog", None),
    (2, 3, "rk4", None),
    (3, 3, "yoshida4", None),
    (2, 3, "leapfrog", (2.0, 0.5)),
    (1, 4, "euler", None),
    (3, 4, "rk2-midpoint", None),
]
TIMES = np.array([0.7, 1.5, 2.0, 3.1, 3.6])  # gaps of 3, 4, 2, 5 and 2 substeps at dt = 0.25


def _problem(case):
    d, order, integrator, mass = case
    model = symplid.HamiltonianModel(
        Polynomial(d, order), integrator=integrator, dt=0.25, mass=mass
    )
    rng = np.random.default_rng(d * 100 + order)
    data = symplid.Observations(TIMES, 0.3 * rng.standard_normal((TIMES.size, 2 * d)))
    exponents = model.hamiltonian.exponents  # a confining quadratic bowl, perturbed
    bowl = np.array([0.5 if sum(e) == 2 and max(e) == 2 else 0.0 for e in exponents])
    coefficients = bowl + 0.05 * rng.standard_normal(bowl.size)
    theta = np.asarray(model.pack(coefficients, 1e-3, 0.05**2))
    thetas = theta * (1.0 + 0.05 * rng.standard_normal((8, theta.size)))
    x0 = 0.3 * rng.standard_normal(2 * d)
    return model, data, thetas, x0


def values(case) -> tuple[list[float], list[float]]:
    """log L by the kernel for θ one at a time, and for the eight as one vmap batch."""
    model, data, thetas, x0 = _problem(case)
    prepared = model.prepare(data)

    def fn(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0)

    single = [float(fn(th)) for th in thetas]
    batch = [float(v) for v in jax.vmap(fn)(thetas)]
    return single, batch


def _in_subprocess(isa: str) -> dict:
    """The instruction set and every case's values, computed in a process that runs ``isa``."""
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1])\n"
        "import test_kernel_variants as t\n"
        "from symplid.model import _kernel as kernel\n"
        "print(json.dumps({'isa': kernel.instruction_set(),"
        " 'values': [t.values(c) for c in t.CASES]}))\n"
    )
    env = dict(os.environ, SYMPLID_KERNEL_ISA=isa, JAX_ENABLE_X64="1")
    folder = os.path.dirname(os.path.abspath(__file__))
    done = subprocess.run(
        [sys.executable, "-c", code, folder], env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("isa", ["avx2", "baseline"])
def test_narrower_variant_gives_the_same_numbers(isa):
    native = compiled_kernel.instruction_set()
    order = ["baseline", "avx2", "avx512"]
    if order.index(isa) >= order.index(native):
        pytest.skip(f"this processor runs {native}: {isa} is not narrower")
    result = _in_subprocess(isa)
    assert result["isa"] == isa
    for case, (single, batch) in zip(CASES, result["values"], strict=True):
        here_single, here_batch = values(case)
        model, data, thetas, x0 = _problem(case)
        reference = dataclasses.replace(model, backend="jax").log_likelihood_fn(data, x0)
        expected = [float(reference(th)) for th in thetas]
        assert np.all(np.isfinite(expected)), case
        tolerance = 1e-12 * np.maximum(1.0, np.abs(expected))  # as test_kernel.py
        for got in (single, batch, here_single, here_batch):
            assert np.all(np.abs(np.subtract(got, expected)) <= tolerance), case
        assert np.all(np.abs(np.subtract(single, here_single)) <= tolerance), case


def test_unknown_or_wider_request_is_ignored():
    """An unknown name never selects a variant the processor cannot run (the native one)."""
    result = subprocess.run(
        [sys.executable, "-c",
         "from symplid.model import _kernel as kernel; print(kernel.instruction_set())"],
        env=dict(os.environ, SYMPLID_KERNEL_ISA="avx1024"),
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout.strip().splitlines()[-1] == compiled_kernel.instruction_set()
