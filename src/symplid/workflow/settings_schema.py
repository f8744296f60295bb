"""The sections of the run settings: frozen dataclasses whose fields carry their checks.

Each field is a :func:`~symplid.workflow.validate.setting` (default, range, choices): the
one validator (:mod:`symplid.workflow.validate`) reads them, and so do the sweeps. Names of
integrators, samplers and prior families come from their registries. The file format, the
loading and the overrides are in :mod:`symplid.workflow.settings`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

from symplid.dynamics.families import (
    HAMILTONIAN_FAMILIES,
    POTENTIAL_FAMILIES,
    build_family,
    family_of,
)
from symplid.dynamics.hamiltonians import is_hamiltonian
from symplid.dynamics.integrators import INTEGRATORS, get_integrator
from symplid.dynamics.neural import ACTIVATIONS
from symplid.dynamics.nonseparable import TaoIntegrator
from symplid.filters.noise import OBSERVATION_NOISE
from symplid.inference.map import EVIDENCE_METHODS
from symplid.inference.samplers import SAMPLERS
from symplid.inference.samplers.dram import VARIANCE_SCALES
from symplid.model.priors import HalfNormal, Laplace, Normal, Prior, PriorSpec, as_prior
from symplid.model.statespace import PROCESS_NOISE_CHOICES
from symplid.workflow.validate import SettingsError, Spec, setting

__all__ = [
    "RENAMED",
    "InitialStateSettings",
    "MapSettings",
    "ModelSettings",
    "PlotSettings",
    "PredictionSettings",
    "PriorSettings",
    "SamplerSettings",
    "Settings",
    "check_model_family",
    "family_prior",
    "with_family_prior",
]


# ----------------------------------------------------------------------------- sections
@dataclass(frozen=True)
class ModelSettings:
    """The state-space model of eq. (7) and its unscented filter (Theorem 1).

    ``order`` is read by the polynomial family; ``width``, ``depth``, ``activation`` and
    ``network_seed`` (the seed of the initial weights) by the ``"mlp"`` family
    (:class:`~symplid.dynamics.neural.MLPPotential`). A family ignores the others.
    """

    potential: str = setting("polynomial", choices=POTENTIAL_FAMILIES)
    hamiltonian: str = setting("separable", choices=HAMILTONIAN_FAMILIES)
    order: int = setting(3, minimum=1)
    width: int = setting(32, minimum=1)
    depth: int = setting(2, minimum=0)
    activation: str = setting("tanh", choices=ACTIVATIONS)
    network_seed: int = setting(0, minimum=0)
    integrator: str = setting("leapfrog", choices=INTEGRATORS)
    binding: float = setting(0.0, minimum=0.0)  # Tao's ω ("tao", "tao4"); 0: ω = 1/dt
    dt: float = setting(0.25, minimum=0.0, strict=True)
    process_noise_per: str = setting("gap", choices=PROCESS_NOISE_CHOICES)  # "none": no Σ
    noise: str = setting("auto", choices=("auto", "isotropic", "diagonal", "per-kind"))
    observation_noise: str = setting("additive", choices=OBSERVATION_NOISE)
    standardise: str = setting("auto", choices=("auto", "on", "off"))
    observation: str = setting("auto", choices=("auto", "full", "positions"))
    mass: tuple[float, ...] = setting(())
    alpha: float = setting(1.0, minimum=0.0, strict=True)
    beta: float = setting(2.0)
    kappa: float = setting(0.0)
    jitter: float = setting(1e-12, minimum=0.0)
    damping: bool = setting(False)
    """Learn a damping rate γ: ṗ = −∂U/∂q − γM⁻¹p (:mod:`symplid.dynamics.damping`)."""


@dataclass(frozen=True)
class InitialStateSettings:
    """The initial state X_0 ~ N(x0, p0_var·I) at time t0, known or learned with θ.

    ``t0 = "first"`` puts the state at the first observation time (the filter starts with
    that observation's update; see :class:`~symplid.model.posterior.Posterior`, ``t0=None``).
    """

    mode: str = setting("known", choices=("known", "learned"))
    x0: tuple[float, ...] = setting(())
    p0_var: float = setting(1e-16, minimum=0.0)
    t0: float | str = setting(0.0, words=("first",))

    @property
    def at_first_observation(self) -> bool:
        """True for ``t0 = "first"``."""
        return self.t0 == "first"

    def start_time(self, first_observation: float) -> float:
        """t0 as a number: the first observation time for ``t0 = "first"``."""
        return float(first_observation) if self.at_first_observation else float(self.t0)


@dataclass(frozen=True)
class PriorSettings:
    """Priors by group of θ: the paper's Laplace(0, 10) and half-normal(1) (Section IV).

    ``variances`` is the prior of every noise variance (process, observation, and the relative
    variance of multiplicative observation noise); ``damping`` that of the damping rate γ of a
    damped model (``model.damping = true``);
    ``initial_state`` (used when the initial state is learned) is the prior of the offset of
    each component from its centre.
    """

    coefficients: Prior = field(default_factory=lambda: Laplace(0.0, 10.0))
    variances: Prior = field(default_factory=lambda: HalfNormal(1.0))
    initial_state: Prior = field(default_factory=lambda: Normal(0.0, 1.0))
    damping: Prior = field(default_factory=lambda: HalfNormal(1.0))

    def prior_spec(self, learned_initial_state: bool) -> PriorSpec:
        """The :class:`~symplid.model.priors.PriorSpec` of these groups for the posterior."""
        return PriorSpec(
            coefficients=self.coefficients,
            process_var=self.variances,
            obs_var=self.variances,
            obs_rel_var=self.variances,
            initial_state=self.initial_state if learned_initial_state else None,
            damping=self.damping,
        )


@dataclass(frozen=True)
class MapSettings:
    """The MAP search: bounded quasi-Newton from several seeded starts.

    A neural family (``model.potential = "mlp"``) takes the scalable path instead
    (:func:`~symplid.inference.neural_fit.find_map_neural`): ``adam_steps`` of Adam with step
    ``learning_rate``, then ``lbfgs_steps`` of L-BFGS, and the Gauss–Newton Laplace covariance;
    ``num_starts`` is not used there. ``evidence``: ``"quadrature"`` integrates the noise
    variances over their logarithms (:mod:`symplid.inference.evidence`; right when a variance
    piles against its floor, a few seconds more per fit), ``"laplace"`` the Gaussian
    approximation alone (what a study that never reads the evidence needs).
    """

    num_starts: int = setting(4, minimum=1)
    evidence: str = setting("quadrature", choices=EVIDENCE_METHODS)
    seed: int = setting(0, minimum=0)
    adam_steps: int = setting(2000, minimum=0)
    learning_rate: float = setting(0.01, minimum=0.0, strict=True)
    lbfgs_steps: int = setting(1000, minimum=0)
    sensitivity: bool = setting(False)
    """Add the step-size and process-noise checks (two MAP refits,
    :mod:`symplid.workflow.sensitivity`) to the run's report."""


@dataclass(frozen=True)
class SamplerSettings:
    """MCMC: DRAM with the paper's budget per chain (200,000 iterations, 100,000 burn-in).

    ``num_iterations`` counts every iteration of a chain, ``burn_in`` included; the draws kept
    per chain are ``(num_iterations − burn_in) // thin`` (:attr:`num_draws`).
    ``variance_scale`` is DRAM's: ``"log"`` (default) moves the variances as log(v) with the
    Jacobian (no wall at their floor), ``"natural"`` as themselves (the paper's).
    """

    method: str = setting("dram", choices=SAMPLERS)
    num_iterations: int = setting(200_000, minimum=1)
    burn_in: int = setting(100_000, minimum=0)
    num_chains: int = setting(4, minimum=1)
    gamma: float = setting(0.01, minimum=0.0, strict=True)
    adapt_start: int = setting(200, minimum=0)
    variance_scale: str = setting("log", choices=VARIANCE_SCALES)
    thin: int = setting(1, minimum=1)
    seed: int = setting(0, minimum=0)

    @property
    def num_draws(self) -> int:
        """Draws kept per chain: the iterations after burn-in, thinned."""
        return (self.num_iterations - self.burn_in) // self.thin


@dataclass(frozen=True)
class PredictionSettings:
    """Predictions from the learned models: leapfrog at a fine dt to t_end (Figs 1–3)."""

    integrator: str = setting("leapfrog", choices=INTEGRATORS)
    dt: float = setting(0.01, minimum=0.0, strict=True)
    t_end: float = setting(200.0)
    num_paths: int = setting(100, minimum=0)


@dataclass(frozen=True)
class PlotSettings:
    """What the run's figures show: the data's time unit (axis labels), how many parameters
    the pair plot and the trace plot draw (the first ones in θ's order; a figure that leaves
    some out says so), and the system the data came from when it is known (a name in
    ``symplid.SYSTEMS``, e.g. for simulated data): its U and coefficients are drawn as the
    truth."""

    time_unit: str = setting("s")
    truth: str = setting("")
    max_pair_params: int = setting(6, minimum=2)
    max_trace_params: int = setting(16, minimum=1)


@dataclass(frozen=True)
class Settings:
    """Everything a run needs; the defaults are the paper's Hénon–Heiles experiment."""

    seed: int = setting(0, minimum=0)
    model: ModelSettings = field(default_factory=ModelSettings)
    initial_state: InitialStateSettings = field(default_factory=InitialStateSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    map: MapSettings = field(default_factory=MapSettings)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    prediction: PredictionSettings = field(default_factory=PredictionSettings)
    plots: PlotSettings = field(default_factory=PlotSettings)


def family_prior(model: Any) -> Prior:
    """The default coefficient prior of the family that model settings name.

    The family's :attr:`~symplid.dynamics.families.Family.coefficient_prior` (``"mlp"``:
    Normal(0, 1) on every weight), else the paper's Laplace(0, 10). A settings file or
    ``--set`` that gives ``priors.coefficients`` overrides it.
    """
    prior = family_of(model).coefficient_prior
    return as_prior(prior, "coefficient prior") if prior else PriorSettings().coefficients


def with_family_prior(data: dict[str, Any]) -> dict[str, Any]:
    """``priors.coefficients`` left out: the model family's default prior."""
    priors = data.get("priors", {})
    model = data.get("model", {})
    if not isinstance(priors, Mapping) or "coefficients" in priors or not isinstance(
            model, Mapping):
        return data
    names = {k: model[k] for k in ("potential", "hamiltonian") if isinstance(model.get(k), str)}
    try:
        prior = family_prior(SimpleNamespace(**names))
    except (KeyError, ValueError):  # an unknown family: the validator says so, with a suggestion
        return data
    return {**data, "priors": {**priors, "coefficients": prior.to_dict()}}


#: Renamed keys: old dotted key → new dotted key (the old one is read with a FutureWarning).
RENAMED = {"sampler.num_samples": "sampler.num_iterations"}
#: Values of prior parameters a settings file leaves out (the family's class decides others).
PRIOR_DEFAULTS = {"loc": 0.0, "scale": 1.0, "low": 0.0, "high": 1.0}
PRIOR_SPECS = {
    "scale": Spec(float, minimum=0.0, strict=True),
    "sigma": Spec(float, minimum=0.0, strict=True),
}
PRIOR_SYNONYMS = {"log-normal": {"loc": "mu", "scale": "sigma"}}


def check_model_family(settings: Settings, dim: int, source: str) -> int:
    """Check the model's U or H against the integrators; its number of parameters.

    The family of ``model.hamiltonian``/``model.potential`` is built for the data's dimension
    ``dim``. A non-separable H needs a learning and a prediction integrator that accept it
    (not leapfrog or Yoshida), no constant mass and no damping; ``model.binding`` is Tao's ω
    only.
    """
    model = settings.model
    try:
        family = build_family(dim, model)
    except ValueError as err:
        key = "model.hamiltonian" if model.hamiltonian != "separable" else "model.potential"
        raise SettingsError(source, key, f"({model.hamiltonian}): {err}") from None
    if model.binding and not isinstance(get_integrator(model.integrator), TaoIntegrator):
        raise SettingsError(source, "model.binding", f"is Tao's ω; model.integrator is "
                            f"{model.integrator!r} (set binding = 0, or use 'tao'/'tao4')")
    if is_hamiltonian(family):
        if model.damping:
            raise SettingsError(source, "model.damping", f"is true but the Hamiltonian "
                                f"{model.hamiltonian!r} is not separable: the friction "
                                "−γM⁻¹p needs H = ½pᵀM⁻¹p + U(q)")
        for key, name in (("model.integrator", model.integrator),
                          ("prediction.integrator", settings.prediction.integrator)):
            if not get_integrator(name).nonseparable:
                choices = [n for n, e in INTEGRATORS.items() if e.nonseparable]
                raise SettingsError(source, key, f"{name!r} needs a separable H; the model's "
                                    f"Hamiltonian {model.hamiltonian!r} is not: choose one of "
                                    f"{', '.join(choices)}")
        if model.mass:
            raise SettingsError(source, "model.mass", "applies to a separable H only; "
                                f"{model.hamiltonian!r} carries its own mass")
    return int(family.num_params)
