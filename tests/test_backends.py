"""The likelihood as a free function, and the registry of likelihood backends.

A toy backend registered from this file alone is chosen by ``backend="auto"`` when it
supports the model (and gives the reference's numbers), ``backend="jax"`` forces the
reference, and an unknown or unsuitable backend is a clear error.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.filters._backends import LikelihoodBackend
from symplid.model import _likelihood as likelihood
from symplid.model._backends import LIKELIHOOD_BACKENDS, select_backend


@pytest.fixture
def toy_backend():
    """A log-likelihood-only backend (like a compiled kernel) for isotropic models only."""
    calls = []

    def supports(model, prepared):
        return None if model.noise == "isotropic" else "isotropic noise only"

    def build(model, prepared):
        reference = likelihood.build_filter(model, prepared.max_steps, prepared.uniform_steps)

        def loglik(theta, inputs, ys, masks, x0, P0):
            calls.append(1)  # traced once per compilation
            return reference(theta, inputs, ys, masks, x0, P0).log_likelihood

        return loglik

    LIKELIHOOD_BACKENDS.register(
        "toy", LikelihoodBackend("toy", supports, build, priority=50, description="a test")
    )
    try:
        yield calls
    finally:
        LIKELIHOOD_BACKENDS.unregister("toy")


def test_reference_is_registered():
    assert "jax" in LIKELIHOOD_BACKENDS
    assert LIKELIHOOD_BACKENDS["jax"].filtered_moments


def test_free_function_equals_the_model(hh_model, small_data, small_x0, small_P0, small_theta):
    prepared = hh_model.prepare(small_data)
    x0, P0 = jnp.asarray(small_x0), jnp.asarray(small_P0)
    free = jax.jit(lambda th: likelihood.log_likelihood(hh_model, th, prepared, x0, P0))
    got = free(jnp.asarray(small_theta))
    # the model may use the compiled backend: equal to the reference to rounding
    model_value = float(hh_model.log_likelihood(small_theta, small_data, x0, P0))
    assert float(got) == pytest.approx(model_value, rel=1e-12)
    result = likelihood.filter_result(hh_model, jnp.asarray(small_theta), prepared, x0, P0)
    np.testing.assert_allclose(
        result.filtered_means, hh_model.filter(small_theta, small_data, x0, P0).filtered_means,
        rtol=1e-12,
    )


def test_auto_picks_a_registered_backend_that_supports_the_model(
    toy_backend, hh, small_data, small_x0, small_P0, small_theta
):
    model = symplid.HamiltonianModel(hh.potential, integrator="leapfrog", dt=0.25)
    reference = symplid.HamiltonianModel(hh.potential, dt=0.25, backend="jax")
    assert model.likelihood_backend == "toy"
    assert reference.likelihood_backend == "jax"

    got = model.log_likelihood_fn(small_data, small_x0, small_P0)(small_theta)
    assert toy_backend, "the toy backend was not used"
    want = reference.log_likelihood_fn(small_data, small_x0, small_P0)(small_theta)
    assert float(got) == float(want)
    # filter() always runs the reference (the toy gives no moments).
    result = model.filter(small_theta, small_data, small_x0, small_P0)
    assert float(result.log_likelihood) == float(want)


def test_auto_skips_a_backend_that_does_not_support_the_model(toy_backend, hh):
    model = symplid.HamiltonianModel(hh.potential, dt=0.25, noise="diagonal")
    toy = LIKELIHOOD_BACKENDS.unregister("toy")
    try:
        without_toy = model.likelihood_backend  # the compiled kernel where built, else jax
    finally:
        LIKELIHOOD_BACKENDS.register("toy", toy)
    assert without_toy in ("compiled", "jax")
    assert model.likelihood_backend == without_toy


def test_forcing_an_unsuitable_backend_says_why(toy_backend, hh):
    with pytest.raises(ValueError, match="isotropic noise only"):
        symplid.HamiltonianModel(hh.potential, noise="diagonal", backend="toy")


def test_unknown_backend_lists_the_choices(hh):
    with pytest.raises(ValueError, match=r"unknown likelihood backend 'jaxx'.*did you mean "
                                         r"'jax'.*choose one of auto, jax"):
        symplid.HamiltonianModel(hh.potential, backend="jaxx")


def test_no_backend_applies():
    class Model:
        pass

    never = LikelihoodBackend("never", lambda m, p: "never applies", lambda m, p: None)
    LIKELIHOOD_BACKENDS.register("never", never)
    try:
        with pytest.raises(ValueError, match="never applies"):
            select_backend("never", Model())
    finally:
        LIKELIHOOD_BACKENDS.unregister("never")
