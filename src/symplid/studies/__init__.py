"""The research studies, beside the library: the paper, its claims, the baselines.

This package sits above the workflow layer, and nothing in the core (``dynamics`` up to
``workflow``) imports it; the command line (``symplid reproduce``, ``symplid study ...``,
``symplid sweep``) and the top-level lazy table are its only users. Each study is an
:class:`~symplid.workflow._experiment.Experiment` (its sweep keys, cell function, metrics and
figures) in its own module:

* ``"paper"`` (:mod:`._paper`): the seed paper's Hénon–Heiles fit; its paper-claims study is
  :mod:`._paper_study` (claims :mod:`._paper_claims`, calibration :mod:`._paper_calibration`,
  statistics :mod:`._claims_stats`, report :mod:`._paper_study_report`, README block
  :mod:`._claims_readme`);
* ``"baselines"`` (:mod:`._baselines_study`): the UKF posterior against HNN and one-step least
  squares;
* ``"sbc"`` (:mod:`._sbc`, report :mod:`._sbc_report`): simulation-based calibration of MAP +
  DRAM on data simulated from the model itself;
* ``"sbc-defaults"`` (:mod:`._sbc_defaults`, report :mod:`._sbc_report`): the same for a user's
  model fitted with every default of ``symplid fit`` on data from the exact flow;
* ``"shift"`` (:mod:`._shift`, fits :mod:`._shift_fits`, report :mod:`._shift_report`): the
  paper-claims posteriors' coefficient shift split into discretisation, noise draws, process
  noise and remainder, one (integrator, dt) row per cell.

A new study is a module here that defines ``EXPERIMENT = Experiment(...)`` (without
registering it), added to :data:`STUDIES` below, the one list of the studies; its command, if
any, goes in :mod:`symplid.cli` under ``symplid study``.
"""

from __future__ import annotations

import importlib
from typing import Any

from symplid._registry import Registry
from symplid.workflow._experiment import EXPERIMENTS, Experiment

__all__ = ["STUDIES", "baselines_study", "paper", "register_studies", "sbc", "sbc_defaults",
           "shift"]

#: The studies' modules, in the order ``symplid sweep`` lists them. They are imported when
#: first used: a worker process that runs the paper's fits imports only what those need.
_MODULES = ("paper", "baselines_study", "sbc", "sbc_defaults", "shift")


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        return importlib.import_module(f"{__name__}._{name}")
    if name == "STUDIES":  # every study's experiment, in the order above
        return tuple(importlib.import_module(f"{__name__}._{m}").EXPERIMENT for m in _MODULES)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register_studies(registry: Registry[Experiment] | None = None) -> None:
    """Register every study of :data:`STUDIES` in ``registry`` (default
    :data:`~symplid.workflow._experiment.EXPERIMENTS`), so that a sweep spec may name them.

    Called by the command line before it reads a sweep spec. Registering again is a no-op;
    a name taken by another experiment is a ``ValueError``.
    """
    registry = EXPERIMENTS if registry is None else registry
    for experiment in __getattr__("STUDIES"):
        if registry.get(experiment.name) is not experiment:
            registry.register(experiment.name, experiment)
