"""How a :class:`~symplid.model._statespace.HamiltonianModel` is built: its settings, normalised.

A user names an integrator, a mass vector, ``"positions"``, a backend ``"JAX"``; the model
stores the integrator object (damped, or with Tao's binding constant ω set), the mass matrix,
the observation matrix, the canonical names. :func:`normalise_fields` turns the first into the
second and raises on anything invalid, with one message per mistake; it is a pure function of
its arguments (no model exists yet), so that every field a model stores is normal from the
start and nothing is rewritten after construction::

    HamiltonianModel(pot, "leapfrog", dt=0.25, mass=[1.0, 2.0])
    # == ModelFields(**normalise_fields(pot, "leapfrog", dt=0.25, mass=[1.0, 2.0]))

:class:`ModelFields` is the frozen record of the normal fields (its generated ``__init__``
stores them as given); ``HamiltonianModel`` subclasses it with an ``__init__`` that
normalises first. Normalising is idempotent: ``normalise_fields(**normal) == normal`` for
fields that are already normal, so ``dataclasses.replace(model, dt=0.1)`` works as before.

What needs a model to answer — whether a forced backend supports it — is asked after
construction (:func:`symplid.model._backends.check_backend`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from symplid.dynamics._damping import is_damped, with_damping
from symplid.dynamics._forced import is_forced, with_force
from symplid.dynamics._forcing import Force
from symplid.dynamics._hamiltonians import is_hamiltonian
from symplid.dynamics._integrators import Integrator, get_integrator, separable_only_error
from symplid.dynamics._nonseparable import DEFAULT_BINDING_STEPS, TaoIntegrator, with_binding
from symplid.dynamics._potentials import has_kinetic, mass_matrix
from symplid.filters import unscented_weights
from symplid.filters._noise import get_observation_noise
from symplid.model._backends import check_backend_name

__all__ = ["NOISE_LAYOUTS", "PROCESS_NOISE_CHOICES", "ModelFields", "normalise_fields"]

#: Where the process noise enters (``HamiltonianModel.process_noise_per``); ``"none"``: nowhere.
PROCESS_NOISE_CHOICES = ("gap", "step", "none")
#: The layouts of the noise variances (``HamiltonianModel.noise``).
NOISE_LAYOUTS = ("isotropic", "diagonal", "per-kind")


@dataclass(frozen=True, eq=False)
class ModelFields:
    """The normal settings of a Hamiltonian state-space model, as stored.

    Built by :func:`normalise_fields`; see :class:`~symplid.model._statespace.HamiltonianModel`
    for what each means and what a user may pass. Here ``integrator`` is an
    :class:`~symplid.dynamics._integrators.Integrator` (the damped one when ``damping``, Tao's
    with its ω set), ``mass`` a ``(d, d)`` matrix or None (identity), ``observation``
    ``"full"``, ``"positions"``, a ``(d_y, 2d)`` matrix or a function, and ``backend`` and
    ``observation_noise`` canonical names.
    """

    hamiltonian: Any
    integrator: Integrator
    dt: float
    observation: str | np.ndarray | Callable[..., Any]
    process_noise_per: str
    noise: str
    mass: np.ndarray | None
    alpha: float
    beta: float
    kappa: float
    jitter: float
    unroll: int
    backend: str
    damping: bool
    observation_noise: str
    binding: float | None
    force: Any = None


def normalise_fields(
    hamiltonian: Any,
    integrator: str | Integrator = "leapfrog",
    dt: float = 0.25,
    observation: Any = "full",
    process_noise_per: str = "gap",
    noise: str = "isotropic",
    mass: Any = None,
    alpha: float = 1.0,
    beta: float = 2.0,
    kappa: float = 0.0,
    jitter: float = 1e-12,
    unroll: int = 1,
    backend: str = "auto",
    damping: bool = False,
    observation_noise: str = "additive",
    binding: float | None = None,
    force: Any = None,
) -> dict[str, Any]:
    """The normal fields of a model from a user's settings; ``ValueError`` on invalid ones.

    The arguments are those of :class:`~symplid.model._statespace.HamiltonianModel`. Returns
    a dict with one entry per field of :class:`ModelFields`.
    """
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a positive number, got {dt}")
    separable = not is_hamiltonian(hamiltonian)
    damping = bool(damping)
    integrator = _integrator(get_integrator(integrator), damping, binding, dt)
    if not separable:
        if not integrator.nonseparable:
            raise separable_only_error(f"the integrator {integrator.name!r}")
        if mass is not None:
            raise ValueError("mass applies to a separable H only; write the mass into the "
                             "Hamiltonian (e.g. symplid.PositionDependentMass)")
    if damping:
        _check_dampable(hamiltonian, separable)
        integrator = with_damping(integrator)
    _check_choices(process_noise_per, noise)
    if force is not None:
        integrator = _forced(integrator, force, hamiltonian, damping, process_noise_per)
    observation_noise = get_observation_noise(observation_noise).name
    if jitter < 0:
        raise ValueError("jitter must be ≥ 0")
    state_dim = 2 * hamiltonian.dim
    unscented_weights(state_dim, alpha, beta, kappa)  # validates
    observation = _observation(observation, state_dim)
    if noise == "per-kind" and not isinstance(observation, str):
        raise ValueError(
            "noise='per-kind' needs observation='full' or 'positions' (the kinds of the "
            "observed components); use 'diagonal' for a matrix or a function"
        )
    return dict(
        hamiltonian=hamiltonian, integrator=integrator, dt=dt, observation=observation,
        process_noise_per=process_noise_per, noise=noise,
        mass=mass_matrix(mass, hamiltonian.dim), alpha=alpha, beta=beta, kappa=kappa,
        jitter=jitter, unroll=unroll, backend=check_backend_name(backend), damping=damping,
        observation_noise=observation_noise, binding=binding, force=force,
    )


def _integrator(integrator: Integrator, damping: bool, binding: float | None,
                dt: float) -> Integrator:
    """The named integrator with Tao's ω bound (ω = ``DEFAULT_BINDING_STEPS``/dt by default);
    an error for a damped one without ``damping`` and for ω given to a method without one."""
    if is_damped(integrator) and not damping:
        raise ValueError(f"the integrator {integrator.name!r} is damped: pass damping=True")
    if is_forced(integrator):
        integrator = integrator.base  # type: ignore[assignment]  # re-forced with the force
    if isinstance(integrator, TaoIntegrator):
        return with_binding(integrator, DEFAULT_BINDING_STEPS / dt if binding is None
                            else binding)
    if binding is not None:
        with_binding(integrator, binding)  # raises: ω is Tao's
    return integrator


def _forced(integrator: Integrator, force: Any, hamiltonian: Any, damping: bool,
            process_noise_per: str) -> Integrator:
    """The forced form of ``integrator`` (:mod:`symplid.dynamics._forced`), after the checks
    that a force allows: the system's dimension, no separate γ (write the friction into F),
    process noise per gap or none."""
    if not isinstance(force, Force):
        raise TypeError(f"force must be a symplid.dynamics._forcing.Force, got "
                        f"{type(force).__name__}")
    if force.dim != hamiltonian.dim:
        raise ValueError(f"the force acts on {force.dim} momenta but H has {hamiltonian.dim} "
                         "coordinates")
    if damping:
        raise ValueError("a model with a force has no separate damping rate γ: write the "
                         "friction into the force (e.g. '- c*p1')")
    if process_noise_per == "step":
        raise ValueError("a model with a force adds process noise per gap or not at all "
                         "(its inputs are tabulated per gap): process_noise_per='gap' or "
                         "'none', not 'step'")
    return with_force(integrator)


def _check_dampable(hamiltonian: Any, separable: bool) -> None:
    if has_kinetic(hamiltonian):
        raise ValueError("damping=True needs T = ½pᵀM⁻¹p (the friction is −γM⁻¹p); "
                         "the model has its own kinetic energy T(p)")
    if not separable:
        raise ValueError("damping=True needs a separable H = ½pᵀM⁻¹p + U(q) (the "
                         "friction is −γM⁻¹p); a non-separable H cannot be damped")


def _check_choices(process_noise_per: str, noise: str) -> None:
    if process_noise_per not in PROCESS_NOISE_CHOICES:
        raise ValueError(
            f"process_noise_per must be 'gap', 'step' or 'none', got {process_noise_per!r}"
        )
    if noise not in NOISE_LAYOUTS:
        raise ValueError(f"noise must be 'isotropic', 'diagonal' or 'per-kind', got {noise!r}")


def _observation(observation: Any, state_dim: int) -> str | np.ndarray | Callable[..., Any]:
    """``"full"``/``"positions"`` and functions as given, anything else as a float matrix with
    ``state_dim`` columns."""
    if isinstance(observation, str):
        if observation not in ("full", "positions"):
            raise ValueError(f"observation must be 'full', 'positions', a matrix or a "
                             f"function, got {observation!r}")
        return observation
    if callable(observation):
        return observation
    matrix = np.atleast_2d(np.asarray(observation, dtype=float))
    if matrix.shape[1] != state_dim:
        raise ValueError(
            f"observation matrix must have {state_dim} columns, got {matrix.shape}"
        )
    return matrix
