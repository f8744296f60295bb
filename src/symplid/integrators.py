"""Integrators: the registry of one-step methods (eqs 5–6) and the pieces to add one.

A model's ``integrator`` (and the settings' ``model.integrator``, the CLI's ``--integrator``)
is a name in :data:`INTEGRATORS` or an :class:`Integrator`. A new method is one registration:
a symplectic composition from its weights (:func:`symplectic_integrator`), a Runge–Kutta
method from its tableau (:func:`runge_kutta_integrator`), or any step
``step(dynamics, q, p, dt) -> (q⁺, p⁺)`` that reads the :class:`Dynamics` it is given. The
first two carry their method as data (:attr:`Integrator.scheme`, a :class:`Composition` or a
:class:`ButcherTableau`), checked against the declared order when made.
"""

from symplid.dynamics._integrators import (
    INTEGRATORS,
    Dynamics,
    GeneralDynamics,
    Integrator,
    get_integrator,
    runge_kutta_integrator,
    symplectic_integrator,
)
from symplid.dynamics._schemes import ButcherTableau, Composition

__all__ = [
    "INTEGRATORS",
    "ButcherTableau",
    "Composition",
    "Dynamics",
    "GeneralDynamics",
    "Integrator",
    "get_integrator",
    "runge_kutta_integrator",
    "symplectic_integrator",
]
