"""Which prior each entry of θ gets, and the joint prior density (Section IV).

The paper places a Laplace prior on every potential coefficient (to encourage sparsity) and a
half-normal prior on every variance; those are the defaults of :class:`PriorSpec`:
Laplace(0, b = 10) and HalfNormal(1). The families themselves are in
:mod:`symplid.model._priors`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._potentials import coefficient_name
from symplid.model._priors import HalfNormal, Laplace, Prior, as_prior

Array = jax.Array

GROUPS = ("coefficients", "damping", "process_var", "obs_var", "obs_rel_var", "initial_state")
"""The groups of θ a :class:`PriorSpec` assigns priors to."""


def _default_coefficients() -> Prior:
    return Laplace(0.0, 10.0)


def _default_variance() -> Prior:
    return HalfNormal(1.0)


def _default_damping() -> Prior:
    return HalfNormal(1.0)


@dataclass(frozen=True)
class PriorSpec:
    """Which prior each parameter of θ gets: one per group, overridden per parameter name.

    Parameters
    ----------
    coefficients
        Prior of every potential coefficient (default Laplace(0, 10), the paper's b = 10).
    process_var, obs_var
        Priors of the process- and observation-noise variances (default HalfNormal(1)).
    obs_rel_var
        Prior of the relative variances of multiplicative observation noise (default
        HalfNormal(1); see :mod:`symplid.filters._noise`).
    initial_state
        For a learned initial state: the prior of the **offset** of each component from its
        centre (the first observation, see :class:`symplid.model._posterior.Posterior`). ``None``
        (default) lets the posterior choose a weakly informative Normal from the data.
        Must have support on the whole real line (normal or laplace).
    overrides
        ``{parameter name: prior}``: an **absolute** prior for that one parameter, e.g.
        ``{"c[q1^2]": Normal(0.5, 0.1), "x0[0].p1": Normal(0.3, 0.1)}``. Names are checked
        against the posterior's parameter names; a coefficient's bare monomial (``"q1^2"``,
        its name before coefficients were written ``c[...]``) is still understood.
    damping
        Prior of the damping rate γ of a damped model (default HalfNormal(1); γ is bounded
        below by 0 whatever its prior).

    Every field also accepts a ``to_dict`` mapping or text such as ``"laplace(0, 10)"``.
    """

    coefficients: Prior = field(default_factory=_default_coefficients)
    process_var: Prior = field(default_factory=_default_variance)
    obs_var: Prior = field(default_factory=_default_variance)
    initial_state: Prior | None = None
    obs_rel_var: Prior = field(default_factory=_default_variance)
    overrides: Mapping[str, Prior] = field(default_factory=dict)
    damping: Prior = field(default_factory=_default_damping)

    def __post_init__(self) -> None:
        for group in ("coefficients", "damping", "process_var", "obs_var", "obs_rel_var"):
            object.__setattr__(self, group, as_prior(getattr(self, group), f"prior of {group}"))
        if self.initial_state is not None:
            prior = as_prior(self.initial_state, "prior of initial_state")
            if prior.support != (-math.inf, math.inf):
                raise ValueError(
                    "prior of initial_state: it is a prior on the offset from the first "
                    f"observation, so it must allow any real value (normal or laplace), got {prior}"
                )
            object.__setattr__(self, "initial_state", prior)
        if not isinstance(self.overrides, Mapping):
            raise TypeError("overrides must be a mapping {parameter name: prior}")
        object.__setattr__(
            self,
            "overrides",
            {coefficient_name(str(k)): as_prior(v, f"prior of {k!r}")
             for k, v in self.overrides.items()},
        )

    @classmethod
    def from_dict(cls, spec: Mapping[str, Any]) -> PriorSpec:
        """From ``{group or parameter name: prior}`` (priors as dicts, text or objects).

        Keys are the groups (``coefficients``, ``damping``, ``process_var``, ``obs_var``,
        ``obs_rel_var``, ``initial_state``), ``variances`` (all the variances at once, as in
        the settings file),
        ``overrides`` (a nested mapping), or any other string, read as a parameter name.
        """
        if isinstance(spec, PriorSpec):
            return spec
        if not isinstance(spec, Mapping):
            raise TypeError(f"a prior specification must be a mapping, got {type(spec).__name__}")
        kwargs: dict[str, Any] = {}
        overrides: dict[str, Any] = {}
        for key, value in spec.items():
            if key == "variances":
                kwargs.setdefault("process_var", value)
                kwargs.setdefault("obs_var", value)
                kwargs.setdefault("obs_rel_var", value)
            elif key in GROUPS:
                kwargs[key] = value
            elif key == "overrides":
                overrides.update(value)
            else:
                overrides[str(key)] = value
        return cls(**kwargs, overrides=overrides)

    def to_dict(self) -> dict[str, Any]:
        """Groups and overrides as plain dicts (``initial_state`` None means the default)."""
        return {
            "coefficients": self.coefficients.to_dict(),
            "damping": self.damping.to_dict(),
            "process_var": self.process_var.to_dict(),
            "obs_var": self.obs_var.to_dict(),
            "obs_rel_var": self.obs_rel_var.to_dict(),
            "initial_state": None if self.initial_state is None else self.initial_state.to_dict(),
            "overrides": {k: v.to_dict() for k, v in self.overrides.items()},
        }

    def group_prior(self, group: str) -> Prior | None:
        """The prior of a group (``None`` for the data-centred initial-state default)."""
        if group == "parameters":  # a user model's declared parameters: their own priors
            return self.coefficients
        if group not in GROUPS:
            raise ValueError(f"unknown group {group!r}; the groups are {', '.join(GROUPS)}")
        return getattr(self, group)

    def check_names(self, names: Sequence[str]) -> None:
        """Raise ``ValueError`` if an override names no parameter of θ."""
        known = {coefficient_name(str(n)) for n in names}
        unknown = [k for k in self.overrides if k not in known]
        if unknown:
            raise ValueError(
                f"prior given for unknown parameter(s) {', '.join(map(repr, unknown))}; "
                f"the parameters are {', '.join(names)}"
            )


def log_density_sum(priors: Sequence[Prior], theta: Array) -> Array:
    """Σ_i log p_i(θ_i): the joint log density of independent priors (−∞ off any support)."""
    theta = jnp.asarray(theta)
    if theta.shape[-1] != len(priors):
        raise ValueError(f"θ has {theta.shape[-1]} entries but {len(priors)} priors were given")
    total = jnp.zeros(theta.shape[:-1])
    for prior, index in _shared(priors):
        total = total + jnp.sum(prior.log_density(theta[..., index]), axis=-1)
    return total


def _shared(priors: Sequence[Prior]) -> list[tuple[Prior, np.ndarray]]:
    """The distinct priors, each with the indices of the parameters it holds, in order of
    first appearance: a network's thousand weights that share one prior are evaluated as one
    vector (one traced expression instead of a thousand)."""
    groups: dict[Any, tuple[Prior, list[int]]] = {}
    for i, prior in enumerate(priors):
        key: Any = prior  # the families are frozen dataclasses: equal fields, equal prior
        try:
            hash(prior)
        except TypeError:  # a user's prior that is not hashable stands alone
            key = ("unhashable", i)
        groups.setdefault(key, (prior, []))[1].append(i)
    return [(prior, np.asarray(index)) for prior, index in groups.values()]


__all__ = ["GROUPS", "PriorSpec", "log_density_sum"]
