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
arithmetic (:mod:`symplid.filters.linalg`) instead of LAPACK calls and ``dot``: without a
custom call or ``dot`` in its body, XLA:CPU compiles a whole chunk of iterations as one kernel
(see :func:`symplid.runtime.configure_xla`). The results equal LAPACK's to rounding (1e-12).
Where the log density is a custom call (the compiled likelihood), XLA runs the chunk operation
by operation anyway, and LAPACK's fewer, larger calls are cheaper (``linalg = "lapack"``); and
a backend that evaluates a batch for little more than one point gets both stages' proposals
in one call (``paired_stages``; stage 2's value is used only when stage 1 rejects, so the
chain is the same to rounding). :func:`~.registry.resolve_dram` picks both per run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from symplid.filters import linalg
from symplid.filters.linalg import MAX_UNROLLED_DIM

Array = jax.Array
LogDensityFn = Callable[[Array], Array]
VARIANCE_SCALES = ("natural", "log")
"""Choices of :attr:`DRAMSettings.variance_scale`."""
LINALG_CHOICES = ("unrolled", "lapack")
"""Choices of :attr:`DRAMSettings.linalg`."""


class Algebra(NamedTuple):
    """The kernel's small linear algebra: proposal factor, triangular solve, ``L z``."""

    cholesky: Callable[[Array], Array]
    solve_lower: Callable[[Array, Array], Array]
    matmul: Callable[[Array, Array], Array]


#: Unrolled small-matrix arithmetic: XLA:CPU compiles a chunk around it as one kernel.
UNROLLED = Algebra(
    lambda a: linalg.cholesky(a, MAX_UNROLLED_DIM),
    lambda chol, b: linalg.solve_lower(chol, b, MAX_UNROLLED_DIM),
    linalg.matmul,
)
#: LAPACK and ``dot``: fewer, larger operations, for a chunk that XLA cannot compile as one
#: kernel anyway (a log density that is a custom call, such as the compiled likelihood).
LAPACK = Algebra(
    jnp.linalg.cholesky,
    lambda chol, b: jax.scipy.linalg.solve_triangular(chol, b, lower=True),
    jnp.matmul,
)

