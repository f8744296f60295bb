"""Observation-noise models: which terms the observation covariance has, and the registry.

A model's ``observation_noise`` (settings: ``model.observation_noise``) is a name in
:data:`OBSERVATION_NOISE`: additive Γ, multiplicative relative variances r, or both; the
filter's update then adds Γ, or Γ + diag(r ∘ E[h∘h]) from the step's moments. A new model is
one registration of an :class:`ObservationNoise`.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "OBSERVATION_NOISE": "symplid.filters._noise",
    "ObservationNoise": "symplid.filters._noise",
    "get_observation_noise": "symplid.filters._noise",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
