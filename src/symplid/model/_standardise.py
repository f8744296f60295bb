"""θ in standardised coordinates q' = q/a, p' = p/a (t' = t): the factors of θ = D θ'.

Under the position scale ``a`` each entry of θ scales by its group: the coefficients by the
potential's own law (:meth:`~symplid.dynamics._potentials.Polynomial.standardised`,
a^(2−|α|)), the process and additive observation variances Σ, Γ by a², a learned initial
state by a; the damping rate γ (1/time, the friction linear in p) and the relative variances
r of multiplicative noise are scale-free. :meth:`HamiltonianModel.standardised
<symplid.model._statespace.HamiltonianModel.standardised>` gives the map for a model's θ; the
fit in standardised coordinates and its results in the user's units are
:mod:`symplid.workflow._scaling`'s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from symplid.model._params import Reparameterisation

__all__ = ["standardised_factors", "standardised_map"]

_SQUARED = ("process_var", "obs_var")
_SCALE_FREE = ("damping", "obs_rel_var")


def standardised_factors(groups: Sequence[str], a: float,
                         coefficient_factors: Sequence[float]) -> np.ndarray:
    """D, entry by entry of θ with these ``groups``: θ = D θ'. ``coefficient_factors`` are
    the potential's law for its coefficients, in their order in θ."""
    a = float(a)
    laws = iter(np.asarray(coefficient_factors, dtype=float))
    out = np.ones(len(groups))
    for i, group in enumerate(groups):
        if group == "coefficients":
            out[i] = next(laws)
        elif group in _SQUARED:
            out[i] = a**2
        elif group == "initial_state":
            out[i] = a
        elif group not in _SCALE_FREE:
            raise ValueError(f"θ's group {group!r} has no law under a change of position "
                             "scale (standardising maps a polynomial model's θ)")
    return out


def standardised_map(hamiltonian: object, groups: Sequence[str], a: float) -> Reparameterisation:
    """θ = D θ' for a model whose Hamiltonian has a scaling law (``standardised(a)``: the
    polynomial potential) as the one :class:`~symplid.model._params.Reparameterisation` of θ
    (no bounds; its log-Jacobian Σ log D is what a log density loses)."""
    law = getattr(hamiltonian, "standardised", None)
    if law is None:
        raise ValueError(f"{type(hamiltonian).__name__} has no scaling law: standardising "
                         "maps the coefficients of a polynomial potential")
    return Reparameterisation.linear(standardised_factors(groups, a, law(a)))
