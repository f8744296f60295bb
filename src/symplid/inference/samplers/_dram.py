"""Delayed-rejection adaptive Metropolis (DRAM).

Haario, Laine, Mira and Saksman (2006), "DRAM: efficient adaptive MCMC", Statistics and
Computing 16, 339–354: the sampler of the seed paper (section II-B.3, γ = 0.01). It is
written as a BlackJAX-style pair of pure functions,

>>> state = init(position, logdensity_fn, cov)                    # doctest: +SKIP
>>> step = build_kernel(logdensity_fn, DRAMSettings())            # doctest: +SKIP
>>> state, info = step(rng_key, state)                            # doctest: +SKIP

so that a chunk of iterations is one ``lax.scan`` and several chains are one ``vmap``.

Conventions (``docs/explanation/conventions.md``):

* **Stage 1** is a Gaussian random walk ``y1 = x + L z``, ``L Lᵀ = C`` the current proposal
  covariance.
* **Adaptive Metropolis.** The running mean and covariance of *every* state of the chain
  (the start included, repeated states counted again) are updated recursively at every
  iteration (Welford). Once ``adapt_start`` states are in (200 by default), the proposal
  covariance becomes ``C = s_d (Cov + ε D)`` with ``s_d = 2.4²/d`` and is re-computed at every
  iteration. ``D = diag(C0)`` is the diagonal of the initial covariance, so the nugget ``ε``
  is relative to each parameter's own scale: the parameters of this library differ by many
  orders of magnitude (a process-noise variance near 1e-7 beside coefficients near 1), and
  an absolute ``ε·I`` would swamp the small ones.
* **Before adaptation** the proposal covariance is ``s_d C0``, where ``C0`` is the given
  initial covariance (the inverse Hessian at the MAP, i.e. the Laplace covariance). Scaling
  ``C0`` by the same ``2.4²/d`` makes the pre-adaptation proposal the optimal random walk
  for a Gaussian target with that covariance and keeps the proposal continuous when the
  adaptation begins. (``initial_scale`` changes this factor.)
* **Stage 2** (delayed rejection), run only when stage 1 rejects: ``y2 = x + √γ L z'``, a
  proposal whose covariance is ``γ C`` (γ = 0.01 scales the covariance, as in the paper).
  It is symmetric in ``(x, y2)``, so the acceptance probability is

      α2 = min(1, π(y2) q1(y2, y1) [1 − α1(y2, y1)] / (π(x) q1(x, y1) [1 − α1(x, y1)]))

  with ``q1(a, b) = N(b; a, C)`` and ``α1(a, b) = min(1, π(b)/π(a))``; it is computed in log
  space with ``log(1 − eᵃ)`` evaluated by the ``log1p``/``expm1`` rule (:func:`log1mexp`).
* **Non-finite log densities** (NaN, ±∞: a failed Cholesky inside the filter, a point
  outside the support) count as ``−∞``: the proposal is rejected, nothing raises, and no NaN
  reaches the state. A non-positive-definite adapted covariance keeps the previous proposal.

Speed: for up to ``MAX_UNROLLED_DIM`` (16) parameters the kernel's linear algebra (the
proposal's Cholesky factor, the triangular solve of ``q1`` and ``L z``) is unrolled small-matrix
arithmetic (:mod:`symplid.filters._linalg`) instead of LAPACK calls and ``dot``: without a
custom call or ``dot`` in its body, XLA:CPU compiles a whole chunk of iterations as one kernel
(see :func:`symplid.runtime.configure_xla`). The results equal LAPACK's to rounding (1e-12).
Where the log density is a custom call (the compiled likelihood), XLA runs the chunk operation
by operation, each fused operation and copy dispatched on its own; there each stretch of the
step between two log-density calls (the random draws, the proposals, the acceptance test, the
adaptive update) is compiled as one kernel of its own (``linalg = "fused"``,
:func:`symplid._kernel_region.one_kernel`): the paper's posterior on the compiled kernel,
one chain, 26.6 → 21.9 µs per iteration; four vectorised chains with paired stages,
40.5 → 36.6 µs (against LAPACK calls, the former choice there;
``benchmarks/dram_regions.py``). A backend that evaluates a batch for little more than one
point gets both stages' proposals in one call (``paired_stages``; stage 2's value is used only
when stage 1 rejects, so the chain is the same to rounding). :func:`~._registry.resolve_dram`
picks both per run.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from symplid._kernel_region import one_kernel
from symplid.inference.samplers._dram_stages import (
    LAPACK,
    UNROLLED,
    Algebra,
    Region,
    Stages,
    finite_or_neg_inf,
    inline,
    log1mexp,
    paired_stages,
    stage2_log_acceptance,
    staged,
)

Array = jax.Array
LogDensityFn = Callable[[Array], Array]
VARIANCE_SCALES = ("natural", "log")
"""Choices of :attr:`DRAMSettings.variance_scale`."""
PARAMETER_SCALES = ("prior", "natural", "log")
"""Choices of :attr:`DRAMSettings.parameter_scale`."""
LINALG_CHOICES = ("unrolled", "lapack", "fused")
"""Choices of :attr:`DRAMSettings.linalg`."""


__all__ = [
    "PARAMETER_SCALES",
    "VARIANCE_SCALES",
    "DRAMInfo",
    "DRAMSettings",
    "DRAMState",
    "build_kernel",
    "init",
    "log1mexp",
    "stage2_log_acceptance",
]


@dataclass(frozen=True)
class DRAMSettings:
    """Static settings of the DRAM kernel.

    Parameters
    ----------
    adapt_start
        Number of chain states (the start included) collected before the proposal covariance
        is first replaced by the adapted one; 200 in the paper's setup.
    adapt_stop
        Iteration from which the proposal is frozen; ``None`` adapts for the whole run
        (Haario et al. 2001 show that adapting for ever keeps the right ergodic limit).
    scale
        ``s_d``, the factor multiplying the adapted covariance; ``None`` means ``2.4²/d``.
    initial_scale
        Factor multiplying the initial covariance before adaptation; ``None`` means ``scale``.
    nugget
        ``ε``: the adapted covariance is ``Cov + ε·diag(C0)``.
    gamma
        Covariance scale of the second-stage proposal (γ = 0.01 in the paper).
    delayed_rejection
        Whether to try the second stage at all (``False`` gives plain adaptive Metropolis).
    variance_scale
        ``"log"`` (default): the variance parameters (bounded below only) move as
        w = log(v − a), the target gaining the log-Jacobian Σ w
        (:func:`~._registry.build_dram`), so a variance whose posterior is piled against its
        floor is no longer a wall that rejects half the proposals. ``"natural"``: the chain
        moves in θ itself (the paper's). On the paper's data (4 chains × 12,000 iterations)
        the log scale raised the smallest ESS from 121 to 263 (leapfrog) and 341 to 468
        (RK2), R-hat 1.056 → 1.034 and 1.020 → 1.011, with the same process-noise medians.
    parameter_scale
        How a user model's declared parameters bounded below only move. ``"prior"``
        (default): on the scale their prior is written on, as log(θ − a) for a log-normal
        prior, as θ for the others (half-normal, normal with a lower bound); ``"natural"``:
        all as θ; ``"log"``: all as log(θ − a), with the Jacobian. A potential is most often
        linear in its coefficients (U = a q²/2 + b q⁴/4), so the data pin down a linear
        combination of them (the small-oscillation frequency) and leave a straight ridge in
        θ, which the adapted Gaussian proposal follows; a log scale bends that ridge where it
        nears 0, and the proposal then cannot follow it. Measured with
        ``benchmarks/parameter_scale.py``: a quartic oscillator and a torsion-spring pendulum
        reached their targets in 8,000 and 14,000 iterations per chain as θ and not within
        the cap of 200,000 as log θ; the examples' systems reached them on both scales.
    paired_stages
        ``True``: both stages' proposals are drawn and evaluated in one batched call, stage
        2's value used only when stage 1 rejects (the same chain, draw for draw, as
        ``False``, where stage 2 is evaluated only when needed). Pays where a batch costs
        little more than one point: four vectorised chains make a batch of eight, which the
        compiled kernel evaluates 2.3 times faster than two batches of four.
        ``None`` (default): :func:`~symplid.sampling.sample` decides from the
        chains and the likelihood backend (:func:`~._registry.resolve_dram`).
    linalg
        How the step's own arithmetic is compiled (the same numbers to rounding):
        ``"unrolled"``: the proposal's Cholesky factor, triangular solve and ``L z`` as
        unrolled small-matrix arithmetic, which lets XLA:CPU compile a whole chunk of
        iterations as one kernel when the log density is plain JAX; ``"fused"``: the same
        arithmetic, each stretch between two log-density calls compiled as one kernel of its
        own, for a log density that is a custom call (the compiled likelihood), around which
        XLA runs the chunk operation by operation; ``"lapack"``: library calls (fewer, larger
        operations). ``None`` (default): decided by :func:`~._registry.resolve_dram` (fused for
        a custom-call backend, else unrolled).
    """

    adapt_start: int = 200
    adapt_stop: int | None = None
    scale: float | None = None
    initial_scale: float | None = None
    nugget: float = 1e-10
    gamma: float = 0.01
    delayed_rejection: bool = True
    variance_scale: str = "log"
    parameter_scale: str = "prior"
    paired_stages: bool | None = None
    linalg: str | None = None

    #: What a run recorded before a setting existed ran with (a resumed run reads its record
    #: with these in place of today's defaults): a user's parameters on the log scale.
    RECORD_DEFAULTS: ClassVar[dict[str, Any]] = {"parameter_scale": "log"}

    def __post_init__(self) -> None:
        for name, choices in (("variance_scale", VARIANCE_SCALES),
                              ("parameter_scale", PARAMETER_SCALES)):
            if getattr(self, name) not in choices:
                raise ValueError(
                    f"{name} must be one of {', '.join(map(repr, choices))}, "
                    f"got {getattr(self, name)!r}"
                )
        if self.linalg not in (None, *LINALG_CHOICES):
            raise ValueError(
                f"linalg must be one of {', '.join(map(repr, LINALG_CHOICES))}, "
                f"got {self.linalg!r}"
            )
        if self.adapt_start < 1:
            raise ValueError(f"adapt_start must be >= 1, got {self.adapt_start}")
        if self.adapt_stop is not None and self.adapt_stop < 0:
            raise ValueError(f"adapt_stop must be >= 0 or None, got {self.adapt_stop}")
        for name in ("scale", "initial_scale"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value}")
        if not (math.isfinite(self.nugget) and self.nugget >= 0):
            raise ValueError(f"nugget must be a finite number >= 0, got {self.nugget}")
        if not (math.isfinite(self.gamma) and self.gamma > 0):
            raise ValueError(f"gamma must be a positive finite number, got {self.gamma}")

    def resolved_scale(self, dim: int) -> float:
        """The adapted-covariance factor ``s_d`` for dimension ``dim``."""
        return 2.4**2 / dim if self.scale is None else float(self.scale)

    def resolved_initial_scale(self, dim: int) -> float:
        """The factor applied to the initial covariance ``C0``."""
        if self.initial_scale is None:
            return self.resolved_scale(dim)
        return float(self.initial_scale)


class DRAMState(NamedTuple):
    """State of one DRAM chain.

    Attributes
    ----------
    position
        Current point, shape ``(d,)``.
    logdensity
        Log density at ``position`` (finite).
    mean, cov
        Running mean and (unbiased) covariance of the ``count`` states seen so far.
    count
        Number of states folded into ``mean``/``cov`` (the start counts as one).
    iteration
        Number of DRAM steps taken.
    chol
        Lower Cholesky factor of the current stage-1 proposal covariance.
    nugget
        The nugget matrix diagonal ``ε·diag(C0)``, shape ``(d,)``.
    """

    position: Array
    logdensity: Array
    mean: Array
    cov: Array
    count: Array
    iteration: Array
    chol: Array
    nugget: Array


class DRAMInfo(NamedTuple):
    """What happened in one DRAM step.

    Attributes
    ----------
    is_accepted
        The chain moved (at either stage).
    stage1_accepted
        The first-stage proposal was accepted.
    stage2_attempted
        Stage 1 rejected and a second-stage proposal was evaluated.
    stage2_accepted
        The second-stage proposal was accepted.
    acceptance_rate1, acceptance_rate2
        Acceptance probabilities α1 and α2 (α2 is 0 when stage 2 did not run).
    proposal1, proposal2
        The two proposals (``proposal2`` is meaningful only when stage 2 ran).
    logdensity
        Log density of the new state.
    """

    is_accepted: Array
    stage1_accepted: Array
    stage2_attempted: Array
    stage2_accepted: Array
    acceptance_rate1: Array
    acceptance_rate2: Array
    proposal1: Array
    proposal2: Array
    logdensity: Array


def _proposal_chol(cov: Array, nugget: Array, factor: float,
                   algebra: Algebra = UNROLLED) -> Array:
    matrix = factor * (0.5 * (cov + cov.T) + jnp.diag(nugget))
    return algebra.cholesky(matrix)


def init(position: Array, logdensity_fn: LogDensityFn, cov: Array,
         settings: DRAMSettings | None = None, logdensity: Array | None = None) -> DRAMState:
    """Initial DRAM state at ``position`` with initial proposal covariance ``cov``.

    Parameters
    ----------
    position
        Starting point, shape ``(d,)``; its log density must be finite for the chain to
        move sensibly (a −∞ start accepts the first valid proposal).
    logdensity_fn
        Target log density.
    cov
        Initial covariance ``C0`` (positive definite), e.g. the inverse Hessian at the MAP.
    settings
        Kernel settings (for the nugget and the initial scale); defaults if ``None``.
    logdensity
        The log density at ``position`` if already known (it is then not evaluated again,
        which spares compiling an expensive log density once more).
    """
    settings = DRAMSettings() if settings is None else settings
    position = jnp.asarray(position, dtype=jnp.float64)
    if position.ndim != 1:
        raise ValueError(f"position must be a 1-D array, got shape {position.shape}")
    dim = position.shape[0]
    cov = jnp.asarray(cov, dtype=jnp.float64)
    if cov.shape != (dim, dim):
        raise ValueError(f"cov must have shape {(dim, dim)}, got {cov.shape}")
    nugget = settings.nugget * jnp.diag(cov)
    chol = jnp.linalg.cholesky(settings.resolved_initial_scale(dim) * 0.5 * (cov + cov.T))
    if logdensity is None:
        logdensity = logdensity_fn(position)
    logdensity = finite_or_neg_inf(logdensity)
    return DRAMState(
        position=position,
        logdensity=logdensity,
        mean=position,
        cov=jnp.zeros((dim, dim)),
        count=jnp.asarray(1, dtype=jnp.int64),
        iteration=jnp.asarray(0, dtype=jnp.int64),
        chol=chol,
        nugget=nugget,
    )


def _update_moments(state: DRAMState, position: Array) -> tuple[Array, Array, Array]:
    """Welford update of the running mean and unbiased covariance with one more state."""
    n = state.count.astype(position.dtype)  # states so far
    delta = position - state.mean
    mean = state.mean + delta / (n + 1.0)
    cov = ((n - 1.0) / n) * state.cov + jnp.outer(delta, delta) / (n + 1.0)
    return mean, cov, state.count + 1


def build_kernel(logdensity_fn: LogDensityFn,
                 settings: DRAMSettings | None = None) -> Callable[[Array, DRAMState],
                                                                   tuple[DRAMState, DRAMInfo]]:
    """Build the DRAM transition ``step(rng_key, state) -> (state, info)``.

    Parameters
    ----------
    logdensity_fn
        Target log density ``θ -> log π(θ)`` (jit-able; non-finite values mean rejection).
    settings
        Static kernel settings, bound by the closure.

    Returns
    -------
    Callable
        A pure, jit- and vmap-able transition.
    """
    settings = DRAMSettings() if settings is None else settings
    num_stages = 2 if settings.delayed_rejection else 1
    paired = bool(settings.paired_stages) and num_stages == 2
    algebra = LAPACK if settings.linalg == "lapack" else UNROLLED
    region = one_kernel if settings.linalg == "fused" else inline
    stage_scales = jnp.array([1.0, math.sqrt(settings.gamma)])

    def logdensity(position: Array) -> Array:
        return finite_or_neg_inf(logdensity_fn(position))

    def step(rng_key: Array, state: DRAMState) -> tuple[DRAMState, DRAMInfo]:
        normals, log_uniforms = _draws(rng_key, state.position, region)
        run = paired_stages if paired else staged
        stages = run(logdensity, state.position, state.logdensity, state.chol, normals,
                     log_uniforms, stage_scales, num_stages, algebra, region)
        finish = region(functools.partial(_finish, settings=settings, algebra=algebra))
        return finish(state, stages)

    return step


def _draws(rng_key: Array, x: Array, region: Region) -> tuple[Array, Array]:
    """The step's two standard normal vectors and the logs of its two uniforms (a region
    takes arrays only: the key goes in as its data and is rebuilt inside, same bits)."""
    impl = jax.random.key_impl(rng_key)

    def draw(key_data: Array) -> tuple[Array, Array]:
        key = jax.random.wrap_key_data(key_data, impl=impl)
        key1, key_u1, key2, key_u2 = jax.random.split(key, 4)
        normals = jnp.stack([jax.random.normal(key1, x.shape, dtype=x.dtype),
                             jax.random.normal(key2, x.shape, dtype=x.dtype)])
        log_uniforms = jnp.log(jnp.stack([jax.random.uniform(key_u1, dtype=x.dtype),
                                          jax.random.uniform(key_u2, dtype=x.dtype)]))
        return normals, log_uniforms

    return region(draw)(jax.random.key_data(rng_key))


def _finish(state: DRAMState, stages: Stages, settings: DRAMSettings,
            algebra: Algebra) -> tuple[DRAMState, DRAMInfo]:
    """The move the stages decided, the adaptive-Metropolis update and the step's info."""
    x, logdensity_x, chol = state.position, state.logdensity, state.chol
    dim = x.shape[0]
    accept1 = stages.accepted & (stages.stage == 1)
    accept2 = stages.accepted & (stages.stage == 2)
    last = stages.stage - 1
    new_position = jnp.where(stages.accepted, stages.proposals[last], x)
    new_logdensity = jnp.where(stages.accepted, stages.logdensities[last], logdensity_x)

    # Adaptive Metropolis: running moments, then the proposal for the next step.
    mean, cov, count = _update_moments(state, new_position)
    iteration = state.iteration + 1
    adapting = count >= settings.adapt_start
    if settings.adapt_stop is not None:
        adapting = adapting & (iteration < settings.adapt_stop)
    candidate = _proposal_chol(cov, state.nugget, settings.resolved_scale(dim), algebra)
    usable = adapting & jnp.all(jnp.isfinite(candidate))
    new_chol = jnp.where(usable, candidate, chol)

    new_state = DRAMState(
        position=new_position,
        logdensity=new_logdensity,
        mean=mean,
        cov=cov,
        count=count,
        iteration=iteration,
        chol=new_chol,
        nugget=state.nugget,
    )
    info = DRAMInfo(
        is_accepted=accept1 | accept2,
        stage1_accepted=accept1,
        stage2_attempted=stages.stage == 2,
        stage2_accepted=accept2,
        acceptance_rate1=jnp.exp(stages.log_alphas[0]),
        acceptance_rate2=jnp.exp(stages.log_alphas[1]),
        proposal1=stages.proposals[0],
        proposal2=stages.proposals[1],
        logdensity=new_logdensity,
    )
    return new_state, info
