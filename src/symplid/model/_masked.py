"""A posterior over a subset of a model's terms, the subset chosen at run time.

Which terms of a library does a potential need (:mod:`symplid.inference._term_search`)? Each
candidate subset is the library's model with the other terms' coefficients fixed at zero. A
model of its own for every subset would compile its likelihood, gradient and Hessian again
for each of the tens of subsets a search visits; :class:`MaskedPosterior` compiles them once
for the whole library instead, because the subset enters the programs as an argument
(``data``), like the observations do.

θ keeps the library's full layout. An excluded coefficient is set to zero before the
likelihood sees it, its prior is taken out (it is a constant there, log π_j(0)), and the
coordinate itself gets a standard normal density in its place::

    log π_S(θ) = log π(θ ∘ 1_S) − Σ_{j∉S} log π_j(0) + Σ_{j∉S} log N(θ_j; 0, 1)

The placeholder is a normalised density independent of everything else, so it integrates to
one, exactly, in the Laplace evidence and in the quadrature evidence (both are Gaussian in the
coefficients): log p(Y | S) is the evidence of the subset's own model, and the MAP of the
placeholder is zero. A MAP search, its Hessian and its evidence
(:func:`symplid.inference.map.find_map`) then run on the view unchanged, and the compiled
programs (cached on the view) serve every subset: :meth:`MaskedPosterior.select` changes the
subset, which the programs read at each call through :attr:`MaskedPosterior.data`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array

_LOG_UNIT_NORMAL = -0.5 * math.log(2.0 * math.pi)


class SubsetData:
    """The arguments of a :class:`MaskedPosterior`'s compiled programs: its current subset
    (which coefficients are excluded, their prior's log density at zero) and the observations.

    It is a JAX pytree read **at each call**: a program compiled once receives the subset
    selected when it is called.
    """

    def __init__(self, view: MaskedPosterior) -> None:
        self.view = view

    def flatten(self) -> tuple[tuple[Any, ...], None]:
        view = self.view
        return (view.excluded_weights, view.excluded_log_prior, view.base.data), None


jax.tree_util.register_pytree_node(
    SubsetData, SubsetData.flatten, lambda _aux, children: tuple(children)
)


class MaskedPosterior:
    """The posterior of ``base`` with only the selected coefficients free (module docstring).

    Parameters
    ----------
    base
        A :class:`~symplid.model._posterior.Posterior` (anything with ``space``,
        ``log_density_with`` and ``data``) whose model holds the whole library.
    terms
        The positions in θ of the library's coefficients that a subset may leave out; every
        other parameter (variances, damping, initial states) is always free.

    Attributes
    ----------
    space, param_names, param_groups, num_params, lower, upper, priors, datasets
        Those of ``base`` (θ keeps the library's layout).
    included
        The boolean mask over ``terms`` of the current subset.
    """

    def __init__(self, base: Any, terms: Sequence[int]) -> None:
        self.base = base
        self.terms = np.asarray(terms, dtype=int)
        if self.terms.size == 0 or np.unique(self.terms).size != self.terms.size:
            raise ValueError("terms: give the distinct positions of at least one coefficient")
        if np.any(self.terms < 0) or np.any(self.terms >= base.num_params):
            raise ValueError(f"terms: positions must lie in 0..{base.num_params - 1}")
        self.space = base.space
        self.datasets = getattr(base, "datasets", None)
        self._log_prior_at_zero = np.array(
            [float(base.priors[i].log_density(0.0)) for i in self.terms])
        if not np.all(np.isfinite(self._log_prior_at_zero)):
            raise ValueError("every library coefficient's prior must allow the value 0")
        self.data = SubsetData(self)
        self.select(np.ones(self.terms.size, dtype=bool))

    # ------------------------------------------------------------------ the layout of θ
    @property
    def param_names(self) -> tuple[str, ...]:
        return self.base.param_names

    @property
    def param_groups(self) -> tuple[str, ...]:
        return self.base.param_groups

    @property
    def num_params(self) -> int:
        return int(self.base.num_params)

    @property
    def priors(self) -> tuple[Any, ...]:
        return self.base.priors

    @property
    def lower(self) -> np.ndarray:
        return self.base.lower

    @property
    def upper(self) -> np.ndarray:
        return self.base.upper

    # ------------------------------------------------------------------ the subset
    def select(self, included: Sequence[bool]) -> None:
        """Make ``included`` (one flag per entry of ``terms``) the current subset."""
        mask = np.asarray(included, dtype=bool)
        if mask.shape != self.terms.shape:
            raise ValueError(f"included: expected {self.terms.size} flags, got {mask.shape}")
        self.included = mask.copy()
        weights = np.zeros(self.num_params)
        weights[self.terms[~mask]] = 1.0
        self.excluded_weights = jnp.asarray(weights)
        self.excluded_log_prior = jnp.asarray(float(np.sum(self._log_prior_at_zero[~mask])))

    def embed(self, theta: Any) -> np.ndarray:
        """θ with the excluded coefficients at zero (the subset model's parameters)."""
        out = np.array(theta, dtype=float)
        out[self.terms[~self.included]] = 0.0
        return out

    # ------------------------------------------------------------------ densities
    def log_density_with(self, data: Any, theta: Array) -> Array:
        """log π_S(θ) of the module docstring; ``data`` is what :attr:`data` flattens to."""
        weights, log_prior_at_zero, observations = data
        theta = jnp.asarray(theta, dtype=float)
        kept = jnp.where(weights > 0, 0.0, theta)
        placeholder = jnp.sum(weights * (_LOG_UNIT_NORMAL - 0.5 * theta**2))
        total = self.base.log_density_with(observations, kept) - log_prior_at_zero + placeholder
        return jnp.where(jnp.isnan(total), -jnp.inf, total)

    def log_density(self, theta: Array) -> Array:
        """log π_S(θ) for the current subset (not compiled; the MAP search compiles its own)."""
        flat, _ = self.data.flatten()
        return self.log_density_with(flat, theta)

    def __repr__(self) -> str:
        return f"MaskedPosterior({int(self.included.sum())} of {self.terms.size} terms)"


__all__ = ["MaskedPosterior", "SubsetData"]
