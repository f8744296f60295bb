"""Priors: the distributions over θ, their assignment to its parameters, and the registry.

The paper's defaults (Section IV) are Laplace(0, 10) on every coefficient and HalfNormal(1) on
every variance; a :class:`PriorSpec` (``Posterior(..., priors=...)``) changes them per group or
per parameter. The families are the registry :data:`PRIOR_FAMILIES` (the settings file's
``family`` names); a new family is a frozen dataclass subclass of :class:`Prior`, registered.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "PRIOR_FAMILIES": "symplid.model._priors",
    "HalfNormal": "symplid.model._priors",
    "Laplace": "symplid.model._priors",
    "LogNormal": "symplid.model._priors",
    "Normal": "symplid.model._priors",
    "Prior": "symplid.model._priors",
    "PriorSpec": "symplid.model._prior_spec",
    "Uniform": "symplid.model._priors",
    "as_prior": "symplid.model._priors",
    "parse_prior": "symplid.model._priors",
    "prior_from_dict": "symplid.model._priors",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
