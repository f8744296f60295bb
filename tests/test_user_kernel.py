"""The compiled kernel for a user's U(q; θ) equals the JAX tier; without a compiler, the JAX
tier runs the model with one note; the unit cache compiles a unit once, also when two
processes ask for it at the same time.

The compiled tests generate, compile (about 10 to 30 s per model on a busy machine) and load
one unit per model into a temporary cache, and compare the log-likelihood and its gradient
over θ, for one θ and a batch of eight, with the JAX filter of the same model (an independent
implementation: its force is ``jax.grad`` of the expression, its derivatives JAX's).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._user_models import build_user_model
from symplid.model import _kernel as compiled_kernel
from symplid.model import _user_kernel as user_kernel
from symplid.model._user_force import UnsupportedExpression, canonical_text, force_code

TIMES = np.array([0.7, 1.5, 2.0, 3.1, 3.6])  # gaps of 3, 4, 2, 5 and 2 substeps at dt = 0.25
TOL = 1e-10

# (expression, d, parameters, their values, model options): sqrt, cos, exp, a polynomial
# written as an expression, and the propagators and options the kernel takes other paths for
# (Runge–Kutta, Σ per substep, a mass matrix, positions observed, diagonal noise).
MODELS = [
    ("-GM/sqrt(q1^2 + q2^2)", 2, ("GM",), (1.0,), {"integrator": "leapfrog"}),
    ("k*(1 - cos(q1))", 1, ("k",), (1.3,), {"integrator": "yoshida4", "noise": "diagonal"}),
    ("D*(1 - exp(-a*(q1 - r)))^2", 1, ("D", "a", "r"), (1.0, 1.2, 0.1),
     {"integrator": "rk4", "process_noise_per": "step"}),
    ("a*(q1^2 + q2^2)/2 + b*(q1^2*q2 - q2^3/3)", 2, ("a", "b"), (1.0, 0.3),
     {"integrator": "leapfrog", "observation": "positions", "mass": ((2.0, 0.5), (0.5, 1.0))}),
]

compiled_only = pytest.mark.skipif(
    not compiled_kernel.available() or user_kernel.compiler() is None,
    reason="needs the compiled kernel and a C++ compiler",
)


@pytest.fixture(autouse=True)
def _user_tier(monkeypatch, tmp_path_factory):
    """The user tier switched on, its units cached in one temporary folder per session."""
    monkeypatch.setenv("SYMPLID_USER_KERNEL", "1")
    monkeypatch.setenv("SYMPLID_KERNEL_CACHE", str(tmp_path_factory.getbasetemp() / "units"))


def _problem(case, rng):
    text, d, names, values, options = case
    options = dict(options)
    mass = options.pop("mass", None)
    model = symplid.HamiltonianModel(
        build_user_model(text, "potential", d, names), dt=0.25,
        mass=None if mass is None else np.array(mass), **options)
    x0 = np.r_[np.linspace(0.8, 1.1, d), np.linspace(0.2, 0.4, d)]
    truth = x0[: model.obs_dim] if model.obs_dim < model.state_dim else x0
    data = truth + 0.05 * rng.standard_normal((TIMES.size, model.obs_dim))
    data[1, 0] = np.nan  # one missing component
    prepared = model.prepare(symplid.Observations(TIMES, data))
    thetas = jnp.asarray(np.array([
        model.pack(np.array(values) * (1 + 0.05 * rng.standard_normal(len(values))),
                   np.exp(rng.uniform(-8, -5, model.num_process_noise)),
                   np.exp(rng.uniform(-6, -4, model.num_obs_noise)))
        for _ in range(8)]))
    return model, prepared, thetas, x0


def _close(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return bool(np.all(np.abs(a - b) <= TOL * np.maximum(1.0, np.abs(b))))


@compiled_only
@pytest.mark.slow
@pytest.mark.parametrize("case", MODELS, ids=lambda c: c[0])
def test_value_and_gradient_equal_the_jax_tier(case):
    """log L and ∂ log L/∂θ of the user unit are the JAX filter's, for one θ and eight."""
    model, prepared, thetas, x0 = _problem(case, np.random.default_rng(MODELS.index(case)))
    assert compiled_kernel.describe(model, prepared)["likelihood_backend"] == "compiled"
    P0 = 1e-4 * np.eye(model.state_dim)
    reference = dataclasses.replace(model, backend="jax")

    def ref(th):
        return reference.log_likelihood(th, prepared, x0, P0)

    def kern(th):
        return compiled_kernel.log_likelihood(model, prepared, th, x0, P0)

    value, grad = jax.value_and_grad(kern)(thetas[0])
    ref_value, ref_grad = jax.value_and_grad(ref)(thetas[0])
    assert np.isfinite(ref_value) and _close(value, ref_value)
    assert _close(grad, ref_grad)
    batch = jax.vmap(kern)(thetas)
    assert _close(batch, jax.vmap(ref)(thetas))
    assert _close(jax.vmap(jax.grad(kern))(thetas[:3]), jax.vmap(jax.grad(ref))(thetas[:3]))


