"""How a HamiltonianModel is built: normalise_fields against the old self-rewriting
__post_init__ (kept here as the reference), programs shared by structure, the renamed field."""

from __future__ import annotations

import dataclasses
import gc
import itertools
import warnings
import weakref

import jax.numpy as jnp
import numpy as np
import pytest

import symplid
from symplid.dynamics._damping import is_damped, with_damping
from symplid.dynamics._hamiltonians import DoublePendulum, is_hamiltonian
from symplid.dynamics._integrators import get_integrator, separable_only_error
from symplid.dynamics._nonseparable import DEFAULT_BINDING_STEPS, TaoIntegrator, with_binding
from symplid.dynamics._potentials import has_kinetic, mass_matrix
from symplid.dynamics._separable import SeparablePotential
from symplid.filters import unscented_weights
from symplid.filters._noise import get_observation_noise
from symplid.model import _programs as programs
from symplid.model._backends import check_backend_name
from symplid.model._construction import ModelFields, normalise_fields

POLY = symplid.Polynomial(dim=2, order=3)
PENDULUM = DoublePendulum()
RELATIVISTIC = SeparablePotential(lambda q, c: 0.5 * c[0] * jnp.sum(q**2),
                                  lambda p, c: jnp.sum(jnp.sqrt(1 + p**2) - 1), dim=2,
                                  num_params=1)
DEFAULTS = {f.name: f.default for f in dataclasses.fields(ModelFields)}


def first_positions(x):
    return x[:2]


def legacy_fields(hamiltonian, integrator="leapfrog", dt=0.25, observation="full",
                  process_noise_per="gap", noise="isotropic", mass=None, alpha=1.0, beta=2.0,
                  kappa=0.0, jitter=1e-12, unroll=1, backend="auto", damping=False,
                  observation_noise="additive", binding=None):
    """The model's fields as the frozen dataclass's __post_init__ rewrote them before the
    factory existed (its checks in their order, minus the forced-backend check)."""
    integrator = get_integrator(integrator)
    if is_damped(integrator) and not damping:
        raise ValueError(f"the integrator {integrator.name!r} is damped: pass damping=True")
    damping = bool(damping)
    separable = not is_hamiltonian(hamiltonian)
    if isinstance(integrator, TaoIntegrator):
        integrator = with_binding(
            integrator, DEFAULT_BINDING_STEPS / dt if binding is None else binding)
    elif binding is not None:
        with_binding(integrator, binding)
    if not separable:
        if not integrator.nonseparable:
            raise separable_only_error(f"the integrator {integrator.name!r}")
        if mass is not None:
            raise ValueError("mass applies to a separable H only; write the mass into the "
                             "Hamiltonian (e.g. symplid.PositionDependentMass)")
    if damping:
        if has_kinetic(hamiltonian):
            raise ValueError("damping=True needs T = ½pᵀM⁻¹p (the friction is −γM⁻¹p); "
                             "the model has its own kinetic energy T(p)")
        if not separable:
            raise ValueError("damping=True needs a separable H = ½pᵀM⁻¹p + U(q) (the "
                             "friction is −γM⁻¹p); a non-separable H cannot be damped")
        integrator = with_damping(integrator)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a positive number, got {dt}")
    if process_noise_per not in ("gap", "step", "none"):
        raise ValueError("process_noise_per must be 'gap', 'step' or 'none', got "
                         f"{process_noise_per!r}")
    if noise not in ("isotropic", "diagonal", "per-kind"):
        raise ValueError(f"noise must be 'isotropic', 'diagonal' or 'per-kind', got {noise!r}")
    observation_noise = get_observation_noise(observation_noise).name
    if jitter < 0:
        raise ValueError("jitter must be ≥ 0")
    state_dim = 2 * hamiltonian.dim
    unscented_weights(state_dim, alpha, beta, kappa)
    mass = mass_matrix(mass, hamiltonian.dim)
    if isinstance(observation, str):
        if observation not in ("full", "positions"):
            raise ValueError(f"observation must be 'full', 'positions', a matrix or a "
                             f"function, got {observation!r}")
    elif not callable(observation):
        matrix = np.atleast_2d(np.asarray(observation, dtype=float))
        if matrix.shape[1] != state_dim:
            raise ValueError(
                f"observation matrix must have {state_dim} columns, got {matrix.shape}")
        observation = matrix
    if noise == "per-kind" and not isinstance(observation, str):
        raise ValueError("noise='per-kind' needs observation='full' or 'positions' (the kinds "
                         "of the observed components); use 'diagonal' for a matrix or a function")
    return dict(hamiltonian=hamiltonian, integrator=integrator, dt=dt, observation=observation,
                process_noise_per=process_noise_per, noise=noise, mass=mass, alpha=alpha,
                beta=beta, kappa=kappa, jitter=jitter, unroll=unroll,
                backend=check_backend_name(backend), damping=damping,
                observation_noise=observation_noise, binding=binding)


