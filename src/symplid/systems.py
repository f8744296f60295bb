"""Named systems: a potential, its true coefficients and an initial state, for simulations.

:func:`get_system` looks a name up in :data:`SYSTEMS` (``symplid simulate NAME`` and the
settings' ``data.system`` use the same names); the factories below build a :class:`System`
with other parameters (a longer FPU chain, another pendulum). A new system is one
registration of a factory that returns a :class:`System`.

The excitation signals that drive a simulated system (``symplid simulate --input NAME``) are
here too: :data:`SIGNALS` by name, and the factories :func:`multisine`, :func:`chirp` and
:func:`steps`, each returning u(t) as a function of NumPy times.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "SIGNALS": "symplid.model._signals",
    "SYSTEMS": "symplid.dynamics._systems",
    "System": "symplid.dynamics._systems",
    "chirp": "symplid.model._signals",
    "damped_pendulum": "symplid.dynamics._systems",
    "double_pendulum": "symplid.dynamics._systems",
    "double_well": "symplid.dynamics._systems",
    "fpu_chain": "symplid.dynamics._systems",
    "get_system": "symplid.dynamics._systems",
    "harmonic": "symplid.dynamics._systems",
    "henon_heiles": "symplid.dynamics._systems",
    "multisine": "symplid.model._signals",
    "steps": "symplid.model._signals",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
