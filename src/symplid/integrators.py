"""Integrators: the registry of one-step methods (eqs 5–6) and the pieces to add one.

A model's ``integrator`` (and the settings' ``model.integrator``, the CLI's ``--integrator``)
is a name in :data:`INTEGRATORS` or an :class:`Integrator`. A new method is one registration:
a symplectic composition from its weights (:func:`symplectic_integrator`), a Runge–Kutta
method from its tableau (:func:`runge_kutta_integrator`), or any step
``step(dynamics, q, p, dt) -> (q⁺, p⁺)`` that reads the :class:`Dynamics` it is given. The
first two carry their method as data (:attr:`Integrator.scheme`, a :class:`Composition` or a
:class:`ButcherTableau`), checked against the declared order when made.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "INTEGRATORS": "symplid.dynamics._integrators",
    "ButcherTableau": "symplid.dynamics._schemes",
    "Composition": "symplid.dynamics._schemes",
    "Dynamics": "symplid.dynamics._integrators",
    "GeneralDynamics": "symplid.dynamics._integrators",
    "Integrator": "symplid.dynamics._integrators",
    "get_integrator": "symplid.dynamics._integrators",
    "runge_kutta_integrator": "symplid.dynamics._integrators",
    "symplectic_integrator": "symplid.dynamics._integrators",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
