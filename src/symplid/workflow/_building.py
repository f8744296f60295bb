"""A run's model and posterior from its settings and data.

The two steps every command that works on a run shares (fit, its diagnostics' refits,
report, predict, compare, resume): :func:`build_model` makes the state-space model of eq. (7)
that ``[model]`` describes, :func:`build_posterior` adds the priors and the initial state.
:mod:`symplid.workflow._fit` re-exports both, where callers have always found them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from symplid._saved_programs import mark
from symplid.io import as_list, observation_layout
from symplid.model._data import Observations
from symplid.model._posterior import Posterior
from symplid.model._statespace import HamiltonianModel
from symplid.model._variance_prior import process_variance_prior
from symplid.workflow._auto import resolve_noise
from symplid.workflow._driven import build_force
from symplid.workflow._model_builder import build_model_family
from symplid.workflow._settings_schema import Settings, prior_spec

__all__ = ["build_model", "build_posterior", "program_identity"]


def build_model(settings: Settings, obs: Observations | list[Observations],
                family: Any = None) -> HamiltonianModel:
    """The state-space model of eq. (7) that ``settings.model`` describes, for these data
    (one trajectory, or a list of them observed the same way).

    ``family``: its U or H when already built (a run builds it once:
    :class:`~symplid.workflow._plan.ModelPlan`), else built here."""

    m = settings.model
    if m.dt == "auto":
        raise ValueError('model.dt = "auto" is chosen by the fit from the data '
                         "(symplid.workflow._step_size.choose_step); give a number to build a "
                         "model without it")
    layout = observation_layout(as_list(obs)[0])
    observation = layout.kind if m.observation == "auto" else m.observation
    return HamiltonianModel(
        build_model_family(layout.dim, m) if family is None else family,
        integrator=m.integrator,
        binding=m.binding or None,
        dt=m.dt,
        observation=observation,
        process_noise_per=m.process_noise_per,
        noise=resolve_noise(m.noise, observation),
        observation_noise=m.observation_noise,
        mass=list(m.mass) if m.mass else None,
        alpha=m.alpha,
        beta=m.beta,
        kappa=m.kappa,
        jitter=m.jitter,
        damping=m.damping,
        force=build_force(m, layout.dim, obs),
    )


def build_posterior(settings: Settings, obs: Observations | list[Observations],
                    model: HamiltonianModel):
    """The posterior of ``settings`` (priors, initial state) for ``model`` and ``obs``.

    Several trajectories share θ; ``initial_state.x0`` is then one state for all, or one
    after the other (K·2d numbers). With ``priors.process_var = "log-uniform"`` the process
    variance's prior is :func:`~symplid.model._variance_prior.process_variance_prior` of
    ``obs``."""

    init = settings.initial_state
    learned = init.mode == "learned"
    x0 = np.asarray(init.x0, dtype=float) if init.x0 else None
    if x0 is not None and not isinstance(obs, Observations):
        x0 = np.resize(x0, (len(obs), model.state_dim))  # one for all, or one each
    spec = prior_spec(settings)  # the groups' priors, and a user model's own
    if settings.priors.process_var == "log-uniform":  # scaled to these data
        spec = dataclasses.replace(spec, process_var=process_variance_prior(obs))
    posterior = Posterior(
        model,
        obs,
        prior=spec,
        x0=x0,
        P0=init.p0_var,
        t0=None if init.at_first_observation else init.t0,  # None: at the first observation
        learn_initial_state=learned,  # its prior is the "initial_state" group above
    )
    return mark(posterior, program_identity(settings, obs))


def program_identity(settings: Settings,
                     obs: Observations | list[Observations]) -> tuple | None:
    """What the compiled programs of the posterior of ``settings`` on ``obs`` close over,
    for the key of a saved program (:mod:`symplid._saved_programs`): the whole settings (a
    user's expression among them) and the data's values. None (never saved) for a model
    that reads a Python file (``file:PATH:NAME``: its code is not in the settings) and for a
    driven model (its inputs come from files)."""
    m = settings.model
    if m.force or any(str(text).startswith("file:")
                      for text in (m.potential, m.hamiltonian, m.kinetic)):
        return None
    data = tuple((o.times, o.values, o.mask) for o in as_list(obs))
    return ("posterior", repr(settings), data)
