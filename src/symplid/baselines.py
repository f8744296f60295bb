"""The least-squares objectives the paper argues against (Section I), on the same data.

HNN's finite-difference loss (eq. 1) and least squares through one integrator step between
consecutive observations (forward Euler, RK4, leapfrog) treat the observed states as exact;
:func:`fit` minimises one of :data:`OBJECTIVES` over a potential's coefficients.
"""

from symplid.inference._baselines import (
    OBJECTIVES,
    Objective,
    Pairs,
    fit,
    loss_function,
    step_objective,
)

__all__ = ["OBJECTIVES", "Objective", "Pairs", "fit", "loss_function", "step_objective"]
