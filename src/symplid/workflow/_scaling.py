"""Fitting in standardised coordinates, reporting in the user's (``model.standardise``).

Data in pixels or millimetres put the coefficients of a polynomial potential many orders of
magnitude apart (a quartic term at q ~ 300 is 10⁵ times a quadratic's), so the MAP search
struggles and the priors (Laplace(0, 10) per coefficient, half-normal(1) per variance) mean
something else for every coefficient. The fit therefore runs in the coordinates

    q' = q / a,   p' = p / a,   t' = t,

with ``a`` the root mean square of the observed positions (about the origin: a shift would mix
the coefficients of different degrees). With a constant mass, q̇ = M⁻¹p keeps its form, and
H'(q', p') = H(a q', a p') / a² generates the same motion, so for the polynomial potential of
eqs (2) and (13) (every integrator is equivariant under this linear map):

    c'_α = c_α · a^{|α|−2},    Σ' = Σ / a²,   Γ' = Γ / a²,   r' = r   (relative variances),
    x0' = x0 / a,              P0' = P0 / a²,  γ' = γ   (damping rate).

The damping rate γ of a damped model (ṗ = −∂U/∂q − γM⁻¹p, :mod:`symplid.dynamics._damping`) has
units 1/time and the friction term is linear in p, so it is unchanged by the position scale.

The priors apply to the standardised parameters (the point of standardising). The MAP, the
Laplace covariance, the draws, the summaries and the predictions are mapped back to the user's
units (θ = D θ', D diagonal; covariance D C' D, Hessian D⁻¹ H' D⁻¹), and the log likelihood,
log posterior and Laplace evidence are those of the user's data: with N measured values,
log p(y) = log p'(y') − N log a, and the log posterior density of θ (the push-forward of the
standardised prior) also loses Σ log D. A sampler's own tuning (its step size, mass matrix or
proposal in ``idata.attrs``) stays in the space it ran in; ``attrs["standardised_scale"]``
and ``summary.json["standardised_scale"]`` record a.

Rule of ``model.standardise``: ``"on"``, ``"off"``, or ``"auto"`` (default), which is on when
the model is a separable polynomial one and ``a`` lies outside [0.1, 10] — data near unit scale
(the paper's, a ≈ 0.3) are fitted as they are, so their numbers do not change.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from symplid.dynamics._potentials import Polynomial, degree_scaling
from symplid.inference.map import MapResult
from symplid.io import observation_layout
from symplid.model._data import Observations
from symplid.model._params import Reparameterisation
from symplid.model._standardise import standardised_factors

__all__ = [
    "AUTO_RANGE",
    "Scaling",
    "can_standardise",
    "position_scale",
    "resolve_standardise",
    "scaling_for",
]

AUTO_RANGE = (0.1, 10.0)
"""``model.standardise = "auto"`` standardises when the position scale is outside this range."""


def position_scale(datasets: Observations | Sequence[Observations]) -> float:
    """The root mean square of the observed positions q1..qd over all data sets (1 if none)."""
    sets = [datasets] if isinstance(datasets, Observations) else list(datasets)
    squares, count = 0.0, 0
    for obs in sets:
        d = observation_layout(obs).dim
        mask = np.asarray(obs.mask)[:, :d]
        values = np.where(mask, np.asarray(obs.values)[:, :d], 0.0)
        squares += float(np.sum(values**2))
        count += int(np.sum(mask))
    scale = math.sqrt(squares / count) if count else 1.0
    return scale if math.isfinite(scale) and scale > 0 else 1.0


def can_standardise(model_settings: Any) -> str | None:
    """Why ``model_settings`` cannot be standardised (None when it can)."""
    if getattr(model_settings, "hamiltonian", "separable") != "separable":
        return f"the Hamiltonian is {model_settings.hamiltonian!r}, not separable"
    if getattr(model_settings, "potential", "polynomial") != "polynomial":
        return f"the potential is {model_settings.potential!r}, not a polynomial"
    if str(getattr(model_settings, "force", "")).strip():
        return "the model has a force (its parameters are in the data's units)"
    return None


def resolve_standardise(model_settings: Any, datasets: Any) -> str:
    """``"on"`` or ``"off"`` for ``model.standardise`` (module docstring); ``ValueError`` when
    ``"on"`` is asked of a model that cannot be standardised."""
    value = model_settings.standardise
    reason = can_standardise(model_settings)
    if value == "on" and reason is not None:
        raise ValueError(f'is "on" but {reason}; standardising maps polynomial coefficients')
    if value != "auto":
        return value
    scale = position_scale(datasets)
    outside = not AUTO_RANGE[0] <= scale <= AUTO_RANGE[1]
    return "on" if reason is None and outside else "off"


@dataclass(frozen=True)
class Scaling:
    """The map between the user's coordinates and q' = q/a (module docstring).

    ``degrees`` holds |α| of each coefficient of the polynomial potential.
    """

    scale: float
    degrees: tuple[int, ...]

    # ------------------------------------------------------------------ data and settings
    def observations(self, obs: Observations) -> Observations:
        """The data in standardised coordinates (every column is a q or a p: all over a)."""
        return Observations(obs.times, np.asarray(obs.values) / self.scale, obs.names)

    def settings(self, settings: Any) -> Any:
        """Settings for the standardised fit: a known x0 over a, p0_var over a²."""
        init = settings.initial_state
        init = dataclasses.replace(
            init,
            x0=tuple(float(v) / self.scale for v in init.x0),
            p0_var=float(init.p0_var) / self.scale**2,
        )
        return dataclasses.replace(settings, initial_state=init)

    # ------------------------------------------------------------------ θ
    def factors(self, groups: Sequence[str]) -> np.ndarray:
        """D: θ_user = D θ' entry by entry, for θ's groups (coefficients in order first):
        the polynomial's law (:func:`~symplid.dynamics._potentials.degree_scaling`) and each
        group's (:func:`~symplid.model._standardise.standardised_factors`)."""
        return standardised_factors(groups, self.scale,
                                    degree_scaling(self.degrees, self.scale))

    def reparameterisation(self, groups: Sequence[str]) -> Reparameterisation:
        """θ_user = D θ' as the one :class:`~symplid.model._params.Reparameterisation` of θ
        (no bounds, D = :meth:`factors`): its log-Jacobian Σ log D is what the log posterior
        density loses."""
        return Reparameterisation.linear(self.factors(groups))

    def num_values(self, datasets: Observations | Sequence[Observations]) -> int:
        """N: the measured values of the data (their Jacobian is a^−N)."""
        sets = [datasets] if isinstance(datasets, Observations) else list(datasets)
        return int(sum(int(np.sum(obs.mask)) for obs in sets))

    def log_likelihood_shift(self, datasets: Any) -> float:
        """log p(y) − log p'(y') = −N log a."""
        return -self.num_values(datasets) * math.log(self.scale)

    def map_result(self, result: MapResult, groups: Sequence[str], datasets: Any) -> MapResult:
        """A MAP result of the standardised fit in the user's units (module docstring)."""
        to_user = self.reparameterisation(groups)
        f = to_user.scale
        shift = self.log_likelihood_shift(datasets)
        density_shift = shift - float(to_user.log_abs_det_jacobian(np.zeros(f.size)))
        starts = tuple(
            dataclasses.replace(
                s, start=to_user.from_unconstrained(np.asarray(s.start)),
                theta=to_user.from_unconstrained(np.asarray(s.theta)),
                log_posterior=s.log_posterior + density_shift,
            )
            for s in result.starts
        )
        outer = np.outer(f, f)
        return dataclasses.replace(
            result,
            theta=to_user.from_unconstrained(np.asarray(result.theta)),
            log_posterior=result.log_posterior + density_shift,
            starts=starts,
            hessian=None if result.hessian is None else np.asarray(result.hessian) / outer,
            covariance=None if result.covariance is None else np.asarray(result.covariance) * outer,
            log_evidence=result.log_evidence + shift,
            settings={**dict(result.settings), "standardised_scale": self.scale},
        )

    def inference_data(self, idata: Any, groups: Sequence[str], datasets: Any) -> Any:
        """Draws of the standardised fit in the user's units (ArviZ ``InferenceData``)."""
        if idata is None:
            return None
        to_user = self.reparameterisation(groups)
        f = to_user.scale
        names = list(idata.attrs["param_names"])
        for name, factor in zip(names, f, strict=True):
            idata.posterior[name] = idata.posterior[name] * factor
        density_shift = (self.log_likelihood_shift(datasets)
                         - float(to_user.log_abs_det_jacobian(np.zeros(f.size))))
        if "lp" in idata.sample_stats:
            idata.sample_stats["lp"] = idata.sample_stats["lp"] + density_shift
        attrs = idata.attrs
        outer = np.outer(f, f)
        for key, transform in (
            ("map_theta", to_user.from_unconstrained),
            ("initial_positions", to_user.from_unconstrained),
            ("map_covariance", lambda v: v * outer),
            ("hessian", lambda v: v / outer),
        ):
            if key in attrs:
                attrs[key] = transform(np.asarray(attrs[key], dtype=float)).tolist()
        if "map_log_posterior" in attrs:
            attrs["map_log_posterior"] = float(attrs["map_log_posterior"]) + density_shift
        attrs["standardised_scale"] = self.scale
        return idata


def scaling_for(settings: Any, datasets: Any) -> Scaling | None:
    """The scaling of a resolved ``settings`` (``model.standardise = "on"``), else None."""
    if settings.model.standardise != "on":
        return None
    order = int(settings.model.order)
    dim = observation_layout(
        datasets if isinstance(datasets, Observations) else datasets[0]
    ).dim
    degrees = tuple(int(sum(e)) for e in Polynomial(dim, order).exponents)
    return Scaling(position_scale(datasets), degrees)
