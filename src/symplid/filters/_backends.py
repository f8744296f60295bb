"""What a likelihood backend is: a way to compute the UKF log marginal likelihood.

A backend computes the UKF log marginal likelihood (Theorem 1) of a state-space model on
prepared data. The registry of backends, :data:`symplid.model._backends.LIKELIHOOD_BACKENDS`,
lives in the model layer beside its two built-in entries (the JAX reference ``"jax"``, which
handles every model and also returns the filtered moments, and the compiled kernel); a faster
backend is added with one call::

    from symplid.filters._backends import LikelihoodBackend
    from symplid.model._backends import LIKELIHOOD_BACKENDS

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
model and the prepared data are only named in type hints (as Protocols). The selection
(:func:`symplid.model._backends.select_backend`) is in the model layer with the registry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

__all__ = ["BuildFn", "LikelihoodBackend", "ModelLike", "SupportsFn"]


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
