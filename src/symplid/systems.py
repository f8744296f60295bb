"""Named systems: a potential, its true coefficients and an initial state, for simulations.

:func:`get_system` looks a name up in :data:`SYSTEMS` (``symplid simulate NAME`` and the
settings' ``data.system`` use the same names); the factories below build a :class:`System`
with other parameters (a longer FPU chain, another pendulum). A new system is one
registration of a factory that returns a :class:`System`.
"""

from symplid.dynamics._systems import (
    SYSTEMS,
    System,
    damped_pendulum,
    double_pendulum,
    double_well,
    fpu_chain,
    get_system,
    harmonic,
    henon_heiles,
)

__all__ = [
    "SYSTEMS",
    "System",
    "damped_pendulum",
    "double_pendulum",
    "double_well",
    "fpu_chain",
    "get_system",
    "harmonic",
    "henon_heiles",
]
