"""The model's family from its settings: what a run's ``[model]`` builds, and its checks.

:mod:`symplid.dynamics._families` names the families of U(q; θ) and H(q, p; θ) and builds them
from typed options only (:class:`~symplid.dynamics._families.FamilyOptions`); this module is
where the workflow reads its settings for them: which family ``model.hamiltonian`` /
``model.potential`` name (:func:`model_family`), the options a builder reads
(:func:`family_options`), the object for the data's dimension (:func:`build_model_family`),
the family's default coefficient prior (:func:`family_prior`, :func:`with_family_prior`), and
the checks of the model against the integrators (:func:`follow_model`,
:func:`check_model_family`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from symplid.dynamics._families import (
    DEFAULT_POTENTIAL,
    SEPARABLE,
    Family,
    FamilyOptions,
    family_of,
)
from symplid.dynamics._hamiltonians import is_hamiltonian
from symplid.dynamics._integrators import INTEGRATORS, get_integrator
from symplid.dynamics._nonseparable import TaoIntegrator
from symplid.dynamics._separable import has_kinetic
from symplid.dynamics._user_models import QUADRATIC, is_user_model
from symplid.model._priors import Prior, as_prior
from symplid.workflow._driven import hamiltonian_parameters, is_driven
from symplid.workflow._settings_schema import ModelSettings, PriorSettings, Settings
from symplid.workflow._validate import SettingsError

__all__ = [
    "NONSEPARABLE_DEFAULT",
    "build_model_family",
    "check_model_family",
    "family_key",
    "family_options",
    "family_prior",
    "follow_model",
    "model_description",
    "model_family",
    "with_family_prior",
]


def family_options(model: ModelSettings) -> FamilyOptions:
    """The options a family's builder reads, from the run's model settings."""
    return FamilyOptions(
        order=model.order,
        width=model.width,
        depth=model.depth,
        activation=model.activation,
        network_seed=model.network_seed,
        parameters=hamiltonian_parameters(model),  # a force's own are not H's
        kinetic=model.kinetic,
        max_expression_size=model.max_expression_size,
    )


def model_family(model: ModelSettings) -> Family:
    """The family that ``model.hamiltonian`` / ``model.potential`` name
    (:func:`~symplid.dynamics._families.family_of`)."""
    return family_of(model.hamiltonian, model.potential)


def _shortened(text: str, limit: int) -> str:
    text = " ".join(text.split())
    if len(text) <= limit:
        return text
    return f"{text[: (2 * limit) // 3]} … {text[-(limit // 3):]} ({len(text):,} characters)"


def model_description(model: ModelSettings, limit: int = 200) -> str:
    """The model of these settings in words, as the user wrote it: a user's expression (at
    most ``limit`` characters of it) or file with its declared parameters, else the family
    (``"polynomial U(q) of order 3"``), and ``", damped"`` for a damped model, the force for
    a driven one."""
    family = model_family(model)
    damped = ", damped" if model.damping else ""
    if is_driven(model):  # the force is part of the model, whatever the family
        damped += f", force F = {_shortened(model.force, limit)}"
    if family.name == "user":
        whole = is_user_model(model.hamiltonian)
        kind, text = ("H(q, p)", model.hamiltonian) if whole else ("U(q)", model.potential)
        out = (f"{kind} from {text.strip()}" if text.strip().startswith("file:")
               else f"{kind} = {_shortened(text, limit)}")
        if not whole and model.kinetic != QUADRATIC:
            out += f", T(p) = {_shortened(model.kinetic, limit)}"
        names = ", ".join(p.name for p in model.parameters) or "none"
        return f"{out} (parameters: {names}){damped}"
    if family.name == "polynomial":
        return f"polynomial U(q) of order {model.order}{damped}"
    if family.name == "polynomial-qp":
        return f"polynomial H(q, p) of order {model.order}"
    if family.neural:
        return (f"{family.name} network, {model.width} units × {model.depth} hidden layers "
                f"({model.activation}){damped}")
    return f"{family.name}: {family.description}{damped}"


def build_model_family(dim: int, model: ModelSettings) -> Any:
    """The potential or Hamiltonian of ``dim`` coordinates that the model settings describe.

    A user's expression is parsed here: a run builds it once
    (:class:`~symplid.workflow._plan.ModelPlan`) and asks that object afterwards."""
    return model_family(model).build(dim, family_options(model))


def family_key(model: ModelSettings) -> tuple[Any, ...]:
    """The model settings that :func:`build_model_family` reads: two settings with the same
    key build the same U or H (a refit at another ``dt`` or with another process noise
    reuses the object)."""
    return (model_family(model).name, model.hamiltonian, model.potential,
            *dataclasses.astuple(family_options(model)))


def family_prior(model: ModelSettings) -> Prior:
    """The default coefficient prior of the family that model settings name.

    The family's :attr:`~symplid.dynamics._families.Family.coefficient_prior` (``"mlp"``:
    Normal(0, 1) on every weight), else the paper's Laplace(0, 10). A settings file or
    ``--set`` that gives ``priors.coefficients`` overrides it.
    """
    return _coefficient_prior(model_family(model))


def _coefficient_prior(family: Family) -> Prior:
    prior = family.coefficient_prior
    return as_prior(prior, "coefficient prior") if prior else PriorSettings().coefficients


def with_family_prior(data: dict[str, Any]) -> dict[str, Any]:
    """``priors.coefficients`` left out: the model family's default prior."""
    priors = data.get("priors", {})
    model = data.get("model", {})
    if not isinstance(priors, Mapping) or "coefficients" in priors or not isinstance(
            model, Mapping):
        return data
    names = {k: model[k] for k in ("potential", "hamiltonian") if isinstance(model.get(k), str)}
    try:
        family = family_of(names.get("hamiltonian", SEPARABLE),
                           names.get("potential", DEFAULT_POTENTIAL))
    except (KeyError, ValueError):  # an unknown family: the validator says so, with a suggestion
        return data
    prior = _coefficient_prior(family)
    table = {("prior" if k == "family" else k): v for k, v in prior.to_dict().items()}
    return {**data, "priors": {**priors, "coefficients": table}}




