"""Priors placed by the data, evaluated with their place as an argument.

A learned initial state's prior is centred on the first observation and scaled by the size of
the motion (:func:`~symplid.model._initial_state.initial_state_prior`): its location and scale
are numbers of the data set. Written into a compiled program as constants, they would make
the program of every data set a different one, and JAX's persistent compilation cache could
not serve a second data set of the same shape. For a location–scale family (normal,
Laplace) the density is that of the standard member at the standardised value::

    log p(x; c, s) = log p((x − c)/s; 0, 1) − log s

so the program holds the standard prior and takes (c, s) as arrays beside the observations
(:class:`~symplid.model._posterior.Posterior` puts them in its ``data``): one program for every
data set of the same shape.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from symplid.model._prior_spec import log_density_sum
from symplid.model._priors import Laplace, Normal, Prior

__all__ = ["LocatedPriors", "located_log_prior"]

Array = jax.Array


class LocatedPriors(NamedTuple):
    """Which entries of θ have a location–scale prior placed by the data, and where."""

    index: np.ndarray  # entries of θ
    loc: np.ndarray  # their priors' locations c
    scale: np.ndarray  # and scales s
    unit: tuple[Prior, ...]  # every entry's prior, those of ``index`` at loc 0 and scale 1

    @classmethod
    def of(cls, priors: Sequence[Prior], candidates: Sequence[int]) -> LocatedPriors | None:
        """The entries among ``candidates`` whose prior is a normal or Laplace one (None
        when there is none)."""
        index = [i for i in candidates if type(priors[i]) in (Normal, Laplace)]
        if not index:
            return None
        unit = list(priors)
        for i in index:
            unit[i] = dataclasses.replace(priors[i], loc=0.0, scale=1.0)
        return cls(np.asarray(index, dtype=int),
                   np.array([priors[i].loc for i in index], dtype=float),
                   np.array([priors[i].scale for i in index], dtype=float), tuple(unit))


def located_log_prior(located: LocatedPriors, theta: Array, loc: Array, scale: Array) -> Array:
    """Σ_i log π_i(θ_i) with the located entries' (c, s) given as arrays (module docstring);
    the bounds are not checked here."""
    z = (theta[..., located.index] - loc) / scale
    standard = theta.at[..., located.index].set(z)
    return log_density_sum(located.unit, standard) - jnp.sum(jnp.log(scale))
