"""Likelihood backends: the implementations of the filter's log-likelihood, and the registry.

A model's ``backend="auto"`` takes the highest-priority entry of :data:`LIKELIHOOD_BACKENDS`
that supports it (the compiled kernel where it applies, the JAX reference otherwise); a name
forces one. A new backend is one registration of a :class:`LikelihoodBackend`: a build
function and the rule for when it applies.
"""

from symplid.filters._backends import LikelihoodBackend
from symplid.model._backends import LIKELIHOOD_BACKENDS

__all__ = ["LIKELIHOOD_BACKENDS", "LikelihoodBackend"]
