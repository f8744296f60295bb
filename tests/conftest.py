"""Shared fixtures: the Hénon–Heiles system, its data, models and compiled log-likelihoods.

Everything expensive (a jitted likelihood, its gradient) is session-scoped so that it is
compiled once for the whole run.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import symplid


def pytest_configure(config):
    """Share compiled programs between tests, xdist workers and the command-line processes
    the tests start, through JAX's disk cache.

    Many tests build the same model structure afresh; XLA compiles it to the same program,
    which the persistent cache then serves instead of compiling again.
    """
    import os
    import tempfile

    from symplid import runtime

    folder = os.environ.get("SYMPLID_TEST_CACHE_DIR") or os.path.join(
        tempfile.gettempdir(), f"symplid-test-jax-cache-{os.getuid()}"
    )
    runtime.enable_compilation_cache(folder)
    # The command-line runs the tests start as processes read the same folder, so that a
    # program compiled in one test is not compiled again by a subprocess (and the tests
    # leave the user's own cache alone).
    os.environ["SYMPLID_CACHE_DIR"] = folder
    # Saved programs (symplid._saved_programs) are off: tests replace functions that a traced
    # program calls (to count calls, to inject a failure), which a program read back from
    # an earlier test would not call. tests/test_saved_programs.py turns them on itself.
    os.environ["SYMPLID_SAVED_PROGRAMS"] = "off"

    # The suite is a top-level user, like the command line: the sweep specs its tests build
    # may name the studies' experiments ("paper", the default, and "baselines").
    from symplid.studies import register_studies

    register_studies()


def pytest_collection_modifyitems(config, items):
    """Tests marked ``long`` (many minutes each: a whole MAP on a long record) run only with
    ``SYMPLID_LONG_TESTS=1``; the suite CI runs stays within its time."""
    import os

    if os.environ.get("SYMPLID_LONG_TESTS") == "1":
        return
    skip = pytest.mark.skip(reason="a long test: set SYMPLID_LONG_TESTS=1 to run it")
    for item in items:
        if "long" in item.keywords:
            item.add_marker(skip)


# Irregular observation times for the small problems: gaps 0.7, 0.8, 0.5, 1.1, 0.5, 0.9,
# so with dt = 0.25 the gaps take 3, 4, 2, 5, 2 and 4 substeps (never an exact multiple).
SMALL_TIMES = np.array([0.7, 1.5, 2.0, 3.1, 3.6, 4.5])


@pytest.fixture(scope="session")
def hh():
    """The Hénon–Heiles reference system (the paper's experiment)."""
    return symplid.get_system("henon-heiles")


@pytest.fixture(scope="session")
def hh_data(hh):
    """The paper's data: 20 full-state observations, 5 s apart, noise std 0.05, seed 0."""
    return symplid.simulate(hh, seed=0)


@pytest.fixture(scope="session")
def hh_model(hh):
    """The paper's learning model: cubic polynomial, leapfrog, dt = 0.25, default settings."""
    return symplid.HamiltonianModel(hh.potential, integrator="leapfrog", dt=0.25)


@pytest.fixture(scope="session")
def hh_theta(hh, hh_model):
    """True coefficients, process variance 1e-6, observation variance 0.05²."""
    return hh_model.pack(hh.coefficients, 1e-6, 0.05**2)


@pytest.fixture(scope="session")
def hh_loglik(hh, hh_model, hh_data):
    """θ ↦ log-likelihood of the paper's data (compiled on first call, cached by the model)."""
    return hh_model.log_likelihood_fn(hh_data, hh.initial_state)


@pytest.fixture(scope="session")
def small_data(hh):
    """Six irregularly spaced full-state observations of Hénon–Heiles, one value missing."""
    data = symplid.simulate(hh, times=SMALL_TIMES, noise_std=0.05, seed=1)
    values = np.array(data.values)
    values[2, 1] = np.nan
    return symplid.Observations(data.times, values, data.names)


@pytest.fixture(scope="session")
def small_theta(hh, hh_model):
    """A θ away from the truth (so that the gradient is not near zero), variances moderate."""
    coeffs = hh.coefficients + 0.02 * np.arange(1, hh.potential.num_params + 1) / 9.0
    return hh_model.pack(coeffs, 1e-4, 0.04**2)


@pytest.fixture(scope="session")
def small_x0(hh):
    return np.asarray(hh.initial_state)


@pytest.fixture(scope="session")
def small_P0():
    return 1e-4 * np.eye(4)


@pytest.fixture(scope="session")
def small_loglik(hh_model, small_data, small_x0, small_P0):
    """θ ↦ log-likelihood of the small problem (default model).

    Not wrapped in another ``jax.jit``: the model caches its compiled filter, so this shares
    one compilation with ``hh_model.log_likelihood`` and ``hh_model.filter`` on the same data.
    """
    return hh_model.log_likelihood_fn(small_data, small_x0, small_P0)


@pytest.fixture(scope="session")
def small_grad(hh_model, small_data, small_x0, small_P0):
    """θ ↦ ∇ log-likelihood of the small problem, jitted once."""
    return jax.jit(jax.grad(hh_model.log_likelihood_fn(small_data, small_x0, small_P0)))


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    """A noisy unit-frequency oscillator, 12 full-state observations at t = 1..12 (CSV): the
    small data set of the command-line tests of run files, resume, locks, limits, signals
    and disk faults."""
    t = np.arange(1, 13.0)
    rng = np.random.default_rng(0)
    q, p = np.cos(t) + 0.02 * rng.normal(size=t.size), -np.sin(t) + 0.02 * rng.normal(size=t.size)
    path = tmp_path_factory.mktemp("d") / "h.csv"
    path.write_text("t,q1,p1\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in
                                         zip(t.tolist(), q.tolist(), p.tolist(), strict=True)))
    return path
