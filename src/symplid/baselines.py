"""The least-squares objectives the paper argues against (Section I), on the same data.

HNN's finite-difference loss (eq. 1) and least squares through one integrator step between
consecutive observations (forward Euler, RK4, leapfrog) treat the observed states as exact;
:func:`fit` minimises one of :data:`OBJECTIVES` over a potential's coefficients.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "OBJECTIVES": "symplid.inference._baselines",
    "Objective": "symplid.inference._baselines",
    "Pairs": "symplid.inference._baselines",
    "fit": "symplid.inference._baselines",
    "loss_function": "symplid.inference._baselines",
    "step_objective": "symplid.inference._baselines",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