def outcome(build, settings):
    """The normal fields, or the (type, message) of the error."""
    try:
        return build(**settings)
    except (ValueError, TypeError) as err:
        return type(err), str(err)


def same_field(a, b) -> bool:
    if isinstance(a, TaoIntegrator):  # rebuilt per model: equal as a method and ω
        return (isinstance(b, TaoIntegrator) and (a.name, a.weights, a.binding)
                == (b.name, b.weights, b.binding))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b) and np.asarray(a).dtype == np.asarray(b).dtype
    return a is b or a == b


def settings_grid():
    """Valid and invalid settings: every option alone, then the combinations that interact."""
    alone = {
        "integrator": ["rk4", "yoshida4", "tao", "implicit-midpoint", "nope"],
        "dt": [0.1, 0.0, -1.0, float("nan")],
        "observation": ["positions", "velocity", np.eye(2, 4), np.ones(4), np.eye(3),
                        first_positions],
        "process_noise_per": ["step", "none", "never"],
        "noise": ["diagonal", "per-kind", "anisotropic"],
        "mass": [[1.0, 2.0], np.diag([2.0, 3.0]), [1.0, -1.0], np.eye(3)],
        "alpha": [0.5, 0.0], "kappa": [-10.0], "jitter": [0.0, -1e-3], "unroll": [4],
        "backend": ["jax", "JAX", "nope"], "damping": [True, 1],
        "observation_noise": ["multiplicative", "both", "neither"], "binding": [5.0, -1.0],
    }
    for name, values in alone.items():
        for value in values:
            for ham in (POLY, PENDULUM, RELATIVISTIC):
                yield {"hamiltonian": ham, name: value}
    combos = itertools.product(
        (POLY, PENDULUM, RELATIVISTIC), ("leapfrog", "rk4", "tao4", with_damping("leapfrog")),
        (False, True), (None, 2.0), (None, [1.0, 3.0]), ("full", np.eye(2, 4)),
        ("isotropic", "per-kind"))
    for ham, integ, damping, binding, mass, obs, noise in combos:
        yield dict(hamiltonian=ham, integrator=integ, damping=damping, binding=binding,
                   mass=mass, observation=obs, noise=noise, dt=0.2)


def test_the_factory_gives_the_fields_and_errors_the_old_post_init_gave():
    grid = list(settings_grid())
    valid = 0
    for settings in grid:
        new, old = outcome(normalise_fields, settings), outcome(legacy_fields, settings)
        if isinstance(old, tuple):
            if not settings.get("dt", 1.0) > 0:  # an invalid dt is now named first
                old = (ValueError, f"dt must be a positive number, got {settings['dt']}")
            assert new == old, settings
            continue
        valid += 1
        assert list(new) == list(DEFAULTS), settings
        assert all(same_field(new[k], old[k]) for k in old), settings
    assert valid > 100 and len(grid) - valid > 100  # both sides are exercised


def test_a_model_stores_the_normal_fields_and_they_normalise_to_themselves():
    model = symplid.HamiltonianModel(POLY, "rk4", dt=0.2, mass=[1.0, 2.0], damping=1,
                                     observation=[[1, 0, 0, 0], [0, 1, 0, 0]], backend="JAX")
    normal = normalise_fields(POLY, "rk4", dt=0.2, mass=[1.0, 2.0], damping=1,
                              observation=[[1, 0, 0, 0], [0, 1, 0, 0]], backend="JAX")
    stored = {f.name: getattr(model, f.name) for f in dataclasses.fields(ModelFields)}
    assert all(same_field(stored[k], normal[k]) for k in normal)
    assert model.damping is True and model.backend == "jax" and model.integrator.base.name == "rk4"
    again = dataclasses.replace(model, dt=0.1)  # re-normalising a normal model changes nothing
    assert again.dt == 0.1 and again.integrator is model.integrator
    np.testing.assert_array_equal(again.mass, model.mass)


