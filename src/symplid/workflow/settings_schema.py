"""The sections of the run settings: frozen dataclasses whose fields carry their checks.

Each field is a :func:`~symplid.workflow.validate.setting` (default, range, choices): the
one validator (:mod:`symplid.workflow.validate`) reads them, and so do the sweeps. Names of
integrators, samplers and prior families come from their registries. The file format, the
loading and the overrides are in :mod:`symplid.workflow.settings`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from symplid.dynamics.families import HAMILTONIAN_FAMILIES, POTENTIAL_FAMILIES, build_family
from symplid.dynamics.hamiltonians import is_hamiltonian
from symplid.dynamics.integrators import INTEGRATORS, get_integrator
from symplid.dynamics.nonseparable import TaoIntegrator
from symplid.inference.samplers import SAMPLERS
from symplid.model.priors import HalfNormal, Laplace, Normal, Prior, PriorSpec
from symplid.workflow.validate import SettingsError, Spec, setting

__all__ = [
    "RENAMED",
    "InitialStateSettings",
    "MapSettings",
    "ModelSettings",
    "PredictionSettings",
    "PriorSettings",
    "SamplerSettings",
    "Settings",
    "check_model_family",
]


# ----------------------------------------------------------------------------- sections
@dataclass(frozen=True)
class ModelSettings:
    """The state-space model of eq. (7) and its unscented filter (Theorem 1)."""

    potential: str = setting("polynomial", choices=POTENTIAL_FAMILIES)
    hamiltonian: str = setting("separable", choices=HAMILTONIAN_FAMILIES)
    order: int = setting(3, minimum=1)
    integrator: str = setting("leapfrog", choices=INTEGRATORS)
    binding: float = setting(0.0, minimum=0.0)  # Tao's ω ("tao", "tao4"); 0: ω = 1/dt
    dt: float = setting(0.25, minimum=0.0, strict=True)
    process_noise_per: str = setting("gap", choices=("gap", "step"))
    noise: str = setting("isotropic", choices=("isotropic", "diagonal"))
    observation: str = setting("auto", choices=("auto", "full", "positions"))
    mass: tuple[float, ...] = setting(())
    alpha: float = setting(1.0, minimum=0.0, strict=True)
    beta: float = setting(2.0)
    kappa: float = setting(0.0)
    jitter: float = setting(1e-12, minimum=0.0)


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

    ``variances`` is the prior of both the process- and the observation-noise variance;
    ``initial_state`` (used when the initial state is learned) is the prior of the offset of
    each component from its centre.
    """

    coefficients: Prior = field(default_factory=lambda: Laplace(0.0, 10.0))
    variances: Prior = field(default_factory=lambda: HalfNormal(1.0))
    initial_state: Prior = field(default_factory=lambda: Normal(0.0, 1.0))

    def prior_spec(self, learned_initial_state: bool) -> PriorSpec:
        """The :class:`~symplid.model.priors.PriorSpec` of these groups for the posterior."""
        return PriorSpec(
            coefficients=self.coefficients,
            process_var=self.variances,
            obs_var=self.variances,
            initial_state=self.initial_state if learned_initial_state else None,
        )


@dataclass(frozen=True)
class MapSettings:
    """The MAP search: bounded quasi-Newton from several seeded starts."""

    num_starts: int = setting(4, minimum=1)
    seed: int = setting(0, minimum=0)


@dataclass(frozen=True)
class SamplerSettings:
    """MCMC: DRAM with the paper's budget per chain (200,000 iterations, 100,000 burn-in).

    ``num_iterations`` counts every iteration of a chain, ``burn_in`` included; the draws kept
    per chain are ``(num_iterations − burn_in) // thin`` (:attr:`num_draws`).
    """

    method: str = setting("dram", choices=SAMPLERS)
    num_iterations: int = setting(200_000, minimum=1)
    burn_in: int = setting(100_000, minimum=0)
    num_chains: int = setting(4, minimum=1)
    gamma: float = setting(0.01, minimum=0.0, strict=True)
    adapt_start: int = setting(200, minimum=0)
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
class Settings:
    """Everything a run needs; the defaults are the paper's Hénon–Heiles experiment."""

    seed: int = setting(0, minimum=0)
    model: ModelSettings = field(default_factory=ModelSettings)
    initial_state: InitialStateSettings = field(default_factory=InitialStateSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    map: MapSettings = field(default_factory=MapSettings)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    prediction: PredictionSettings = field(default_factory=PredictionSettings)


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
    (not leapfrog or Yoshida) and no constant mass; ``model.binding`` is Tao's ω only.
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
