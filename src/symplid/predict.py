"""Predictions from a learned Hamiltonian: MAP trajectories, posterior predictive bands, energy.

The paper predicts by integrating the learned Hamiltonian from a known initial state,
X_k = Ψ^k(X_0; θ_Ψ) (Section II-B.2): :func:`predict_trajectory` for one θ (the MAP's),
:func:`posterior_predictive` for a band over posterior draws (Fig. 3), and
:func:`forecast_from_filter` from the filtered state at the end of the data.
"""

from symplid.inference._predict import (
    DEFAULT_STORED_POINTS,
    PosteriorPredictive,
    forecast_from_filter,
    hamiltonian_along,
    posterior_predictive,
    predict_trajectory,
    prediction_horizon,
    time_grid,
)

__all__ = [
    "DEFAULT_STORED_POINTS",
    "PosteriorPredictive",
    "forecast_from_filter",
    "hamiltonian_along",
    "posterior_predictive",
    "predict_trajectory",
    "prediction_horizon",
    "time_grid",
]
