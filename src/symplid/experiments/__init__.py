"""Named experiments: studies that own their sweep keys, metrics and figures.

:data:`EXPERIMENTS` holds them by name (the registry object is
:data:`symplid.workflow.experiment.EXPERIMENTS`, where the generic sweep reads it); importing
this package registers the seed paper's experiment, ``"paper"`` (:mod:`.paper`), whose
paper-claims study is :mod:`.paper_study`, the baselines study, ``"baselines"``
(:mod:`.baselines_study`), and simulation-based calibration, ``"sbc"`` (:mod:`.sbc`).
"""

from symplid.experiments import baselines_study, paper, sbc
from symplid.workflow.experiment import EXPERIMENTS, Experiment

__all__ = ["EXPERIMENTS", "Experiment", "baselines_study", "paper", "sbc"]
