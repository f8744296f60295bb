"""Predictions from a learned Hamiltonian: MAP trajectories, posterior predictive bands, energy.

The paper predicts by integrating the learned Hamiltonian from a known initial state,
X_k = Ψ^k(X_0; θ_Ψ) (Section II-B.2): :func:`predict_trajectory` for one θ (the MAP's),
:func:`posterior_predictive` for a band over posterior draws (Fig. 3), and
:func:`forecast_from_filter` from the filtered state at the end of the data.
"""

from symplid._namespace import lazy_attributes

#: The public names: name -> the module that defines it, imported on first use.
_PUBLIC = {
    "DEFAULT_STORED_POINTS": "symplid.inference._predict",
    "PosteriorPredictive": "symplid.inference._predict",
    "forecast_from_filter": "symplid.inference._predict",
    "hamiltonian_along": "symplid.inference._predict",
    "posterior_predictive": "symplid.inference._predict",
    "predict_trajectory": "symplid.inference._predict",
    "prediction_horizon": "symplid.inference._predict",
    "time_grid": "symplid.inference._predict",
}
__getattr__, __dir__ = lazy_attributes(globals(), _PUBLIC)

__all__ = [*_PUBLIC]
