"""What the data decide: the ``"auto"`` model settings and the line that says so.

* ``model.noise = "auto"`` (:func:`resolve_noise`): one observation variance per kind of
  column when the data mix positions and momenta, one for all otherwise.
* ``model.standardise = "auto"``: see :func:`symplid.workflow._scaling.resolve_standardise`.

:func:`auto_notes` gives the one line per decision that ``fit`` passes to its ``status``.
"""

from __future__ import annotations

from typing import Any

from symplid.filters._noise import OBSERVATION_NOISE
from symplid.workflow._scaling import position_scale

__all__ = ["auto_notes", "num_noise_variances", "resolve_noise"]


def resolve_noise(noise: str, observation: str) -> str:
    """``model.noise = "auto"``: one observation variance per kind of column (``"per-kind"``)
    when the data mix positions and momenta (or velocities, the same with unit mass), one
    for all (``"isotropic"``) when they hold positions only. Columns of different kinds are
    rarely measured alike (a velocity column smoothed from positions is much less noisy or
    much noisier), and one shared variance then biases the potential. The paper's experiment
    sets ``"isotropic"`` itself (its simulated q and p share one noise level)."""
    if noise != "auto":
        return noise
    return "per-kind" if observation == "full" else "isotropic"


def num_noise_variances(noise: str, observation: str, observation_noise: str, dim: int) -> int:
    """How many variances θ holds for a resolved ``noise`` layout (as HamiltonianModel lays
    them out): Σ's, then Γ's and the relative ones that the noise model has."""
    d_y = 2 * dim if observation == "full" else dim
    per_term = {"isotropic": 1, "diagonal": d_y, "per-kind": 2 if observation == "full" else 1}
    entry = OBSERVATION_NOISE.get_entry(observation_noise)
    terms = int(entry.additive) + int(entry.multiplicative)
    return (2 * dim if noise == "diagonal" else 1) + terms * per_term[noise]


def auto_notes(given: Any, resolved: Any, obs: Any) -> list[str]:
    """One line for each ``"auto"`` model setting that the data decided non-trivially."""
    notes = []
    if given.model.noise == "auto" and resolved.model.noise == "per-kind":
        notes.append(
            'model.noise = "auto": the data have positions and momenta, so each kind gets its '
            'own observation variance (set model.noise = "isotropic" for one)'
        )
    if given.model.standardise == "auto" and resolved.model.standardise == "on":
        notes.append(
            f'model.standardise = "auto": the positions\' scale is {position_scale(obs):.4g}, '
            "so the fit runs in coordinates divided by it and reports in the data's units "
            '(set model.standardise = "off" to fit as given)'
        )
    return notes
