"""Priors: the distributions over θ, their assignment to its parameters, and the registry.

The paper's defaults (Section IV) are Laplace(0, 10) on every coefficient and HalfNormal(1) on
every variance; a :class:`PriorSpec` (``Posterior(..., priors=...)``) changes them per group or
per parameter. The families are the registry :data:`PRIOR_FAMILIES` (the settings file's
``family`` names); a new family is a frozen dataclass subclass of :class:`Prior`, registered.
"""

from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import (
    PRIOR_FAMILIES,
    HalfNormal,
    Laplace,
    LogNormal,
    Normal,
    Prior,
    Uniform,
    as_prior,
    parse_prior,
    prior_from_dict,
)

__all__ = [
    "PRIOR_FAMILIES",
    "HalfNormal",
    "Laplace",
    "LogNormal",
    "Normal",
    "Prior",
    "PriorSpec",
    "Uniform",
    "as_prior",
    "parse_prior",
    "prior_from_dict",
]