def test_a_dt_that_is_not_positive_is_named_before_tao_derives_its_binding_from_it():
    with pytest.raises(ValueError, match=r"dt must be a positive number, got 0\.0"):
        symplid.HamiltonianModel(PENDULUM, "tao", dt=0.0)


def test_the_old_keyword_potential_still_builds_the_model_with_a_future_warning():
    with pytest.warns(FutureWarning, match="'potential' is now 'hamiltonian'"):
        model = symplid.HamiltonianModel(potential=POLY, dt=0.2)
    assert model.hamiltonian is POLY and model.dt == 0.2
    with pytest.warns(FutureWarning, match="'potential' is now 'hamiltonian'"):
        assert model.potential is POLY
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new name and positional use do not warn
        assert symplid.HamiltonianModel(hamiltonian=POLY).hamiltonian is POLY
        assert symplid.HamiltonianModel(POLY, "rk4").integrator.name == "rk4"
    with pytest.raises(TypeError, match="both 'hamiltonian' and its old name"):
        symplid.HamiltonianModel(POLY, potential=POLY)
    with pytest.raises(TypeError, match="missing required argument: 'hamiltonian'"):
        symplid.HamiltonianModel()


@pytest.fixture(scope="module")
def prepared():
    hh = symplid.get_system("henon-heiles")
    data = symplid.simulate(hh, times=np.arange(1, 13) * 0.5, seed=3)
    return symplid.HamiltonianModel(hh.potential).prepare(data), hh


def test_equal_structures_share_one_compiled_program_and_others_do_not(prepared):
    prep, hh = prepared
    pot = hh.potential
    first = symplid.HamiltonianModel(pot, dt=0.25, observation=np.eye(4), backend="jax")
    twin = symplid.HamiltonianModel(pot, dt=0.25, observation=np.eye(4), backend="auto")
    program = programs.compiled(first, prep)
    assert programs.compiled(twin, prep) is program
    # dt reaches the filter only through the prepared data's step sizes and counts (run-time
    # arguments), so a model at another dt shares the program on the same prepared data
    assert programs.compiled(symplid.HamiltonianModel(pot, dt=0.1, observation=np.eye(4)),
                             prep) is program
    assert programs.compiled(symplid.HamiltonianModel(pot, "rk4", observation=np.eye(4)),
                             prep) is not program
    other_pot = symplid.Polynomial(dim=2, order=3)  # equal, but another object: its own store
    assert programs.compiled(symplid.HamiltonianModel(other_pot, observation=np.eye(4)),
                             prep) is not program
    theta = first.pack(hh.coefficients, 1e-6, 2.5e-3)
    x0 = hh.initial_state
    shared = twin.filter(theta, prep, x0).log_likelihood  # runs first's (shared) program
    assert program._cache_size() == 1  # one trace for both models
    alone = symplid.HamiltonianModel(other_pot, observation=np.eye(4)).filter(theta, prep, x0)
    assert float(shared) == pytest.approx(float(alone.log_likelihood), rel=1e-12)


def test_tao_models_with_the_same_binding_share_their_program(prepared):
    prep, _ = prepared
    a = symplid.HamiltonianModel(PENDULUM, "tao", dt=0.25)
    b = symplid.HamiltonianModel(PENDULUM, "tao", dt=0.25)
    c = symplid.HamiltonianModel(PENDULUM, "tao", dt=0.25, binding=3.0)
    assert a.integrator is not b.integrator
    assert programs.structure_key(a) == programs.structure_key(b)
    assert programs.structure_key(a) != programs.structure_key(c)
    assert hash(programs.structure_key(a)) == hash(programs.structure_key(b))
    assert programs.compiled(a, prep) is programs.compiled(b, prep)
    assert programs.compiled(c, prep) is not programs.compiled(a, prep)


def test_a_hamiltonian_and_the_programs_kept_on_it_are_freed_with_its_models(prepared):
    """The programs live on the Hamiltonian, not in a module-level table: dropping the
    Hamiltonian and its models frees them all."""
    prep, hh = prepared
    pot = symplid.Polynomial(dim=2, order=3)
    model = symplid.HamiltonianModel(pot, backend="jax")
    theta = model.pack(hh.coefficients, 1e-6, 2.5e-3)
    assert np.isfinite(float(model.log_likelihood(theta, prep, hh.initial_state)))
    refs = weakref.ref(pot), weakref.ref(model)
    del pot, model
    gc.collect()
    assert all(ref() is None for ref in refs), "something keeps the Hamiltonian alive"
