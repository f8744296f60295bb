"""Dynamics (layer 1): potentials, integrators, the trajectory solver, named systems.

Nothing here knows about noise, data or inference: :mod:`~symplid.dynamics._potentials`
(H = ½pᵀM⁻¹p + U(q), eqs 2 and 4), :mod:`~symplid.dynamics._integrators` (the registry of
one-step methods, eqs 5–6), :mod:`~symplid.dynamics._trajectory` (Ψ over a gap, eq. 14, and
fixed-step paths) and :mod:`~symplid.dynamics._systems` (the registry of named systems).
"""

__all__ = []
