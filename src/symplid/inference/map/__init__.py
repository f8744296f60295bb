"""The MAP and what hangs on it (Sections II-B.2 and IV of the paper): one package.

The search (:func:`find_map`: L-BFGS-B from several starts with exact JAX gradients), its
starting points (the data start, perturbed starts, homotopies in the process noise), the checks
that a point found is a MAP worth reporting, the Hessian and the Laplace approximation there,
the evidence (Laplace and quadrature over the variances), the neural MAP, and the search's own
space θ ↔ u (:class:`SearchSpace`). The modules inside are private; this namespace is what
the rest of the package imports.

=================  ===============================================================
module             job
=================  ===============================================================
``_find``          :func:`find_map`: the starts, the search, the Hessian, the result
``_space``         :class:`SearchSpace`: θ ↔ u, where L-BFGS-B moves
``_search``        one L-BFGS-B run and its convergence test
``_starts``        starting points and distinct optima
``_data_start``    the data start: dynamics and momenta from the data
``_noise``         the observation noise the data show without a model
``_checks``        is the point found a MAP worth reporting (:class:`MapFailedError`)
``_result``        :class:`MapResult`, :class:`StartResult` and the MAP's warnings
``_homotopy``      MAP starts through the process noise's prior and likelihood
``_laplace``       the Hessian, its repair, the Laplace covariance
``_evidence``      the log evidence by quadrature over the variances
``_neural``        the MAP of a neural potential (Adam, then a Gauss–Newton precision)
=================  ===============================================================

The neural MAP (:func:`find_map_neural`) loads Equinox and Optax, so it is imported when first
asked for.
"""

from __future__ import annotations

import importlib
from typing import Any

from symplid.inference.map._checks import MapFailedError, failure_message
from symplid.inference.map._data_start import fastest_rate
from symplid.inference.map._evidence import EvidenceSettings, quadrature_evidence
from symplid.inference.map._find import EVIDENCE_METHODS, default_start, find_map
from symplid.inference.map._homotopy import (
    filter_start,
    half_normal_start,
    with_process_noise,
    without_process_var,
)
from symplid.inference.map._laplace import LowOptimisationJit, laplace_covariance
from symplid.inference.map._result import (
    BoundWarning,
    MapConvergenceWarning,
    MapResult,
    MultipleOptimaWarning,
    Optimum,
    StartResult,
)
from symplid.inference.map._space import SearchSpace
from symplid.inference.map._starts import homotopy_start

_LAZY = {"NeuralMapResult", "find_map_neural", "neural_posterior"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module("symplid.inference.map._neural"), name)
    raise AttributeError(f"module 'symplid.inference.map' has no attribute {name!r}")


__all__ = [
    "EVIDENCE_METHODS",
    "BoundWarning",
    "EvidenceSettings",
    "LowOptimisationJit",
    "MapConvergenceWarning",
    "MapFailedError",
    "MapResult",
    "MultipleOptimaWarning",
    "NeuralMapResult",
    "Optimum",
    "SearchSpace",
    "StartResult",
    "default_start",
    "failure_message",
    "fastest_rate",
    "filter_start",
    "find_map",
    "find_map_neural",
    "half_normal_start",
    "homotopy_start",
    "laplace_covariance",
    "neural_posterior",
    "quadrature_evidence",
    "with_process_noise",
    "without_process_var",
]