@compiled_only
@pytest.mark.slow
def test_a_non_positive_variance_gives_minus_infinity():
    model, prepared, thetas, x0 = _problem(MODELS[0], np.random.default_rng(7))
    bad = thetas[0].at[-1].set(-1.0)
    value = compiled_kernel.log_likelihood(model, prepared, bad, x0, 1e-4 * np.eye(4))
    assert value == -np.inf


def test_without_a_compiler_the_jax_tier_runs_it_with_one_note(monkeypatch, capfd):
    """A compiler setting that names no compiler: the JAX tier, one line on stderr."""
    monkeypatch.setenv("SYMPLID_CXX", "/nonexistent/c++")
    model, prepared, thetas, x0 = _problem(
        ("w*q1^2/2 + g*q1^4", 1, ("w", "g"), (1.0, 0.1), {}), np.random.default_rng(3))
    described = compiled_kernel.describe(model, prepared)
    assert described["likelihood_backend"] == "jax"
    assert "/nonexistent/c++" in described["reason"]
    P0 = 1e-4 * np.eye(2)
    value = compiled_kernel.log_likelihood(model, prepared, thetas[0], x0, P0)
    reference = dataclasses.replace(model, backend="jax").log_likelihood(thetas[0], prepared,
                                                                         x0, P0)
    assert _close(value, reference)
    compiled_kernel.log_likelihood(model, prepared, thetas[1], x0, P0)
    notes = [line for line in capfd.readouterr().err.splitlines() if "compiled kernel" in line]
    assert len(notes) == 1 and "JAX tier" in notes[0]


def test_the_tier_is_off_unless_switched_on(monkeypatch):
    monkeypatch.setenv("SYMPLID_USER_KERNEL", "0")
    model, prepared, _, _ = _problem(MODELS[0], np.random.default_rng(0))
    assert "not a Polynomial" in compiled_kernel.unsupported_reason(model, prepared)


def test_equal_models_have_equal_keys_and_other_models_other_keys():
    """The cache key's text: the same for the same expression written in another order,
    not for another parameter order or dimension."""
    a = build_user_model("k*(1-cos(q1))", "potential", 1, ("k",)).expression
    b = build_user_model("(-cos(q1) + 1) * k", "potential", 1, ("k",)).expression
    c = build_user_model("a*q1^2 + b*q1^4", "potential", 1, ("a", "b")).expression
    assert canonical_text(a, 1, ("k",)) == canonical_text(b, 1, ("k",))
    assert canonical_text(c, 1, ("a", "b")) != canonical_text(c, 1, ("b", "a"))
    assert canonical_text(a, 1, ("k",)) != canonical_text(a, 2, ("k",))


def test_functions_without_a_compiled_form_are_refused():
    import sympy

    q1, k = sympy.symbols("q1 k", real=True)
    with pytest.raises(UnsupportedExpression, match="gamma"):
        force_code(k * sympy.gamma(q1), 1, ("k",))
    code = force_code(k * sympy.sqrt(q1) ** 3 + k / q1**2, 1, ("k",))
    assert "um::sqrt" in code.source and "pow(" not in code.source


_FAKE_COMPILER = """\
#!{python}
import pathlib, sys, time
if "--version" in sys.argv:
    print("fake 1.0")
    sys.exit(0)
log = pathlib.Path({log!r})
with open(log, "a") as handle:
    handle.write("run\\n")
time.sleep(1.0)
out = sys.argv[sys.argv.index("-o") + 1]
pathlib.Path(out).write_bytes(b"unit")
"""


def test_two_processes_compile_a_unit_once(tmp_path):
    """Two processes that need the same unit at once: one compiles (under the lock, into a
    temporary file renamed into place), the other waits and finds it; a third finds it
    cached. The compiler here is a script that counts its runs."""
    log = tmp_path / "runs.txt"
    fake = tmp_path / "fakecxx"
    fake.write_text(_FAKE_COMPILER.format(python=sys.executable, log=str(log)))
    fake.chmod(0o755)
    script = textwrap.dedent("""
        from symplid.dynamics._user_models import build_user_model
        from symplid.model import _user_force as user_force, _user_kernel as user_kernel
        pot = build_user_model("k*(1-cos(q1))", "potential", 1, ("k",))
        code = user_force.force_code(pot.expression, 1, ("k",))
        print(user_kernel._build(code, "baseline"))
    """)
    env = dict(os.environ, SYMPLID_CXX=str(fake), SYMPLID_KERNEL_CACHE=str(tmp_path / "c"))
    runs = [subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE,
                             text=True) for _ in range(2)]
    paths = {run.communicate(timeout=120)[0].strip() for run in runs}
    assert len(paths) == 1
    path = paths.pop()
    assert path.endswith(".so") and Path(path).read_bytes() == b"unit"
    again = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                           text=True, timeout=120)
    assert again.stdout.strip() == path
    assert log.read_text().count("run") == 1
    assert not [p for p in (tmp_path / "c").iterdir() if p.name.startswith(".build-")]
