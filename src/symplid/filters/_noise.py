"""Observation-noise models: how the noise enters Y_k and the innovation covariance it adds.

The state-space model of eq. (7) observes Y_k = h(X_k) + η_k with additive Gaussian noise
η ~ N(0, Γ). The follow-up work on multiplicative noise (Galioto, Sharma, Kramer &
Gorodetsky, CMAME 430, 2024) also observes

    Y_k = h(X_k) ∘ (1 + ε_k),             ε ~ N(0, diag(r))          ("multiplicative")
    Y_k = h(X_k) ∘ (1 + ε_k) + η_k,       ε ⟂ η ⟂ X_k                ("both")

with relative variances r (one per observed component, or one for all).

The Gaussian update (eqs 11–12)
-------------------------------
The filter moment-matches the joint law of (X_k, Y_k) given y_1..k−1 by a Gaussian. With the
prediction X ~ (m⁻, P⁻) and h's moments ŷ = E[h], S_h = Cov[h], C = Cov[X, h] (exact for a
linear h, from the sigma points otherwise), independence of ε and X gives

    E[Y]      = E[h] + E[h ∘ ε]                               = ŷ
    Cov[Y]    = Cov[h] + E[diag(h) diag(r) diag(h)]          = S_h + diag(r ∘ E[h ∘ h])
    Cov[X, Y] = Cov[X, h] + E[(X − m⁻)(h ∘ ε)ᵀ]             = C

(ε has mean zero and diagonal covariance, so the cross terms vanish and only the diagonal of
h hᵀ survives), with E[h ∘ h] = ŷ ∘ ŷ + diag S_h. Adding η adds Γ to Cov[Y]. So the update of
eqs (11)–(12) is unchanged except that Γ in S = S_h + Γ is replaced by

    R_k = Γ + diag(r ∘ (ŷ ∘ ŷ + diag S_h)),

a noise covariance that now depends on the prediction (it is recomputed at every step). For a
linear h and a Gaussian state the three moments are exact; the filter's likelihood term is
then the Gaussian density with the exact mean and covariance of Y (which is not Gaussian).

Missing components are handled by the update as before: R_k's rows and columns of a missing
component are replaced like S's.

The registry :data:`OBSERVATION_NOISE` is the one place a noise model is added: the model's
θ layout, the settings' choices, the simulation and the predictive bands all read it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from symplid._registry import Registry
from symplid.filters._unscented import ObservationMoments

Array = jax.Array

__all__ = [
    "OBSERVATION_NOISE",
    "ObservationNoise",
    "get_observation_noise",
    "multiplicative_covariance",
]


def multiplicative_covariance(moments: ObservationMoments, rel_var: Array) -> Array:
    """diag(r ∘ E[h∘h]) with E[h∘h] = ŷ∘ŷ + diag S_h (module docstring)."""
    # Diagonals by a mask, not a gather/scatter: the loop body's gradient stays one kernel
    # (see :func:`symplid.filters._update._diagonal`).
    eye = jnp.eye(moments.cov.shape[-1], dtype=moments.cov.dtype)
    second = moments.predicted**2 + jnp.sum(eye * moments.cov, axis=-1)
    return eye * (rel_var * second)


@dataclass(frozen=True)
class ObservationNoise:
    """One observation-noise model.

    Attributes
    ----------
    name
        The registry name (``"additive"``, ``"multiplicative"``, ``"both"``).
    additive, multiplicative
        Which terms the model has: the additive variances Γ (``obs_var``) and the relative
        variances r (``obs_rel_var``) each join θ only when present.
    description
        One line for the command line's help.
    """

    name: str
    additive: bool
    multiplicative: bool
    description: str = ""

    def covariance_fn(
        self, additive_cov: Array, rel_var: Array
    ) -> Array | Callable[[ObservationMoments], Array]:
        """The noise covariance the update adds to S_h: Γ itself when the noise is additive
        only (a constant), else ``moments -> R_k`` (module docstring)."""
        if not self.multiplicative:
            return additive_cov

        def covariance(moments: ObservationMoments) -> Array:
            cov = multiplicative_covariance(moments, rel_var)
            return cov + additive_cov if self.additive else cov

        return covariance

    def sample(
        self, clean: np.ndarray, obs_var: np.ndarray, rel_var: np.ndarray, rng: np.ndarray
    ) -> np.ndarray:
        """Noisy observations of ``clean`` = h(x) from standard normal draws ``rng``.

        ``rng`` has shape ``(2,) + clean.shape`` (the multiplicative and the additive draws);
        ``obs_var`` and ``rel_var`` broadcast against ``clean`` (zero where absent).
        """
        out = clean
        if self.multiplicative:
            out = out * (1.0 + np.sqrt(rel_var) * rng[0])
        if self.additive:
            out = out + np.sqrt(obs_var) * rng[1]
        return out

    def variance(self, clean: np.ndarray, obs_var: np.ndarray, rel_var: np.ndarray) -> np.ndarray:
        """Var[Y | h(x) = clean]: ``obs_var + rel_var·clean²`` for the terms present."""
        out = np.zeros_like(np.asarray(clean, dtype=float))
        if self.multiplicative:
            out = out + rel_var * np.square(clean)
        if self.additive:
            out = out + obs_var
        return out


#: The observation-noise models by name; ``model.observation_noise`` reads it.
OBSERVATION_NOISE: Registry[ObservationNoise] = Registry("observation-noise model")
OBSERVATION_NOISE.register(
    "additive", ObservationNoise("additive", True, False, "Y = h(X) + η, η ~ N(0, Γ) (eq. 7)")
)
OBSERVATION_NOISE.register(
    "multiplicative",
    ObservationNoise(
        "multiplicative", False, True, "Y = h(X)∘(1 + ε), ε ~ N(0, diag r): relative noise"
    ),
    aliases=("relative",),
)
OBSERVATION_NOISE.register(
    "both",
    ObservationNoise("both", True, True, "Y = h(X)∘(1 + ε) + η: relative and absolute noise"),
)


def get_observation_noise(name: str | ObservationNoise) -> ObservationNoise:
    """The registered noise model ``name`` (``ValueError`` listing the choices otherwise)."""
    if isinstance(name, ObservationNoise):
        return name
    return OBSERVATION_NOISE.get_entry(name)
