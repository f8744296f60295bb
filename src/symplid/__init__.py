"""symplid: Bayesian identification of Hamiltonian dynamics from sparse, noisy data.

The library puts a symplectic integrator inside the likelihood of a noisy state-space model
and turns it into a marginal likelihood with an unscented Kalman filter (seed paper,
Theorem 1 and eq. 14).

Float64 is switched on when the package is imported: the filter's covariances and the
sampler's acceptance ratios are not trustworthy in float32. This is the only global JAX
setting the package touches. Before JAX is imported, :func:`symplid.runtime.configure_xla`
asks XLA to compile small loops whole (merged with the user's ``XLA_FLAGS``; the numbers agree
to rounding, the filter runs several times faster; ``SYMPLID_XLA_FLAGS=off`` opts out).

The public surface is ``__all__`` below: the names of the top level and the public namespaces
(``symplid.integrators``, ``symplid.priors``, ``symplid.samplers``, ...), each with its own
``__all__``; everything else is internal and may change. The public names are imported when
first used (PEP 562), so that ``import symplid`` (and ``symplid --version``, ``symplid --help``)
does not start JAX. Float64 holds all the same: when JAX is already imported it is switched on
at once; otherwise ``JAX_ENABLE_X64`` is set, which JAX reads when it starts, so any
``symplid`` module that imports JAX computes in float64 from its first array.
"""

from __future__ import annotations

import os
import sys

from symplid import _moved, runtime
from symplid._namespace import lazy_attributes

runtime.configure_xla()  # must run before JAX starts its backend
_moved.install()  # the old paths of the internal modules, for one version

if "jax" in sys.modules:
    sys.modules["jax"].config.update("jax_enable_x64", True)
else:
    os.environ["JAX_ENABLE_X64"] = "1"  # read by JAX when it starts

#: The top level's public names: name -> the module that defines it (imported on first access).
#: Making a name public here is this one entry (``__all__`` below is built from it).
_PUBLIC = {
    "INTEGRATORS": "symplid.dynamics._integrators",
    "Integrator": "symplid.dynamics._integrators",
    "get_integrator": "symplid.dynamics._integrators",
    "DoublePendulum": "symplid.dynamics._hamiltonians",
    "FunctionHamiltonian": "symplid.dynamics._hamiltonians",
    "Hamiltonian": "symplid.dynamics._hamiltonians",
    "PolynomialHamiltonian": "symplid.dynamics._hamiltonians",
    "PositionDependentMass": "symplid.dynamics._hamiltonians",
    "SeparableHamiltonian": "symplid.dynamics._hamiltonians",
    "MLPHamiltonian": "symplid.dynamics._neural",
    "MLPPotential": "symplid.dynamics._neural",
    "NeuralMapResult": "symplid.inference.map",
    "find_map_neural": "symplid.inference.map",
    "neural_posterior": "symplid.inference.map",
    "Force": "symplid.dynamics._forcing",
    "user_force": "symplid.dynamics._forcing",
    "FunctionPotential": "symplid.dynamics._potentials",
    "Polynomial": "symplid.dynamics._potentials",
    "Potential": "symplid.dynamics._potentials",
    "hamiltonian": "symplid.dynamics._potentials",
    "OBSERVATION_NOISE": "symplid.filters._noise",
    "SYSTEMS": "symplid.dynamics._systems",
    "System": "symplid.dynamics._systems",
    "get_system": "symplid.dynamics._systems",
    "summary": "symplid.inference._diagnostics",
    "BoundWarning": "symplid.inference.map",
    "MapResult": "symplid.inference.map",
    "MultipleOptimaWarning": "symplid.inference.map",
    "find_map": "symplid.inference.map",
    "discover": "symplid.workflow._discover",
    "sample": "symplid.sampling",
    "TargetsOutOfReach": "symplid.sampling",
    "DataError": "symplid.model._data",
    "Observations": "symplid.model._data",
    "AnalyticInputs": "symplid.model._inputs",
    "SampledInputs": "symplid.model._inputs",
    "Posterior": "symplid.model._posterior",
    "HalfNormal": "symplid.model._priors",
    "Laplace": "symplid.model._priors",
    "LogNormal": "symplid.model._priors",
    "Normal": "symplid.model._priors",
    "Uniform": "symplid.model._priors",
    "simulate": "symplid.model._simulate",
    "true_trajectory": "symplid.model._simulate",
    "HamiltonianModel": "symplid.model._statespace",
}
#: The public namespaces (``symplid.priors``, ...): modules whose ``__all__`` is public too, under
#: the namespace's path (``symplid.priors.Prior``). Most are thin modules beside this file, each
#: a table like ``_PUBLIC`` of the names it shows from the layers (``symplid._namespace``). The
#: docs' API reference and ``tests/test_public_surface.py`` read the whole surface from
#: ``__all__`` below and these modules' ``__all__``.
_NAMESPACES = (
    "backends",
    "baselines",
    "integrators",
    "io",
    "noise",
    "plotting",
    "predict",
    "priors",
    "runtime",
    "samplers",
    "systems",
    "workflow",
)


__getattr__, __dir__ = lazy_attributes(
    globals(), _PUBLIC, {name: f"symplid.{name}" for name in _NAMESPACES}
)

__version__ = "0.1.0"

__all__ = ["__version__", *_PUBLIC, *_NAMESPACES]
