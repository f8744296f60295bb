"""Likelihood backends: the one place where a new filter implementation is added.

A backend computes the UKF log marginal likelihood (Theorem 1) of a state-space model on
prepared data. The JAX reference ``"jax"`` (registered by :mod:`symplid.model.likelihood`)
handles every model and also returns the filtered moments; a faster backend, such as a
compiled kernel for the common models, is added with one call::

    from symplid.filters.backends import LIKELIHOOD_BACKENDS, LikelihoodBackend

    LIKELIHOOD_BACKENDS.register("kernel", LikelihoodBackend(
        name="kernel",
        supports=lambda model, prepared: None if model.noise == "isotropic" else "isotropic only",
        build=lambda model, prepared: kernel_loglik,  # (θ, inputs, ys, masks, x0, P0) -> ll
        priority=10,
    ))

``HamiltonianModel(..., backend="auto")`` then uses, for its log-likelihood, the supporting
backend of highest ``priority`` (ties: the first registered); ``backend="kernel"`` forces one.
``HamiltonianModel.filter`` (the moments) always runs the JAX reference.

This module lives in the filters layer and imports nothing from :mod:`symplid.model`: the
model and the prepared data are only named in type hints (as Protocols).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from symplid.registry import Registry

__all__ = [
    "LIKELIHOOD_BACKENDS",
    "LikelihoodBackend",
    "backend_names",
    "check_backend_name",
    "select_backend",
]

AUTO = "auto"


class ModelLike(Protocol):
    """What a backend may read from a model (see :class:`symplid.HamiltonianModel`)."""

    state_dim: int
    num_params: int


SupportsFn = Callable[[ModelLike, Any], "str | None"]
BuildFn = Callable[[ModelLike, Any], Callable[..., Any]]


@dataclass(frozen=True)
class LikelihoodBackend:
    """A way to compute the log marginal likelihood.

    Parameters
    ----------
    name
        The registered name.
    supports
        ``supports(model, prepared) -> None`` when the backend applies, else a short reason
        why not (``"only full-state observations"``). ``prepared`` is None when the question
        is about the model alone (at construction); it must then answer for typical data.
    build
        ``build(model, prepared) -> fn`` with ``fn(theta, inputs, ys, masks, x0, P0)``
        returning a ``FilterResult`` (``filtered_moments=True``) or the log-likelihood alone.
        ``fn`` must be jit-able; the model compiles and caches it.
    filtered_moments
        Whether ``fn`` returns the full ``FilterResult``.
    priority
        ``backend="auto"`` takes the supporting backend of highest priority (the JAX
        reference has 0).
    batch_width
        How many θ on the same data the backend evaluates together, in one batched call, at
        well under that many times the cost of one (1: a batch costs its size). A sampler
        that can choose how it batches its evaluations (DRAM's paired stages) reads it.
    custom_call
        Whether the backend's program is an opaque custom call: XLA:CPU then cannot compile
        a loop around it as one kernel, and a sampler's small linear algebra is cheaper as
        library calls than unrolled (DRAM's ``linalg``).
    description
        One line for help texts.
    """

    name: str
    supports: SupportsFn
    build: BuildFn
    filtered_moments: bool = False
    priority: int = 0
    batch_width: int = 1
    custom_call: bool = False
    description: str = ""


#: Every likelihood backend, by name. ``"jax"`` (the reference) is always there once
#: :mod:`symplid.model` is imported.
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
    detail = "; ".join(reasons) or "none is registered (import symplid.model)"
    raise ValueError(f"no likelihood backend applies to this model ({detail})")
