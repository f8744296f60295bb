"""The sections of the run settings: frozen dataclasses whose fields carry their checks.

Each field is a :func:`~symplid.workflow._validate.setting` (default, range, choices): the
one validator (:mod:`symplid.workflow._validate`) reads them, and so do the sweeps. Names of
integrators, samplers and prior families come from their registries. The file format, the
loading and the overrides are in :mod:`symplid.workflow._settings`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from symplid.dynamics._families import (
    HAMILTONIAN_FAMILIES,
    POTENTIAL_FAMILIES,
)
from symplid.dynamics._integrators import INTEGRATORS
from symplid.dynamics._neural import ACTIVATIONS
from symplid.dynamics._user_models import MAX_EXPRESSION_SIZE, QUADRATIC, is_user_model
from symplid.filters._noise import OBSERVATION_NOISE
from symplid.inference.map import EVIDENCE_METHODS
from symplid.inference.samplers import SAMPLERS
from symplid.inference.samplers._dram import PARAMETER_SCALES, VARIANCE_SCALES
from symplid.model._inputs import INTERPOLATIONS
from symplid.model._prior_spec import PriorSpec
from symplid.model._priors import HalfNormal, Laplace, Normal, Prior
from symplid.model._statespace import PROCESS_NOISE_CHOICES
from symplid.workflow._user_parameters import (
    UserParameter,
    initial_values,
    parameter_priors,
)
from symplid.workflow._validate import Spec, setting

__all__ = [
    "PRIOR_DEFAULTS",
    "PRIOR_SPECS",
    "PRIOR_SYNONYMS",
    "RENAMED",
    "InitialStateSettings",
    "InputSettings",
    "MapSettings",
    "ModelSettings",
    "PlotSettings",
    "PredictionSettings",
    "PriorSettings",
    "SamplerSettings",
    "Settings",
    "map_start",
    "prior_spec",
]


# ----------------------------------------------------------------------------- sections
def _as_written(text: str) -> bool:
    """Any text is kept as written (an expression, a path): not a choice, not lowercased."""
    return True


@dataclass(frozen=True)
class ModelSettings:
    """The state-space model of eq. (7) and its unscented filter (Theorem 1).

    ``order`` is read by the polynomial family; ``width``, ``depth``, ``activation`` and
    ``network_seed`` (the seed of the initial weights) by the ``"mlp"`` family
    (:class:`~symplid.dynamics._neural.MLPPotential`). A family ignores the others.
    ``potential`` and ``hamiltonian`` also take a user's own model, an expression or
    ``file:PATH:NAME`` (:mod:`symplid.dynamics._user_models`), whose parameters
    ``parameters`` declares (:mod:`symplid.workflow._user_parameters`); ``kinetic`` is the
    T(p) of such a potential (``"quadratic"``: ½pᵀM⁻¹p).
    """

    potential: str = setting(
        "polynomial", choices=POTENTIAL_FAMILIES, other=is_user_model,
        doc=(
            "Family of U(q; θ): the polynomial of eq. 13, a neural network (``\"mlp\"``), an "
            "expression in q1..qd or ``file:PATH:NAME`` (a user's model)."
        ),
    )
    hamiltonian: str = setting(
        "separable", choices=HAMILTONIAN_FAMILIES, other=is_user_model,
        doc=(
            "Family of a whole H(q, p; θ); ``\"separable\"``: H = ½pᵀM⁻¹p + U(q) with U from "
            "``potential``; also an expression in q1..qd, p1..pd or ``file:PATH:NAME``."
        ),
    )
    kinetic: str = setting(
        QUADRATIC, choices=(QUADRATIC,), other=is_user_model,
        doc=(
            "T(p) of a user's potential: ``\"quadratic\"`` (½pᵀM⁻¹p) or an expression in "
            "p1..pd (or ``file:PATH:NAME``) with declared parameters."
        ),
    )
    parameters: tuple[UserParameter, ...] = setting(
        (),
        doc=(
            "A user model's parameters, one table each: ``NAME = { prior = ..., scale = ..., "
            "lower = ..., upper = ..., initial = ... }``."
        ),
    )
    max_expression_size: int = setting(
        MAX_EXPRESSION_SIZE, minimum=1,
        doc=(
            "The most tokens (numbers, names, operators) a user's expression may have: the "
            "compile time of its likelihood grows faster than its size."
        ),
    )
    order: int = setting(
        3, minimum=1,
        doc="Polynomial order ℓ of U (monomials of total degree 1..ℓ).",
    )
    width: int = setting(32, minimum=1, doc="Units per hidden layer of an ``\"mlp\"`` network.")
    depth: int = setting(2, minimum=0, doc="Hidden layers of an ``\"mlp\"`` network.")
    activation: str = setting(
        "tanh", choices=ACTIVATIONS,
        doc="Activation of an ``\"mlp\"`` network.",
    )
    network_seed: int = setting(
        0, minimum=0,
        doc="Seed of an ``\"mlp\"`` network's initial weights.",
    )
    integrator: str = setting(
        "leapfrog", choices=INTEGRATORS,
        doc="Propagator Ψ inside the likelihood (eq. 14); any name in ``symplid.INTEGRATORS``.",
    )
    binding: float = setting(
        0.0, minimum=0.0,
        doc="Tao's binding ω (``\"tao\"``, ``\"tao4\"``); 0: ω = 1/dt.",
    )
    dt: float | str = setting(
        "auto", minimum=0.0, strict=True, words=("auto",),
        doc=(
            "Learning step: each observation gap is split into ⌈gap/dt⌉ equal substeps; "
            "``\"auto\"`` (the default): the fit chooses the largest step whose halving moves "
            "no dynamics parameter by more than 0.1 posterior sds at the MAP, at most the "
            "data's smallest gap or, where larger, a quarter of the median gap, halved until "
            "it resolves the fastest motion the MAP's data starts show (a few warm-started MAP "
            "refits)."
        ),
    )
    process_noise_per: str = setting(
        "gap", choices=PROCESS_NOISE_CHOICES,
        doc=(
            "Process noise Σ added once per observation gap (the paper's), after every substep, "
            "or ``\"none\"``: no Σ, the exact likelihood of the data around one integrated path."
        ),
    )
    noise: str = setting(
        "auto", choices=("auto", "isotropic", "diagonal", "per-kind"),
        doc=(
            "Observation variances: ``\"auto\"`` is one per kind of column (q, p) when the data "
            "have both, one in all for positions only."
        ),
    )
    observation_noise: str = setting(
        "additive", choices=OBSERVATION_NOISE,
        doc="How the noise enters the data: y = h(x) + η, y = h(x)∘(1 + ε), or both.",
    )
    standardise: str = setting(
        "auto", choices=("auto", "on", "off"),
        doc=(
            "Fit in q/a, p/a (a = RMS of the positions) and report in the data's units; "
            "``\"auto\"``: on when a is outside [0.1, 10]."
        ),
    )
    observation: str = setting(
        "auto", choices=("auto", "full", "positions"),
        doc=(
            "Observation operator h: the full state or the positions; ``\"auto\"``: from the data's"
            " columns."
        ),
    )
    mass: tuple[float, ...] = setting(
        (),
        doc="Diagonal of the mass matrix M (empty: the identity).",
    )
    alpha: float = setting(1.0, minimum=0.0, strict=True, doc="Unscented transform's spread α.")
    beta: float = setting(2.0, doc="Unscented transform's β (2 is optimal for a Gaussian).")
    kappa: float = setting(0.0, doc="Unscented transform's κ.")
    jitter: float = setting(
        1e-12, minimum=0.0,
        doc="Added to the diagonal of covariances before a Cholesky factorisation.",
    )
    damping: bool = setting(
        False,
        doc="Learn a damping rate γ: ṗ = −∂U/∂q − γM⁻¹p (CLI ``--damping``).",
    )
    """Learn a damping rate γ: ṗ = −∂U/∂q − γM⁻¹p (:mod:`symplid.dynamics._damping`)."""
    force: str = setting(
        "", other=_as_written,
        doc=(
            "A generalised force F(q, p, u, t): ṗ = −∂H/∂q + F, an expression in q1..qd, "
            "p1..pd, the inputs u1..um, t and declared parameters (one per momentum, separated "
            "by ``;``), or ``file:PATH:NAME``; empty: none (free motion)."
        ),
    )


@dataclass(frozen=True)
class InputSettings:
    """The measured inputs u(t) of a driven model (``model.force``): input columns of the
    data file, a file of their own, or expressions in t (:mod:`symplid.model._inputs`)."""

    columns: tuple[str, ...] = setting(
        (),
        doc=(
            "The data file's input columns, read as u1, u2, … in this order; empty: the "
            "columns named u1, u2, …."
        ),
    )
    file: str = setting(
        "", other=_as_written,
        doc="A CSV file t,u1,… of the inputs (instead of columns of the data file).",
    )
    expressions: tuple[str, ...] = setting(
        (),
        doc="The inputs u1, u2, … as expressions in t (a known excitation), e.g. "
            "``[\"0.5*sin(1.3*t)\"]``.",
    )
    interpolation: str = setting(
        "linear", choices=INTERPOLATIONS,
        doc="Between input samples: ``\"zoh\"`` (hold the last), ``\"linear\"`` or "
            "``\"cubic\"`` (spline).",
    )


@dataclass(frozen=True)
class InitialStateSettings:
    """The initial state X_0 ~ N(x0, p0_var·I) at time t0, known or learned with θ.

    ``t0 = "first"`` puts the state at the first observation time (the filter starts with
    that observation's update; see :class:`~symplid.model._posterior.Posterior`, ``t0=None``).
    """

    mode: str = setting(
        "known", choices=("known", "learned"),
        doc=(
            "``\"known\"``: x0 is given; ``\"learned\"``: each trajectory's initial state joins θ, "
            "its prior centred on the first observation."
        ),
    )
    x0: tuple[float, ...] = setting(
        (),
        doc="The known initial state q1..qd, p1..pd (one per trajectory, one after the other).",
    )
    p0_var: float = setting(
        1e-16, minimum=0.0,
        doc="Variance of the known initial state (P0 = p0_var·I).",
    )
    t0: float | str = setting(
        0.0, words=("first",),
        doc=("Time of the initial state; ``\"first\"``: at the first observation (as is a "
             "t0 equal to the first observation time)."),
    )

    @property
    def at_first_observation(self) -> bool:
        """True for ``t0 = "first"``."""
        return self.t0 == "first"

    def start_time(self, first_observation: float) -> float:
        """t0 as a number: the first observation time for ``t0 = "first"``."""
        return float(first_observation) if self.at_first_observation else float(self.t0)


#: What ``priors.process_var`` may name (:class:`PriorSettings`).
PROCESS_VAR_PRIORS = ("variances", "log-uniform")


@dataclass(frozen=True)
class PriorSettings:
    """Priors by group of θ: the paper's Laplace(0, 10) and half-normal(1) (Section IV).

    ``variances`` is the prior of every noise variance (process, observation, and the relative
    variance of multiplicative observation noise); ``damping`` that of the damping rate γ of a
    damped model (``model.damping = true``);
    ``initial_state`` (used when the initial state is learned) is the prior of the offset of
    each component from its centre. ``process_var = "log-uniform"`` gives the process
    variance Σ a log-uniform prior scaled to the data instead (resolved with the data by
    :func:`symplid.workflow._fit.build_posterior`; see :mod:`symplid.model._variance_prior`).
    """

    coefficients: Prior = field(default_factory=lambda: Laplace(0.0, 10.0))
    """Prior of every coefficient of U or H (a neural family names its own default)."""
    variances: Prior = field(default_factory=lambda: HalfNormal(1.0))
    """Prior of every noise variance (process, observation, relative)."""
    initial_state: Prior = field(default_factory=lambda: Normal(0.0, 1.0))
    """Prior of a learned initial state's offset from its centre (the first observation)."""
    damping: Prior = field(default_factory=lambda: HalfNormal(1.0))
    """Prior of the damping rate γ (bounded below by 0 whatever its prior)."""
    process_var: str = setting(
        "variances", choices=PROCESS_VAR_PRIORS,
        doc=(
            "Prior of the process variance Σ: ``\"variances\"``, the ``variances`` prior (the "
            "paper's half-normal); ``\"log-uniform\"``, log-uniform from b·1e-8 to b, b the "
            "data's variance scale (:mod:`symplid.model._variance_prior`)."
        ),
    )

    def prior_spec(self, learned_initial_state: bool) -> PriorSpec:
        """The :class:`~symplid.model._prior_spec.PriorSpec` of these groups for the posterior."""
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
    (:func:`~symplid.inference.map._neural.find_map_neural`): ``adam_steps`` of Adam with step
    ``learning_rate``, then ``lbfgs_steps`` of L-BFGS, and the Gauss–Newton Laplace covariance;
    ``num_starts`` is not used there. ``evidence``: ``"quadrature"`` integrates the noise
    variances over their logarithms (:mod:`symplid.inference.map._evidence`; right when a variance
    piles against its floor, a few seconds more per fit), ``"laplace"`` the Gaussian
    approximation alone (what a study that never reads the evidence needs).
    """

    num_starts: int = setting(4, minimum=1, doc="Seeded starts of the MAP search (L-BFGS-B).")
    evidence: str = setting(
        "quadrature", choices=EVIDENCE_METHODS,
        doc=(
            "Log evidence: noise variances integrated over log v (``\"quadrature\"``) or the "
            "Laplace approximation alone."
        ),
    )
    seed: int = setting(0, minimum=0, doc="Seed of the MAP starts.")
    adam_steps: int = setting(2000, minimum=0, doc="Adam steps of a neural family's MAP.")
    learning_rate: float = setting(
        0.01, minimum=0.0, strict=True,
        doc="Adam's step size for a neural family.",
    )
    lbfgs_steps: int = setting(1000, minimum=0, doc="L-BFGS steps after Adam for a neural family.")
    sensitivity: bool = setting(
        True,
        doc=(
            "The sensitivity checks of a fit (:mod:`symplid.workflow._sensitivity`), right "
            "after its MAP: the MAP refitted at dt/2 and with the other process-noise model, "
            "each dynamics parameter's shift in posterior sds, saved as ``diagnostics.json``, "
            "printed by ``symplid fit`` and shown in the report. ``false`` skips the two "
            "refits (the paper's studies do)."
        ),
    )


@dataclass(frozen=True)
class SamplerSettings:
    """MCMC: DRAM, by default until the draws are good enough.

    ``num_iterations = "auto"`` (the default) samples until every parameter's bulk and tail
    ESS reach ``target_ess`` and its R-hat is at most ``target_rhat``, checked between the
    chunks, or up to ``max_iterations`` per chain or ``max_seconds`` of sampling, whichever
    comes first (:mod:`symplid.sampling._budget`); the burn-in starts at the
    sampler's own first burn-in and is extended while the chains disagree. A number is a fixed
    budget: ``num_iterations`` then counts every iteration of a chain, ``burn_in`` included
    (``"auto"``: half of them, the paper's 100,000 of 200,000); the draws kept per chain are
    ``(num_iterations − burn_in) // thin`` (the property ``num_draws``).
    ``variance_scale`` is DRAM's: ``"log"`` (default) moves the variances as log(v) with the
    Jacobian (no wall at their floor), ``"natural"`` as themselves (the paper's);
    ``parameter_scale`` the same for a user model's parameters, by default the scale of each
    one's prior (log θ for a log-normal prior, θ for the others).
    """

    method: str = setting(
        "dram", choices=SAMPLERS,
        doc=("The sampler: any name in ``symplid.samplers.SAMPLERS``. DRAM, the default, "
             "reached the ESS and R-hat targets first on every system measured against NUTS "
             "(the table in the how-to on the sampling budget)."),
    )
    num_iterations: int | str = setting(
        "auto", minimum=1, words=("auto",),
        doc=(
            "Iterations per chain, burn-in included: a fixed budget (the paper's: 200000; "
            "CLI ``--iterations``), or ``\"auto\"``: until the targets are met "
            "(``target_ess``, ``target_rhat``) or a cap (``max_iterations``, ``max_seconds``)."
        ),
    )
    burn_in: int | str = setting(
        "auto", minimum=0, words=("auto",),
        doc=(
            "Iterations per chain discarded at the start; ``\"auto\"``: half of a fixed "
            "budget, or the sampler's first burn-in (DRAM max(2000, 500 d), NUTS 1000), "
            "extended while the chains disagree."
        ),
    )
    target_ess: float = setting(
        400.0, minimum=0.0, strict=True,
        doc=("``num_iterations = \"auto\"`` stops once every parameter's bulk and tail ESS "
             "reach it."),
    )
    target_rhat: float = setting(
        1.01, minimum=1.0, strict=True,
        doc="... and every parameter's R-hat is at most this.",
    )
    max_iterations: int = setting(
        200_000, minimum=1,
        doc="Cap on the iterations per chain, burn-in included, of ``num_iterations = \"auto\"``.",
    )
    max_seconds: float = setting(
        0.0, minimum=0.0,
        doc="Cap on the sampling's wall time of ``num_iterations = \"auto\"``; 0: none.",
    )
    num_chains: int = setting(4, minimum=1, doc="Independent chains.")
    gamma: float = setting(0.01, minimum=0.0, strict=True, doc="DRAM's second-stage scale.")
    adapt_start: int = setting(
        200, minimum=0,
        doc="Iteration from which DRAM adapts its proposal covariance.",
    )
    variance_scale: str = setting(
        "log", choices=VARIANCE_SCALES,
        doc="DRAM moves the noise variances as log(v) (with the Jacobian) or as v (the paper's).",
    )
    parameter_scale: str = setting(
        "prior", choices=PARAMETER_SCALES,
        doc=("How DRAM moves a user model's parameters bounded below only: ``\"prior\"``, "
             "as log(θ) for a log-normal prior and as θ for the others; ``\"natural\"``: "
             "all as θ, along the straight ridges of a potential linear in its "
             "coefficients; ``\"log\"``: all as log(θ), with the Jacobian."),
    )
    thin: int = setting(1, minimum=1, doc="Keep every thin-th draw.")
    seed: int = setting(0, minimum=0, doc="Seed of the sampler.")
    restart_stuck_chains: bool = setting(
        True,
        doc=(
            "At the end of the burn-in, restart a chain whose median log density stays more "
            "than max(10, 5√(d/2)) nats below the best chain's from a good chain's state "
            "(a region of negligible mass); the draws are unchanged when no chain is stuck."
        ),
    )
    chunk_size: int = setting(
        2000, minimum=1,
        doc=(
            "Iterations per compiled block of the sampler: after each, the block's draws are "
            "saved to the run folder (``draws/``), a stop (Ctrl-C, SIGTERM) is obeyed and "
            "an ``\"auto\"`` budget may check its targets. A fixed budget's draws do not "
            "depend on it."
        ),
    )

    @property
    def fixed(self) -> bool:
        """Whether the budget is a fixed number of iterations (not ``"auto"``)."""
        return self.num_iterations != "auto"

    @property
    def resolved_burn_in(self) -> int | None:
        """The burn-in: the number given, half of a fixed budget, or None (the sampler's
        first burn-in, ``"auto"`` both)."""
        if self.burn_in != "auto":
            return int(self.burn_in)
        return int(self.num_iterations) // 2 if self.fixed else None

    @property
    def num_draws(self) -> int | None:
        """Draws kept per chain with a fixed budget: the iterations after burn-in, thinned
        (None: ``"auto"``)."""
        if not self.fixed:
            return None
        return (int(self.num_iterations) - int(self.resolved_burn_in)) // self.thin

    @property
    def iterations_cap(self) -> int:
        """The most iterations per chain the run can take (burn-in included)."""
        return int(self.num_iterations) if self.fixed else int(self.max_iterations)

    @property
    def max_draws(self) -> int:
        """The most draws a chain can keep."""
        if self.fixed:
            return int(self.num_draws)
        return (self.max_iterations - (self.resolved_burn_in or 0)) // self.thin

    def budget_words(self) -> str:
        """The budget in words, for reports: fixed, or the targets and caps."""
        if self.fixed:
            return (f"{int(self.num_iterations):,} iterations "
                    f"({int(self.resolved_burn_in):,} burn-in)")
        cap = f"at most {self.max_iterations:,} iterations"
        if self.max_seconds:
            cap += f" or {self.max_seconds:g} s"
        return (f"until bulk and tail ESS ≥ {self.target_ess:g} and R-hat ≤ "
                f"{self.target_rhat:g} ({cap})")


@dataclass(frozen=True)
class PredictionSettings:
    """Predictions from the learned models: leapfrog at a fine dt to t_end (Figs 1–3)."""

    integrator: str = setting("leapfrog", choices=INTEGRATORS, doc="Propagator of the predictions.")
    dt: float = setting(0.01, minimum=0.0, strict=True, doc="Step of the predictions.")
    t_end: float = setting(200.0, doc="Predictions run to this time.")
    num_paths: int = setting(
        100, minimum=0,
        doc="Posterior sample paths drawn for the prediction band.",
    )


@dataclass(frozen=True)
class PlotSettings:
    """What the run's figures show: the data's time unit (axis labels), how many parameters
    the pair plot and the trace plot draw (the first ones in θ's order; a figure that leaves
    some out says so), and the system the data came from when it is known (a name in
    ``symplid.SYSTEMS``, e.g. for simulated data): its U and coefficients are drawn as the
    truth."""

    time_unit: str = setting("s", doc="Unit written on every time axis (CLI ``--time-unit``).")
    truth: str = setting(
        "",
        doc="The named system that made the data, if known: its U and true values are drawn.",
    )
    max_pair_params: int = setting(
        6, minimum=2,
        doc=(
            "Parameters in the pair plot (the first ones in θ's order; a note says when some are "
            "left out)."
        ),
    )
    max_trace_params: int = setting(16, minimum=1, doc="Parameters in the trace plot.")


@dataclass(frozen=True)
class Settings:
    """Everything a run needs; the defaults are the paper's Hénon–Heiles experiment."""

    seed: int = setting(
        0, minimum=0,
        doc="Seed of the run (data simulation, MAP starts and sampler unless they set their own).",
    )
    model: ModelSettings = field(default_factory=ModelSettings)
    initial_state: InitialStateSettings = field(default_factory=InitialStateSettings)
    priors: PriorSettings = field(default_factory=PriorSettings)
    map: MapSettings = field(default_factory=MapSettings)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    prediction: PredictionSettings = field(default_factory=PredictionSettings)
    plots: PlotSettings = field(default_factory=PlotSettings)
    inputs: InputSettings = field(default_factory=InputSettings)


def prior_spec(settings: Settings) -> PriorSpec:
    """The posterior's priors: the groups of ``settings.priors`` and, for a user's model, each
    declared parameter's own prior within its bounds (``[model.parameters]``)."""
    spec = settings.priors.prior_spec(settings.initial_state.mode == "learned")
    own = parameter_priors(settings.model.parameters)
    return dataclasses.replace(spec, overrides={**spec.overrides, **own}) if own else spec


def map_start(settings: Settings) -> dict[str, float] | None:
    """The MAP's first start that the settings give: the ``initial`` values of
    ``[model.parameters]`` (None when none is declared)."""
    return initial_values(settings.model.parameters) or None


#: Renamed keys: old dotted key → new dotted key (the old one is read with a FutureWarning).
RENAMED = {"sampler.num_samples": "sampler.num_iterations"}
#: Values of prior parameters a settings file leaves out (the family's class decides others).
PRIOR_DEFAULTS = {"loc": 0.0, "scale": 1.0, "low": 0.0, "high": 1.0}
PRIOR_SPECS = {
    "scale": Spec(float, minimum=0.0, strict=True),
    "sigma": Spec(float, minimum=0.0, strict=True),
}
PRIOR_SYNONYMS = {"log-normal": {"loc": "mu", "scale": "sigma"}}
