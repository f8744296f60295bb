"""Likelihood backends: the implementations of the filter's log-likelihood, and the registry.

A model's ``backend="auto"`` takes the highest-priority entry of :data:`LIKELIHOOD_BACKENDS`
that supports it (the compiled kernel where it applies, the JAX reference otherwise); a name
forces one. A new backend is one registration of a :class:`LikelihoodBackend`: a build
function and the rule for when it applies.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "LIKELIHOOD_BACKENDS": "symplid.model._backends",
    "LikelihoodBackend": "symplid.filters._backends",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