__all__ = [
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
        (:func:`~.registry.build_dram`), so a variance whose posterior is piled against its
        floor is no longer a wall that rejects half the proposals. ``"natural"``: the chain
        moves in θ itself (the paper's). On the paper's data (4 chains × 12,000 iterations)
        the log scale raised the smallest ESS from 121 to 263 (leapfrog) and 341 to 468
        (RK2), R-hat 1.056 → 1.034 and 1.020 → 1.011, with the same process-noise medians.
    paired_stages
        ``True``: both stages' proposals are drawn and evaluated in one batched call, stage
        2's value used only when stage 1 rejects (the same chain, draw for draw, as
        ``False``, where stage 2 is evaluated only when needed). Pays where a batch costs
        little more than one point: four vectorised chains make a batch of eight, which the
        compiled kernel evaluates 2.3 times faster than two batches of four.
        ``None`` (default): :func:`~symplid.inference.samplers.sample` decides from the
        chains and the likelihood backend (:func:`~.registry.resolve_dram`).
    linalg
        ``"unrolled"``: the proposal's Cholesky factor, triangular solve and ``L z`` as
        unrolled small-matrix arithmetic, which lets XLA:CPU compile a whole chunk of
        iterations as one kernel; ``"lapack"``: library calls, cheaper where the log density
        is a custom call (the compiled likelihood), around which XLA runs every operation of
        the chunk separately (four vectorised chains with paired stages on the paper's
        posterior: 108 → 73 µs per iteration). The same numbers to rounding. ``None``
        (default): decided by :func:`~.registry.resolve_dram` (unrolled when the backend is
        unknown).
    """

    adapt_start: int = 200
    adapt_stop: int | None = None
    scale: float | None = None
    initial_scale: float | None = None
    nugget: float = 1e-10
    gamma: float = 0.01
    delayed_rejection: bool = True
    variance_scale: str = "log"
    paired_stages: bool | None = None
    linalg: str | None = None

    def __post_init__(self) -> None:
        if self.variance_scale not in VARIANCE_SCALES:
            raise ValueError(
                f"variance_scale must be one of {', '.join(map(repr, VARIANCE_SCALES))}, "
                f"got {self.variance_scale!r}"
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


def log1mexp(a: Array) -> Array:
    """``log(1 − exp(a))`` for ``a ≤ 0``, accurate in both tails.

    Uses ``log(−expm1(a))`` for ``a > −log 2`` and ``log1p(−exp(a))`` otherwise
    (Mächler 2012); ``log1mexp(0) = −∞`` and ``log1mexp(−∞) = 0``.
    """
    a = jnp.minimum(a, 0.0)
    near_zero = a > -math.log(2.0)
    safe_near = jnp.where(near_zero, a, -1.0)
    safe_far = jnp.where(near_zero, -1.0, a)
    return jnp.where(near_zero, jnp.log(-jnp.expm1(safe_near)), jnp.log1p(-jnp.exp(safe_far)))


def _finite_or_neg_inf(logdensity: Array) -> Array:
    logdensity = jnp.asarray(logdensity)
    return jnp.where(jnp.isfinite(logdensity), logdensity, -jnp.inf)


def _log_alpha1(logdensity_from: Array, logdensity_to: Array) -> Array:
    """``log α1(from, to) = min(0, log π(to) − log π(from))``, −∞ when ``to`` is invalid."""
    diff = jnp.where(jnp.isfinite(logdensity_to), logdensity_to - logdensity_from, -jnp.inf)
    return jnp.minimum(0.0, diff)


def _log_q1(chol: Array, start: Array, end: Array, algebra: Algebra = UNROLLED) -> Array:
    """Log density of the stage-1 proposal ``N(end; start, L Lᵀ)`` up to its constant."""
    white = algebra.solve_lower(chol, end - start)
    return -0.5 * jnp.sum(white**2)


def stage2_log_acceptance(
    x: Array,
    logdensity_x: Array,
    y1: Array,
    logdensity_y1: Array,
    y2: Array,
    logdensity_y2: Array,
    chol: Array,
    algebra: Algebra = UNROLLED,
) -> Array:
    """Log of the second-stage acceptance probability α2(x, y1, y2).

    Parameters
    ----------
    x, logdensity_x
        Current point and its (finite) log density.
    y1, logdensity_y1
        Rejected first-stage proposal and its log density (may be −∞).
    y2, logdensity_y2
        Second-stage proposal and its log density (may be −∞ or NaN).
    chol
        Lower Cholesky factor of the first-stage proposal covariance ``C``.
    algebra
        :data:`UNROLLED` or :data:`LAPACK` (the same numbers to rounding).

    Returns
    -------
    Array
        ``log α2 ≤ 0``; −∞ when ``y2`` has a non-finite log density or when
        ``π(y1) ≥ π(y2)`` (then ``1 − α1(y2, y1) = 0``). Never NaN.
    """
    logdensity_y1 = _finite_or_neg_inf(logdensity_y1)
    logdensity_y2 = _finite_or_neg_inf(logdensity_y2)
    y2_valid = jnp.isfinite(logdensity_y2)
    safe_y2 = jnp.where(y2_valid, logdensity_y2, logdensity_x)
    numerator = (
        safe_y2
        + _log_q1(chol, y2, y1, algebra)
        + log1mexp(_log_alpha1(safe_y2, logdensity_y1))
    )
    denominator = (
        logdensity_x
        + _log_q1(chol, x, y1, algebra)
        + log1mexp(_log_alpha1(logdensity_x, logdensity_y1))
    )
    log_ratio = numerator - denominator
    log_ratio = jnp.where(jnp.isnan(log_ratio), -jnp.inf, log_ratio)
    return jnp.where(y2_valid, jnp.minimum(0.0, log_ratio), -jnp.inf)


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
    logdensity = _finite_or_neg_inf(logdensity)
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


class _Stages(NamedTuple):
    """Carry of the delayed-rejection loop (index 0: stage 1, index 1: stage 2)."""

    stage: Array
    accepted: Array
    proposals: Array
    logdensities: Array
    log_alphas: Array


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
    stage_scales = jnp.array([1.0, math.sqrt(settings.gamma)])

    def logdensity(position: Array) -> Array:
        return _finite_or_neg_inf(logdensity_fn(position))

    def step(rng_key: Array, state: DRAMState) -> tuple[DRAMState, DRAMInfo]:
        x = state.position
        dim = x.shape[0]
        key1, key_u1, key2, key_u2 = jax.random.split(rng_key, 4)
        normals = jnp.stack([jax.random.normal(key1, (dim,), dtype=x.dtype),
                             jax.random.normal(key2, (dim,), dtype=x.dtype)])
        log_uniforms = jnp.log(jnp.stack([jax.random.uniform(key_u1, dtype=x.dtype),
                                          jax.random.uniform(key_u2, dtype=x.dtype)]))
        run = _paired_stages if paired else _staged
        stages = run(logdensity, state, normals, log_uniforms, stage_scales, num_stages, algebra)
        return _finish(state, stages, settings, algebra)

    return step


def _staged(logdensity: LogDensityFn, state: DRAMState, normals: Array, log_uniforms: Array,
            stage_scales: Array, num_stages: int, algebra: Algebra) -> _Stages:
    """The stages in a loop with one call site of the log density, so that it is compiled
    once (an expensive filter would otherwise be compiled twice), and stage 2 runs only when
    stage 1 rejects. Stage 1: y1 ~ N(x, C); stage 2: y2 ~ N(x, γ C)."""
    x, logdensity_x, chol = state.position, state.logdensity, state.chol

    def keep_going(carry: _Stages) -> Array:
        return (carry.stage < num_stages) & jnp.logical_not(carry.accepted)

    def one_stage(carry: _Stages) -> _Stages:
        s = carry.stage
        y = x + stage_scales[s] * algebra.matmul(chol, normals[s])
        logdensity_y = logdensity(y)
        log_alpha = jnp.where(
            s == 0,
            _log_alpha1(logdensity_x, logdensity_y),
            stage2_log_acceptance(x, logdensity_x, carry.proposals[0],
                                  carry.logdensities[0], y, logdensity_y, chol, algebra),
        )
        return _Stages(
            stage=s + 1,
            accepted=log_uniforms[s] < log_alpha,
            proposals=carry.proposals.at[s].set(y),
            logdensities=carry.logdensities.at[s].set(logdensity_y),
            log_alphas=carry.log_alphas.at[s].set(log_alpha),
        )

    start = _Stages(
        stage=jnp.asarray(0, dtype=jnp.int32),
        accepted=jnp.asarray(False),
        proposals=jnp.stack([x, x]),
        logdensities=jnp.stack([logdensity_x, logdensity_x]),
        log_alphas=jnp.full((2,), -jnp.inf, dtype=x.dtype),
    )
    return lax.while_loop(keep_going, one_stage, start)


def _paired_stages(logdensity: LogDensityFn, state: DRAMState, normals: Array,
                   log_uniforms: Array, stage_scales: Array, num_stages: int,
                   algebra: Algebra) -> _Stages:
    """Both proposals drawn and evaluated in one batched call (a batch of two; of 2 × chains
    when the chains are vectorized), then judged as :func:`_staged` judges them: stage 2's
    value is used only when stage 1 rejects, so the chain is the same to rounding. For a
    likelihood backend that evaluates a batch for little more than one point
    (``LikelihoodBackend.batch_width``)."""
    x, logdensity_x, chol = state.position, state.logdensity, state.chol
    y = jnp.stack([x + stage_scales[s] * algebra.matmul(chol, normals[s]) for s in range(2)])
    values = jax.vmap(logdensity)(y)
    log_alpha1 = _log_alpha1(logdensity_x, values[0])
    accept1 = log_uniforms[0] < log_alpha1
    log_alpha2 = stage2_log_acceptance(x, logdensity_x, y[0], values[0], y[1], values[1], chol,
                                       algebra)
    accept2 = jnp.logical_not(accept1) & (log_uniforms[1] < log_alpha2)
    return _Stages(
        stage=jnp.where(accept1, 1, 2).astype(jnp.int32),
        accepted=accept1 | accept2,
        proposals=jnp.stack([y[0], jnp.where(accept1, x, y[1])]),
        logdensities=jnp.stack([values[0], jnp.where(accept1, logdensity_x, values[1])]),
        log_alphas=jnp.stack([log_alpha1, jnp.where(accept1, -jnp.inf, log_alpha2)]),
    )


def _finish(state: DRAMState, stages: _Stages, settings: DRAMSettings,
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
