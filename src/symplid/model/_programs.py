"""A model's compiled likelihood programs, shared by structure.

A model holds settings; :func:`symplid.model._backends.select` picks the backend that computes
its likelihood, and :func:`compiled` returns that backend's jitted program
``fn(theta, inputs, ys, masks, x0, P0)``, built once per **structure**: the model's normal
fields that a backend's ``build`` may read (:func:`structure_key`), the backend and the two
facts of the prepared data that shape the program (the most substeps in a gap, whether all
gaps have as many). Two models with equal structure therefore share one compiled program,
and so does every posterior built on them.

The programs are kept on the model's Hamiltonian (:func:`symplid._compiled.cached`), the one
setting that is an arbitrary user object: they live as long as it does, and no module-level
table keeps models or data alive. A Hamiltonian without a ``__dict__`` keeps nothing: its
models then each keep their own programs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable
from typing import Any

import jax
import numpy as np

from symplid._compiled import cached
from symplid.dynamics._nonseparable import TaoIntegrator
from symplid.filters._backends import LikelihoodBackend, ModelLike
from symplid.model._likelihood import JAX_BACKEND, PreparedData

__all__ = ["compiled", "structure_key"]

#: The fields that are not part of a program's structure: the Hamiltonian owns the programs
#: (it is the cache itself), the ``backend`` setting only chooses among them, and the learning
#: step ``dt`` reaches a program only through the prepared data (each gap's substep size and
#: count are arguments; the most substeps in a gap, which fixes the loop, is in the key) and
#: through Tao's ω, which the integrator carries: a model refitted at another dt with as many
#: substeps per gap at most runs the same program.
_NOT_STRUCTURE = ("hamiltonian", "backend", "dt")


def structure_key(model: ModelLike) -> tuple[Hashable, ...]:
    """The model's normal fields, but its Hamiltonian, backend setting and dt, as a hashable key.

    Arrays (mass, observation matrix) enter by shape and value, an observation function by
    identity, Tao's integrator by its method and binding constant ω (it is rebuilt for each
    model), every other integrator as itself. Computed once per model (its fields are frozen).
    """
    return cached(model, "structure-key", lambda: tuple(
        (name, _hashable(getattr(model, name)))
        for name in (f.name for f in dataclasses.fields(model)) if name not in _NOT_STRUCTURE
    ))


def compiled(model: ModelLike, prepared: PreparedData,
             backend: LikelihoodBackend = JAX_BACKEND) -> Callable[..., Any]:
    """The jitted ``fn(theta, inputs, ys, masks, x0, P0)`` of ``backend`` for ``model``'s
    structure on data shaped like ``prepared`` (built on first use, then shared)."""
    key = ("likelihood", backend.name, structure_key(model), prepared.max_steps,
           prepared.uniform_steps)
    entry = backend
    owner = model.hamiltonian if hasattr(model.hamiltonian, "__dict__") else model
    return cached(owner, key, lambda: jax.jit(entry.build(model, prepared)))


def _hashable(value: Any) -> Hashable:
    if isinstance(value, np.ndarray):
        return ("array", value.shape, value.dtype.str, value.tobytes())
    if isinstance(value, TaoIntegrator):
        return ("tao", value.name, value.order, value.weights, value.binding)
    return value
