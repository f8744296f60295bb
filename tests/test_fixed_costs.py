"""Fixed costs paid once: a parameter space's transforms compiled as one program, ArviZ
imported while a fit computes, every compiled program kept by the persistent cache."""

from __future__ import annotations

import pickle
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import monitoring

from symplid.model._params import ParameterProperties, ParameterSpace

BOUNDS = [(0.0, np.inf), (-1.0, 2.0), (-np.inf, np.inf), (-np.inf, 3.0)]


def _space() -> ParameterSpace:
    return ParameterSpace([ParameterProperties(f"t{i}", "parameters", None, lo, hi)
                           for i, (lo, hi) in enumerate(BOUNDS)])


@pytest.fixture
def compilations():
    """A list that grows by one for every backend compilation (or cache read) while in use."""
    seen: list[str] = []

    def listen(name, _secs, **_kwargs):
        if name == "/jax/core/compile/backend_compile_duration":
            seen.append(name)

    monitoring.register_event_duration_secs_listener(listen)
    yield seen
    monitoring.unregister_event_duration_listener(listen)


def test_compiled_transforms_equal_numpys_and_compile_once(compilations):
    space = _space()
    theta = np.array([[0.5, 0.3, 4.0, 2.0], [2.0, -0.9, -3.0, -7.0]])
    # the bijector's NumPy path is a second implementation of the same formulas
    z_ref = space.reparameterisation().to_unconstrained(theta)
    z = space.to_unconstrained(jnp.asarray(theta))
    np.testing.assert_allclose(np.asarray(z), z_ref, rtol=1e-14)
    np.testing.assert_allclose(np.asarray(space.from_unconstrained(z)), theta, rtol=1e-13)
    rows = [jnp.asarray(row * scale) for row in theta for scale in (1.0, 1.01)]
    before = len(compilations)
    for row in rows:
        space.to_unconstrained(row)
    assert len(compilations) - before <= 1  # one program for the row's shape, not a dozen
    # inside a trace the transform is traced inline, and gives the same numbers
    np.testing.assert_allclose(np.asarray(jax.jit(space.to_unconstrained)(theta[0])),
                               z_ref[0], rtol=1e-14)


def test_pushforward_jacobian_is_the_bijectors_derivative():
    space = _space()
    theta = np.array([0.5, 0.3, 4.0, 2.0])
    cov = np.diag([0.01, 0.02, 0.03, 0.04])
    # dz/dθ by hand: 1/(θ − a), (b − a)/((θ − a)(b − θ)), 1, −1/(b − θ)... squared on the diagonal
    jac = np.array([1 / 0.5, 3.0 / (1.3 * 1.7), 1.0, 1 / (3.0 - 2.0)])
    np.testing.assert_allclose(space.pushforward_covariance(theta, cov), np.diag(jac**2 * 0.01
                               * np.arange(1, 5)), rtol=1e-12)


def test_a_space_pickles_without_its_programs():
    space = _space()
    space.to_unconstrained(jnp.zeros(4) + 0.5)
    again = pickle.loads(pickle.dumps(space))
    np.testing.assert_array_equal(np.asarray(again.to_unconstrained(jnp.zeros(4) + 0.5)),
                                  np.asarray(space.to_unconstrained(jnp.zeros(4) + 0.5)))


def test_prefetch_imports_arviz_in_a_thread():
    code = ("import sys, threading\n"
            "from symplid.inference._diagnostics import import_arviz, prefetch_arviz\n"
            "assert 'arviz' not in sys.modules\n"
            "prefetch_arviz()\n"
            "[t.join() for t in threading.enumerate() if t.name == 'symplid-import-arviz']\n"
            "assert 'arviz' in sys.modules\n"
            "assert import_arviz() is sys.modules['arviz']\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)


def test_the_cache_keeps_every_program(tmp_path, monkeypatch):
    code = ("import jax\nfrom symplid import runtime\n"
            f"runtime.enable_compilation_cache({str(tmp_path)!r})\n"
            "print(jax.config.jax_persistent_cache_min_compile_time_secs)\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True, timeout=300).stdout
    assert float(out.strip()) == 0.0
