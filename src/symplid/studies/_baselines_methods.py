"""The methods the baselines study compares (:mod:`._baselines_study`), in one registry.

A method learns the potential either by the UKF posterior with a propagator, or by a baseline
objective of :data:`symplid.inference._baselines.OBJECTIVES`; the study's tables list them in
registration order. A new method is one registration::

    METHODS.register("ukf-yoshida4", Method("ukf-yoshida4", integrator="yoshida4",
                                            label="UKF posterior, Yoshida 4"))
"""

from __future__ import annotations

from dataclasses import dataclass

from symplid._registry import Registry

__all__ = ["METHODS", "REFERENCE", "Method"]


@dataclass(frozen=True)
class Method:
    """A way to learn the potential: the UKF posterior with ``integrator``, or a baseline
    ``objective`` of :data:`symplid.inference._baselines.OBJECTIVES`."""

    name: str
    integrator: str | None = None
    objective: str | None = None
    label: str = ""

    @property
    def bayesian(self) -> bool:
        """Whether the method gives a posterior (the UKF ones)."""
        return self.integrator is not None


METHODS: Registry[Method] = Registry("study method")
"""The methods of the study by name; the table lists them in this order."""
METHODS.register("ukf-leapfrog", Method("ukf-leapfrog", integrator="leapfrog",
                                        label="UKF posterior, leapfrog"))
METHODS.register("ukf-rk2", Method("ukf-rk2", integrator="rk2-midpoint",
                                   label="UKF posterior, RK2"))
METHODS.register("hnn", Method("hnn", objective="hnn", label="HNN loss, eq. 1"))
METHODS.register("euler", Method("euler", objective="euler", label="LS through one Euler step"))
METHODS.register("rk4", Method("rk4", objective="rk4", label="LS through one RK4 step"))
METHODS.register("leapfrog-ls", Method("leapfrog-ls", objective="leapfrog",
                                       label="LS through one leapfrog step"))

#: The reference method of the deciding numbers.
REFERENCE = "ukf-leapfrog"
