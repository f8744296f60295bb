"""symplid: Bayesian identification of Hamiltonian dynamics from sparse, noisy data.

The library puts a symplectic integrator inside the likelihood of a noisy state-space model
and turns it into a marginal likelihood with an unscented Kalman filter (seed paper,
Theorem 1 and eq. 14).

Float64 is switched on when the package is imported: the filter's covariances and the
sampler's acceptance ratios are not trustworthy in float32. This is the only global JAX
setting the package touches. Before JAX is imported, :func:`symplid.runtime.configure_xla`
asks XLA to compile small loops whole (merged with the user's ``XLA_FLAGS``; the numbers agree
to rounding, the filter runs several times faster; ``SYMPLID_XLA_FLAGS=off`` opts out).
"""

from __future__ import annotations

from symplid import runtime

runtime.configure_xla()  # must run before JAX starts its backend

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from symplid.dynamics.hamiltonians import (  # noqa: E402
    DoublePendulum,
    FunctionHamiltonian,
    Hamiltonian,
    PolynomialHamiltonian,
    PositionDependentMass,
    SeparableHamiltonian,
)
from symplid.dynamics.integrators import INTEGRATORS, Integrator, get_integrator  # noqa: E402
from symplid.dynamics.neural import MLPHamiltonian, MLPPotential  # noqa: E402
from symplid.dynamics.potentials import (  # noqa: E402
    FunctionPotential,
    Polynomial,
    Potential,
    hamiltonian,
)
from symplid.dynamics.systems import SYSTEMS, System, get_system  # noqa: E402
from symplid.inference import baselines, predict, samplers  # noqa: E402
from symplid.inference.diagnostics import summary  # noqa: E402
from symplid.inference.map import BoundWarning, MapResult, find_map  # noqa: E402
from symplid.inference.samplers import sample  # noqa: E402
from symplid.model.data import DataError, Observations  # noqa: E402
from symplid.model.posterior import Posterior  # noqa: E402
from symplid.model.priors import HalfNormal, Laplace, LogNormal, Normal, Uniform  # noqa: E402
from symplid.model.simulate import simulate, true_trajectory  # noqa: E402
from symplid.model.statespace import HamiltonianModel  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "INTEGRATORS",
    "SYSTEMS",
    "BoundWarning",
    "DataError",
    "DoublePendulum",
    "FunctionHamiltonian",
    "FunctionPotential",
    "HalfNormal",
    "Hamiltonian",
    "HamiltonianModel",
    "Integrator",
    "Laplace",
    "LogNormal",
    "MLPHamiltonian",
    "MLPPotential",
    "MapResult",
    "Normal",
    "Observations",
    "Polynomial",
    "PolynomialHamiltonian",
    "PositionDependentMass",
    "Posterior",
    "Potential",
    "SeparableHamiltonian",
    "System",
    "Uniform",
    "__version__",
    "baselines",
    "find_map",
    "get_integrator",
    "get_system",
    "hamiltonian",
    "predict",
    "sample",
    "samplers",
    "simulate",
    "summary",
    "true_trajectory",
]
