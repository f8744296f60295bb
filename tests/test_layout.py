"""θ's layout (model/_layout.py) and its one reparameterisation (model/_params.py).

The expected names below are written out by hand from the documented layout rules (module
docstrings of ``statespace`` and ``layout``), not read from the code; the reparameterisation's
log-Jacobian is checked against ``jax.jacfwd``'s log |det|.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import symplid  # noqa: F401  (float64)
from symplid import HamiltonianModel, Observations, Polynomial, Posterior
from symplid.dynamics._user_models import UserPotential
from symplid.inference.map._space import SearchSpace
from symplid.inference.samplers._registry import LogScale
from symplid.model._layout import Block, ParameterLayout
from symplid.model._params import ParameterProperties, ParameterSpace, Reparameterisation
from symplid.model._priors import HalfNormal, Laplace, Normal, Uniform

QUAD = Polynomial(1, 2)  # c[q1], c[q1^2]
COEFFS = ("c[q1]", "c[q1^2]")
USER = UserPotential(lambda q, c: 0.5 * c[0] * q[0] ** 2, dim=1, num_params=1, names=("k",))

VARIANTS = {
    "isotropic": (dict(), (*COEFFS, "process_var", "obs_var"),
                  ("coefficients",) * 2 + ("process_var", "obs_var")),
    "diagonal": (dict(noise="diagonal"),
                 (*COEFFS, "process_var[0]", "process_var[1]", "obs_var[0]", "obs_var[1]"),
                 ("coefficients",) * 2 + ("process_var",) * 2 + ("obs_var",) * 2),
    "per-kind": (dict(noise="per-kind"), (*COEFFS, "process_var", "obs_var[q]", "obs_var[p]"),
                 ("coefficients",) * 2 + ("process_var", "obs_var", "obs_var")),
    "per-kind positions": (dict(noise="per-kind", observation="positions"),
                           (*COEFFS, "process_var", "obs_var[q]"),
                           ("coefficients",) * 2 + ("process_var", "obs_var")),
    "damped": (dict(damping=True), (*COEFFS, "gamma", "process_var", "obs_var"),
               ("coefficients",) * 2 + ("damping", "process_var", "obs_var")),
    "multiplicative": (dict(observation_noise="multiplicative"),
                       (*COEFFS, "process_var", "obs_rel_var"),
                       ("coefficients",) * 2 + ("process_var", "obs_rel_var")),
    "both diagonal": (dict(observation_noise="both", noise="diagonal"),
                      (*COEFFS, "process_var[0]", "process_var[1]", "obs_var[0]", "obs_var[1]",
                       "obs_rel_var[0]", "obs_rel_var[1]"),
                      ("coefficients",) * 2 + ("process_var",) * 2 + ("obs_var",) * 2
                      + ("obs_rel_var",) * 2),
    "deterministic": (dict(process_noise_per="none"), (*COEFFS, "obs_var"),
                      ("coefficients",) * 2 + ("obs_var",)),
    "deterministic damped both": (
        dict(process_noise_per="none", damping=True, observation_noise="both"),
        (*COEFFS, "gamma", "obs_var", "obs_rel_var"),
        ("coefficients",) * 2 + ("damping", "obs_var", "obs_rel_var")),
}


def _model(kwargs):
    return HamiltonianModel(kwargs.pop("potential", QUAD), "leapfrog", dt=0.1, **kwargs)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_model_layout_names_groups_and_slices(variant):
    kwargs, names, groups = VARIANTS[variant]
    model = _model(dict(kwargs))
    layout = model.layout
    assert layout.names == model.param_names == names
    assert layout.groups == model.param_groups == groups
    assert layout.size == model.num_params == len(names)
    for block in layout.blocks:  # each block's slice holds its own entries, of its group
        sl = layout.slice(block.name)
        assert names[sl] == block.entries and set(groups[sl]) == {block.group}
    # the blocks tile θ in the documented order
    order = ("coefficients", "damping", "process_var", "obs_var", "obs_rel_var")
    assert list(layout.block_names) == [b for b in order if b in layout]


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_pack_unpack_round_trip_and_the_model_views(variant):
    kwargs, names, _ = VARIANTS[variant]
    model = _model(dict(kwargs))
    layout = model.layout
    theta = np.arange(1.0, len(names) + 1.0) / 10
    blocks = layout.unpack(theta)
    np.testing.assert_array_equal(layout.pack(**blocks), theta)
    # the model's pack puts each argument where the layout says
    theta_model = model.pack(
        blocks["coefficients"], blocks.get("process_var", ()), blocks.get("obs_var", ()),
        blocks.get("obs_rel_var", ()), gamma=blocks.get("damping"),
    )
    np.testing.assert_array_equal(theta_model, theta)
    # split, damping_rate and relative_variances read the same entries
    coeffs, proc, _ = model.split(jnp.asarray(theta))
    np.testing.assert_array_equal(coeffs, theta[:2])
    want_q = blocks.get("process_var", np.zeros(1))
    np.testing.assert_array_equal(np.diag(proc), np.broadcast_to(want_q, (2,)) if
                                  "process_var" in layout else np.zeros(2))
    gamma = float(model.damping_rate(theta))
    assert gamma == (float(blocks["damping"][0]) if "damping" in layout else 0.0)
    rel = np.asarray(model.relative_variances(jnp.asarray(theta)))
    if "obs_rel_var" in layout:
        np.testing.assert_array_equal(rel, blocks["obs_rel_var"][model.obs_noise_index])
    else:
        np.testing.assert_array_equal(rel, np.zeros(model.obs_dim))


def test_unpack_works_on_traced_and_batched_theta():
    model = _model(dict(damping=True, noise="diagonal"))
    layout = model.layout
    thetas = jnp.asarray(np.random.default_rng(0).normal(size=(3, 5, layout.size)))
    batched = layout.unpack(thetas)
    assert batched["process_var"].shape == (3, 5, 2)
    gammas = jax.jit(jax.vmap(lambda t: layout.unpack(t)["damping"][0]))(thetas[0])
    np.testing.assert_array_equal(gammas, thetas[0, :, 2])
    np.testing.assert_array_equal(model.damping_rate(thetas), thetas[..., 2])
    with pytest.raises(ValueError, match="entries on its last axis"):
        layout.unpack(np.zeros(layout.size + 1))


def test_pack_refuses_what_the_model_does_not_have():
    damped, plain = _model(dict(damping=True)), _model({})
    with pytest.raises(ValueError, match="needs a damping rate: pass gamma"):
        damped.pack([0.0, 0.5], 1e-4, 0.01)
    with pytest.raises(ValueError, match="has no damping rate: pass gamma"):
        plain.pack([0.0, 0.5], 1e-4, 0.01, gamma=0.1)
    with pytest.raises(ValueError, match=r"θ has 4 entries .* got 5"):
        plain.pack([0.0, 0.5], 1e-4, [0.01, 0.02])
    with pytest.raises(ValueError, match="block 'process_var' has 1 entries, got 0"):
        plain.pack([0.0, 0.5], (), [0.01, 0.02])
    with pytest.raises(KeyError, match="no block 'damping'"):
        plain.layout.slice("damping")


def test_a_user_model_names_its_block_after_its_group():
    model = HamiltonianModel(USER, "leapfrog", dt=0.1)
    layout = model.layout
    assert layout.block_names[0] == "parameters" and layout.names == ("k", "process_var",
                                                                     "obs_var")
    assert model.num_coefficients == 1
    np.testing.assert_array_equal(model.pack([2.0], 1e-4, 0.01), [2.0, 1e-4, 0.01])
    np.testing.assert_array_equal(model.split(jnp.array([2.0, 1e-4, 0.01]))[0], [2.0])


def test_a_posterior_extends_the_layout_with_each_initial_state():
    model = _model(dict(damping=True))
    t = np.linspace(0.1, 2.0, 12)
    data = [Observations(t, np.stack([np.cos(t), -np.sin(t)], 1) * s) for s in (1.0, 0.5)]
    post = Posterior(model, data, learn_initial_state=True, t0=None)
    layout = post.layout
    assert layout.names == (*model.param_names, "x0[0].q1", "x0[0].p1", "x0[1].q1", "x0[1].p1")
    assert layout.block_names[-2:] == ("x0[0]", "x0[1]")
    assert post.param_names == layout.names and post.param_groups == layout.groups
    theta = np.arange(layout.size, dtype=float)
    for k in (0, 1):
        assert post.initial_state_slice(k) == layout.slice(f"x0[{k}]") == slice(5 + 2 * k,
                                                                                7 + 2 * k)
        np.testing.assert_array_equal(post.initial_state(theta, k), theta[5 + 2 * k:7 + 2 * k])
    np.testing.assert_array_equal(
        layout.pack(**layout.unpack(theta)), theta)  # x0[k] names go through a mapping


def test_a_model_stating_only_names_and_groups_gets_a_layout():
    layout = ParameterLayout.from_groups(["a", "b", "v", "w"],
                                         ["coefficients", "coefficients", "obs_var", "obs_var"])
    assert layout.block_names == ("coefficients", "obs_var") and layout.size == 4
    extended = layout.extend([Block("x0[0]", "initial_state", ("x0[0].q1",))])
    assert extended.names[-1] == "x0[0].q1" and extended.slice("x0[0]") == slice(4, 5)
    with pytest.raises(ValueError, match="two blocks named"):
        layout.extend([Block("obs_var", "obs_var", ("z",))])


# ------------------------------------------------------------------------ the reparameterisation
LOWER = np.array([-math.inf, 0.0, -math.inf, -1.0, 2.0])
UPPER = np.array([math.inf, math.inf, 2.0, 3.0, math.inf])
SELECTIONS = {
    "all (NUTS, Laplace)": None,
    "bounded below only (MAP)": np.isfinite(LOWER) & ~np.isfinite(UPPER),
    "one of them (DRAM's log-scale groups)": np.array([False, True, False, False, False]),
    "none": np.zeros(5, bool),
}


@pytest.mark.parametrize("selection", list(SELECTIONS))
@pytest.mark.parametrize("scale", [None, np.array([2.0, 0.5, 1.0, 3.0, 0.25])])
def test_reparameterisation_is_inverse_and_its_jacobian_matches_autodiff(selection, scale):
    rep = Reparameterisation(LOWER, UPPER, SELECTIONS[selection], scale)
    for z in ([0.7, -3.0, 1.2, -0.4, 0.3], [-2.0, 2.5, -1.0, 3.0, -4.0]):
        z = jnp.asarray(z)
        theta = rep.from_unconstrained(z)
        np.testing.assert_allclose(rep.to_unconstrained(theta), z, rtol=1e-12, atol=1e-13)
        jac = np.asarray(jax.jacfwd(rep.from_unconstrained)(z))
        assert np.allclose(jac, np.diag(np.diag(jac)), atol=0)  # entry by entry
        assert float(rep.log_abs_det_jacobian(z)) == pytest.approx(
            float(np.linalg.slogdet(jac)[1]), rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(rep.jacobian_diagonal(z), np.diag(jac), rtol=1e-12)
        # NumPy in, NumPy out, the same numbers
        z_np = np.asarray(z)
        assert isinstance(rep.from_unconstrained(z_np), np.ndarray)
        np.testing.assert_allclose(rep.from_unconstrained(z_np), theta, rtol=1e-14)
        np.testing.assert_allclose(rep.log_abs_det_jacobian(z_np),
                                   rep.log_abs_det_jacobian(z), rtol=1e-13)


def test_selected_entries_take_the_closed_form_maps():
    """log(θ − a), log(b − θ), logit((θ − a)/(b − a)) on selected entries, θ on the others."""
    theta = np.array([0.3, 0.02, 1.5, 0.5, 2.5])
    lower_only = SELECTIONS["bounded below only (MAP)"]
    z = Reparameterisation(LOWER, UPPER, lower_only).to_unconstrained(theta)
    np.testing.assert_allclose(z, [0.3, np.log(0.02), 1.5, 0.5, np.log(0.5)], rtol=1e-15)
    z_all = Reparameterisation(LOWER, UPPER).to_unconstrained(theta)
    u = (0.5 + 1.0) / 4.0
    np.testing.assert_allclose(z_all, [0.3, np.log(0.02), np.log(0.5), np.log(u / (1 - u)),
                                       np.log(0.5)], rtol=1e-14)


def test_every_consumer_selects_from_the_one_object():
    space = ParameterSpace([
        ParameterProperties("c", "coefficients", Laplace(0.0, 10.0), -math.inf, math.inf),
        ParameterProperties("k", "coefficients", Normal(1.0, 1.0), 0.5, math.inf),
        ParameterProperties("v", "process_var", HalfNormal(1.0), 0.0, math.inf),
        ParameterProperties("r", "obs_var", Uniform(0.0, 1.0), 0.0, 1.0),
    ])
    assert space.bijectors == ("identity", "log", "log", "logit")
    search = SearchSpace.of(space, 1e-14)  # the MAP: every entry bounded below only
    np.testing.assert_array_equal(search.log, [False, True, True, False])
    theta = np.array([0.3, 0.75, 1e-20, 0.4])
    u = search.to_u(theta)
    np.testing.assert_array_equal(u, [0.3, np.log(0.25), np.log(1e-14), 0.4])
    np.testing.assert_allclose(search.to_theta(jnp.asarray(u))[:2], theta[:2], rtol=1e-15)

    class Target:  # DRAM: by default the variances bounded below only
        def __init__(self):
            self.space = space

        def log_density(self, theta):
            return -0.5 * jnp.sum(theta**2)

    dram = LogScale(Target())
    np.testing.assert_array_equal(dram.mask, [False, False, True, False])
    # the mask is data on the space's one map for DRAM, usable without a sampler
    np.testing.assert_array_equal(space.log_scale().transformed, dram.mask)
    w = dram.to_w(jnp.asarray([0.3, 0.75, 0.2, 0.4]))
    np.testing.assert_allclose(w, [0.3, 0.75, np.log(0.2), 0.4], rtol=1e-15)
    assert float(dram.log_jacobian(w)) == pytest.approx(np.log(0.2), rel=1e-14)
    # NUTS: the space's own bijectors
    z = space.to_unconstrained(jnp.asarray([0.3, 0.75, 0.2, 0.4]))
    np.testing.assert_allclose(z, [0.3, np.log(0.25), np.log(0.2), np.log(0.4 / 0.6)],
                               rtol=1e-12)