#: The integrator a user's non-separable H gets when the settings keep the default leapfrog.
NONSEPARABLE_DEFAULT = "tao"


def follow_model(settings: Settings, dim: int, family: Any = None) -> Settings:
    """A user's non-separable H with the default leapfrog: ``model.integrator`` becomes
    :data:`NONSEPARABLE_DEFAULT` (explicit, symplectic in the extended phase space), and
    ``prediction.integrator`` left at leapfrog follows ``model.integrator``.

    ``family``: the model's U or H already built for ``dim`` (the run's
    :class:`~symplid.workflow._plan.ModelPlan`), else built here."""
    model = settings.model
    if model_family(model).name != "user" or not is_user_model(model.hamiltonian):
        return settings
    if family is None:
        try:
            family = build_model_family(dim, model)
        except ValueError:  # check_model_family says what is wrong
            return settings
    if not is_hamiltonian(family):
        return settings
    default = "rk4" if is_driven(model) else NONSEPARABLE_DEFAULT  # Tao's has no forced form
    integrator = default if model.integrator == "leapfrog" else model.integrator
    prediction = settings.prediction
    if prediction.integrator == "leapfrog":
        prediction = dataclasses.replace(prediction, integrator=integrator)
    return dataclasses.replace(settings, model=dataclasses.replace(model, integrator=integrator),
                               prediction=prediction)


def check_model_family(settings: Settings, dim: int, source: str, family: Any = None) -> int:
    """Check the model's U or H against the integrators; its number of parameters.

    The family of ``model.hamiltonian``/``model.potential`` is built for the data's dimension
    ``dim`` (unless ``family`` is that object already, built by the run's
    :class:`~symplid.workflow._plan.ModelPlan`). A non-separable H needs a learning and a
    prediction integrator that accept it (not leapfrog or Yoshida), no constant mass and no
    damping; ``model.binding`` is Tao's ω only.
    """
    model = settings.model
    user = model_family(model).name == "user"
    if model.kinetic != QUADRATIC and not (user and model.hamiltonian == "separable"):
        raise SettingsError(source, "model.kinetic", "is the T(p) of a user's potential "
                            "(model.potential = an expression or file:PATH:NAME); a whole H "
                            "carries its own")
    if model.parameters and not user and not is_driven(model):
        raise SettingsError(source, "model.parameters", "declares parameters of a user's "
                            "model, but the model is the family "
                            f"{model_family(model).name!r}; write model.potential or "
                            "model.hamiltonian as an expression or file:PATH:NAME")
    try:
        family = build_model_family(dim, model) if family is None else family
    except ValueError as err:
        if user:
            raise SettingsError(source, None, str(err)) from None
        key = "model.hamiltonian" if model.hamiltonian != "separable" else "model.potential"
        raise SettingsError(source, key, f"({model.hamiltonian}): {err}") from None
    if model.binding and not isinstance(get_integrator(model.integrator), TaoIntegrator):
        raise SettingsError(source, "model.binding", f"is Tao's ω; model.integrator is "
                            f"{model.integrator!r} (set binding = 0, or use 'tao'/'tao4')")
    if has_kinetic(family) and (model.damping or model.mass):
        raise SettingsError(source, "model.damping" if model.damping else "model.mass",
                            "needs T = ½pᵀM⁻¹p; the model has its own kinetic energy T(p)")
    if is_hamiltonian(family):
        if model.damping:
            raise SettingsError(source, "model.damping", f"is true but the Hamiltonian "
                                f"{model.hamiltonian!r} is not separable: the friction "
                                "−γM⁻¹p needs H = ½pᵀM⁻¹p + U(q)")
        for key, name in (("model.integrator", model.integrator),
                          ("prediction.integrator", settings.prediction.integrator)):
            if not get_integrator(name).nonseparable:
                choices = [n for n, e in INTEGRATORS.items() if e.nonseparable]
                raise SettingsError(source, key, f"{name!r} needs a separable H; the model's "
                                    f"Hamiltonian {model.hamiltonian!r} is not: choose one of "
                                    f"{', '.join(choices)}")
        if model.mass:
            raise SettingsError(source, "model.mass", "applies to a separable H only; "
                                f"{model.hamiltonian!r} carries its own mass")
    return int(family.num_params)
