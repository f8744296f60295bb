"""The registry of likelihood backends, its built-in entries, and how a model's is chosen.

A backend (:class:`~symplid.filters._backends.LikelihoodBackend`) computes the UKF log
marginal likelihood (Theorem 1) of a state-space model on prepared data. The built-in
backends are listed at the end of this module, the one place that registers them:

* ``"jax"`` (:data:`symplid.model._likelihood.JAX_BACKEND`): the JAX reference, every model,
  the filtered moments as well as the log-likelihood (priority 0);
* ``"compiled"`` (:data:`symplid.model._kernel.COMPILED_BACKEND`): the C++ kernel, for the
  models it supports, when it is built (priority 10).

``HamiltonianModel(..., backend="auto")`` then uses, for its log-likelihood, the supporting
backend of highest ``priority`` (ties: the first registered); ``backend="kernel"`` forces one.
A user's backend is one more call::

    from symplid.filters._backends import LikelihoodBackend
    from symplid.model._backends import LIKELIHOOD_BACKENDS

    LIKELIHOOD_BACKENDS.register("mine", LikelihoodBackend(name="mine", ...))
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from symplid._registry import Registry
from symplid.filters._backends import LikelihoodBackend, ModelLike
from symplid.model._kernel import COMPILED_BACKEND
from symplid.model._likelihood import JAX_BACKEND
from symplid.model._programs import compiled

__all__ = [
    "AUTO",
    "LIKELIHOOD_BACKENDS",
    "backend_names",
    "check_backend",
    "check_backend_name",
    "loglik_program",
    "select",
    "select_backend",
]

#: The backend setting that lets the model choose.
AUTO = "auto"


#: Every likelihood backend, by name; the built-ins are registered at the end of this module.
LIKELIHOOD_BACKENDS: Registry[LikelihoodBackend] = Registry("likelihood backend")


def backend_names() -> tuple[str, ...]:
    """The choices of a model's ``backend`` setting: ``"auto"`` and every registered name."""
    return (AUTO, *LIKELIHOOD_BACKENDS.names())


def check_backend_name(name: str) -> str:
    """``"auto"`` or the canonical registered name; ``ValueError`` listing the choices."""
    if str(name).strip().lower() == AUTO:
        return AUTO
    if name not in LIKELIHOOD_BACKENDS:
        raise ValueError(
            LIKELIHOOD_BACKENDS.unknown_message(name).replace(
                "choose one of ", f"choose one of {AUTO}, "
            )
        )
    return LIKELIHOOD_BACKENDS.canonical(name)


def select_backend(name: str, model: ModelLike, prepared: Any = None) -> LikelihoodBackend:
    """The backend that computes ``model``'s likelihood on ``prepared`` (None: any data).

    ``name="auto"``: the supporting backend of highest priority (registration order breaks
    ties). A named backend that does not support the model is a ``ValueError`` with its reason.
    """
    name = check_backend_name(name)
    if name != AUTO:
        backend = LIKELIHOOD_BACKENDS.get_entry(name)
        reason = backend.supports(model, prepared)
        if reason is not None:
            raise ValueError(f"the likelihood backend {name!r} does not apply: {reason}")
        return backend
    candidates = sorted(
        enumerate(LIKELIHOOD_BACKENDS.values()), key=lambda item: (-item[1].priority, item[0])
    )
    reasons = []
    for _, backend in candidates:
        reason = backend.supports(model, prepared)
        if reason is None:
            return backend
        reasons.append(f"{backend.name}: {reason}")
    detail = "; ".join(reasons) or "none is registered"
    raise ValueError(f"no likelihood backend applies to this model ({detail})")


def check_backend(model: ModelLike) -> None:
    """``ValueError`` when the model forces a backend that does not support it."""
    if model.backend != AUTO:
        select_backend(model.backend, model)


def select(model: ModelLike, prepared: Any = None) -> LikelihoodBackend:
    """The backend that computes ``model``'s log-likelihood on ``prepared`` (None: any data),
    from the model's ``backend`` setting."""
    return select_backend(model.backend, model, prepared)


def loglik_program(model: ModelLike, prepared: Any) -> Callable[..., Any]:
    """The selected backend's compiled ``fn(theta, inputs, ys, masks, x0, P0) -> ll``
    (:func:`symplid.model._programs.compiled`: shared by equal-structure models)."""
    backend = select(model, prepared)
    fn = compiled(model, prepared, backend)
    return partial(_only_loglik, fn) if backend.filtered_moments else fn


def _only_loglik(fn: Callable[..., Any], *args: Any) -> Any:
    return fn(*args).log_likelihood


LIKELIHOOD_BACKENDS.register(JAX_BACKEND.name, JAX_BACKEND)
LIKELIHOOD_BACKENDS.register(COMPILED_BACKEND.name, COMPILED_BACKEND)
