"""HamiltonianModel: compiled-filter caching and layout of θ."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import symplid


def test_model_first_used_inside_jit_still_works_eagerly():
    """The compiled filter is cached on the model; building it under a trace must not leak."""
    system = symplid.get_system("harmonic")
    data = symplid.simulate(system, seed=0)
    model = symplid.HamiltonianModel(system.potential, dt=0.25)
    theta = model.pack(system.coefficients, 1e-6, 0.0025)
    traced = jax.jit(lambda t: model.log_likelihood(t, data, system.initial_state))(theta)
    eager = model.log_likelihood(theta, data, system.initial_state)
    assert np.isfinite(eager)
    assert float(traced) == pytest.approx(float(eager), rel=1e-12)


def test_param_layout_and_pack_roundtrip():
    system = symplid.get_system("henon-heiles")
    model = symplid.HamiltonianModel(system.potential, noise="diagonal", observation="positions")
    assert model.num_params == 9 + 4 + 2
    assert model.param_names[9:] == (
        "process_var[0]",
        "process_var[1]",
        "process_var[2]",
        "process_var[3]",
        "obs_var[0]",
        "obs_var[1]",
    )
    theta = model.pack(system.coefficients, [1.0, 2.0, 3.0, 4.0], [5.0, 6.0])
    coeffs, proc, obs = model.split(theta)
    np.testing.assert_allclose(coeffs, system.coefficients)
    np.testing.assert_allclose(np.diag(proc), [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(np.diag(obs), [5.0, 6.0])
    with pytest.raises(ValueError, match="θ has 15 entries"):
        model.pack(system.coefficients, 1.0, 1.0)
