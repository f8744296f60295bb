"""Observation-noise models: which terms the observation covariance has, and the registry.

A model's ``observation_noise`` (settings: ``model.observation_noise``) is a name in
:data:`OBSERVATION_NOISE`: additive Γ, multiplicative relative variances r, or both; the
filter's update then adds Γ, or Γ + diag(r ∘ E[h∘h]) from the step's moments. A new model is
one registration of an :class:`ObservationNoise`.
"""

from symplid.filters._noise import OBSERVATION_NOISE, ObservationNoise, get_observation_noise

__all__ = ["OBSERVATION_NOISE", "ObservationNoise", "get_observation_noise"]
