"""The run's model, built once: :class:`ModelPlan`.

A run's settings name a model's U or H (a family, or a user's expression that SymPy parses);
the settings are validated as text (:mod:`symplid.workflow._validate`), then checked against
the data, which needs the object itself (its parameters, whether its H is separable). Every
step of a run after that (the fit's model, the MAP refits of the sensitivity checks at dt/2
and with the other process noise, the report's predictions, the held-out scores) asks the
same object: the expression is parsed **once per run**, and the compiled programs that
:mod:`symplid.model._programs` keeps on the model's Hamiltonian are shared by every model of
the run built on it::

    plan = ModelPlan.from_settings(settings, obs, source)   # checks, one parse
    model = plan.model(plan.settings, obs)                  # the fit's model
    half = plan.model(settings_at_half_dt, obs)             # the same U or H, at dt/2

:func:`resolve_for_data` (re-exported by :mod:`symplid.workflow._settings`) is
``ModelPlan.from_settings(...).settings``, for callers that need the settings only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from symplid.io import observation_layout
from symplid.model._data import Observations
from symplid.model._posterior import Posterior
from symplid.model._statespace import HamiltonianModel
from symplid.workflow._building import build_model, build_posterior
from symplid.workflow._model_builder import (
    build_model_family,
    check_model_family,
    family_key,
    follow_model,
)
from symplid.workflow._settings_data import check_data, check_layout
from symplid.workflow._settings_schema import Settings

__all__ = ["ModelPlan", "resolve_for_data"]


@dataclass(frozen=True, eq=False)
class ModelPlan:
    """A run's resolved settings and its model's U or H, built once for the data.

    Attributes
    ----------
    settings
        The settings checked against the data, with what the data decide filled in
        (:func:`resolve_for_data`).
    family
        The potential or Hamiltonian that ``settings.model`` names, built for the data's
        dimension (:func:`~symplid.workflow._model_builder.build_model_family`).
    dim
        The data's number of coordinates d.
    """

    settings: Settings
    family: Any
    dim: int

    @classmethod
    def from_settings(cls, settings: Settings, data: Observations | list[Observations],
                      source: str = "settings") -> ModelPlan:
        """Check ``settings`` against ``data`` and build the model's U or H, once.

        ``model.observation = "auto"`` becomes ``"full"`` or ``"positions"`` from the data's
        columns (see :func:`symplid.io.observation_kind`), ``model.noise = "auto"`` becomes
        ``"per-kind"`` or ``"isotropic"`` (:func:`symplid.workflow._auto.resolve_noise`) and
        ``model.standardise = "auto"`` becomes ``"on"`` or ``"off"``
        (:func:`symplid.workflow._scaling.resolve_standardise`); a user's non-separable H with
        the default leapfrog gets Tao's method
        (:func:`~symplid.workflow._model_builder.follow_model`). Checks that the observation
        kind matches the columns, that a known initial state has ``x0`` with 2d numbers, that
        ``t0`` is before the first observation (or is ``"first"``), that the data have two
        times or more and no column without values, that no gap needs more than
        :data:`~symplid.workflow._settings_data.MAX_SUBSTEPS_PER_GAP` integrator steps and
        that the model's U or H suits the integrators
        (:func:`~symplid.workflow._model_builder.check_model_family`). Warns (one line) when
        θ has more entries than there are data values, and when a learned initial state
        whose prior is centred on the first observation sits more than one data gap before
        it. A :class:`~symplid.workflow._validate.SettingsError` or
        :class:`~symplid.model._data.DataError` says what is wrong in one line.
        """
        trajectories = list(data) if isinstance(data, list | tuple) else [data]
        observation = check_layout(settings, trajectories, source)
        dim = observation_layout(trajectories[0]).dim
        try:
            family = build_model_family(dim, settings.model)
        except ValueError:
            family = None  # check_model_family says what is wrong, with the key
        if family is not None:
            settings = follow_model(settings, dim, family)
        check_model_family(settings, dim, source, family)
        if family is None:  # not refused above: the builder's own error
            family = build_model_family(dim, settings.model)
        settings = check_data(settings, trajectories, source, family, observation)
        return cls(settings, family, dim)

    def family_for(self, settings: Settings) -> Any:
        """The U or H of ``settings``: this plan's object when they name the same one
        (:func:`~symplid.workflow._model_builder.family_key`: a refit at another ``dt``, with
        another process noise or in standardised coordinates), else a new one."""
        if family_key(settings.model) == family_key(self.settings.model):
            return self.family
        return build_model_family(self.dim, settings.model)

    def model(self, settings: Settings,
              data: Observations | list[Observations]) -> HamiltonianModel:
        """The state-space model of ``settings`` for ``data``
        (:func:`~symplid.workflow._building.build_model`), on the plan's U or H."""
        return build_model(settings, data, family=self.family_for(settings))

    def posterior(self, settings: Settings, data: Observations | list[Observations],
                  model: HamiltonianModel | None = None) -> Posterior:
        """The posterior of ``settings`` on ``data`` (:func:`~symplid.workflow._building.
        build_posterior`), its model built by :meth:`model` unless given."""
        model = self.model(settings, data) if model is None else model
        return build_posterior(settings, data, model)


def resolve_for_data(settings: Settings, obs: Any, source: str = "settings") -> Settings:
    """Check the settings against a data set and fill what the data decide (see
    :meth:`ModelPlan.from_settings`). The result is what a run folder records."""
    return ModelPlan.from_settings(settings, obs, source).settings
