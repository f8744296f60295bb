"""Model (layer 3): data, the state-space model of eq. (7), its likelihood, priors, posterior.

Builds on :mod:`symplid.dynamics` and :mod:`symplid.filters`; knows nothing of optimisers,
samplers, files or figures.
"""

__all__ = []
